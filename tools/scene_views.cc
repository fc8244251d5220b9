#include "tools/scene_views.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <functional>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "base/tsan_region.h"
#include "oneapi/tbb/blocked_range.h"
#include "oneapi/tbb/parallel_for.h"
#include "pbgi/status.h"

namespace pbgi::tools {

absl::StatusOr<UpAxis> ParseUpAxis(const std::string& text) {
  if (text == "z" || text == "Z") return UpAxis::kZ;
  if (text == "y" || text == "Y") return UpAxis::kY;
  return absl::InvalidArgumentError(absl::StrFormat("--up %s: use y or z", text));
}

const char* UpAxisName(UpAxis up) { return up == UpAxis::kY ? "y" : "z"; }

void RotateYUpToZUp(Scene* scene) {
  // (x, y, z) -> (x, -z, y): +90 degrees about x.
  const glm::mat4 r(glm::vec4(1, 0, 0, 0), glm::vec4(0, 0, 1, 0), glm::vec4(0, -1, 0, 0),
                    glm::vec4(0, 0, 0, 1));
  for (Instance& i : scene->instances) i.transform = r * i.transform;
}

absl::StatusOr<bool> ParseOrient(const std::string& text) {
  if (text == "auto") return true;
  if (text == "none") return false;
  return absl::InvalidArgumentError(absl::StrFormat("--orient %s: use auto or none", text));
}

std::string DescribeOrientation(const OrientReport& r) {
  std::string s =
      absl::StrFormat("%d components: %d closed (outward", r.components, r.closed_components);
  if (r.cavities > 0) s += absl::StrFormat(", %d of them cavities facing in", r.cavities);
  s += absl::StrFormat("), %d open, %d non-manifold, %d non-orientable; %d triangles flipped, ",
                       r.open_components, r.non_manifold_components, r.non_orientable_components,
                       r.flipped_triangles);
  s += absl::StrFormat("%d marked thin (two-sided), %d vertices welded", r.thin_triangles,
                       r.welded_vertices);
  if (r.collapsed_triangles > 0) {
    s += absl::StrFormat(", %d slivers left as they were", r.collapsed_triangles);
  }
  if (r.nesting_unchecked > 0) {
    s += absl::StrFormat(", %d closed shells not tested for nesting (work budget): outward",
                         r.nesting_unchecked);
  }
  if (r.mixed_mirror_meshes > 0) {
    s += absl::StrFormat(", %d meshes placed both mirrored and not (outward where not mirrored)",
                         r.mixed_mirror_meshes);
  }
  return s;
}

absl::StatusOr<std::shared_ptr<const Scene>> LoadScene(const std::string& spec, uint64_t seed,
                                                       int size, UpAxis up, bool orient,
                                                       ImportReport* out_report) {
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
  ImportOptions options;
  options.orient = orient;
  PBGI_ASSIGN_OR_RETURN(Scene scene, ImportMesh(spec, options, &report));
  if (up == UpAxis::kY) RotateYUpToZUp(&scene);
  if (out_report != nullptr) *out_report = std::move(report);
  return std::make_shared<const Scene>(std::move(scene));
}

absl::StatusOr<std::shared_ptr<const Scene>> LoadLitScene(
    const std::string& spec, uint64_t seed, int size, UpAxis up, bool orient,
    const LightFlags& lights, const char* tool, ImportReport* report,
    const std::map<std::string, std::string>* recorded) {
  PBGI_ASSIGN_OR_RETURN(std::shared_ptr<const Scene> scene,
                        LoadScene(spec, seed, size, up, orient, report));
  const std::vector<std::string> names = ProceduralSceneNames();
  const bool mesh = std::find(names.begin(), names.end(), spec) == names.end();
  const bool given = !lights.sun.empty() || !lights.sky.empty();
  if (!mesh && !given) return scene;
  if (mesh && !given && recorded != nullptr && recorded->count("light.sky") != 0) {
    std::fprintf(stderr, "%s: %s lit by the lights recorded in the database\n", tool, spec.c_str());
    return WithRecordedLights(scene, *recorded);
  }
  auto lit = std::make_shared<Scene>(*scene);
  bool white_sky = false;
  PBGI_RETURN_IF_ERROR(ApplyLightFlags(lights, mesh, lit.get(), &white_sky));
  if (white_sky) {
    std::fprintf(stderr, "%s: %s brings no lights: lit by a white sky (--sun, --sky)\n", tool,
                 spec.c_str());
  }
  return std::shared_ptr<const Scene>(std::move(lit));
}

std::map<std::string, std::string> SceneFingerprint(const Scene& scene, uint64_t seed, int size,
                                                    UpAxis up, bool oriented) {
  // FNV-1a over the bits of every instanced triangle's world-space vertices: equal for the same
  // geometry, whatever options made it.
  uint64_t h = 1469598103934665603ull;
  auto mix = [&](float f) {
    uint32_t b;
    std::memcpy(&b, &f, 4);
    for (int k = 0; k < 4; ++k) {
      h ^= (b >> (8 * k)) & 0xff;
      h *= 1099511628211ull;
    }
  };
  for (const Instance& inst : scene.instances) {
    const Mesh& m = scene.meshes[inst.mesh];
    for (const glm::uvec3& t : m.triangles) {
      for (int k = 0; k < 3; ++k) {
        const glm::vec3 p = glm::vec3(inst.transform * glm::vec4(m.positions[t[k]], 1.0f));
        mix(p.x), mix(p.y), mix(p.z);
      }
    }
  }
  const Bounds b = scene.ComputeBounds();
  // One copy of the names: begin() and end() of two temporaries compared nothing (every mesh
  // was fingerprinted as a procedural scene, without its up axis).
  const std::vector<std::string> names = ProceduralSceneNames();
  const bool procedural = std::find(names.begin(), names.end(), scene.name) != names.end();
  std::map<std::string, std::string> f;
  f["scene.name"] = scene.name;
  if (procedural) {
    f["scene.seed"] = absl::StrFormat("%d", seed);
    f["scene.size"] = absl::StrFormat("%d", size);
  } else {
    f["scene.up"] = UpAxisName(up);
    f["scene.orient"] = oriented ? "auto" : "none";
  }
  f["scene.triangles"] = absl::StrFormat("%d", scene.TriangleCount());
  f["scene.bounds"] = absl::StrFormat("%.9g,%.9g,%.9g,%.9g,%.9g,%.9g", b.lo.x, b.lo.y, b.lo.z,
                                      b.hi.x, b.hi.y, b.hi.z);
  f["scene.geometry"] = absl::StrFormat("%016x", h);
  return f;
}

std::map<std::string, std::string> SpecFingerprint(const Scene& scene, const std::string& spec,
                                                   uint64_t seed, int size, UpAxis up,
                                                   bool oriented) {
  auto fingerprint = SceneFingerprint(scene, seed, size, up, oriented);
  if (fingerprint.count("scene.up") != 0) fingerprint["scene.file"] = spec;
  return fingerprint;
}

// "a,b,c" or "a,b,c,d,e,f" -> numbers; `what` names the option in errors.
static absl::StatusOr<std::vector<float>> ParseLightFloats(const std::string& text,
                                                           const char* what, size_t n1, size_t n2) {
  std::vector<float> v;
  for (absl::string_view part : absl::StrSplit(text, ',')) {
    float f = 0.0f;
    if (!absl::SimpleAtof(part, &f) || !std::isfinite(f)) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s: '%s' is not a number in '%s'", what, part, text));
    }
    v.push_back(f);
  }
  if (v.size() != n1 && v.size() != n2) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s wants %d or %d comma-separated numbers, got '%s'", what, n1, n2, text));
  }
  return v;
}

