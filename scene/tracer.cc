// The Embree wrapper: device and scenes held by RAII handles, one RTCScene per mesh instanced
// into a top-level scene; camera rays, shadow rays, the lighting function that bakes surfels,
// and the reference integrator that checks PBGI against ray tracing (docs/design.md, "Accuracy").
#include <embree3/rtcore.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "absl/strings/str_format.h"
#include "absl/synchronization/mutex.h"
#include "base/tsan_region.h"
#include "pbgi/scene.h"
#include "scene/sample_math.h"
#include "scene/scene_index.h"
#include "tbb/blocked_range.h"
#include "tbb/parallel_for.h"

namespace pbgi {
namespace {

using internal::SceneIndex;

const char* EmbreeErrorName(RTCError e) {
  switch (e) {
    case RTC_ERROR_NONE:
      return "no error";
    case RTC_ERROR_UNKNOWN:
      return "unknown error";
    case RTC_ERROR_INVALID_ARGUMENT:
      return "invalid argument";
    case RTC_ERROR_INVALID_OPERATION:
      return "invalid operation";
    case RTC_ERROR_OUT_OF_MEMORY:
      return "out of memory";
    case RTC_ERROR_UNSUPPORTED_CPU:
      return "unsupported CPU";
    case RTC_ERROR_CANCELLED:
      return "cancelled";
  }
  return "unrecognized error";
}

// The first error the device reported, kept for the Status that Create() returns.
struct DeviceErrors {
  absl::Mutex mu;
  std::string first ABSL_GUARDED_BY(mu);
};

void OnDeviceError(void* user, RTCError code, const char* str) {
  auto* errors = static_cast<DeviceErrors*>(user);
  absl::MutexLock lock(&errors->mu);
  if (errors->first.empty()) {
    errors->first = absl::StrFormat("%s (%s)", EmbreeErrorName(code), str ? str : "");
  }
}

struct DeviceDeleter {
  void operator()(RTCDevice d) const { rtcReleaseDevice(d); }
};
struct SceneDeleter {
  void operator()(RTCScene s) const { rtcReleaseScene(s); }
};
using DevicePtr = std::unique_ptr<RTCDeviceTy, DeviceDeleter>;
using ScenePtr = std::unique_ptr<RTCSceneTy, SceneDeleter>;

// Meshes up to this size are flattened into world space rather than instanced.
constexpr size_t kFlattenMaxTriangles = 256;

}  // namespace

struct Tracer::Impl {
  explicit Impl(const Scene& s) : scene(s), index(s) {}
  const Scene& scene;
  SceneIndex index;
  DeviceErrors errors;
  DevicePtr device;
  std::vector<ScenePtr> meshes;  // per Scene::meshes entry that stays instanced, else null
  ScenePtr top;
  // Geometry 0 of `top` holds the flattened instances: (instance, triangle) per primitive.
  std::vector<std::pair<uint32_t, uint32_t>> flat_map;
  // Scene instance of each geometry id of `top` (entry 0 unused: the flattened geometry).
  std::vector<uint32_t> geom_instance;
  float eps = 1e-4f;
  float far = std::numeric_limits<float>::infinity();

