// The public tests of the cut (include/pbgi/query.h) over the traversal math (tree/cut.h).
#include "tree/cut.h"

#include <cmath>

#include "absl/strings/str_format.h"
#include "glm/geometric.hpp"
#include "pbgi/query.h"

namespace pbgi {

bool SurfelWhollyBehind(const Surfel& s, const Receiver& r) {
  return internal::SurfelWhollyBehindUnit(s, r.position, glm::normalize(r.normal));
}

bool SurfelBeyond(const Surfel& s, const Receiver& r, float max_distance) {
  return internal::SurfelBeyondPoint(s, r.position, max_distance);
}

float ClusterSolidAngle(const Cluster& c, const Receiver& r) {
  return internal::NodeSolidAngle(c.bounds.lo, c.bounds.hi, c.sh_area.data(), r.position);
}

absl::Status ValidateCutLobe(const CutLobe& lobe) {
  // Checked without a lobe too: ShadeOptions::lobe_cut takes it from there.
  if (!(lobe.min_weight > 0.0f) || !std::isfinite(lobe.min_weight)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("CutLobe.min_weight = %g: must be finite and > 0", lobe.min_weight));
  }
  switch (lobe.kind) {
    case CutLobeKind::kNone:
      return absl::OkStatus();
    case CutLobeKind::kPhong:
      if (!(lobe.phong_exponent >= 0.0f) || !std::isfinite(lobe.phong_exponent)) {
        return absl::InvalidArgumentError(absl::StrFormat(
            "CutLobe.phong_exponent = %g: must be finite and >= 0", lobe.phong_exponent));
      }
      break;
    case CutLobeKind::kGgx:
      if (!(lobe.ggx_roughness > 0.0f && lobe.ggx_roughness <= 1.0f)) {
        return absl::InvalidArgumentError(
            absl::StrFormat("CutLobe.ggx_roughness = %g: must be in (0, 1]", lobe.ggx_roughness));
      }
      break;
    default:
      return absl::InvalidArgumentError(
          absl::StrFormat("CutLobe.kind = %d is not a CutLobeKind", int(lobe.kind)));
  }
  const glm::vec3 d = lobe.direction;
  const float len2 = glm::dot(d, d);
  if (!std::isfinite(d.x) || !std::isfinite(d.y) || !std::isfinite(d.z) || !(len2 > 0.0f) ||
      !std::isfinite(len2)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "CutLobe.direction = (%g, %g, %g): must be finite and not zero", d.x, d.y, d.z));
  }
  return absl::OkStatus();
}

float LobeWeight(const CutLobe& lobe, float cos_to_axis) {
  if (lobe.kind == CutLobeKind::kNone) return 1.0f;
  return internal::LobeCutWeight(internal::MakeLobeCut(lobe), cos_to_axis);
}

}  // namespace pbgi