absl::Status ApplyLightFlags(const LightFlags& flags, bool mesh, Scene* scene, bool* defaulted) {
  if (defaulted != nullptr) *defaulted = false;
  if (!flags.sun.empty()) {
    PBGI_ASSIGN_OR_RETURN(std::vector<float> v, ParseLightFloats(flags.sun, "--sun", 3, 6));
    glm::vec3 d(v[0], v[1], v[2]);
    if (!(glm::length(d) > 0.0f)) return absl::InvalidArgumentError("--sun: zero direction");
    scene->lights.has_sun = true;
    scene->lights.sun.direction = glm::normalize(d);
    scene->lights.sun.radiance = v.size() == 6 ? glm::vec3(v[3], v[4], v[5]) : glm::vec3(1.0f);
  }
  if (!flags.sky.empty()) {
    PBGI_ASSIGN_OR_RETURN(std::vector<float> v, ParseLightFloats(flags.sky, "--sky", 3, 3));
    scene->lights.sky = glm::vec3(v[0], v[1], v[2]);
  }
  const bool given = !flags.sun.empty() || !flags.sky.empty();
  if (!given && mesh) {
    scene->lights.sky = glm::vec3(1.0f);
    if (defaulted != nullptr) *defaulted = true;
  }
  if (given || mesh) {
    if (flags.sky_rays < 1) {
      return absl::InvalidArgumentError(
          absl::StrFormat("--sky-rays %d: must be at least 1", flags.sky_rays));
    }
    scene->lights.sky_rays = flags.sky_rays;
  }
  return absl::OkStatus();
}