  // A triangle geometry over copies of the arrays (Embree pads its own buffers for SIMD loads).
  RTCGeometry NewTriangles(const std::vector<glm::vec3>& positions,
                           const std::vector<glm::uvec3>& triangles) {
    RTCGeometry g = rtcNewGeometry(device.get(), RTC_GEOMETRY_TYPE_TRIANGLE);
    if (!g) return nullptr;
    // Small geometry is built once and traced billions of times: a better BVH pays for itself.
    if (triangles.size() <= (1u << 20)) rtcSetGeometryBuildQuality(g, RTC_BUILD_QUALITY_HIGH);
    auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(
        g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), positions.size()));
    auto* idx = static_cast<uint32_t*>(rtcSetNewGeometryBuffer(
        g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(uint32_t), triangles.size()));
    if (!v || !idx) {
      rtcReleaseGeometry(g);
      return nullptr;
    }
    for (size_t i = 0; i < positions.size(); ++i) {
      v[3 * i] = positions[i].x;
      v[3 * i + 1] = positions[i].y;
      v[3 * i + 2] = positions[i].z;
    }
    for (size_t i = 0; i < triangles.size(); ++i) {
      idx[3 * i] = triangles[i].x;
      idx[3 * i + 1] = triangles[i].y;
      idx[3 * i + 2] = triangles[i].z;
    }
    rtcCommitGeometry(g);
    return g;
  }

  absl::Status DeviceStatus(const char* what) {
    RTCError e = device ? rtcGetDeviceError(device.get()) : RTC_ERROR_UNKNOWN;
    absl::MutexLock lock(&errors.mu);
    if (e == RTC_ERROR_NONE && errors.first.empty()) return absl::OkStatus();
    std::string msg = errors.first.empty() ? EmbreeErrorName(e) : errors.first;
    return absl::InternalError(
        absl::StrFormat("Embree failed to %s for scene '%s': %s", what, scene.name, msg));
  }
};

Tracer::Tracer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Tracer::~Tracer() {
  // Release scenes before the device that owns them.
  if (impl_) {
    impl_->top.reset();
    impl_->meshes.clear();
    impl_->device.reset();
  }
}

const Scene& Tracer::scene() const { return impl_->scene; }
float Tracer::epsilon() const { return impl_->eps; }

absl::StatusOr<std::unique_ptr<Tracer>> Tracer::Create(const Scene& scene) {
  absl::Status valid = scene.Validate();
  if (!valid.ok()) return valid;
  auto impl = std::make_unique<Impl>(scene);
  impl->device.reset(rtcNewDevice(nullptr));
  if (!impl->device) {
    return absl::InternalError(
        absl::StrFormat("Embree could not create a device for scene '%s': %s", scene.name,
                        EmbreeErrorName(rtcGetDeviceError(nullptr))));
  }
  RTCDevice dev = impl->device.get();
  rtcSetDeviceErrorFunction(dev, OnDeviceError, &impl->errors);

  // Small meshes (a building's box, a Cornell wall) are flattened into one world-space geometry:
  // a two-level traversal through thousands of tiny instances costs more than their triangles.
  // Large meshes (a tree with its leaves) stay instanced, so the scene stays compact.
  // A mesh placed only once is flattened too: that costs no more memory than instancing it.
  std::vector<int64_t> uses(scene.meshes.size(), 0);
  for (const Instance& in : scene.instances) ++uses[in.mesh];
  std::vector<char> flatten(scene.meshes.size(), 0);
  for (size_t m = 0; m < scene.meshes.size(); ++m) {
    flatten[m] = scene.meshes[m].triangles.size() <= kFlattenMaxTriangles || uses[m] <= 1;
  }
  impl->top.reset(rtcNewScene(dev));
  std::vector<glm::vec3> flat_positions;
  std::vector<glm::uvec3> flat_triangles;
  for (uint32_t i = 0; i < scene.instances.size(); ++i) {
    const Instance& in = scene.instances[i];
    const Mesh& mesh = scene.meshes[in.mesh];
    if (!flatten[in.mesh] || mesh.triangles.empty()) continue;
    const uint32_t base = static_cast<uint32_t>(flat_positions.size());
    for (const glm::vec3& p : mesh.positions) {
      flat_positions.push_back(internal::TransformPoint(in.transform, p));
    }
    for (uint32_t t = 0; t < mesh.triangles.size(); ++t) {
      flat_triangles.push_back(mesh.triangles[t] + glm::uvec3(base));
      impl->flat_map.push_back({i, t});
    }
  }
  if (!flat_triangles.empty()) {
    RTCGeometry g = impl->NewTriangles(flat_positions, flat_triangles);
    if (!g) return impl->DeviceStatus("create the flattened geometry");
    rtcAttachGeometryByID(impl->top.get(), g, 0);
    rtcReleaseGeometry(g);
  }
  impl->geom_instance.push_back(0);  // geometry 0 is the flattened one
  impl->meshes.resize(scene.meshes.size());
  for (uint32_t i = 0; i < scene.instances.size(); ++i) {
    const Instance& in = scene.instances[i];
    const Mesh& mesh = scene.meshes[in.mesh];
    if (flatten[in.mesh] || mesh.triangles.empty()) continue;
    if (!impl->meshes[in.mesh]) {
      RTCScene proto = rtcNewScene(dev);
      impl->meshes[in.mesh].reset(proto);
      RTCGeometry g = impl->NewTriangles(mesh.positions, mesh.triangles);
      if (!g) return impl->DeviceStatus("create a mesh geometry");
      rtcAttachGeometryByID(proto, g, 0);
      rtcReleaseGeometry(g);
      rtcCommitScene(proto);
    }
    RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_INSTANCE);
    if (!g) return impl->DeviceStatus("create an instance");
    rtcSetGeometryInstancedScene(g, impl->meshes[in.mesh].get());
    rtcSetGeometryTransform(g, 0, RTC_FORMAT_FLOAT4X4_COLUMN_MAJOR, &in.transform[0][0]);
    rtcCommitGeometry(g);
    rtcAttachGeometryByID(impl->top.get(), g, static_cast<unsigned>(impl->geom_instance.size()));
    rtcReleaseGeometry(g);
    impl->geom_instance.push_back(i);
  }
  rtcCommitScene(impl->top.get());
  absl::Status s = impl->DeviceStatus("build the scene");
  if (!s.ok()) return s;
  // Rays leave surfaces from a point lifted along the normal by a small fraction of the scene's
  // size: enough to clear float round-off in the hit point, small against any feature.
  const Bounds& b = impl->index.bounds();
  float scale =
      b.Empty()
          ? 1.0f
          : std::max({impl->index.extent(), std::abs(b.lo.x), std::abs(b.lo.y), std::abs(b.lo.z),
                      std::abs(b.hi.x), std::abs(b.hi.y), std::abs(b.hi.z)});
  impl->eps = std::max(1e-5f * scale, 1e-7f);
  return std::unique_ptr<Tracer>(new Tracer(std::move(impl)));
}

