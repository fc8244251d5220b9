// The query test harness: brute-force oracle and cut checks (include/pbgi/testing.h).
#include "pbgi/testing.h"

#include <algorithm>
#include <cmath>
#include <random>

#include "absl/strings/str_format.h"
#include "tree/cut.h"

namespace pbgi::testing {
namespace {

using internal::BelowCurvedBoxCut;
using internal::BelowCut;
using internal::LobeCut;
using internal::MakeLobeCut;
using internal::NearSphere;
using internal::NodeBeyond;
using internal::NodeBoxSolidAngleFrom;
using internal::NodeContrastScale;
using internal::NodeCut;
using internal::NodeCutCosine;
using internal::NodeIsFlat;
using internal::NodeLobeWeight;
using internal::NodeNearField;
using internal::NodeNearSphere;
using internal::NodeReach;
using internal::NodeWhollyBehind;
using internal::SurfelWhollyBehindUnit;

std::string Describe(const Receiver& r) {
  return absl::StrFormat("receiver at (%g, %g, %g) normal (%g, %g, %g)", r.position.x, r.position.y,
                         r.position.z, r.normal.x, r.normal.y, r.normal.z);
}

bool InFront(const Surfel& s, const Receiver& r, const glm::vec3& n, const Cut& cut) {
  if (SurfelWhollyBehindUnit(s, r.position, n)) return false;
  if (std::isfinite(cut.max_distance) && SurfelBeyond(s, r, cut.max_distance)) return false;
  return true;
}

// Index of the coarse element (clusters first, then surfels) covering each point, or -1.
absl::StatusOr<std::vector<int64_t>> Owners(const Gathered& g, uint64_t n) {
  std::vector<int64_t> owner(n, -1);
  for (size_t c = 0; c < g.clusters.size(); ++c) {
    const Cluster& cl = g.clusters[c];
    if (cl.point_count > n || cl.first_point > n - cl.point_count) {
      return absl::InvalidArgumentError(
          absl::StrFormat("cluster %d covers points [%d, +%d) outside the %d surfels", c,
                          cl.first_point, cl.point_count, n));
    }
    for (uint64_t i = cl.first_point; i < cl.first_point + cl.point_count; ++i) {
      if (owner[i] != -1) {
        return absl::InvalidArgumentError(absl::StrFormat(
            "surfel %d is represented twice (cluster %d and element %d)", i, c, owner[i]));
      }
      owner[i] = static_cast<int64_t>(c);
    }
  }
  for (size_t k = 0; k < g.surfel_ids.size(); ++k) {
    const uint64_t id = g.surfel_ids[k];
    if (id >= n) {
      return absl::InvalidArgumentError(
          absl::StrFormat("surfel id %d out of range (%d surfels)", id, n));
    }
    if (owner[id] != -1) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "surfel %d is represented twice (as a surfel and by element %d)", id, owner[id]));
    }
    owner[id] = static_cast<int64_t>(g.clusters.size() + k);
  }
  return owner;
}

}  // namespace

std::vector<uint64_t> SurfelsInFront(absl::Span<const Surfel> surfels, const Receiver& receiver,
                                     const Cut& cut) {
  const glm::vec3 n = glm::normalize(receiver.normal);
  std::vector<uint64_t> ids;
  for (size_t i = 0; i < surfels.size(); ++i) {
    if (InFront(surfels[i], receiver, n, cut)) ids.push_back(i);
  }
  return ids;
}

