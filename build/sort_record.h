// The record that the external sort moves around: a Morton key and the surfel it belongs to,
// its two-sided flag in the radius's sign bit and its sheet tag in that radius's low bits
// (tree/format.h, EncodeRadius), and a two-sided surfel's front and back radiance as their
// stored codes in the radiance floats (PackSidesRadiance; RecordRadiances reads them).
#ifndef PBGI_BUILD_SORT_RECORD_H_
#define PBGI_BUILD_SORT_RECORD_H_

#include <cmath>
#include <cstdint>

#include "pbgi/surfel.h"
#include "tree/format.h"

namespace pbgi::internal {

struct SortRecord {
  uint64_t key;
  float position[3];
  float normal[3];
  float radius;
  float radiance[3];
};
static_assert(sizeof(SortRecord) == 48);

// A record's sort key and its index in the run buffer (build/external_sort.h).
struct KeyIndex {
  uint64_t key;
  uint64_t index;
};

inline SortRecord MakeSortRecord(uint64_t key, const Surfel& s) {
  if (s.two_sided) {
    return SortRecord{key,
                      {s.position.x, s.position.y, s.position.z},
                      {s.normal.x, s.normal.y, s.normal.z},
                      EncodeRadius(s.radius, true, s.sheet),
                      {PackSidesRadiance(s.radiance.x, s.back_radiance.x),
                       PackSidesRadiance(s.radiance.y, s.back_radiance.y),
                       PackSidesRadiance(s.radiance.z, s.back_radiance.z)}};
  }
  return SortRecord{key,
                    {s.position.x, s.position.y, s.position.z},
                    {s.normal.x, s.normal.y, s.normal.z},
                    EncodeRadius(s.radius, false, s.sheet),
                    {s.radiance.x, s.radiance.y, s.radiance.z}};
}

// Whether a sort record is two-sided with a back radiance that differs from its front, as
// stored: what makes the builder store Channels::kRadianceBothSides.
inline bool RecordBackDiffers(const SortRecord& r) {
  if (!RadiusTwoSided(r.radius)) return false;
  for (int k = 0; k < 3; ++k) {
    if (FrontCode(r.radiance[k]) != BackCode(r.radiance[k])) return true;
  }
  return false;
}

// Why a surfel cannot be stored, or nullptr when it can. `use_radiance`: radiance is checked
// only when it will be stored; a radius (a normal) that the build estimates is not checked.
inline const char* InvalidSurfelReason(const Surfel& s, bool use_radiance,
                                       bool estimate_radius = false, bool estimate_normal = false) {
  auto finite3 = [](const glm::vec3& v) {
    return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
  };
  if (!finite3(s.position)) return "position is NaN or infinite";
  if (!estimate_normal && !finite3(s.normal)) return "normal is NaN or infinite";
  if (!estimate_radius && !std::isfinite(s.radius)) return "radius is NaN or infinite";
  if (!estimate_radius && !(s.radius > 0)) return "radius is zero or negative";
  double n2 = double(s.normal.x) * s.normal.x + double(s.normal.y) * s.normal.y +
              double(s.normal.z) * s.normal.z;
  if (!estimate_normal && !(n2 > 1e-12)) return "normal is zero";
  if (use_radiance && !finite3(s.radiance)) return "radiance is NaN or infinite";
  if (use_radiance && s.two_sided && !finite3(s.back_radiance)) {
    return "back radiance is NaN or infinite";
  }
  return nullptr;
}

}  // namespace pbgi::internal

#endif  // PBGI_BUILD_SORT_RECORD_H_
