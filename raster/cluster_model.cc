#include "raster/cluster_model.h"

#include <algorithm>
#include <array>
#include <cmath>

#include "pbgi/sh.h"

namespace pbgi::internal {
namespace {

// The same constants as ClusterView's (cluster_model.h), which must agree with this reference.
using cluster_model_internal::kRadianceBlend;
using cluster_model_internal::kY0;

// The basis at w; the basis at -w flips the sign of band 1 only.
struct Basis9 {
  std::array<float, 9> y;
};

float Dot(const Sh9& c, const Basis9& b, float odd_sign) {
  const float even =
      c[0] * b.y[0] + c[4] * b.y[4] + c[5] * b.y[5] + c[6] * b.y[6] + c[7] * b.y[7] + c[8] * b.y[8];
  const float odd = c[1] * b.y[1] + c[2] * b.y[2] + c[3] * b.y[3];
  return even + odd_sign * odd;
}

// The sign of band 1 that a side rule evaluates; kBoth takes the side whose area (`area`, the
// area SH) is the larger, for the area and the power alike (raster/cluster_model.h).
float SideSign(const Sh9& area, const Basis9& b, HitSides sides) {
  switch (sides) {
    case HitSides::kFront:
      return 1.0f;
    case HitSides::kBack:
      return -1.0f;
    case HitSides::kBoth:
      return area[1] * b.y[1] + area[2] * b.y[2] + area[3] * b.y[3] >= 0.0f ? 1.0f : -1.0f;
  }
  return 1.0f;
}

float EvalSide(const Sh9& c, const Basis9& b, float sign) {
  return std::max(0.0f, Dot(c, b, sign));
}

}  // namespace

float ProjectedAreaShEval(const Cluster& cluster, const glm::vec3& w, HitSides sides) {
  const Basis9 b{sh::Basis(w.x, w.y, w.z)};
  return EvalSide(cluster.sh_area, b, SideSign(cluster.sh_area, b, sides));
}

glm::vec3 ClusterRadiance(const Cluster& cluster, const glm::vec3& w, HitSides sides) {
  if (glm::vec3 axis; AxisFacesRadiance(cluster, w, sides, &axis)) return axis;
  const Basis9 b{sh::Basis(w.x, w.y, w.z)};
  const float sign = SideSign(cluster.sh_area, b, sides);
  const float a = EvalSide(cluster.sh_area, b, sign);
  const float a_mean = kY0 * cluster.sh_area[0];
  const float den = a + kRadianceBlend * a_mean;
  glm::vec3 out(0.0f);
  if (!(den > 0.0f)) return out;
  for (int ch = 0; ch < 3; ++ch) {
    const float p = EvalSide(cluster.sh_power[ch], b, sign);
    const float p_mean = std::max(0.0f, kY0 * cluster.sh_power[ch][0]);
    out[ch] = (p + kRadianceBlend * p_mean) / den;
  }
  return out;
}

}  // namespace pbgi::internal