absl::Status CheckValidCut(const Gathered& result, absl::Span<const Surfel> surfels,
                           const Receiver& receiver, const Cut& cut) {
  const auto fail = [&](const std::string& what) {
    return absl::FailedPreconditionError(
        absl::StrFormat("invalid cut for %s, max_solid_angle %g, max_distance %g: %s",
                        Describe(receiver), cut.max_solid_angle, cut.max_distance, what));
  };
  if (result.surfels.size() != result.surfel_ids.size()) {
    return fail(absl::StrFormat("%d surfels but %d surfel ids", result.surfels.size(),
                                result.surfel_ids.size()));
  }
  if (absl::Status s = ValidateCutLobe(cut.lobe); !s.ok()) return fail(std::string(s.message()));
  const LobeCut lobe = MakeLobeCut(cut.lobe);
  const uint64_t n = surfels.size();
  absl::StatusOr<std::vector<int64_t>> owner = Owners(result, n);
  if (!owner.ok()) return fail(std::string(owner.status().message()));
  const glm::vec3 nrm = glm::normalize(receiver.normal);
  const glm::vec3 p = receiver.position;
  const bool check_distance = std::isfinite(cut.max_distance);

  for (size_t c = 0; c < result.clusters.size(); ++c) {
    const Cluster& cl = result.clusters[c];
    const std::string name = absl::StrFormat("cluster %d (points [%d, +%d), depth %d)", c,
                                             cl.first_point, cl.point_count, cl.depth);
    if (cl.point_count == 0) return fail(name + " is empty");
    if (NodeNearField(cl.bounds.lo, cl.bounds.hi, NodeReach(cl.area), p)) {
      return fail(name + " has the receiver in its near field (near-field rule)");
    }
    const float reach = NodeReach(cl.area);
    const float sa = ClusterSolidAngle(cl, receiver);
    const NearSphere near = NodeNearSphere(cl.bounds.lo, cl.bounds.hi, reach);
    const Cut node_cut = NodeCut(cut, cl.sh_area.data(), cl.bounds.lo, cl.bounds.hi,
                                 NodeContrastScale(cut, cl.contrast, cl.sh_power, cl.sh_area[0]));
    const auto cosine = [&] { return NodeCutCosine(near.centre, near.radius2, p, nrm); };
    const auto lobe_weight = [&] { return NodeLobeWeight(lobe, near.centre, near.radius2, p); };
    if (!BelowCut(sa, node_cut, cosine, lobe_weight)) {
      return fail(
          absl::StrFormat("%s subtends %g sr (cosine weight %g, lobe weight %g), not below "
                          "the cut",
                          name, sa, cosine(), lobe.active ? lobe_weight() : 1.0f));
    }
    const bool flat = NodeIsFlat(cl.sh_area.data(), cl.bounds.lo, cl.bounds.hi);
    const glm::vec3 centre = 0.5f * (cl.bounds.lo + cl.bounds.hi);
    const auto box_weight = [&] {
      return lobe.active ? lobe_weight() : cut.cosine_weighted ? cosine() : 1.0f;
    };
    if (!BelowCurvedBoxCut(cut, flat, centre, cl.bounds.lo, cl.bounds.hi, p, box_weight)) {
      return fail(absl::StrFormat(
          "%s is not flat and its box subtends %g sr (weight %g), not below the curved-box cut",
          name, NodeBoxSolidAngleFrom(centre, cl.bounds.lo, cl.bounds.hi, p), box_weight()));
    }
    if (NodeWhollyBehind(cl.bounds.lo, cl.bounds.hi, reach, p, nrm)) {
      return fail(name + " lies wholly behind the tangent plane");
    }
    if (check_distance && NodeBeyond(cl.bounds.lo, cl.bounds.hi, reach, p, cut.max_distance)) {
      return fail(name + " lies wholly beyond max_distance");
    }
    double area = 0;
    for (uint64_t i = cl.first_point; i < cl.first_point + cl.point_count; ++i) {
      if (!cl.bounds.Contains(surfels[i].position)) {
        return fail(absl::StrFormat("%s does not contain its surfel %d", name, i));
      }
      area += surfels[i].Area();
    }
    if (std::abs(area - cl.area) > 1e-3 * area + 1e-6) {
      return fail(absl::StrFormat("%s has area %g, its surfels %g", name, cl.area, area));
    }
  }
  for (size_t k = 0; k < result.surfels.size(); ++k) {
    const uint64_t id = result.surfel_ids[k];
    const Surfel& s = result.surfels[k];
    if (s.position != surfels[id].position || s.normal != surfels[id].normal ||
        s.radius != surfels[id].radius || s.two_sided != surfels[id].two_sided) {
      return fail(absl::StrFormat("surfel %d differs from the database's surfel %d", k, id));
    }
    if (SurfelWhollyBehindUnit(s, p, nrm)) {
      return fail(absl::StrFormat("surfel %d lies wholly behind the tangent plane", id));
    }
    if (check_distance && SurfelBeyond(s, receiver, cut.max_distance)) {
      return fail(absl::StrFormat("surfel %d lies beyond max_distance", id));
    }
  }
  for (uint64_t i = 0; i < n; ++i) {
    if ((*owner)[i] == -1 && InFront(surfels[i], receiver, nrm, cut)) {
      return fail(absl::StrFormat("surfel %d at (%g, %g, %g) is in front but not represented", i,
                                  surfels[i].position.x, surfels[i].position.y,
                                  surfels[i].position.z));
    }
  }
  return absl::OkStatus();
}

