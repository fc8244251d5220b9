#include "tools/scene_views.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "pbgi/status.h"

namespace pbgi::tools {

absl::StatusOr<std::shared_ptr<const Scene>> LoadScene(const std::string& spec, uint64_t seed,
                                                       int size) {
  for (const std::string& name : ProceduralSceneNames()) {
    if (name == spec) {
      SceneOptions options;
      options.seed = seed;
      options.size = size;
      PBGI_ASSIGN_OR_RETURN(Scene scene, MakeScene(spec, options));
      return std::make_shared<const Scene>(std::move(scene));
    }
  }
  if (!std::filesystem::exists(spec)) {
    std::string names;
    for (const std::string& n : ProceduralSceneNames()) names += (names.empty() ? "" : ", ") + n;
    return absl::NotFoundError(absl::StrFormat(
        "'%s' is neither a procedural scene (%s) nor an existing mesh file", spec, names));
  }
  ImportReport report;
  PBGI_ASSIGN_OR_RETURN(Scene scene, ImportMesh(spec, &report));
  return std::make_shared<const Scene>(std::move(scene));
}

Camera DefaultCamera(const Scene& scene, int width, int height) {
  Camera c;
  c.width = width;
  c.height = height;
  c.up = glm::vec3(0.0f, 0.0f, 1.0f);
  if (scene.name == "cornell") {
    c.eye = glm::vec3(0.5f, -1.35f, 0.5f);
    c.look_at = glm::vec3(0.5f, 0.5f, 0.5f);
    c.fov_y_degrees = 40.0f;
    return c;
  }
  const Bounds b = scene.ComputeBounds();
  const glm::vec3 center = b.Center();
  const glm::vec3 ext = b.Extent();
  if (scene.name == "city") {
    // An oblique view over downtown, low enough to see walls bleed colour into the streets.
    const float half = 0.5f * std::max(ext.x, ext.y);
    c.eye = center + glm::vec3(-0.28f * half, -0.42f * half, 0.16f * half);
    c.look_at = glm::vec3(center.x + 0.02f * half, center.y + 0.04f * half, 0.0f);
    c.fov_y_degrees = 50.0f;
    return c;
  }
  const float diag = glm::length(ext);
  c.eye = center + diag * glm::vec3(-0.45f, -0.9f, 0.55f);
  c.look_at = center;
  c.fov_y_degrees = 45.0f;
  return c;
}

absl::StatusOr<glm::vec3> ParseVec3(const std::string& text) {
  std::vector<std::string> parts = absl::StrSplit(text, ',');
  glm::vec3 v(0.0f);
  if (parts.size() != 3) {
    return absl::InvalidArgumentError(absl::StrFormat("'%s' is not X,Y,Z", text));
  }
  for (int i = 0; i < 3; ++i) {
    float f = 0;
    if (!absl::SimpleAtof(parts[i], &f) || !std::isfinite(f)) {
      return absl::InvalidArgumentError(absl::StrFormat("'%s' is not X,Y,Z", text));
    }
    v[i] = f;
  }
  return v;
}

std::vector<ShadeReceiver> ShadeReceiversOf(absl::Span<const Receiver> receivers) {
  std::vector<ShadeReceiver> out(receivers.size());
  for (size_t i = 0; i < receivers.size(); ++i) {
    out[i] = {receivers[i].position, receivers[i].normal, receivers[i].normal};
  }
  return out;
}

CameraReceivers MakeCameraReceivers(const Tracer& tracer, const Camera& camera) {
  CameraReceivers out;
  out.width = camera.width;
  out.height = camera.height;
  out.hits = tracer.TraceCamera(camera);
  out.receivers.reserve(out.hits.size());
  for (size_t p = 0; p < out.hits.size(); ++p) {
    if (!out.hits[p].hit) continue;
    const int x = static_cast<int>(p % size_t(camera.width));
    const int y = static_cast<int>(p / size_t(camera.width));
    const glm::vec3 d = camera.Direction(float(x) + 0.5f, float(y) + 0.5f);
    glm::vec3 n = out.hits[p].normal;
    if (glm::dot(n, d) > 0.0f) n = -n;  // shade the side the camera sees
    // A hair above the surface, so that the receiver's own surfels are behind its plane.
    const glm::vec3 p_lifted = out.hits[p].position + tracer.epsilon() * n;
    out.receivers.push_back({p_lifted, n});
    out.shade.push_back({p_lifted, n, glm::reflect(d, n)});
    out.pixel_of.push_back(static_cast<uint32_t>(p));
    out.surface.push_back(out.hits[p].material);
  }
  return out;
}

ShadeOptions CameraReceivers::WithLayout(const ShadeOptions& options) const {
  ShadeOptions o = options;
  o.sharing.image.width = width;
  o.sharing.image.height = height;
  o.sharing.image.pixel_of = pixel_of;
  o.sharing.image.surface_id = surface;
  return o;
}

absl::StatusOr<ViewImages> RenderView(const Tracer& tracer, Database& db, const Camera& camera,
                                      const ShadeOptions& options) {
  using Clock = std::chrono::steady_clock;
  const Scene& scene = tracer.scene();
  ViewImages out;
  out.occlusion = Image(camera.width, camera.height);
  out.indirect = Image(camera.width, camera.height);
  out.direct = Image(camera.width, camera.height);
  out.composite = Image(camera.width, camera.height);

  const auto t0 = Clock::now();
  const CameraReceivers cr = MakeCameraReceivers(tracer, camera);
  const std::vector<CameraHit>& hits = cr.hits;
  const std::vector<Receiver>& receivers = cr.receivers;
  const std::vector<uint32_t>& pixel_of = cr.pixel_of;
  out.trace_seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  out.receivers = receivers.size();

  std::vector<ShadeResult> results(receivers.size());
  PBGI_RETURN_IF_ERROR(
      ShadeBatch(db, cr.shade, cr.WithLayout(options), absl::MakeSpan(results), &out.shade));

  const bool radiance = HasRadiance(db.meta().channels);
  const glm::vec3 sky = scene.lights.sky;
  for (size_t p = 0; p < hits.size(); ++p) {
    if (!hits[p].hit) {
      out.composite.pixels[p] = sky;
      out.direct.pixels[p] = sky;
      out.occlusion.pixels[p] = glm::vec3(1.0f);
    }
  }
  for (size_t i = 0; i < receivers.size(); ++i) {
    const uint32_t p = pixel_of[i];
    const CameraHit& h = hits[p];
    const Material& m = scene.materials[std::min<size_t>(h.material, scene.materials.size() - 1)];
    const ShadeResult& r = results[i];
    const glm::vec3 direct =
        tracer.SurfaceRadiance(receivers[i].position, receivers[i].normal, h.material, p);
    const float open = 1.0f - std::clamp(r.occlusion, 0.0f, 1.0f);
    out.occlusion.pixels[p] = glm::vec3(open);
    out.direct.pixels[p] = direct;
    if (radiance) {
      out.indirect.pixels[p] = m.albedo * r.irradiance * float(1.0 / sh::kPi);
      out.composite.pixels[p] = direct + out.indirect.pixels[p];
    } else {
      // Occlusion only: an ambient term from the sky, dimmed by the occlusion.
      out.composite.pixels[p] = direct + m.albedo * sky * open;
    }
  }
  return out;
}

}  // namespace pbgi::tools