Hit Tracer::Intersect(const glm::vec3& origin, const glm::vec3& dir, float tmax) const {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRayHit rh;
  rh.ray.org_x = origin.x;
  rh.ray.org_y = origin.y;
  rh.ray.org_z = origin.z;
  rh.ray.dir_x = dir.x;
  rh.ray.dir_y = dir.y;
  rh.ray.dir_z = dir.z;
  rh.ray.tnear = 0.0f;
  rh.ray.tfar = tmax;
  rh.ray.time = 0.0f;
  rh.ray.mask = 0xffffffffu;
  rh.ray.id = 0;
  rh.ray.flags = 0;
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(impl_->top.get(), &ctx, &rh);
  Hit h;
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return h;
  h.hit = true;
  h.distance = rh.ray.tfar;
  if (rh.hit.instID[0] == RTC_INVALID_GEOMETRY_ID) {
    h.instance = impl_->flat_map[rh.hit.primID].first;
    h.triangle = impl_->flat_map[rh.hit.primID].second;
  } else {
    h.instance = impl_->geom_instance[rh.hit.instID[0]];
    h.triangle = rh.hit.primID;
  }
  h.position = origin + dir * rh.ray.tfar;
  // The normal from the world-space triangle: Embree reports Ng in object space for instances.
  internal::WorldTriangle w = impl_->index.Triangle(h.instance, h.triangle);
  glm::vec3 c = w.Cross();
  float len = glm::length(c);
  h.normal = len > 0.0f ? c / len : -dir;
  h.front = glm::dot(h.normal, dir) < 0.0f;
  h.material = impl_->index.MaterialOf(h.instance, h.triangle);
  return h;
}

