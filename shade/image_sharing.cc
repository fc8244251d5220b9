// ShadeImageShared (shade/image_sharing.h).
#include "shade/image_sharing.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <limits>
#include <vector>

#include "base/tsan_region.h"
#include "glm/geometric.hpp"
#include "glm/trigonometric.hpp"
#include "oneapi/tbb/blocked_range.h"
#include "oneapi/tbb/combinable.h"
#include "oneapi/tbb/parallel_for.h"
#include "pbgi/status.h"
#include "shade/shared_value.h"

namespace pbgi::internal {
namespace {

constexpr uint32_t kNone = std::numeric_limits<uint32_t>::max();
constexpr int kMaxSpacing = 64;

// What is known of a receiver.
enum Known : uint8_t { kUnknown = 0, kShaded = 1, kMidpoint = 2 };

// The receivers on the image's pixels, and their geometry as the tests need it.
struct Pixels {
  int width = 0, height = 0;
  std::vector<uint32_t> receiver;  // per pixel: its receiver, or kNone
  absl::Span<const ShadeReceiver> receivers;
  std::vector<glm::vec3> normal;  // per receiver, unit
  absl::Span<const uint32_t> surface_id;

  uint32_t At(int x, int y) const {
    if (x < 0 || y < 0 || x >= width || y >= height) return kNone;
    return receiver[size_t(y) * size_t(width) + size_t(x)];
  }
  uint32_t Id(uint32_t r) const { return surface_id.empty() ? 0 : surface_id[r]; }
};

// One level of the refinement: cells of `size` pixels, (cx, cy) with corner (cx, cy) * size.
struct Level {
  int size = 0;
  int cells_x = 0, cells_y = 0;
  std::vector<uint32_t> active;   // cy * cells_x + cx
  std::vector<uint8_t> accepted;  // per cell of the level
  std::vector<uint32_t> leaves;   // the accepted cells
};

// A midpoint to resolve and the pairs of known pixels it may be interpolated between.
struct Midpoint {
  int x = 0, y = 0;
  int pairs = 0;
  std::array<std::array<int, 4>, 4> pair{};  // (xa, ya, xb, yb)
};

// The tests that make a cell or a segment safe to interpolate (see image_sharing.h).
class Tests {
 public:
  Tests(const Pixels& px, const ShadeOptions& options, absl::Span<const ShadeResult> out,
        absl::Span<const float> distance, const Agreement& agree)
      : px_(px),
        out_(out),
        distance_(distance),
        agree_(agree),
        cos_max_(std::cos(glm::radians(options.sharing.max_normal_angle_degrees))),
        plane_(options.sharing.max_plane_distance),
        radius_factor_(options.sharing.radius_factor) {}

  // Whether the cell (x0, y0, s), whose corners are known, may be interpolated: 0, or the number
  // of the first test that failed (1 a missing corner, 2 the values, 3 the ids, 4 the split
  // sphere, 5 and 6 the corners' normals and planes, 7 to 9 a pixel inside).
  bool Accept(int x0, int y0, int s) const { return Why(x0, y0, s) == 0; }
  int Why(int x0, int y0, int s) const {
    const int x1 = x0 + s, y1 = y0 + s;
    const std::array<uint32_t, 4> c = {px_.At(x0, y0), px_.At(x1, y0), px_.At(x0, y1),
                                       px_.At(x1, y1)};
    for (uint32_t r : c) {
      if (r == kNone) return 1;
    }
    const std::array<const ShadeResult*, 4> values = {&out_[c[0]], &out_[c[1]], &out_[c[2]],
                                                      &out_[c[3]]};
    if (!agree_(values)) return 2;
    std::array<glm::vec3, 4> p, n;
    float radius = std::numeric_limits<float>::infinity();
    const uint32_t id = px_.Id(c[0]);
    for (int k = 0; k < 4; ++k) {
      p[k] = px_.receivers[c[k]].position;
      n[k] = px_.normal[c[k]];
      radius = std::min(radius, distance_[c[k]]);
      if (px_.Id(c[k]) != id) return 3;
    }
    const float extent = std::max(glm::distance(p[0], p[3]), glm::distance(p[1], p[2]));
    if (!(extent <= radius_factor_ * radius)) return 4;
    const float plane_tol = plane_ * extent;
    for (int k = 0; k < 4; ++k) {
      for (int j = 0; j < 4; ++j) {
        if (j == k) continue;
        if (glm::dot(n[k], n[j]) < cos_max_) return 5;
        if (std::abs(glm::dot(n[k], p[j] - p[k])) > plane_tol) return 6;
      }
    }
    const float inv_s = 1.0f / float(s);
    for (int y = y0; y <= y1; ++y) {
      const float v = float(y - y0) * inv_s;
      for (int x = x0; x <= x1; ++x) {
        const uint32_t r = px_.At(x, y);
        if (r == kNone || px_.Id(r) != id) return 7;
        const glm::vec3& q = px_.receivers[r].position;
        const glm::vec3& nq = px_.normal[r];
        const float u = float(x - x0) * inv_s;
        const std::array<float, 4> w = {(1 - u) * (1 - v), u * (1 - v), (1 - u) * v, u * v};
        float off = 0;
        for (int k = 0; k < 4; ++k) {
          if (glm::dot(nq, n[k]) < cos_max_) return 8;
          off += w[k] * std::abs(glm::dot(n[k], q - p[k]));
        }
        if (off > plane_tol) return 9;
      }
    }
    return 0;
  }