absl::Status CheckFinerCutNotSmaller(const Gathered& coarse, const Gathered& fine,
                                     absl::Span<const Surfel> surfels, const Receiver& receiver,
                                     const Cut& coarse_cut, const Cut& fine_cut) {
  const auto fail = [&](const std::string& what) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "finer cut (%g sr) does not refine the coarser (%g sr) for %s: %s",
        fine_cut.max_solid_angle, coarse_cut.max_solid_angle, Describe(receiver), what));
  };
  if (fine_cut.max_solid_angle > coarse_cut.max_solid_angle ||
      fine_cut.max_solid_angle * fine_cut.curved_scale >
          coarse_cut.max_solid_angle * coarse_cut.curved_scale ||
      (coarse_cut.curved_box_scale > 0.0f &&
       !(fine_cut.curved_box_scale > 0.0f &&
         fine_cut.max_solid_angle * fine_cut.curved_box_scale <=
             coarse_cut.max_solid_angle * coarse_cut.curved_box_scale))) {
    return absl::InvalidArgumentError("CheckFinerCutNotSmaller: fine_cut is coarser");
  }
  const uint64_t n = surfels.size();
  absl::StatusOr<std::vector<int64_t>> cown = Owners(coarse, n);
  if (!cown.ok()) return fail("coarse: " + std::string(cown.status().message()));
  absl::StatusOr<std::vector<int64_t>> fown = Owners(fine, n);
  if (!fown.ok()) return fail("fine: " + std::string(fown.status().message()));
  // Every fine element lies inside one coarse element.
  for (size_t c = 0; c < fine.clusters.size(); ++c) {
    const Cluster& cl = fine.clusters[c];
    const int64_t o = (*cown)[cl.first_point];
    for (uint64_t i = cl.first_point; i < cl.first_point + cl.point_count; ++i) {
      if ((*cown)[i] != o || o == -1) {
        return fail(
            absl::StrFormat("fine cluster %d (points [%d, +%d)) is not inside one "
                            "coarse element",
                            c, cl.first_point, cl.point_count));
      }
    }
  }
  for (uint64_t id : fine.surfel_ids) {
    if ((*cown)[id] == -1) {
      return fail(absl::StrFormat("fine surfel %d is not represented by the coarse cut", id));
    }
  }
  // Coarse elements that stand for at least one surfel in front.
  const glm::vec3 nrm = glm::normalize(receiver.normal);
  std::vector<char> live(coarse.size(), 0);
  for (uint64_t i = 0; i < n; ++i) {
    if ((*cown)[i] != -1 && InFront(surfels[i], receiver, nrm, coarse_cut)) live[(*cown)[i]] = 1;
  }
  const size_t needed = static_cast<size_t>(std::count(live.begin(), live.end(), 1));
  if (fine.size() < needed) {
    return fail(absl::StrFormat("%d fine elements for %d coarse elements with surfels in front",
                                fine.size(), needed));
  }
  return absl::OkStatus();
}