bool Tracer::Occluded(const glm::vec3& origin, const glm::vec3& dir, float tmax) const {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRay r;
  r.org_x = origin.x;
  r.org_y = origin.y;
  r.org_z = origin.z;
  r.dir_x = dir.x;
  r.dir_y = dir.y;
  r.dir_z = dir.z;
  r.tnear = 0.0f;
  r.tfar = tmax;
  r.time = 0.0f;
  r.mask = 0xffffffffu;
  r.id = 0;
  r.flags = 0;
  rtcOccluded1(impl_->top.get(), &ctx, &r);
  return r.tfar < 0.0f;
}

glm::vec3 Camera::Direction(float px, float py) const {
  glm::vec3 forward = glm::normalize(look_at - eye);
  glm::vec3 right = glm::normalize(glm::cross(forward, up));
  glm::vec3 true_up = glm::cross(right, forward);
  float tan_half = std::tan(0.5f * fov_y_degrees * internal::kPiFloat / 180.0f);
  float aspect = static_cast<float>(width) / static_cast<float>(height);
  float sx = (2.0f * px / static_cast<float>(width) - 1.0f) * tan_half * aspect;
  float sy = (1.0f - 2.0f * py / static_cast<float>(height)) * tan_half;
  return glm::normalize(forward + right * sx + true_up * sy);
}

std::vector<CameraHit> Tracer::TraceCamera(const Camera& camera) const {
  const int w = std::max(camera.width, 0), hgt = std::max(camera.height, 0);
  std::vector<CameraHit> out(static_cast<size_t>(w) * static_cast<size_t>(hgt));
  const internal::TsanRegion region;
  tbb::parallel_for(tbb::blocked_range<int>(0, hgt), [&](const tbb::blocked_range<int>& rows) {
    const internal::TsanRegion::Task task(region);
    for (int y = rows.begin(); y < rows.end(); ++y) {
      for (int x = 0; x < w; ++x) {
        glm::vec3 d = camera.Direction(static_cast<float>(x) + 0.5f, static_cast<float>(y) + 0.5f);
        Hit h = Intersect(camera.eye, d, impl_->far);
        CameraHit& c = out[static_cast<size_t>(y) * w + x];
        if (!h.hit) continue;
        c.hit = true;
        // Pulled back towards the eye by epsilon(): the hit point rounded onto the plane of a
        // surface meeting the one hit (a wall's pixel at the floor), and rays leaving it missed
        // that surface at t = 0: the reference's own light dots along cornell's room edges
        // (docs/eval.md, "Session 16"). The segment from the eye is free, so the point lies in
        // front of every surface there.
        c.position = camera.eye + d * std::max(0.0f, h.distance - impl_->eps);
        c.normal = h.front ? h.normal : -h.normal;
        c.material = h.material;
        c.sheet = impl_->index.SheetOf(h.instance, h.triangle);
      }
    }
  });
  region.Joined();
  return out;
}

void Tracer::OccludedGroup(int count, const glm::vec3* origin, const glm::vec3* dir,
                           const float* tfar, const bool* active, bool* blocked) const {
  // One rtcOccluded1 per ray: measured faster than rtcOccluded16 packets here (the sky's rays
  // are too incoherent for packets to pay), and a ray's answer never depends on its neighbours.
  for (int i = 0; i < count; ++i) {
    blocked[i] = active[i] && Occluded(origin[i], dir[i], tfar[i]);
  }
}

