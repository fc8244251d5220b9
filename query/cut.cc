// The public tests of the cut (include/pbgi/query.h) over the traversal math (tree/cut.h).
#include "tree/cut.h"

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

}  // namespace pbgi
