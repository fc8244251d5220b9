// Consistent orientation of imported meshes: weld by position, propagate a winding across
// manifold edges, orient closed shells by signed volume and nesting parity, mark the rest thin.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <deque>
#include <numeric>
#include <unordered_map>
#include <utility>
#include <vector>

#include "glm/geometric.hpp"
#include "glm/mat3x3.hpp"
#include "pbgi/scene.h"

namespace pbgi {
namespace {

constexpr double kPi = 3.14159265358979323846;

// Welded vertex ids: positions closer than `tol` (per axis, looked up in the 27 neighbouring
// cells of a grid of that size) share one id. Files that duplicate vertices per face (STL, many
// PLY and glTF exports) only become connected this way.
std::vector<uint32_t> WeldVertices(const std::vector<glm::vec3>& p, double tol, int64_t* merged) {
  struct CellHash {
    size_t operator()(const glm::i64vec3& c) const {
      uint64_t h = static_cast<uint64_t>(c.x) * 0x9E3779B97F4A7C15ull;
      h ^= static_cast<uint64_t>(c.y) * 0xC2B2AE3D27D4EB4Full + (h << 6) + (h >> 2);
      h ^= static_cast<uint64_t>(c.z) * 0x165667B19E3779F9ull + (h << 6) + (h >> 2);
      return static_cast<size_t>(h);
    }
  };
  std::unordered_map<glm::i64vec3, std::vector<uint32_t>, CellHash> grid;
  grid.reserve(p.size());
  std::vector<uint32_t> id(p.size());
  *merged = 0;
  for (uint32_t v = 0; v < p.size(); ++v) {
    const glm::dvec3 q(p[v]);
    const glm::i64vec3 cell(std::floor(q.x / tol), std::floor(q.y / tol), std::floor(q.z / tol));
    uint32_t found = v;
    for (int dx = -1; dx <= 1 && found == v; ++dx) {
      for (int dy = -1; dy <= 1 && found == v; ++dy) {
        for (int dz = -1; dz <= 1 && found == v; ++dz) {
          auto it = grid.find(cell + glm::i64vec3(dx, dy, dz));
          if (it == grid.end()) continue;
          for (uint32_t r : it->second) {
            const glm::dvec3 d = glm::abs(glm::dvec3(p[r]) - q);
            if (d.x <= tol && d.y <= tol && d.z <= tol) {
              found = r;
              break;
            }
          }
        }
      }
    }
    id[v] = found;
    if (found == v) {
      grid[cell].push_back(v);
    } else {
      ++*merged;
    }
  }
  return id;
}

// The box of a mesh's triangles' vertices.
void TriangleBounds(const Mesh& mesh, glm::dvec3* lo, glm::dvec3* hi) {
  *lo = glm::dvec3(HUGE_VAL);
  *hi = glm::dvec3(-HUGE_VAL);
  for (const glm::uvec3& t : mesh.triangles) {
    for (int k = 0; k < 3; ++k) {
      *lo = glm::min(*lo, glm::dvec3(mesh.positions[t[k]]));
      *hi = glm::max(*hi, glm::dvec3(mesh.positions[t[k]]));
    }
  }
}

// The welding tolerance of a mesh whose triangles span [lo, hi]: a millionth of the diagonal,
// far above float rounding of coordinates written twice, far below any feature a sampler
// resolves.
double WeldTolerance(const glm::dvec3& lo, const glm::dvec3& hi) {
  return std::max(1e-6 * glm::length(hi - lo), 1e-30);
}

struct EdgeUse {
  uint64_t key;  // (min id << 32) | max id of the welded end points
  uint32_t tri;  // triangle using the edge
  bool forward;  // the triangle runs the edge from the min id to the max id
};

// Solid angle of triangle (a, b, c) seen from the origin, signed by its winding (Van Oosterom
// and Strackee's formula).
double SolidAngle(glm::dvec3 a, glm::dvec3 b, glm::dvec3 c) {
  const double la = glm::length(a), lb = glm::length(b), lc = glm::length(c);
  const double num = glm::dot(a, glm::cross(b, c));
  const double den = la * lb * lc + glm::dot(a, b) * lc + glm::dot(a, c) * lb + glm::dot(b, c) * la;
  return 2.0 * std::atan2(num, den);
}

struct Component {
  std::vector<uint32_t> tris;
  bool boundary = false;        // an edge used once by the component
  bool non_manifold = false;    // an edge used three or more times by the component
  bool non_orientable = false;  // the winding cannot be made consistent
  glm::dvec3 lo{HUGE_VAL}, hi{-HUGE_VAL};
  bool closed() const { return !boundary && !non_manifold && !non_orientable; }
};

// Orients one mesh in object space; `mirrored` when every placement mirrors it (then "outward"
// in world space is "inward" here). Returns per-triangle thin marks.
std::vector<bool> OrientMesh(Mesh& mesh, bool mirrored, OrientReport& r) {
  const size_t nt = mesh.triangles.size();
  std::vector<bool> thin(nt, false);
  if (nt == 0) return thin;
  glm::dvec3 lo, hi;
  TriangleBounds(mesh, &lo, &hi);
  const double tol = WeldTolerance(lo, hi);
  int64_t merged = 0;
  const std::vector<uint32_t> id = WeldVertices(mesh.positions, tol, &merged);
  r.welded_vertices += merged;

  std::vector<EdgeUse> uses;
  uses.reserve(3 * nt);
  std::vector<bool> collapsed(nt, false);
  for (uint32_t t = 0; t < nt; ++t) {
    const uint32_t w[3] = {id[mesh.triangles[t][0]], id[mesh.triangles[t][1]],
                           id[mesh.triangles[t][2]]};
    if (w[0] == w[1] || w[1] == w[2] || w[0] == w[2]) {
      collapsed[t] = true;  // welded into a sliver: left as it is, joins nothing
      ++r.collapsed_triangles;
      continue;
    }
    for (int k = 0; k < 3; ++k) {
      const uint32_t a = w[k], b = w[(k + 1) % 3];
      uses.push_back({(static_cast<uint64_t>(std::min(a, b)) << 32) | std::max(a, b), t, a < b});
    }
  }
  std::sort(uses.begin(), uses.end(), [](const EdgeUse& x, const EdgeUse& y) {
    return x.key != y.key ? x.key < y.key : x.tri < y.tri;
  });

  // Neighbours across manifold edges (exactly two uses): `same` when both run the edge the same
  // way, so that one of them must be flipped.
  struct Link {
    uint32_t other;
    bool same;
  };
  std::vector<std::vector<Link>> links(nt);
  for (size_t i = 0; i < uses.size();) {
    size_t j = i;
    while (j < uses.size() && uses[j].key == uses[i].key) ++j;
    if (j - i == 2 && uses[i].tri != uses[i + 1].tri) {
      const bool same = uses[i].forward == uses[i + 1].forward;
      links[uses[i].tri].push_back({uses[i + 1].tri, same});
      links[uses[i + 1].tri].push_back({uses[i].tri, same});
    }
    i = j;
  }

  // Components by breadth-first search across manifold edges, each triangle's flip relative to
  // its component's seed.
  std::vector<int32_t> comp(nt, -1);
  std::vector<uint8_t> flip(nt, 0);
  std::vector<Component> comps;
  std::deque<uint32_t> queue;
  for (uint32_t seed = 0; seed < nt; ++seed) {
    if (collapsed[seed] || comp[seed] >= 0) continue;
    const int32_t c = static_cast<int32_t>(comps.size());
    comps.emplace_back();
    Component& cc = comps.back();
    comp[seed] = c;
    queue.push_back(seed);
    while (!queue.empty()) {
      const uint32_t f = queue.front();
      queue.pop_front();
      cc.tris.push_back(f);
      for (int k = 0; k < 3; ++k) {
        cc.lo = glm::min(cc.lo, glm::dvec3(mesh.positions[mesh.triangles[f][k]]));
        cc.hi = glm::max(cc.hi, glm::dvec3(mesh.positions[mesh.triangles[f][k]]));
      }
      for (const Link& l : links[f]) {
        const uint8_t want = flip[f] ^ (l.same ? 1 : 0);
        if (comp[l.other] < 0) {
          comp[l.other] = c;
          flip[l.other] = want;
          queue.push_back(l.other);
        } else if (flip[l.other] != want) {
          cc.non_orientable = true;  // a Moebius strip, or faces glued the wrong way round
        }
      }
    }
  }

  // Closedness: every edge of a component used exactly twice by it, in opposite directions (an
  // edge shared with another component, as where two shells meet along an edge, still counts
  // as closed for each shell when each uses it twice).
  for (size_t i = 0; i < uses.size();) {
    size_t j = i;
    while (j < uses.size() && uses[j].key == uses[i].key) ++j;
    // Uses of this edge per component (few: usually one component, two uses).
    for (size_t a = i; a < j; ++a) {
      const int32_t c = comp[uses[a].tri];
      bool first = true;
      for (size_t b = i; b < a; ++b) first = first && comp[uses[b].tri] != c;
      if (!first) continue;
      int n = 0, balance = 0;
      for (size_t b = a; b < j; ++b) {
        if (comp[uses[b].tri] != c) continue;
        ++n;
        balance += (uses[b].forward != (flip[uses[b].tri] != 0)) ? 1 : -1;
      }
      if (n == 1) comps[c].boundary = true;
      if (n > 2) comps[c].non_manifold = true;
      if (n == 2 && balance != 0) comps[c].non_orientable = true;
    }
    i = j;
  }

  const auto corner = [&](uint32_t t, int k) {
    return glm::dvec3(mesh.positions[mesh.triangles[t][k]]);
  };
  // Winding of each triangle after its flip.
  const auto oriented = [&](uint32_t t, glm::dvec3* a, glm::dvec3* b, glm::dvec3* c) {
    *a = corner(t, 0);
    *b = corner(t, flip[t] ? 2 : 1);
    *c = corner(t, flip[t] ? 1 : 2);
  };
  // Generalised winding number of closed component `d` (as currently flipped) at p.
  const auto winding = [&](const Component& d, const glm::dvec3& p) {
    double sum = 0.0;
    for (uint32_t t : d.tris) {
      glm::dvec3 a, b, c;
      oriented(t, &a, &b, &c);
      sum += SolidAngle(a - p, b - p, c - p);
    }
    return sum / (4.0 * kPi);
  };

  // Closed shells: outward by signed volume, then a shell nested in an odd number of others
  // bounds a cavity and faces inward (towards the hollow, away from the matter around it).
  std::vector<int> closed;
  for (size_t c = 0; c < comps.size(); ++c) {
    if (!comps[c].closed()) continue;
    closed.push_back(static_cast<int>(c));
    const glm::dvec3 o = 0.5 * (comps[c].lo + comps[c].hi);
    double volume = 0.0;
    for (uint32_t t : comps[c].tris) {
      glm::dvec3 a, b, cc;
      oriented(t, &a, &b, &cc);
      volume += glm::dot(a - o, glm::cross(b - o, cc - o));
    }
    if (volume < 0.0) {
      for (uint32_t t : comps[c].tris) flip[t] ^= 1;
    }
  }
  // Which closed shells hold which: a shell can only lie inside one whose box holds its box. A
  // grid over the mesh's box finds those candidates without comparing every pair (a mesh of many
  // pebbles has many shells and few candidates each); a shell whose box spans too many cells
  // is a candidate for every one.
  std::vector<int> depth(comps.size(), 0);
  const int n = std::clamp(static_cast<int>(std::cbrt(static_cast<double>(closed.size()))), 1, 64);
  const glm::dvec3 cell = glm::max((hi - lo) / static_cast<double>(n), glm::dvec3(tol));
  const auto cell_of = [&](const glm::dvec3& p) {
    return glm::clamp(glm::ivec3(glm::floor((p - lo) / cell)), glm::ivec3(0), glm::ivec3(n - 1));
  };
  std::vector<std::vector<int>> grid(static_cast<size_t>(n) * n * n);
  std::vector<int> big;
  for (int d : closed) {
    const glm::ivec3 a = cell_of(comps[d].lo), b = cell_of(comps[d].hi);
    const glm::ivec3 span = b - a + 1;
    if (static_cast<int64_t>(span.x) * span.y * span.z > 512) {
      big.push_back(d);
      continue;
    }
    for (int x = a.x; x <= b.x; ++x) {
      for (int y = a.y; y <= b.y; ++y) {
        for (int z = a.z; z <= b.z; ++z)
          grid[(static_cast<size_t>(x) * n + y) * n + z].push_back(d);
      }
    }
  }
  // The winding numbers cost a pass over the holder's triangles per point: past this budget
  // the remaining shells are left facing out (and counted) rather than stall the import.
  constexpr int64_t kWindingBudget = int64_t{200} << 20;
  int64_t work = 0;
  for (int c : closed) {
    // A few centroids spread over the shell; each votes inside or outside of a candidate
    // holder (a centroid on a touching surface, winding near 1/2, abstains).
    const Component& cc = comps[c];
    const glm::ivec3 k = cell_of(0.5 * (cc.lo + cc.hi));
    std::vector<int> candidates = grid[(static_cast<size_t>(k.x) * n + k.y) * n + k.z];
    candidates.insert(candidates.end(), big.begin(), big.end());
    const size_t samples = std::min<size_t>(7, cc.tris.size());
    bool unchecked = false;
    for (int d : candidates) {
      const Component& dd = comps[d];
      if (d == c || glm::any(glm::lessThan(cc.lo, dd.lo - tol)) ||
          glm::any(glm::greaterThan(cc.hi, dd.hi + tol))) {
        continue;
      }
      if (work > kWindingBudget) {
        unchecked = true;
        break;
      }
      int in = 0, out = 0;
      for (size_t s = 0; s < samples; ++s) {
        const uint32_t t = cc.tris[(s * cc.tris.size()) / samples];
        const glm::dvec3 p = (corner(t, 0) + corner(t, 1) + corner(t, 2)) / 3.0;
        const double w = std::abs(winding(dd, p));
        work += static_cast<int64_t>(dd.tris.size());
        if (w > 0.75) ++in;
        if (w < 0.25) ++out;
      }
      if (in > out) ++depth[c];
    }
    if (unchecked) {
      depth[c] = 0;
      ++r.nesting_unchecked;
    }
  }

  for (size_t c = 0; c < comps.size(); ++c) {
    Component& cc = comps[c];
    ++r.components;
    bool invert = false;
    if (cc.closed()) {
      ++r.closed_components;
      if (depth[c] % 2 == 1) {
        ++r.cavities;
        invert = true;
      }
      if (mirrored) invert = !invert;
    } else {
      if (cc.non_orientable) {
        ++r.non_orientable_components;
      } else if (cc.non_manifold) {
        ++r.non_manifold_components;
      } else {
        ++r.open_components;
      }
      // Which side is the front of an open sheet is the author's call: keep the majority.
      size_t flips = 0;
      for (uint32_t t : cc.tris) flips += flip[t];
      invert = 2 * flips > cc.tris.size();
      for (uint32_t t : cc.tris) thin[t] = true;
      r.thin_triangles += static_cast<int64_t>(cc.tris.size());
    }
    for (uint32_t t : cc.tris) {
      if ((flip[t] != 0) != invert) {
        std::swap(mesh.triangles[t][1], mesh.triangles[t][2]);
        ++r.flipped_triangles;
      }
    }
  }
  return thin;
}

}  // namespace

namespace internal {

std::vector<uint32_t> MeshPieces(const Mesh& mesh) {
  const size_t nt = mesh.triangles.size();
  std::vector<uint32_t> piece(nt);
  std::iota(piece.begin(), piece.end(), 0u);
  if (nt == 0) return piece;
  glm::dvec3 lo, hi;
  TriangleBounds(mesh, &lo, &hi);
  int64_t merged = 0;
  const std::vector<uint32_t> id = WeldVertices(mesh.positions, WeldTolerance(lo, hi), &merged);
  auto find = [&](uint32_t t) {
    while (piece[t] != t) t = piece[t] = piece[piece[t]];
    return t;
  };
  // Triangles that share a welded edge (however many use it) are one piece.
  std::vector<std::pair<uint64_t, uint32_t>> edges;
  edges.reserve(3 * nt);
  for (uint32_t t = 0; t < nt; ++t) {
    for (int k = 0; k < 3; ++k) {
      const uint32_t a = id[mesh.triangles[t][k]], b = id[mesh.triangles[t][(k + 1) % 3]];
      if (a != b) {
        edges.push_back({(static_cast<uint64_t>(std::min(a, b)) << 32) | std::max(a, b), t});
      }
    }
  }
  std::sort(edges.begin(), edges.end());
  for (size_t i = 1; i < edges.size(); ++i) {
    if (edges[i].first != edges[i - 1].first) continue;
    const uint32_t a = find(edges[i - 1].second), b = find(edges[i].second);
    if (a != b) piece[std::max(a, b)] = std::min(a, b);
  }
  for (uint32_t t = 0; t < nt; ++t) piece[t] = find(t);
  return piece;
}

}  // namespace internal

OrientReport OrientScene(Scene* scene) {
  OrientReport r;
  // Per mesh: mirrored when every placement has a negative determinant; a mesh placed both ways
  // cannot face out everywhere and is oriented for its unmirrored placements.
  std::vector<int> plain(scene->meshes.size(), 0), mirror(scene->meshes.size(), 0);
  for (const Instance& inst : scene->instances) {
    if (inst.mesh >= scene->meshes.size()) continue;
    (glm::determinant(glm::mat3(inst.transform)) < 0.0f ? mirror : plain)[inst.mesh]++;
  }
  // Thin copies of materials, made once each and only where needed, so that closed parts that
  // share a material keep it.
  std::vector<int64_t> thin_copy(scene->materials.size(), -1);
  for (size_t m = 0; m < scene->meshes.size(); ++m) {
    if (plain[m] > 0 && mirror[m] > 0) ++r.mixed_mirror_meshes;
    Mesh& mesh = scene->meshes[m];
    const std::vector<bool> thin = OrientMesh(mesh, plain[m] == 0 && mirror[m] > 0, r);
    for (size_t t = 0; t < thin.size(); ++t) {
      if (!thin[t] || t >= mesh.materials.size()) continue;
      const uint32_t mat = mesh.materials[t];
      if (mat >= thin_copy.size() || scene->materials[mat].thin) continue;
      if (thin_copy[mat] < 0) {
        thin_copy[mat] = static_cast<int64_t>(scene->materials.size());
        Material copy = scene->materials[mat];
        copy.thin = true;
        scene->materials.push_back(copy);
        ++r.thin_materials;
      }
      mesh.materials[t] = static_cast<uint32_t>(thin_copy[mat]);
    }
  }
  return r;
}

}  // namespace pbgi