void Tracer::DirectLightGroup(int count, const glm::vec3* p, const glm::vec3* n, const bool* active,
                              const uint8_t* slot, uint64_t key, glm::vec3* out) const {
  const Lights& lights = impl_->scene.lights;
  const float eps = impl_->eps;
  const float inf = impl_->far;
  glm::vec3 origin[kGroup] = {}, dir[kGroup] = {}, t[kGroup] = {}, b[kGroup] = {};
  float tfar[kGroup] = {}, weight[kGroup] = {};
  // Each point's share of the strata: its slot over kGroup.
  float share[kGroup] = {};
  uint32_t slots[kGroup] = {};
  for (int i = 0; i < count; ++i) {
    slots[i] = slot != nullptr ? slot[i] : static_cast<uint32_t>(i);
    share[i] = static_cast<float>(slots[i]) / static_cast<float>(kGroup);
  }
  bool on[kGroup] = {}, blocked[kGroup] = {};
  for (int i = 0; i < count; ++i) {
    out[i] = glm::vec3(0.0f);
    origin[i] = p[i] + n[i] * eps;
  }
  if (lights.has_sun) {
    for (int i = 0; i < count; ++i) {
      weight[i] = glm::dot(n[i], lights.sun.direction);
      on[i] = active[i] && weight[i] > 0.0f;
      dir[i] = lights.sun.direction;
      tfar[i] = inf;
    }
    OccludedGroup(count, origin, dir, tfar, on, blocked);
    for (int i = 0; i < count; ++i) {
      if (on[i] && !blocked[i]) out[i] += lights.sun.radiance * weight[i];
    }
  }
  const bool sky = lights.sky.x > 0.0f || lights.sky.y > 0.0f || lights.sky.z > 0.0f;
  if (sky && lights.sky_rays > 0) {
    const int m = lights.sky_rays;
    const uint64_t k = internal::HashCombine(key, 0x736b79u);
    const float r0 = internal::Random(k, 0), r1 = internal::Random(k, 1);
    int open[kGroup] = {};
    for (int i = 0; i < count; ++i) {
      internal::OrthonormalBasis(n[i], &t[i], &b[i]);
      tfar[i] = inf;
    }
    for (int ray = 0; ray < m; ++ray) {
      // Each point's m directions are a stratified set of its own: the group's shift r plus
      // (i / (kGroup m), RadicalInverse2(i)) for the point in slot i, so the group's kGroup * m
      // directions are stratified together. One direction shared by the group (before) gave every
      // point of a wall's strip the same sky estimate, an error that no cluster averages.
      for (int i = 0; i < count; ++i) {
        const glm::vec2 u =
            internal::RotatedHammersley(ray, m, r0 + share[i] / static_cast<float>(m),
                                        r1 + internal::RadicalInverse2(slots[i]));
        dir[i] = internal::CosineDirection(n[i], t[i], b[i], u);
      }
      OccludedGroup(count, origin, dir, tfar, active, blocked);
      for (int i = 0; i < count; ++i) open[i] += (active[i] && !blocked[i]) ? 1 : 0;
    }
    for (int i = 0; i < count; ++i) {
      out[i] += lights.sky * (static_cast<float>(open[i]) / static_cast<float>(m));
    }
  }
  const auto& emitters = impl_->index.emitters();
  if (!emitters.empty() && lights.area_light_samples > 0) {
    const int m = lights.area_light_samples;
    const uint64_t k = internal::HashCombine(key, 0x6172656155u);
    const float r0 = internal::Random(k, 0);
    const auto& cdf = impl_->index.emitter_cdf();
    const double total = cdf.back();
    // Irradiance / pi averaged over the m samples.
    const float norm = 1.0f / (internal::kPiFloat * static_cast<float>(m));
    glm::vec3 emission[kGroup] = {};
    for (int s = 0; s < m; ++s) {
      // Stratified over the power CDF: sample s of point i picks an emitter in the s-th 1/m of
      // the power, at r0 + i / kGroup of it, and a point of its own on the emitter.
      for (int i = 0; i < count; ++i) {
        const double at = static_cast<double>(s) + internal::Wrap01(r0 + share[i]);
        const size_t e = impl_->index.PickEmitter(at / m);
        const auto& em = emitters[e];
        const uint64_t j = static_cast<uint64_t>(s) * kGroup + slots[i];
        const glm::vec2 uv(internal::Random(k, 2 * j + 2), internal::Random(k, 2 * j + 3));
        const glm::vec3 q = internal::TrianglePoint(em.tri.a, em.tri.b, em.tri.c, uv);
        // pdf over area: (w_e / W) / area_e, with w_e = luminance * area.
        const float inv_pdf = static_cast<float>(total / (cdf[e + 1] - cdf[e])) * em.area;
        emission[i] = em.emission;
        const glm::vec3 to = q - origin[i];
        const float dist2 = glm::dot(to, to);
        on[i] = false;
        if (!active[i] || !(dist2 > 0.0f)) continue;
        const float dist = std::sqrt(dist2);
        dir[i] = to / dist;
        const float cos_r = glm::dot(n[i], dir[i]);
        const float cos_e = -glm::dot(em.normal, dir[i]);
        if (cos_r <= 0.0f || cos_e <= 0.0f) continue;
        on[i] = true;
        tfar[i] = dist * (1.0f - 1e-4f) - eps;
        weight[i] = cos_r * cos_e / dist2 * inv_pdf * norm;
      }
      OccludedGroup(count, origin, dir, tfar, on, blocked);
      for (int i = 0; i < count; ++i) {
        if (on[i] && !blocked[i]) out[i] += emission[i] * weight[i];
      }
    }
  }
}