absl::StatusOr<std::vector<Surfel>> ReadAllSurfels(Database& db) {
  absl::StatusOr<std::unique_ptr<Reader>> reader = db.NewReader();
  if (!reader.ok()) return reader.status();
  std::vector<Surfel> all;
  all.reserve(db.meta().point_count);
  // In slices so that a small cache is enough.
  const uint64_t n = db.meta().point_count;
  for (uint64_t i = 0; i < n; i += 4096) {
    absl::Status s = (*reader)->ReadPoints(i, std::min<uint64_t>(4096, n - i), &all);
    if (!s.ok()) return s;
  }
  return all;
}

namespace {

// Three draws of `u` as a vector, z drawn first. A call's arguments are not sequenced, and GCC
// and clang evaluate them in opposite orders; this is GCC's, so that a seed gives the scenes and
// receivers it gave before, whichever compiler built the harness.
template <class Dist, class Rng>
glm::vec3 Draw3(Dist& u, Rng& rng) {
  const float z = u(rng), y = u(rng), x = u(rng);
  return glm::vec3(x, y, z);
}

}  // namespace

std::vector<Surfel> RandomSceneSurfels(size_t count, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  auto unit = [&]() {
    glm::vec3 v;
    do {
      v = Draw3(u, rng) * 2.0f - 1.0f;
    } while (glm::dot(v, v) > 1.0f || glm::dot(v, v) < 1e-4f);
    return glm::normalize(v);
  };
  struct Patch {
    glm::vec3 origin, a, b, n;
  };
  std::vector<Patch> patches;
  const int np = 4;
  for (int i = 0; i < np; ++i) {
    glm::vec3 n = unit();
    glm::vec3 t = glm::normalize(
        glm::cross(n, std::abs(n.x) < 0.9f ? glm::vec3(1, 0, 0) : glm::vec3(0, 1, 0)));
    glm::vec3 bt = glm::cross(n, t);
    const float size = 0.3f + 0.4f * u(rng);
    const glm::vec3 a = t * size, c = bt * size;
    // Place the patch wholly inside the unit cube (its extent per axis is below 1).
    const glm::vec3 lo = glm::min(glm::min(glm::vec3(0.0f), a), glm::min(c, a + c));
    const glm::vec3 hi = glm::max(glm::max(glm::vec3(0.0f), a), glm::max(c, a + c));
    const glm::vec3 room = glm::max(glm::vec3(1.0f) - (hi - lo), glm::vec3(0.0f));
    const glm::vec3 o = -lo + Draw3(u, rng) * room;
    patches.push_back({o, a, c, n});
  }
  const glm::vec3 centre(0.5f + 0.2f * (u(rng) - 0.5f), 0.5f, 0.5f);
  const float sphere_r = 0.2f;
  std::vector<Surfel> out;
  out.reserve(count);
  const float spacing = 1.0f / std::sqrt(static_cast<float>(std::max<size_t>(count, 1)) / 2.0f);
  for (size_t i = 0; i < count; ++i) {
    Surfel s;
    if (i % 3 == 2) {  // a third on the sphere
      glm::vec3 d = unit();
      s.position = centre + sphere_r * d;
      s.normal = d;
    } else {
      const Patch& p = patches[rng() % np];
      const float tb = u(rng), ta = u(rng);  // the same order (Draw3)
      s.position = p.origin + ta * p.a + tb * p.b;
      s.normal = p.n;
    }
    s.radius = spacing * (0.4f + 0.4f * u(rng));
    s.radiance = Draw3(u, rng);
    out.push_back(s);
  }
  return out;
}

std::vector<Receiver> RandomReceivers(size_t count, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::vector<Receiver> out(count);
  for (Receiver& r : out) {
    r.position = Draw3(u, rng) * 1.4f - 0.2f;
    glm::vec3 v;
    do {
      v = Draw3(u, rng) * 2.0f - 1.0f;
    } while (glm::dot(v, v) > 1.0f || glm::dot(v, v) < 1e-4f);
    r.normal = glm::normalize(v);
  }
  return out;
}

}  // namespace pbgi::testing