std::map<std::string, std::string> LightsProvenance(const Lights& lights) {
  std::map<std::string, std::string> f;
  if (lights.has_sun) {
    const Sun& s = lights.sun;
    f["light.sun"] = absl::StrFormat("%.9g,%.9g,%.9g,%.9g,%.9g,%.9g", s.direction.x, s.direction.y,
                                     s.direction.z, s.radiance.x, s.radiance.y, s.radiance.z);
  }
  f["light.sky"] = absl::StrFormat("%.9g,%.9g,%.9g", lights.sky.x, lights.sky.y, lights.sky.z);
  f["light.sky_rays"] = absl::StrFormat("%d", lights.sky_rays);
  return f;
}

std::shared_ptr<const Scene> WithRecordedLights(std::shared_ptr<const Scene> scene,
                                                const std::map<std::string, std::string>& stats) {
  const Lights& l = scene->lights;
  const bool unlit = !l.has_sun && l.sky == glm::vec3(0.0f);
  auto sky = stats.find("light.sky");
  if (!unlit || sky == stats.end()) return scene;
  auto floats = [](const std::string& text) {
    std::vector<float> v;
    for (absl::string_view part : absl::StrSplit(text, ',')) {
      float f = 0;
      if (absl::SimpleAtof(part, &f)) v.push_back(f);
    }
    return v;
  };
  auto lit = std::make_shared<Scene>(*scene);
  const std::vector<float> k = floats(sky->second);
  if (k.size() == 3) lit->lights.sky = glm::vec3(k[0], k[1], k[2]);
  if (auto sun = stats.find("light.sun"); sun != stats.end()) {
    const std::vector<float> v = floats(sun->second);
    if (v.size() == 6) {
      lit->lights.has_sun = true;
      lit->lights.sun.direction = glm::vec3(v[0], v[1], v[2]);
      lit->lights.sun.radiance = glm::vec3(v[3], v[4], v[5]);
    }
  }
  if (auto rays = stats.find("light.sky_rays"); rays != stats.end()) {
    int n = 0;
    if (absl::SimpleAtoi(rays->second, &n) && n > 0) lit->lights.sky_rays = n;
  }
  return lit;
}

namespace {

std::string Describe(const std::map<std::string, std::string>& f) {
  auto get = [&](const char* k) {
    auto it = f.find(k);
    return it == f.end() ? std::string() : it->second;
  };
  std::string s = "'" + get("scene.name") + "'";
  if (!get("scene.seed").empty()) s += " seed " + get("scene.seed");
  if (!get("scene.size").empty() && get("scene.size") != "0") s += " size " + get("scene.size");
  if (!get("scene.up").empty()) s += " up " + get("scene.up");
  if (!get("scene.orient").empty()) s += " orient " + get("scene.orient");
  if (!get("scene.file").empty()) s += " (file " + get("scene.file") + ")";
  s += ", " + get("scene.triangles") + " triangles";
  return s;
}

// The recorded fields in which the database and the view differ, as "field: database X, view
// Y"; the file (a path as typed) and the bounds (implied by the rest) are left out.
std::string Differences(const std::map<std::string, std::string>& db,
                        const std::map<std::string, std::string>& view) {
  std::vector<std::string> keys;
  for (const auto& [k, v] : db) keys.push_back(k);
  for (const auto& [k, v] : view) {
    if (db.count(k) == 0) keys.push_back(k);
  }
  std::string out;
  for (const std::string& k : keys) {
    if (k == "scene.file" || k == "scene.bounds" || k == "scene.geometry") continue;
    auto d = db.find(k);
    auto v = view.find(k);
    const std::string dv = d == db.end() ? "(none)" : d->second;
    const std::string vv = v == view.end() ? "(none)" : v->second;
    if (dv == vv) continue;
    // A database from before scene.orient was recorded: its meshes were not oriented.
    if (k == "scene.orient" && d == db.end()) continue;
    out +=
        absl::StrFormat("%s%s: database %s, view %s", out.empty() ? "" : "; ", k.substr(6), dv, vv);
  }
  if (out.empty()) {
    out =
        "only the geometry hash (the same name and triangle count, other vertices: another "
        "version of the file, or other import options)";
  }
  return out;
}

}  // namespace