glm::vec3 Tracer::DirectLight(const glm::vec3& p, const glm::vec3& n, uint64_t key) const {
  const bool active = true;
  glm::vec3 out;
  DirectLightGroup(1, &p, &n, &active, nullptr, internal::HashCombine(key, 0), &out);
  return out;
}

glm::vec3 Tracer::SurfaceRadiance(const glm::vec3& p, const glm::vec3& n, uint32_t material,
                                  uint64_t key) const {
  glm::vec3 out;
  SurfaceRadiance(absl::MakeConstSpan(&p, 1), absl::MakeConstSpan(&n, 1),
                  absl::MakeConstSpan(&material, 1), key, absl::MakeSpan(&out, 1));
  return out;
}

void Tracer::SurfaceRadiance(absl::Span<const glm::vec3> p, absl::Span<const glm::vec3> n,
                             absl::Span<const uint32_t> materials, uint64_t key,
                             absl::Span<glm::vec3> out, absl::Span<const uint8_t> slots) const {
  const auto& mats = impl_->scene.materials;
  for (size_t first = 0, group = 0; first < p.size(); first += kGroup, ++group) {
    const int count = static_cast<int>(std::min<size_t>(kGroup, p.size() - first));
    bool active[kGroup];
    glm::vec3 direct[kGroup];
    for (int i = 0; i < count; ++i) {
      const glm::vec3& a = mats[materials[first + i]].albedo;
      active[i] = a.x > 0.0f || a.y > 0.0f || a.z > 0.0f;
    }
    DirectLightGroup(count, p.data() + first, n.data() + first, active,
                     slots.empty() ? nullptr : slots.data() + first,
                     internal::HashCombine(key, group), direct);
    for (int i = 0; i < count; ++i) {
      const Material& m = mats[materials[first + i]];
      out[first + i] = active[i] ? m.albedo * direct[i] + m.emission : m.emission;
    }
  }
}

float Tracer::ReferenceOcclusion(const glm::vec3& p, const glm::vec3& n, int rays,
                                 float max_distance, uint64_t seed) const {
  if (rays <= 0) return 0.0f;
  glm::vec3 t, b;
  internal::OrthonormalBasis(n, &t, &b);
  const float r0 = internal::Random(seed, 0), r1 = internal::Random(seed, 1);
  const glm::vec3 origin = p + n * impl_->eps;
  int hits = 0;
  for (int i = 0; i < rays; ++i) {
    glm::vec3 d = internal::CosineDirection(n, t, b, internal::RotatedHammersley(i, rays, r0, r1));
    if (Occluded(origin, d, max_distance)) ++hits;
  }
  return static_cast<float>(hits) / static_cast<float>(rays);
}

