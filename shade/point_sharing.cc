// ShadePointsShared (shade/point_sharing.h).
#include "shade/point_sharing.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <utility>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "base/math.h"
#include "base/tsan_region.h"
#include "glm/geometric.hpp"
#include "glm/trigonometric.hpp"
#include "oneapi/tbb/blocked_range.h"
#include "oneapi/tbb/combinable.h"
#include "oneapi/tbb/parallel_for.h"
#include "oneapi/tbb/parallel_sort.h"
#include "pbgi/status.h"
#include "shade/shared_value.h"
#include "tree/morton.h"

namespace pbgi::internal {
namespace {

constexpr int kBits = kMortonBitsPerAxis;  // per axis
constexpr int kMaxCandidates = 64;

struct Cube {
  glm::dvec3 origin{0.0};
  double side = 1.0;
};

Cube CubeAround(absl::Span<const ShadeReceiver> receivers) {
  Bounds b;
  for (const ShadeReceiver& r : receivers) b.Extend(r.position);
  const glm::dvec3 lo(b.lo), hi(b.hi);
  const glm::dvec3 c = 0.5 * (lo + hi);
  double half = 0.5 * std::max({hi.x - lo.x, hi.y - lo.y, hi.z - lo.z});
  const double mag = std::max({std::abs(c.x), std::abs(c.y), std::abs(c.z)});
  half = half * (1.0 + 1e-6) + mag * 1e-7 + 1e-30;
  if (!(half > 0) || !std::isfinite(half)) half = 1.0;
  return {c - glm::dvec3(half), 2.0 * half};
}

uint64_t CellKey(uint32_t x, uint32_t y, uint32_t z) {
  return (uint64_t(x) << (2 * kBits)) | (uint64_t(y) << kBits) | uint64_t(z);
}

// Whether directions (angles in the tangent plane) leave no gap of half a turn or more.
bool Surrounds(std::array<float, kMaxCandidates>& angle, int n) {
  if (n < 3) return false;
  std::sort(angle.begin(), angle.begin() + n);
  float gap = angle[0] + 2.0f * kPiFloat - angle[n - 1];
  for (int k = 1; k < n; ++k) gap = std::max(gap, angle[k] - angle[k - 1]);
  return gap < kPiFloat;
}

// A field of SharedValue, by index (0 occlusion, 1 coverage, 2-4 irradiance, 5-7 glossy).
constexpr int kFields = 8;
float& Field(SharedValue& v, int k) {
  return k == 0 ? v.occlusion : k == 1 ? v.coverage : k < 5 ? v.irradiance[k - 2] : v.glossy[k - 5];
}

// Fewest candidates for a plane fit to be tested: three fit any values exactly, so at least two
// more must agree with the plane the others make.
constexpr int kMinFitCandidates = 5;
// A plane interpolates when every candidate lies within this many tolerances of it: its error at
// the receiver is of the order of the candidates' residuals where the values curve (occlusion
// rising toward a wall's foot), so the bound is a quarter, not the half that the spread test's
// max - min <= tolerance allows a weighted mean (docs/shade.md, "Point sets").
constexpr float kFitResidual = 0.25f;

// The weighted least-squares plane f(u, v) = a + gu u + gv v through the candidates' values f[j]
// at their offsets (u[j], v[j]) in the receiver's tangent plane, per field; *at_receiver = a,
// clamped per field into the candidates' range (a fit never reaches outside what was shaded), and
// *residual the largest |f[j] - f(u[j], v[j])| per field. False when the offsets do not span the
// plane (their weighted variance along its thinnest direction under a ninth of the widest's).
bool FitPlane(const float* w, const float* u, const float* v, const SharedValue* f, int m,
              SharedValue* at_receiver, SharedValue* residual) {
  double sw = 0, su = 0, sv = 0;
  for (int j = 0; j < m; ++j) sw += w[j], su += w[j] * u[j], sv += w[j] * v[j];
  if (!(sw > 0)) return false;
  const double mu = su / sw, mv = sv / sw;
  double cuu = 0, cuv = 0, cvv = 0;
  double mean[kFields] = {}, cuf[kFields] = {}, cvf[kFields] = {};
  for (int j = 0; j < m; ++j) {
    const double du = u[j] - mu, dv = v[j] - mv;
    cuu += w[j] * du * du, cuv += w[j] * du * dv, cvv += w[j] * dv * dv;
    SharedValue fj = f[j];
    for (int k = 0; k < kFields; ++k) {
      const double x = Field(fj, k);
      mean[k] += w[j] * x, cuf[k] += w[j] * du * x, cvf[k] += w[j] * dv * x;
    }
  }
  // det / (tr / 2)^2 = 4 l1 l2 / (l1 + l2)^2 for the eigenvalues l1 >= l2: above 0.36 when l2
  // is more than a ninth of l1.
  const double det = cuu * cvv - cuv * cuv, tr = cuu + cvv;
  if (!(tr > 0) || !(det > 0.36 * 0.25 * tr * tr)) return false;
  double gu[kFields], gv[kFields], a[kFields];
  for (int k = 0; k < kFields; ++k) {
    mean[k] /= sw;
    gu[k] = (cvv * cuf[k] - cuv * cvf[k]) / det;
    gv[k] = (cuu * cvf[k] - cuv * cuf[k]) / det;
    a[k] = mean[k] - gu[k] * mu - gv[k] * mv;
  }
  SharedValue lo = f[0], hi = f[0], r;
  for (int j = 0; j < m; ++j) {
    SharedValue fj = f[j];
    for (int k = 0; k < kFields; ++k) {
      const float x = Field(fj, k);
      Field(lo, k) = std::min(Field(lo, k), x);
      Field(hi, k) = std::max(Field(hi, k), x);
      const float d = static_cast<float>(std::abs(x - (a[k] + gu[k] * u[j] + gv[k] * v[j])));
      Field(r, k) = std::max(Field(r, k), d);
    }
  }
  for (int k = 0; k < kFields; ++k) {
    Field(*at_receiver, k) = std::clamp(static_cast<float>(a[k]), Field(lo, k), Field(hi, k));
  }
  *residual = r;
  return true;
}

}  // namespace

absl::Status ShadePointsShared(ShadeEngine& engine, absl::Span<const ShadeReceiver> receivers,
                               const ShadeOptions& options, absl::Span<ShadeResult> out,
                               absl::Span<uint8_t> shaded, SharingCounts* counts) {
  const SharingOptions& so = options.sharing;
  const size_t n = receivers.size();
  tbb::combinable<double> busy;  // thread time outside shading
  auto timed = [&](auto&& body) {
    const Stopwatch t;
    body();
    busy.local() += t.Seconds();
  };

  const Cube cube = CubeAround(receivers);
  std::vector<std::array<uint32_t, 3>> q(n);
  std::vector<glm::vec3> normal(n);
  std::vector<uint64_t> morton(n);
  int first_level = kBits;
  timed([&] {
    const double scale = double(1u << kBits) / cube.side;
    for (size_t i = 0; i < n; ++i) {
      for (int a = 0; a < 3; ++a) {
        const double v = (double(receivers[i].position[a]) - cube.origin[a]) * scale;
        q[i][a] = v <= 0 ? 0u : static_cast<uint32_t>(std::min(v, double((1u << kBits) - 1)));
      }
      morton[i] = MortonEncode(q[i][0], q[i][1], q[i][2]);
      normal[i] = glm::normalize(receivers[i].normal);
    }
    // The first level whose occupied cells hold about spacing^2 receivers or fewer on average.
    std::vector<uint64_t> sorted = morton;
    tbb::parallel_sort(sorted.begin(), sorted.end());
    const double per_cell = double(so.spacing) * double(so.spacing);
    for (int level = 0; level <= kBits; ++level) {
      size_t cells = 0;
      for (size_t k = 0; k < sorted.size(); ++k) {
        if (k == 0 ||
            KeyPrefix(sorted[k], uint32_t(level)) != KeyPrefix(sorted[k - 1], uint32_t(level))) {
          ++cells;
        }
      }
      if (double(n) <= per_cell * double(cells)) {
        first_level = level;
        break;
      }
    }
  });

  std::vector<uint8_t> state(n, 0);  // 0 undecided, 1 shaded, 2 interpolated
  std::vector<float> distance(n, std::numeric_limits<float>::infinity());
  std::vector<uint32_t> todo(n), shaded_list, request;
  for (size_t i = 0; i < n; ++i) todo[i] = static_cast<uint32_t>(i);
  std::unique_ptr<Agreement> agree;
  tbb::combinable<uint64_t> interpolated;
  const float cos_max = std::cos(glm::radians(so.max_normal_angle_degrees));

  for (int level = first_level; level <= kBits && !todo.empty(); ++level) {
    const int shift = kBits - level;
    auto key_of = [&](uint32_t i) {
      return CellKey(q[i][0] >> shift, q[i][1] >> shift, q[i][2] >> shift);
    };
    // The shaded receivers by cell of this level.
    std::vector<std::pair<uint64_t, uint32_t>> by_cell;
    absl::flat_hash_map<uint64_t, std::pair<uint32_t, uint32_t>> cell_range;
    auto index_shaded = [&] {
      by_cell.clear();
      cell_range.clear();
      for (uint32_t i : shaded_list) by_cell.push_back({key_of(i), i});
      std::sort(by_cell.begin(), by_cell.end());
      for (uint32_t k = 0; k < by_cell.size();) {
        uint32_t e = k;
        while (e < by_cell.size() && by_cell[e].first == by_cell[k].first) ++e;
        cell_range[by_cell[k].first] = {k, e};
        k = e;
      }
    };
    // One shaded receiver in every cell with undecided ones and none shaded: the one nearest
    // the cell's centre (every one on the finest level, whose cells cannot be told apart).
    request.clear();
    timed([&] {
      index_shaded();
      std::vector<std::pair<uint64_t, uint32_t>> cells(todo.size());
      for (size_t k = 0; k < todo.size(); ++k) cells[k] = {key_of(todo[k]), todo[k]};
      std::sort(cells.begin(), cells.end());
      const double cell_side = cube.side / double(1u << level);
      for (size_t k = 0; k < cells.size();) {
        size_t e = k;
        while (e < cells.size() && cells[e].first == cells[k].first) ++e;
        if (level == kBits) {
          for (size_t m = k; m < e; ++m) request.push_back(cells[m].second);
        } else if (!cell_range.contains(cells[k].first)) {
          const uint32_t i0 = cells[k].second;
          const glm::dvec3 centre =
              cube.origin +
              cell_side *
                  (glm::dvec3(q[i0][0] >> shift, q[i0][1] >> shift, q[i0][2] >> shift) + 0.5);
          uint32_t best = i0;
          double best_d = std::numeric_limits<double>::infinity();
          for (size_t m = k; m < e; ++m) {
            const uint32_t i = cells[m].second;
            const double d = glm::distance(glm::dvec3(receivers[i].position), centre);
            if (d < best_d) best_d = d, best = i;  // ties: the lowest index (sorted)
          }
          request.push_back(best);
        }
        k = e;
      }
      for (uint32_t i : request) state[i] = 1, shaded_list.push_back(i);
    });
    PBGI_RETURN_IF_ERROR(engine.CheckCancel());
    PBGI_RETURN_IF_ERROR(engine.Shade(request, distance.data()));
    if (agree == nullptr) {
      std::vector<const ShadeResult*> first;
      for (uint32_t i : request) first.push_back(&out[i]);
      agree = std::make_unique<Agreement>(options, first);
    }
    timed([&] { index_shaded(); });

    const double side = cube.side / double(1u << level);
    const float eps2 = static_cast<float>(1e-8 * side * side);
    // Candidates within 1.5 cells: the shaded receivers of the adjacent cells' centres (1 to
    // 1.7 cells away) surround a receiver, and the agreement test spans no more than them.
    const float near = static_cast<float>(1.5 * side);
    const int cells_per_axis = 1 << level;
    const TsanRegion region;
    engine.arena().execute([&] {
      tbb::parallel_for(
          tbb::blocked_range<size_t>(0, todo.size(), 64),
          [&](const tbb::blocked_range<size_t>& range) {
            const TsanRegion::Task task(region);
            timed([&] {
              uint64_t done = 0;
              std::array<float, kMaxCandidates> weight, angle, u, v;
              std::array<const ShadeResult*, kMaxCandidates> values;
              std::array<SharedValue, kMaxCandidates> fields;
              for (size_t k = range.begin(); k != range.end(); ++k) {
                const uint32_t r = todo[k];
                if (state[r] != 0) continue;
                const glm::vec3 p = receivers[r].position, nr = normal[r];
                glm::vec3 t, b;
                OrthonormalBasis(nr, &t, &b);
                int m = 0;
                const int cx = int(q[r][0] >> shift), cy = int(q[r][1] >> shift),
                          cz = int(q[r][2] >> shift);
                for (int dz = -1; dz <= 1; ++dz) {
                  for (int dy = -1; dy <= 1; ++dy) {
                    for (int dx = -1; dx <= 1; ++dx) {
                      const int x = cx + dx, y = cy + dy, z = cz + dz;
                      if (x < 0 || y < 0 || z < 0 || x >= cells_per_axis || y >= cells_per_axis ||
                          z >= cells_per_axis) {
                        continue;
                      }
                      const auto it =
                          cell_range.find(CellKey(uint32_t(x), uint32_t(y), uint32_t(z)));
                      if (it == cell_range.end()) continue;
                      for (uint32_t e = it->second.first;
                           e < it->second.second && m < kMaxCandidates; ++e) {
                        const uint32_t s = by_cell[e].second;
                        const glm::vec3 d = receivers[s].position - p;
                        const float dist = glm::length(d);
                        const glm::vec3& ns = normal[s];
                        if (glm::dot(nr, ns) < cos_max) continue;
                        const float reach = so.radius_factor * distance[s];
                        if (!(dist <= reach) || dist > near) continue;
                        const float plane = so.max_plane_distance * dist;
                        if (std::abs(glm::dot(ns, d)) > plane ||
                            std::abs(glm::dot(nr, d)) > plane) {
                          continue;
                        }
                        const float taper = reach < std::numeric_limits<float>::infinity()
                                                ? 1.0f - (dist / reach) * (dist / reach)
                                                : 1.0f;
                        weight[m] = taper * taper / std::max(dist * dist, eps2);
                        u[m] = glm::dot(d, t) / near, v[m] = glm::dot(d, b) / near;
                        angle[m] = std::atan2(v[m], u[m]);
                        values[m] = &out[s];
                        ++m;
                      }
                    }
                  }
                }
                if (!Surrounds(angle, m)) continue;
                // A plane through the candidates' values that each lies within kFitResidual
                // tolerances of interpolates across a smooth gradient (a floor darkening toward
                // a wall), where their spread exceeds a tolerance; its value at the receiver is
                // also closer than the weighted mean wherever the values slope.
                for (int j = 0; j < m; ++j) fields[j] = SharedValue::Of(*values[j]);
                SharedValue fitted, residual;
                const bool fits = m >= kMinFitCandidates &&
                                  FitPlane(weight.data(), u.data(), v.data(), fields.data(), m,
                                           &fitted, &residual) &&
                                  agree->Within(residual, kFitResidual);
                if (fits) {
                  out[r] = fitted.Result(options.raster.clamp);
                } else {
                  if (!(*agree)(absl::MakeConstSpan(values.data(), size_t(m)))) continue;
                  SharedValue mean;
                  float total = 0;
                  for (int j = 0; j < m; ++j) {
                    mean += weight[j] * fields[j];
                    total += weight[j];
                  }
                  if (!(total > 0)) continue;
                  out[r] = ((1.0f / total) * mean).Result(options.raster.clamp);
                }
                state[r] = 2;
                ++done;
              }
              interpolated.local() += done;
            });
          });
    });
    region.Joined();
    timed([&] {
      size_t kept = 0;
      for (uint32_t r : todo) {
        if (state[r] == 0) todo[kept++] = r;
      }
      todo.resize(kept);
    });
  }
  counts->interpolated = interpolated.combine(std::plus<>());
  counts->seconds = busy.combine(std::plus<>());
  engine.AddDone(counts->interpolated);
  if (!shaded.empty()) {
    for (size_t i = 0; i < n; ++i) shaded[i] = state[i] == 1 ? 1 : 0;
  }
  if (!todo.empty() || counts->interpolated + shaded_list.size() != n) {
    return absl::InternalError("kShared left receivers neither shaded nor interpolated");
  }
  return engine.status();
}

}  // namespace pbgi::internal