  // The same tests on the segment from known pixel a to known pixel b (a line of pixels along a
  // row, a column or a diagonal): whether its midpoint may be interpolated between them; then
  // *spread says how far apart their values are (Agreement::Spread).
  bool Segment(int xa, int ya, int xb, int yb, float* spread) const {
    const uint32_t a = px_.At(xa, ya), b = px_.At(xb, yb);
    if (a == kNone || b == kNone || px_.Id(a) != px_.Id(b)) return false;
    *spread = agree_.Spread(out_[a], out_[b]);
    if (!(*spread <= 1.0f)) return false;
    const glm::vec3 pa = px_.receivers[a].position, pb = px_.receivers[b].position;
    const glm::vec3 na = px_.normal[a], nb = px_.normal[b];
    const float extent = glm::distance(pa, pb);
    if (!(extent <= radius_factor_ * std::min(distance_[a], distance_[b]))) return false;
    if (glm::dot(na, nb) < cos_max_) return false;
    const float plane_tol = plane_ * extent;
    if (std::abs(glm::dot(na, pb - pa)) > plane_tol ||
        std::abs(glm::dot(nb, pa - pb)) > plane_tol) {
      return false;
    }
    const int steps = std::max(std::abs(xb - xa), std::abs(yb - ya));
    const int dx = (xb - xa) / steps, dy = (yb - ya) / steps;
    for (int t = 1; t < steps; ++t) {
      const uint32_t r = px_.At(xa + t * dx, ya + t * dy);
      if (r == kNone || px_.Id(r) != px_.Id(a)) return false;
      const glm::vec3& q = px_.receivers[r].position;
      const glm::vec3& nq = px_.normal[r];
      if (glm::dot(nq, na) < cos_max_ || glm::dot(nq, nb) < cos_max_) return false;
      const float w = float(t) / float(steps);
      const float off =
          (1 - w) * std::abs(glm::dot(na, q - pa)) + w * std::abs(glm::dot(nb, q - pb));
      if (off > plane_tol) return false;
    }
    return true;
  }

 private:
  const Pixels& px_;
  absl::Span<const ShadeResult> out_;
  absl::Span<const float> distance_;
  const Agreement& agree_;
  const float cos_max_, plane_, radius_factor_;
};

// The Coons patch of an accepted cell (see image_sharing.h): its four edges, each piecewise
// linear through the known pixels on it.
class Patch {
 public:
  Patch(const Pixels& px, absl::Span<const ShadeResult> out, absl::Span<const uint8_t> known,
        int x0, int y0, int s)
      : s_(s) {
    Edge(px, out, known, x0, y0, 1, 0, top_.data());
    Edge(px, out, known, x0, y0 + s, 1, 0, bottom_.data());
    Edge(px, out, known, x0, y0, 0, 1, left_.data());
    Edge(px, out, known, x0 + s, y0, 0, 1, right_.data());
  }
  // At pixel (i, j) of the cell, 0 <= i, j <= s.
  SharedValue At(int i, int j) const {
    const float u = float(i) / float(s_), v = float(j) / float(s_);
    const SharedValue bilinear = (1 - u) * (1 - v) * top_[0] + u * (1 - v) * top_[s_] +
                                 (1 - u) * v * bottom_[0] + u * v * bottom_[s_];
    return (1 - v) * top_[i] + v * bottom_[i] + (1 - u) * left_[j] + u * right_[j] - bilinear;
  }