float Tracer::ReferenceOcclusionPackets(const glm::vec3& p, const glm::vec3& n, int rays,
                                        float max_distance, uint64_t seed) const {
  if (rays <= 0) return 0.0f;
  glm::vec3 t, b;
  internal::OrthonormalBasis(n, &t, &b);
  const float r0 = internal::Random(seed, 0), r1 = internal::Random(seed, 1);
  const glm::vec3 origin = p + n * impl_->eps;
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  int hits = 0;
  for (int first = 0; first < rays; first += 16) {
    alignas(64) RTCRay16 r;
    alignas(64) int valid[16];
    for (int k = 0; k < 16; ++k) {
      const int i = first + k;
      valid[k] = i < rays ? -1 : 0;
      const glm::vec3 d = i < rays ? internal::CosineDirection(
                                         n, t, b, internal::RotatedHammersley(i, rays, r0, r1))
                                   : n;
      r.org_x[k] = origin.x;
      r.org_y[k] = origin.y;
      r.org_z[k] = origin.z;
      r.dir_x[k] = d.x;
      r.dir_y[k] = d.y;
      r.dir_z[k] = d.z;
      r.tnear[k] = 0.0f;
      r.tfar[k] = max_distance;
      r.time[k] = 0.0f;
      r.mask[k] = 0xffffffffu;
      r.id[k] = static_cast<unsigned>(k);
      r.flags[k] = 0;
    }
    rtcOccluded16(valid, impl_->top.get(), &ctx, &r);
    for (int k = 0; k < 16 && first + k < rays; ++k) hits += r.tfar[k] < 0.0f ? 1 : 0;
  }
  return static_cast<float>(hits) / static_cast<float>(rays);
}

// The reference's hit points and the radiance they send back along the ray: a front side's
// SurfaceRadiance(); the back of a thin sheet is a surface of its own, lit from its side
// (albedo times its direct light, no emission, which is one-sided); the back of any other
// triangle is the inside of a solid, dark.
class Tracer::HitRadiance {
 public:
  void Add(const Hit& h, const Scene& scene) {
    if (!h.hit) return;
    if (h.front) {
      points_.push_back(h.position), normals_.push_back(h.normal);
      materials_.push_back(h.material);
    } else if (scene.materials[h.material].thin) {
      back_points_.push_back(h.position), back_normals_.push_back(-h.normal);
      back_materials_.push_back(h.material);
    }
  }
  glm::vec3 Sum(const Tracer& tracer, uint64_t key) const {
    glm::vec3 sum(0.0f);
    std::vector<glm::vec3> l(points_.size());
    tracer.SurfaceRadiance(points_, normals_, materials_, key, absl::MakeSpan(l));
    for (const glm::vec3& x : l) sum += x;
    l.assign(back_points_.size(), glm::vec3(0.0f));
    tracer.SurfaceRadiance(back_points_, back_normals_, back_materials_,
                           internal::HashCombine(key, 0x6261636bu), absl::MakeSpan(l));
    const auto& mats = tracer.impl_->scene.materials;
    for (size_t i = 0; i < l.size(); ++i) sum += l[i] - mats[back_materials_[i]].emission;
    return sum;
  }

 private:
  std::vector<glm::vec3> points_, normals_, back_points_, back_normals_;
  std::vector<uint32_t> materials_, back_materials_;
};

glm::vec3 Tracer::ReferenceIrradiance(const glm::vec3& p, const glm::vec3& n, int rays,
                                      uint64_t seed, float max_distance) const {
  if (rays <= 0) return glm::vec3(0.0f);
  glm::vec3 t, b;
  internal::OrthonormalBasis(n, &t, &b);
  const float r0 = internal::Random(seed, 0), r1 = internal::Random(seed, 1);
  const glm::vec3 origin = p + n * impl_->eps;
  HitRadiance hits;
  for (int i = 0; i < rays; ++i) {
    glm::vec3 d = internal::CosineDirection(n, t, b, internal::RotatedHammersley(i, rays, r0, r1));
    hits.Add(Intersect(origin, d, std::min(impl_->far, max_distance)), impl_->scene);
  }
  // The hit points' radiance is the very lighting function that baked the surfels.
  const glm::vec3 sum = hits.Sum(*this, internal::HashCombine(seed, 2));
  // Cosine-weighted estimator of the integral of L cos: pi / N * sum L.
  return sum * (internal::kPiFloat / static_cast<float>(rays));
}