absl::Status CheckSceneMatchesDatabase(const Scene& scene,
                                       const std::map<std::string, std::string>& fingerprint,
                                       const StoreMeta& meta, const std::string& db_path,
                                       std::string* warning) {
  warning->clear();
  auto built = meta.stats.find("scene.geometry");
  if (built != meta.stats.end()) {
    const auto name = meta.stats.find("scene.name");
    const auto tris = meta.stats.find("scene.triangles");
    const bool same = built->second == fingerprint.at("scene.geometry") &&
                      name != meta.stats.end() && name->second == fingerprint.at("scene.name") &&
                      tris != meta.stats.end() && tris->second == fingerprint.at("scene.triangles");
    if (same) return absl::OkStatus();
    std::map<std::string, std::string> db;
    for (const auto& [k, v] : meta.stats) {
      if (k.rfind("scene.", 0) == 0) db[k] = v;
    }
    std::string fix;
    if (db.count("scene.seed") != 0) {
      fix = absl::StrFormat("--scene %s --seed %s", db["scene.name"], db["scene.seed"]);
      if (db.count("scene.size") != 0 && db["scene.size"] != "0") {
        fix += " --size " + db["scene.size"];
      }
    } else {
      fix = absl::StrFormat("--scene %s%s%s",
                            db.count("scene.file") ? db["scene.file"] : db["scene.name"],
                            db["scene.up"] == "y" ? " --up y" : "",
                            db["scene.orient"] == "none" ? " --orient none" : "");
    }
    return absl::FailedPreconditionError(absl::StrFormat(
        "%s was built from scene %s, but the view is of scene %s (differs in %s): its surfels "
        "do not lie on this geometry and the image would be wrong. Shade the scene it was built "
        "from (%s), or pass --any-scene to shade anyway",
        db_path, Describe(db), Describe(fingerprint), Differences(db, fingerprint), fix));
  }
  // No fingerprint (points from elsewhere): compare the boxes, axis by axis, with a tolerance
  // of 2% of the scene's diagonal.
  const Bounds s = scene.ComputeBounds();
  const Bounds& d = meta.bounds;
  const float tol = 0.02f * glm::length(s.Extent());
  float worst = 1.0f;
  for (int a = 0; a < 3; ++a) {
    const float lo = std::max(s.lo[a], d.lo[a]), hi = std::min(s.hi[a], d.hi[a]);
    const float uni = std::max(s.hi[a], d.hi[a]) - std::min(s.lo[a], d.lo[a]);
    worst = std::min(worst, (std::max(0.0f, hi - lo) + tol) / (uni + tol));
  }
  if (worst < 0.8f) {
    *warning = absl::StrFormat(
        "%s holds no record of its scene, and its bounds (%g, %g, %g)..(%g, %g, %g) do not fit "
        "the scene's (%g, %g, %g)..(%g, %g, %g): the view may not be of the scene it was built "
        "from (wrong scene, --up or scale?)",
        db_path, d.lo.x, d.lo.y, d.lo.z, d.hi.x, d.hi.y, d.hi.z, s.lo.x, s.lo.y, s.lo.z, s.hi.x,
        s.hi.y, s.hi.z);
  }
  return absl::OkStatus();
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
    out[i] = {receivers[i].position, receivers[i].normal, receivers[i].normal, receivers[i].sheet};
  }
  return out;
}