 private:
  // The edge from (x, y) along (dx, dy), s + 1 pixels; its ends are known corners.
  void Edge(const Pixels& px, absl::Span<const ShadeResult> out, absl::Span<const uint8_t> known,
            int x, int y, int dx, int dy, SharedValue* edge) const {
    int last = 0;
    edge[0] = SharedValue::Of(out[px.At(x, y)]);
    for (int t = 1; t <= s_; ++t) {
      const uint32_t r = px.At(x + t * dx, y + t * dy);
      if (known[r] == kUnknown) continue;
      edge[t] = SharedValue::Of(out[r]);
      for (int m = last + 1; m < t; ++m) {
        const float a = float(m - last) / float(t - last);
        edge[m] = (1 - a) * edge[last] + a * edge[t];
      }
      last = t;
    }
  }

  int s_;
  std::array<SharedValue, kMaxSpacing + 1> top_, bottom_, left_, right_;
};

}  // namespace

absl::Status ShadeImageShared(ShadeEngine& engine, absl::Span<const ShadeReceiver> receivers,
                              const ShadeOptions& options, absl::Span<ShadeResult> out,
                              absl::Span<uint8_t> shaded, SharingCounts* counts) {
  const SharingOptions& so = options.sharing;
  tbb::combinable<double> busy;  // thread time outside shading
  auto timed = [&](auto&& body) {
    const Stopwatch t;
    body();
    busy.local() += t.Seconds();
  };
  auto parallel = [&](size_t n, size_t grain, auto&& body) {
    const TsanRegion region;
    engine.arena().execute([&] {
      tbb::parallel_for(tbb::blocked_range<size_t>(0, n, grain),
                        [&](const tbb::blocked_range<size_t>& range) {
                          const TsanRegion::Task task(region);
                          timed([&] {
                            for (size_t k = range.begin(); k != range.end(); ++k) body(k);
                          });
                        });
    });
    region.Joined();
  };

  Pixels px;
  px.width = so.image.width;
  px.height = so.image.height;
  px.receivers = receivers;
  px.surface_id = so.image.surface_id;
  std::vector<uint8_t> known(receivers.size(), kUnknown);
  std::vector<float> distance(receivers.size(), std::numeric_limits<float>::infinity());
  timed([&] {
    px.receiver.assign(size_t(px.width) * size_t(px.height), kNone);
    px.normal.resize(receivers.size());
    for (size_t i = 0; i < receivers.size(); ++i) {
      px.receiver[so.image.pixel_of[i]] = static_cast<uint32_t>(i);
      px.normal[i] = glm::normalize(receivers[i].normal);
    }
  });

  // The sparse set: every spacing-th pixel in both directions.
  const int s0 = so.spacing;
  std::vector<uint32_t> request;
  timed([&] {
    for (int y = 0; y < px.height; y += s0) {
      for (int x = 0; x < px.width; x += s0) {
        const uint32_t r = px.At(x, y);
        if (r != kNone) request.push_back(r), known[r] = kShaded;
      }
    }
  });
  PBGI_RETURN_IF_ERROR(engine.Shade(request, distance.data()));
  std::vector<const ShadeResult*> first;
  for (uint32_t r : request) first.push_back(&out[r]);
  const Agreement agree(options, first);
  const Tests test(px, options, out, distance, agree);
  std::atomic<uint64_t> midpoints_interpolated{0};

  // Resolves each midpoint by the segment of smallest spread that passes the tests, else asks
  // for it to be shaded; then shades those.
  auto resolve = [&](std::vector<Midpoint>& mids) -> absl::Status {
    std::vector<uint8_t> interpolated(mids.size(), 0);
    parallel(mids.size(), 64, [&](size_t k) {
      const Midpoint& m = mids[k];
      float best = std::numeric_limits<float>::infinity();
      int pick = -1;
      for (int j = 0; j < m.pairs; ++j) {
        const auto& [xa, ya, xb, yb] = m.pair[j];
        float spread = 0;
        if (test.Segment(xa, ya, xb, yb, &spread) && spread < best) best = spread, pick = j;
      }
      if (pick < 0) return;
      const auto& [xa, ya, xb, yb] = m.pair[pick];
      const uint32_t a = px.At(xa, ya), b = px.At(xb, yb), r = px.At(m.x, m.y);
      out[r] =
          (0.5f * (SharedValue::Of(out[a]) + SharedValue::Of(out[b]))).Result(options.raster.clamp);
      distance[r] = std::min(distance[a], distance[b]);
      interpolated[k] = 1;
    });
    request.clear();
    timed([&] {
      for (size_t k = 0; k < mids.size(); ++k) {
        const uint32_t r = px.At(mids[k].x, mids[k].y);
        known[r] = interpolated[k] ? kMidpoint : kShaded;
        if (!interpolated[k]) request.push_back(r);
      }
    });
    midpoints_interpolated.fetch_add(mids.size() - request.size());
    PBGI_RETURN_IF_ERROR(engine.CheckCancel());
    return engine.Shade(request, distance.data());
  };

  std::vector<Level> levels;
  for (int s = s0; s >= 2; s /= 2) {
    Level& level = levels.emplace_back();
    level.size = s;
    level.cells_x = (std::max(1, px.width - 1) + s - 1) / s;
    level.cells_y = (std::max(1, px.height - 1) + s - 1) / s;
    level.accepted.assign(size_t(level.cells_x) * size_t(level.cells_y), 0);
    if (s == s0) {
      level.active.resize(level.accepted.size());
      for (size_t c = 0; c < level.active.size(); ++c) level.active[c] = static_cast<uint32_t>(c);
    } else {
      // The children of the cells that the level above split.
      const Level& up = levels[levels.size() - 2];
      timed([&] {
        for (uint32_t c : up.active) {
          if (up.accepted[c]) continue;
          const int cx = int(c % uint32_t(up.cells_x)), cy = int(c / uint32_t(up.cells_x));
          for (int j = 0; j < 2; ++j) {
            for (int i = 0; i < 2; ++i) {
              const int x = 2 * cx + i, y = 2 * cy + j;
              // A child that starts on the image's last column (row) holds only pixels of its
              // sibling's edge.
              if (x * s >= std::max(1, px.width - 1) || y * s >= std::max(1, px.height - 1)) {
                continue;
              }
              level.active.push_back(uint32_t(y) * uint32_t(level.cells_x) + uint32_t(x));
            }
          }
        }
      });
    }
    if (level.active.empty()) break;
    parallel(level.active.size(), 256, [&](size_t k) {
      const uint32_t c = level.active[k];
      const int cx = int(c % uint32_t(level.cells_x)), cy = int(c / uint32_t(level.cells_x));
      level.accepted[c] = test.Accept(cx * s, cy * s, s) ? 1 : 0;
    });

    // The split cells' midpoints, each once: first those of the edges (between the edge's two
    // corners), then the centres (between two opposite corners, or two opposite edge midpoints).
    const int h = s / 2;
    std::vector<Midpoint> edges, centres;
    std::vector<uint8_t> claimed;
    timed([&] {
      for (uint32_t c : level.active) {
        const int x0 = int(c % uint32_t(level.cells_x)) * s;
        const int y0 = int(c / uint32_t(level.cells_x)) * s;
        if (level.accepted[c]) {
          level.leaves.push_back(c);
          continue;
        }
        const int x1 = x0 + s, y1 = y0 + s;
        for (const std::array<int, 4>& e : {std::array<int, 4>{x0, y0, x1, y0},
                                            {x0, y0, x0, y1},
                                            {x1, y0, x1, y1},
                                            {x0, y1, x1, y1}}) {
          const int x = (e[0] + e[2]) / 2, y = (e[1] + e[3]) / 2;
          const uint32_t r = px.At(x, y);
          if (r == kNone || known[r] != kUnknown) continue;
          known[r] = kMidpoint;  // claimed; set for real by resolve()
          Midpoint m{x, y, 0, {}};
          if (px.At(e[0], e[1]) != kNone && px.At(e[2], e[3]) != kNone) m.pair[m.pairs++] = e;
          edges.push_back(m);
        }
        const uint32_t r = px.At(x0 + h, y0 + h);
        if (r != kNone && known[r] == kUnknown) {
          known[r] = kMidpoint;
          centres.push_back({x0 + h, y0 + h, 0, {}});
        }
      }
      // Claimed midpoints are unknown until resolved.
      for (const Midpoint& m : edges) known[px.At(m.x, m.y)] = kUnknown;
      for (const Midpoint& m : centres) known[px.At(m.x, m.y)] = kUnknown;
    });
    PBGI_RETURN_IF_ERROR(resolve(edges));
    timed([&] {
      for (Midpoint& m : centres) {
        const int x0 = m.x - h, y0 = m.y - h, x1 = m.x + h, y1 = m.y + h;
        for (const std::array<int, 4>& e : {std::array<int, 4>{x0, y0, x1, y1},
                                            {x1, y0, x0, y1},
                                            {x0, m.y, x1, m.y},
                                            {m.x, y0, m.x, y1}}) {
          const uint32_t a = px.At(e[0], e[1]), b = px.At(e[2], e[3]);
          if (a != kNone && b != kNone && known[a] != kUnknown && known[b] != kUnknown) {
            m.pair[m.pairs++] = e;
          }
        }
      }
    });
    PBGI_RETURN_IF_ERROR(resolve(centres));
  }

  // Each pixel that is not known belongs to the smallest accepted cell that holds it (on a
  // shared edge, to the first such cell in row order: both give it the same value).
  std::vector<uint8_t> leaf_size;
  timed([&] {
    leaf_size.assign(px.receiver.size(), 0);
    for (const Level& level : levels) {
      const int s = level.size;
      for (uint32_t c : level.leaves) {
        const int x0 = int(c % uint32_t(level.cells_x)) * s;
        const int y0 = int(c / uint32_t(level.cells_x)) * s;
        for (int y = y0; y <= std::min(y0 + s, px.height - 1); ++y) {
          for (int x = x0; x <= std::min(x0 + s, px.width - 1); ++x) {
            leaf_size[size_t(y) * size_t(px.width) + size_t(x)] = static_cast<uint8_t>(s);
          }
        }
      }
    }
  });
  auto owner = [&](const Level& level, int x, int y) {
    const int s = level.size;
    const int cx = x / s, cy = y / s;
    for (int j = (y % s == 0 && cy > 0) ? -1 : 0; j <= 0; ++j) {
      for (int i = (x % s == 0 && cx > 0) ? -1 : 0; i <= 0; ++i) {
        if (cx + i >= level.cells_x || cy + j >= level.cells_y) continue;
        const uint32_t c = uint32_t(cy + j) * uint32_t(level.cells_x) + uint32_t(cx + i);
        if (level.accepted[c]) return c;
      }
    }
    return kNone;
  };
  std::vector<std::pair<uint32_t, uint32_t>> leaves;  // (level, cell)
  for (size_t l = 0; l < levels.size(); ++l) {
    for (uint32_t c : levels[l].leaves) leaves.push_back({uint32_t(l), c});
  }
  tbb::combinable<uint64_t> filled;
  parallel(leaves.size(), 16, [&](size_t k) {
    const Level& level = levels[leaves[k].first];
    const uint32_t c = leaves[k].second;
    const int s = level.size;
    const int x0 = int(c % uint32_t(level.cells_x)) * s;
    const int y0 = int(c / uint32_t(level.cells_x)) * s;
    const Patch patch(px, out, known, x0, y0, s);
    uint64_t n = 0;
    for (int y = y0; y <= y0 + s; ++y) {
      for (int x = x0; x <= x0 + s; ++x) {
        const uint32_t r = px.At(x, y);
        if (r == kNone || known[r] != kUnknown) continue;
        if (leaf_size[size_t(y) * size_t(px.width) + size_t(x)] != s || owner(level, x, y) != c) {
          continue;
        }
        out[r] = patch.At(x - x0, y - y0).Result(options.raster.clamp);
        ++n;
      }
    }
    filled.local() += n;
  });
  counts->interpolated = filled.combine(std::plus<>()) + midpoints_interpolated.load();
  counts->seconds = busy.combine(std::plus<>());
  engine.AddDone(counts->interpolated);
  if (!shaded.empty()) {
    for (size_t i = 0; i < receivers.size(); ++i) shaded[i] = known[i] == kShaded ? 1 : 0;
  }
  PBGI_RETURN_IF_ERROR(engine.status());
  if (counts->interpolated + engine.Stats().shaded != receivers.size()) {
    return absl::InternalError("kShared left receivers neither shaded nor interpolated");
  }
  return absl::OkStatus();
}

}  // namespace pbgi::internal