glm::vec3 Tracer::ReferenceGlossy(const glm::vec3& p, const glm::vec3& n,
                                  const glm::vec3& reflection, const GlossyParams& lobe, int rays,
                                  uint64_t seed) const {
  const float rl = glm::length(reflection);
  if (rays <= 0 || !(rl > 0.0f) || !std::isfinite(rl)) return glm::vec3(0.0f);
  const glm::vec3 r = reflection / rl;
  glm::vec3 t, b;
  internal::OrthonormalBasis(r, &t, &b);
  const float r0 = internal::Random(seed, 0), r1 = internal::Random(seed, 1);
  const glm::vec3 origin = p + n * impl_->eps;
  HitRadiance hits;
  int kept = 0;
  for (int i = 0; i < rays; ++i) {
    const glm::vec2 u = internal::RotatedHammersley(i, rays, r0, r1);
    const double x = lobe.lobe == GlossyLobe::kGgx
                         ? internal::GgxLobeCosine(u.x, lobe.ggx_roughness)
                         : internal::PhongLobeCosine(u.x, lobe.phong_exponent);
    const float c = static_cast<float>(x);
    const float s = std::sqrt(std::max(0.0f, 1.0f - c * c));
    const float phi = 2.0f * internal::kPiFloat * u.y;
    const glm::vec3 d = glm::normalize(t * (s * std::cos(phi)) + b * (s * std::sin(phi)) + r * c);
    // The rasterizer's glossy sums only the pixels above the receiver's horizon.
    if (!(glm::dot(d, n) > 0.0f)) continue;
    ++kept;
    hits.Add(Intersect(origin, d, impl_->far), impl_->scene);
  }
  if (kept == 0) return glm::vec3(0.0f);
  return hits.Sum(*this, internal::HashCombine(seed, 2)) / static_cast<float>(kept);
}

std::vector<float> Tracer::ReferenceOcclusion(absl::Span<const Receiver> receivers, int rays,
                                              float max_distance, uint64_t seed) const {
  std::vector<float> out(receivers.size());
  const internal::TsanRegion region;
  tbb::parallel_for(tbb::blocked_range<size_t>(0, receivers.size(), 16),
                    [&](const tbb::blocked_range<size_t>& r) {
                      const internal::TsanRegion::Task task(region);
                      for (size_t i = r.begin(); i < r.end(); ++i) {
                        out[i] =
                            ReferenceOcclusion(receivers[i].position, receivers[i].normal, rays,
                                               max_distance, internal::HashCombine(seed, i));
                      }
                    });
  region.Joined();
  return out;
}

std::vector<glm::vec3> Tracer::ReferenceIrradiance(absl::Span<const Receiver> receivers, int rays,
                                                   uint64_t seed) const {
  std::vector<glm::vec3> out(receivers.size());
  const internal::TsanRegion region;
  tbb::parallel_for(tbb::blocked_range<size_t>(0, receivers.size(), 4),
                    [&](const tbb::blocked_range<size_t>& r) {
                      const internal::TsanRegion::Task task(region);
                      for (size_t i = r.begin(); i < r.end(); ++i) {
                        out[i] = ReferenceIrradiance(receivers[i].position, receivers[i].normal,
                                                     rays, internal::HashCombine(seed, i));
                      }
                    });
  region.Joined();
  return out;
}

std::vector<glm::vec3> Tracer::ReferenceGlossy(absl::Span<const ShadeReceiver> receivers,
                                               const GlossyParams& lobe, int rays,
                                               uint64_t seed) const {
  std::vector<glm::vec3> out(receivers.size());
  const internal::TsanRegion region;
  tbb::parallel_for(tbb::blocked_range<size_t>(0, receivers.size(), 4),
                    [&](const tbb::blocked_range<size_t>& r) {
                      const internal::TsanRegion::Task task(region);
                      for (size_t i = r.begin(); i < r.end(); ++i) {
                        const ShadeReceiver& s = receivers[i];
                        out[i] = ReferenceGlossy(s.position, glm::normalize(s.normal), s.reflection,
                                                 lobe, rays, internal::HashCombine(seed, i));
                      }
                    });
  region.Joined();
  return out;
}

}  // namespace pbgi