CameraReceivers MakeCameraReceivers(const Tracer& tracer, const Camera& camera) {
  CameraReceivers out;
  out.width = camera.width;
  out.height = camera.height;
  out.hits = tracer.TraceCamera(camera);
  // Reserved for every hit, so that no vector grows to twice what it holds.
  size_t hit_count = 0;
  for (const CameraHit& h : out.hits) hit_count += h.hit ? 1 : 0;
  out.receivers.reserve(hit_count);
  out.shade.reserve(hit_count);
  out.pixel_of.reserve(hit_count);
  out.surface.reserve(hit_count);
  for (size_t p = 0; p < out.hits.size(); ++p) {
    if (!out.hits[p].hit) continue;
    const int x = static_cast<int>(p % size_t(camera.width));
    const int y = static_cast<int>(p / size_t(camera.width));
    const glm::vec3 d = camera.Direction(float(x) + 0.5f, float(y) + 0.5f);
    glm::vec3 n = out.hits[p].normal;
    if (glm::dot(n, d) > 0.0f) n = -n;  // shade the side the camera sees
    // A hair above the surface, so that the receiver's own surfels are behind its plane.
    const glm::vec3 p_lifted = out.hits[p].position + tracer.epsilon() * n;
    out.receivers.push_back({p_lifted, n, out.hits[p].sheet});
    out.shade.push_back({p_lifted, n, glm::reflect(d, n), out.hits[p].sheet});
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
                                      const ShadeOptions& options,
                                      const std::function<void()>& after_shading) {
  using Clock = std::chrono::steady_clock;
  const Scene& scene = tracer.scene();
  ViewImages out;

  const auto t0 = Clock::now();
  CameraReceivers cr = MakeCameraReceivers(tracer, camera);
  out.trace_seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  out.receivers = cr.receivers.size();
  // Memory: the page cache fills up during shading and stays full until the database closes,
  // so what the view holds beside it sets the peak (docs/shade.md, Session 12). The hits and
  // the plain receivers are not needed after this point (the shade receivers carry the same
  // positions and normals, `surface` the materials, and a pixel without a receiver is sky),
  // and the images are made only once the shading's own buffers are gone.
  std::vector<CameraHit>().swap(cr.hits);
  std::vector<Receiver>().swap(cr.receivers);
  const std::vector<ShadeReceiver>& receivers = cr.shade;
  const std::vector<uint32_t>& pixel_of = cr.pixel_of;

  std::vector<ShadeResult> results(receivers.size());
  PBGI_RETURN_IF_ERROR(
      ShadeBatch(db, cr.shade, cr.WithLayout(options), absl::MakeSpan(results), &out.shade));
  const bool radiance = HasRadiance(db.meta().channels);
  // The database is not used after this: a caller that closes it here composes without its
  // page cache.
  if (after_shading) after_shading();

  // Composing is a shadow-ray query per pixel (the direct light); each pixel's value depends
  // only on its receiver and its pixel (the tracer's key), so the loop runs on all cores and the
  // images keep their bits.
  const auto t1 = Clock::now();
  const glm::vec3 sky = scene.lights.sky;
  out.occlusion = Image(camera.width, camera.height);
  out.indirect = Image(camera.width, camera.height);
  // Without a glossy lobe there is no glossy image to hold (0x0).
  const bool glossy = options.raster.lobe != GlossyLobe::kNone;
  if (glossy) out.glossy = Image(camera.width, camera.height);
  out.direct = Image(camera.width, camera.height);
  out.composite = Image(camera.width, camera.height);
  std::fill(out.composite.pixels.begin(), out.composite.pixels.end(), sky);
  std::fill(out.direct.pixels.begin(), out.direct.pixels.end(), sky);
  std::fill(out.occlusion.pixels.begin(), out.occlusion.pixels.end(), glm::vec3(1.0f));
  const internal::TsanRegion region;
  tbb::parallel_for(tbb::blocked_range<size_t>(0, receivers.size(), 1024),
                    [&](const tbb::blocked_range<size_t>& range) {
                      const internal::TsanRegion::Task task(region);
                      for (size_t i = range.begin(); i != range.end(); ++i) {
                        const uint32_t p = pixel_of[i];
                        const uint32_t material = cr.surface[i];
                        const Material& m =
                            scene.materials[std::min<size_t>(material, scene.materials.size() - 1)];
                        const ShadeResult& r = results[i];
                        const glm::vec3 direct = tracer.SurfaceRadiance(
                            receivers[i].position, receivers[i].normal, material, p);
                        const float open = 1.0f - std::clamp(r.occlusion, 0.0f, 1.0f);
                        out.occlusion.pixels[p] = glm::vec3(open);
                        out.direct.pixels[p] = direct;
                        if (radiance) {
                          if (glossy) out.glossy.pixels[p] = r.glossy;
                          out.indirect.pixels[p] = m.albedo * r.irradiance * float(1.0 / sh::kPi);
                          out.composite.pixels[p] = direct + out.indirect.pixels[p];
                        } else {
                          // Occlusion only: an ambient term from the sky, dimmed by the
                          // occlusion.
                          out.composite.pixels[p] = direct + m.albedo * sky * open;
                        }
                      }
                    });
  region.Joined();
  out.compose_seconds = std::chrono::duration<double>(Clock::now() - t1).count();
  return out;
}

}  // namespace pbgi::tools
