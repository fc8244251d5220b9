// Procedural scenes: deterministic from a seed, compact (instanced boxes and trees), so that the
// sampler's density, not the triangle count, sets the number of surfels.
#include <algorithm>
#include <cmath>

#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "glm/gtc/matrix_transform.hpp"
#include "pbgi/scene.h"
#include "scene/sample_math.h"

namespace pbgi {
namespace {

using internal::kPiFloat;

// A small deterministic generator for scene layout (not for sampling).
class Rng {
 public:
  explicit Rng(uint64_t seed) : state_(internal::Mix64(seed)) {}
  float Uniform() { return internal::ToUnitFloat(internal::Mix64(state_++)); }
  float Uniform(float lo, float hi) { return lo + (hi - lo) * Uniform(); }
  int Int(int lo, int hi) {  // inclusive
    return std::min(hi, lo + static_cast<int>(Uniform() * static_cast<float>(hi - lo + 1)));
  }
  float Normal() {
    float u1 = std::max(Uniform(), 1e-7f), u2 = Uniform();
    return std::sqrt(-2.0f * std::log(u1)) * std::cos(2.0f * kPiFloat * u2);
  }

 private:
  uint64_t state_;
};

uint32_t AddMaterial(Scene* s, glm::vec3 albedo, glm::vec3 emission = glm::vec3(0.0f)) {
  s->materials.push_back({albedo, emission});
  return static_cast<uint32_t>(s->materials.size() - 1);
}

// Adds triangle (a, b, c) turned so that its normal points along `facing`; skips it when it
// has no area.
void AddTriangle(Mesh* m, glm::vec3 a, glm::vec3 b, glm::vec3 c, glm::vec3 facing,
                 uint32_t material) {
  glm::vec3 n = glm::cross(b - a, c - a);
  if (!(glm::dot(n, n) > 0.0f)) return;
  if (glm::dot(n, facing) < 0.0f) std::swap(b, c);
  uint32_t base = static_cast<uint32_t>(m->positions.size());
  m->positions.insert(m->positions.end(), {a, b, c});
  m->triangles.emplace_back(base, base + 1, base + 2);
  m->materials.push_back(material);
}

// A planar quad p0 p1 p2 p3 (in order around it) facing `facing`.
void AddQuad(Mesh* m, glm::vec3 p0, glm::vec3 p1, glm::vec3 p2, glm::vec3 p3, glm::vec3 facing,
             uint32_t material) {
  AddTriangle(m, p0, p1, p2, facing, material);
  AddTriangle(m, p0, p2, p3, facing, material);
}

// The faces of the box [lo, hi] mapped by `xf`, facing out (or in). `skip_bottom` leaves out
// the face at z = lo.z (buildings stand on the ground).
void AddBox(Mesh* m, glm::vec3 lo, glm::vec3 hi, const glm::mat4& xf, uint32_t material,
            bool inward = false, bool skip_bottom = false) {
  glm::vec3 center = internal::TransformPoint(xf, 0.5f * (lo + hi));
  for (int axis = 0; axis < 3; ++axis) {
    for (int side = 0; side < 2; ++side) {
      if (skip_bottom && axis == 2 && side == 0) continue;
      int u = (axis + 1) % 3, v = (axis + 2) % 3;
      glm::vec3 corner[4];
      for (int k = 0; k < 4; ++k) {
        glm::vec3 p;
        p[axis] = side ? hi[axis] : lo[axis];
        p[u] = (k == 1 || k == 2) ? hi[u] : lo[u];
        p[v] = (k >= 2) ? hi[v] : lo[v];
        corner[k] = internal::TransformPoint(xf, p);
      }
      glm::vec3 face_center = 0.25f * (corner[0] + corner[1] + corner[2] + corner[3]);
      glm::vec3 out = face_center - center;
      AddQuad(m, corner[0], corner[1], corner[2], corner[3], inward ? -out : out, material);
    }
  }
}

// A latitude-longitude sphere facing out (degenerate pole triangles are skipped).
void AddSphere(Mesh* m, glm::vec3 center, float radius, int rings, int segments,
               uint32_t material) {
  auto point = [&](int i, int j) {
    float theta = kPiFloat * static_cast<float>(i) / static_cast<float>(rings);
    float phi = 2.0f * kPiFloat * static_cast<float>(j % segments) / static_cast<float>(segments);
    return center + radius * glm::vec3(std::sin(theta) * std::cos(phi),
                                       std::sin(theta) * std::sin(phi), std::cos(theta));
  };
  for (int i = 0; i < rings; ++i) {
    for (int j = 0; j < segments; ++j) {
      glm::vec3 a = point(i, j), b = point(i + 1, j), c = point(i + 1, j + 1), d = point(i, j + 1);
      glm::vec3 out = 0.25f * (a + b + c + d) - center;
      AddTriangle(m, a, b, c, out, material);
      AddTriangle(m, a, c, d, out, material);
    }
  }
}

void AddSingleInstance(Scene* s, Mesh mesh) {
  s->meshes.push_back(std::move(mesh));
  s->instances.push_back({static_cast<uint32_t>(s->meshes.size() - 1), glm::mat4(1.0f), -1});
}

glm::mat4 Place(glm::vec3 translate, float rotate_z, glm::vec3 scale) {
  glm::mat4 m = glm::translate(glm::mat4(1.0f), translate);
  m = glm::rotate(m, rotate_z, glm::vec3(0.0f, 0.0f, 1.0f));
  return glm::scale(m, scale);
}

}  // namespace

Scene MakeCornellScene(const SceneOptions& options) {
  Scene s;
  s.name = "cornell";
  uint32_t white = AddMaterial(&s, glm::vec3(0.73f));
  uint32_t red = AddMaterial(&s, glm::vec3(0.63f, 0.065f, 0.05f));
  uint32_t green = AddMaterial(&s, glm::vec3(0.14f, 0.45f, 0.091f));
  uint32_t light = AddMaterial(&s, glm::vec3(0.78f), glm::vec3(17.0f, 12.0f, 4.0f));
  Mesh m;
  const glm::vec3 o(0.0f), x(1.0f, 0.0f, 0.0f), y(0.0f, 1.0f, 0.0f), z(0.0f, 0.0f, 1.0f);
  AddQuad(&m, o, x, x + y, y, z, white);               // floor
  AddQuad(&m, z, z + x, z + x + y, z + y, -z, white);  // ceiling
  AddQuad(&m, y, y + x, y + x + z, y + z, -y, white);  // back wall
  AddQuad(&m, o, y, y + z, z, x, red);                 // left wall
  AddQuad(&m, x, x + y, x + y + z, x + z, -x, green);  // right wall
  const float lz = 0.998f;                             // the light, just under the ceiling
  AddQuad(&m, {0.4f, 0.4f, lz}, {0.6f, 0.4f, lz}, {0.6f, 0.6f, lz}, {0.4f, 0.6f, lz}, -z, light);
  // Two blocks; the seed turns them a little.
  Rng rng(options.seed);
  float tall_angle = glm::radians(17.0f + rng.Uniform(-5.0f, 5.0f));
  float short_angle = glm::radians(-17.0f + rng.Uniform(-5.0f, 5.0f));
  AddBox(&m, {-0.15f, -0.15f, 0.0f}, {0.15f, 0.15f, 0.6f},
         Place({0.33f, 0.62f, 0.0f}, tall_angle, glm::vec3(1.0f)), white, false, true);
  AddBox(&m, {-0.15f, -0.15f, 0.0f}, {0.15f, 0.15f, 0.3f},
         Place({0.67f, 0.33f, 0.0f}, short_angle, glm::vec3(1.0f)), white, false, true);
  AddSingleInstance(&s, std::move(m));
  s.lights.area_light_samples = 8;
  return s;
}

Scene MakeCityScene(const SceneOptions& options) {
  Scene s;
  s.name = "city";
  const int blocks = options.size > 0 ? options.size : 16;
  const float pitch = 100.0f, street = 20.0f;
  Rng rng(options.seed);
  uint32_t ground = AddMaterial(&s, glm::vec3(0.25f));
  const glm::vec3 palette[] = {{0.75f, 0.72f, 0.66f}, {0.62f, 0.55f, 0.48f}, {0.55f, 0.6f, 0.65f},
                               {0.8f, 0.78f, 0.75f},  {0.7f, 0.45f, 0.35f},  {0.45f, 0.5f, 0.45f},
                               {0.85f, 0.82f, 0.6f},  {0.5f, 0.52f, 0.58f}};
  const uint32_t first_color = static_cast<uint32_t>(s.materials.size());
  for (const glm::vec3& c : palette) AddMaterial(&s, c);
  const float half = 0.5f * pitch * static_cast<float>(blocks);
  const float margin = pitch;
  Mesh ground_mesh;
  AddQuad(&ground_mesh, {-half - margin, -half - margin, 0.0f},
          {half + margin, -half - margin, 0.0f}, {half + margin, half + margin, 0.0f},
          {-half - margin, half + margin, 0.0f}, {0.0f, 0.0f, 1.0f}, ground);
  AddSingleInstance(&s, std::move(ground_mesh));
  // One unit box (footprint [-0.5,0.5]^2, height [0,1], no bottom) instanced for every building
  // and every tower on a roof.
  Mesh box;
  AddBox(&box, {-0.5f, -0.5f, 0.0f}, {0.5f, 0.5f, 1.0f}, glm::mat4(1.0f), 0, false, true);
  s.meshes.push_back(std::move(box));
  const uint32_t box_mesh = static_cast<uint32_t>(s.meshes.size() - 1);
  auto building = [&](glm::vec3 base, float sx, float sy, float h, uint32_t material) {
    s.instances.push_back(
        {box_mesh, Place(base, 0.0f, glm::vec3(sx, sy, h)), static_cast<int32_t>(material)});
  };
  for (int bx = 0; bx < blocks; ++bx) {
    for (int by = 0; by < blocks; ++by) {
      const float x0 = -half + pitch * static_cast<float>(bx) + 0.5f * street;
      const float y0 = -half + pitch * static_cast<float>(by) + 0.5f * street;
      const float size = pitch - street;
      // Downtown is taller: heights fall off with the distance from the center.
      const float cx = x0 + 0.5f * size, cy = y0 + 0.5f * size;
      const float falloff = std::exp(-(cx * cx + cy * cy) / (0.5f * half * half + 1.0f));
      const int lots = rng.Int(1, 3);
      const float lot = size / static_cast<float>(lots);
      for (int i = 0; i < lots; ++i) {
        for (int j = 0; j < lots; ++j) {
          const float setback = rng.Uniform(1.0f, 0.2f * lot);
          const float w = lot - 2.0f * setback * rng.Uniform(0.5f, 1.0f);
          const float d = lot - 2.0f * setback * rng.Uniform(0.5f, 1.0f);
          const float h =
              std::clamp(std::exp(2.6f + 0.5f * rng.Normal() + 1.6f * falloff), 4.0f, 250.0f);
          glm::vec3 c(x0 + lot * (static_cast<float>(i) + 0.5f),
                      y0 + lot * (static_cast<float>(j) + 0.5f), 0.0f);
          uint32_t mat = first_color + static_cast<uint32_t>(rng.Int(0, 7));
          building(c, w, d, h, mat);
          if (h > 30.0f && rng.Uniform() < 0.5f) {  // a tower on the roof
            float tw = w * rng.Uniform(0.3f, 0.7f), td = d * rng.Uniform(0.3f, 0.7f);
            building(c + glm::vec3(0.0f, 0.0f, h), tw, td, h * rng.Uniform(0.2f, 0.6f), mat);
          }
        }
      }
    }
  }
  s.lights.has_sun = true;
  s.lights.sun.direction = glm::normalize(glm::vec3(0.45f, -0.3f, 0.65f));
  s.lights.sun.radiance = glm::vec3(2.6f, 2.4f, 2.1f);
  s.lights.sky = glm::vec3(0.35f, 0.45f, 0.65f);
  s.lights.sky_rays = 4;
  return s;
}

Scene MakeForestScene(const SceneOptions& options) {
  Scene s;
  s.name = "forest";
  s.has_radiance = false;
  const int per_side = options.size > 0 ? options.size : 40;
  const float spacing = 4.0f;
  Rng rng(options.seed);
  uint32_t soil = AddMaterial(&s, glm::vec3(0.3f, 0.22f, 0.15f));
  uint32_t bark = AddMaterial(&s, glm::vec3(0.35f, 0.25f, 0.18f));
  uint32_t leaf = AddMaterial(&s, glm::vec3(0.2f, 0.45f, 0.15f));
  s.materials[leaf].thin = true;  // a leaf's back is its other side, not the inside of a solid
  const float half = 0.5f * spacing * static_cast<float>(per_side) + spacing;
  Mesh ground;
  AddQuad(&ground, {-half, -half, 0.0f}, {half, -half, 0.0f}, {half, half, 0.0f},
          {-half, half, 0.0f}, {0.0f, 0.0f, 1.0f}, soil);
  AddSingleInstance(&s, std::move(ground));
  // A few tree shapes: an octagonal trunk and a crown of leaf quads in an ellipsoid.
  const int kShapes = 4, kLeaves = 300, kSides = 8;
  const uint32_t first_tree = static_cast<uint32_t>(s.meshes.size());
  for (int shape = 0; shape < kShapes; ++shape) {
    Mesh tree;
    const float height = rng.Uniform(3.0f, 5.0f), radius = rng.Uniform(0.1f, 0.2f);
    for (int k = 0; k < kSides; ++k) {
      float a0 = 2.0f * kPiFloat * static_cast<float>(k) / kSides;
      float a1 = 2.0f * kPiFloat * static_cast<float>(k + 1) / kSides;
      glm::vec3 p0(radius * std::cos(a0), radius * std::sin(a0), 0.0f);
      glm::vec3 p1(radius * std::cos(a1), radius * std::sin(a1), 0.0f);
      glm::vec3 up(0.0f, 0.0f, height);
      AddQuad(&tree, p0, p1, p1 + up, p0 + up, 0.5f * (p0 + p1), bark);
    }
    const float crown_r = rng.Uniform(1.2f, 1.8f), crown_h = rng.Uniform(1.5f, 2.5f);
    const glm::vec3 crown_c(0.0f, 0.0f, height + 0.3f * crown_h);
    for (int l = 0; l < kLeaves; ++l) {
      glm::vec3 p;
      do {
        p = glm::vec3(rng.Uniform(-1.0f, 1.0f), rng.Uniform(-1.0f, 1.0f), rng.Uniform(-1.0f, 1.0f));
      } while (glm::dot(p, p) > 1.0f);
      p = crown_c + p * glm::vec3(crown_r, crown_r, crown_h);
      glm::vec3 n = glm::normalize(glm::vec3(rng.Normal(), rng.Normal(), rng.Normal() + 1e-3f));
      glm::vec3 t, b;
      internal::OrthonormalBasis(n, &t, &b);
      const float lw = 0.18f, lh = 0.12f;
      AddQuad(&tree, p - t * lw - b * lh, p + t * lw - b * lh, p + t * lw + b * lh,
              p - t * lw + b * lh, n, leaf);
    }
    s.meshes.push_back(std::move(tree));
  }
  for (int i = 0; i < per_side; ++i) {
    for (int j = 0; j < per_side; ++j) {
      glm::vec3 c(-half + spacing * (static_cast<float>(i) + 1.0f + rng.Uniform(-0.3f, 0.3f)),
                  -half + spacing * (static_cast<float>(j) + 1.0f + rng.Uniform(-0.3f, 0.3f)),
                  0.0f);
      uint32_t shape = first_tree + static_cast<uint32_t>(rng.Int(0, kShapes - 1));
      float scale = rng.Uniform(0.75f, 1.3f);
      s.instances.push_back(
          {shape, Place(c, rng.Uniform(0.0f, 2.0f * kPiFloat), glm::vec3(scale)), -1});
    }
  }
  s.lights.has_sun = true;
  s.lights.sun.direction = glm::normalize(glm::vec3(0.3f, 0.4f, 0.85f));
  s.lights.sun.radiance = glm::vec3(2.5f);
  s.lights.sky = glm::vec3(0.5f);
  return s;
}

Scene MakeDiskScene(float radius, int segments, glm::vec3 emission) {
  Scene s;
  s.name = "disk";
  uint32_t mat = AddMaterial(&s, glm::vec3(0.0f), emission);
  Mesh m;
  segments = std::max(segments, 3);
  for (int i = 0; i < segments; ++i) {
    float a0 = 2.0f * kPiFloat * static_cast<float>(i) / static_cast<float>(segments);
    float a1 = 2.0f * kPiFloat * static_cast<float>(i + 1) / static_cast<float>(segments);
    AddTriangle(&m, glm::vec3(0.0f), radius * glm::vec3(std::cos(a0), std::sin(a0), 0.0f),
                radius * glm::vec3(std::cos(a1), std::sin(a1), 0.0f), {0.0f, 0.0f, -1.0f}, mat);
  }
  AddSingleInstance(&s, std::move(m));
  return s;
}

Scene MakeSphereInBoxScene(const SceneOptions& options) {
  Scene s;
  s.name = "sphere-in-box";
  uint32_t wall = AddMaterial(&s, glm::vec3(0.5f));
  uint32_t glow = AddMaterial(&s, glm::vec3(0.0f), glm::vec3(1.0f));
  Mesh m;
  AddBox(&m, glm::vec3(-2.0f), glm::vec3(2.0f), glm::mat4(1.0f), wall, /*inward=*/true);
  AddSphere(&m, glm::vec3(0.0f), 0.5f, 48, 96, glow);
  AddSingleInstance(&s, std::move(m));
  s.lights.has_sun = true;
  s.lights.sun.direction = glm::normalize(glm::vec3(0.3f, 0.2f, 0.9f));
  s.lights.sun.radiance = glm::vec3(5.0f);
  s.lights.sky = glm::vec3(1.0f);
  s.lights.area_light_samples = 16;
  return s;
}

std::vector<std::string> ProceduralSceneNames() {
  return {"cornell", "city", "forest", "disk", "sphere-in-box"};
}

absl::StatusOr<Scene> MakeScene(absl::string_view name, const SceneOptions& options) {
  Scene s;
  if (name == "cornell") {
    s = MakeCornellScene(options);
  } else if (name == "city") {
    s = MakeCityScene(options);
  } else if (name == "forest") {
    s = MakeForestScene(options);
  } else if (name == "disk") {
    s = MakeDiskScene();
  } else if (name == "sphere-in-box") {
    s = MakeSphereInBoxScene(options);
  } else {
    return absl::NotFoundError(absl::StrFormat("no procedural scene named '%s' (known: %s)", name,
                                               absl::StrJoin(ProceduralSceneNames(), ", ")));
  }
  absl::Status valid = s.Validate();
  if (!valid.ok()) return valid;
  return s;
}

}  // namespace pbgi
