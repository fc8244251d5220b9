// Analytic test scenes for the rasterizer: disks and spheres of surfels, and clusters
// aggregated from groups of surfels the way the builder does (SH sums in double).
#ifndef PBGI_TESTS_RASTER_SCENES_H_
#define PBGI_TESTS_RASTER_SCENES_H_

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <map>
#include <tuple>
#include <utility>
#include <vector>

#include "glm/geometric.hpp"
#include "glm/mat3x3.hpp"
#include "glm/vec3.hpp"
#include "pbgi/sh.h"
#include "pbgi/surfel.h"

namespace pbgi::testing_raster {

constexpr double kPi = sh::kPi;

// An orthonormal basis (t, b) perpendicular to unit n.
inline void Basis(const glm::vec3& n, glm::vec3* t, glm::vec3* b) {
  const glm::vec3 a = std::fabs(n.x) < 0.9f ? glm::vec3(1, 0, 0) : glm::vec3(0, 1, 0);
  *t = glm::normalize(glm::cross(a, n));
  *b = glm::cross(n, *t);
}

// A deterministic uniform number in [0, 1) from an integer (a 32-bit integer hash).
inline float Hash01(uint32_t x) {
  x ^= x >> 16;
  x *= 0x7feb352dU;
  x ^= x >> 15;
  x *= 0x846ca68bU;
  x ^= x >> 16;
  return static_cast<float>(x >> 8) * (1.0f / 16777216.0f);
}

// A disk of radius `radius` centred at `centre` with unit normal `normal`, made of surfels on a
// square grid of pitch `pitch`; each surfel's area is pitch^2, so the areas sum to the disk's.
// `jitter` moves each centre to a random point of its grid square (stratified sampling).
inline std::vector<Surfel> DiskSurfels(const glm::vec3& centre, const glm::vec3& normal,
                                       float radius, float pitch,
                                       const glm::vec3& radiance = glm::vec3(0.0f),
                                       bool jitter = false) {
  glm::vec3 t, b;
  Basis(normal, &t, &b);
  std::vector<Surfel> out;
  const int n = static_cast<int>(std::ceil(radius / pitch));
  const float r = pitch / std::sqrt(static_cast<float>(kPi));
  for (int j = -n; j <= n; ++j) {
    for (int i = -n; i <= n; ++i) {
      float u = (i + 0.5f) * pitch, v = (j + 0.5f) * pitch;
      if (u * u + v * v > radius * radius) continue;
      if (jitter) {
        // Stratified like the scene sampler: one uniform point per lattice square.
        u += (Hash01(uint32_t(i) * 73856093u ^ uint32_t(j) * 19349663u) - 0.5f) * pitch;
        v += (Hash01(uint32_t(i) * 83492791u ^ uint32_t(j) * 2654435761u) - 0.5f) * pitch;
      }
      Surfel s;
      s.position = centre + u * t + v * b;
      s.normal = normal;
      s.radius = r;
      s.radiance = radiance;
      out.push_back(s);
    }
  }
  return out;
}

// n surfels on a sphere (Fibonacci lattice), normals inward or outward, areas summing to the
// sphere's area.
inline std::vector<Surfel> SphereSurfels(const glm::vec3& centre, float radius, int n, bool inward,
                                         const glm::vec3& radiance = glm::vec3(0.0f)) {
  std::vector<Surfel> out;
  const double golden = kPi * (3.0 - std::sqrt(5.0));
  const float r = static_cast<float>(2.0 * radius / std::sqrt(static_cast<double>(n)));
  for (int i = 0; i < n; ++i) {
    const double z = 1.0 - (2.0 * i + 1.0) / n;
    const double rho = std::sqrt(std::max(0.0, 1.0 - z * z));
    const double phi = golden * i;
    const glm::vec3 dir(static_cast<float>(rho * std::cos(phi)),
                        static_cast<float>(rho * std::sin(phi)), static_cast<float>(z));
    Surfel s;
    s.position = centre + radius * dir;
    s.normal = inward ? -dir : dir;
    s.radius = r;  // pi r^2 = 4 pi R^2 / n
    s.radiance = radiance;
    out.push_back(s);
  }
  return out;
}

// One cluster standing for `surfels`, as the builder aggregates it (a two-sided surfel as the
// pair n, -n: build/octree_builder.cc).
inline Cluster Aggregate(const std::vector<Surfel>& surfels) {
  Cluster c;
  std::array<double, 9> area{};
  std::array<std::array<double, 9>, 3> power{};
  double total = 0.0;
  for (const Surfel& s : surfels) {
    const double a = s.Area();
    total += a;
    c.bounds.Extend(s.position);
    const auto c1 = sh::ProjectClampedCosine<double>(s.normal.x, s.normal.y, s.normal.z, a);
    std::array<double, 9> y = c1;
    std::array<std::array<double, 9>, 3> p;
    for (int ch = 0; ch < 3; ++ch) {
      if (s.two_sided) {  // front on n's lobe, back on -n's
        sh::ProjectTwoSided(c1.data(), double{s.radiance[ch]}, double{s.back_radiance[ch]},
                            p[ch].data());
      } else {
        for (int i = 0; i < 9; ++i) p[ch][i] = c1[i] * s.radiance[ch];
      }
    }
    if (s.two_sided) {  // the pair (n, -n)
      for (int i = 0; i < 9; ++i) y[i] = (i >= 1 && i <= 3) ? 0.0 : 2.0 * y[i];
    }
    for (int i = 0; i < 9; ++i) {
      area[i] += y[i];
      for (int ch = 0; ch < 3; ++ch) power[ch][i] += p[ch][i];
    }
  }
  c.area = static_cast<float>(total);
  for (int i = 0; i < 9; ++i) {
    c.sh_area[i] = static_cast<float>(area[i]);
    for (int ch = 0; ch < 3; ++ch) c.sh_power[ch][i] = static_cast<float>(power[ch][i]);
  }
  c.point_count = surfels.size();
  return c;
}

// Groups surfels into cubic cells of edge `cell` and aggregates each group into a cluster.
inline std::vector<Cluster> Clusters(const std::vector<Surfel>& surfels, float cell) {
  std::map<std::tuple<int, int, int>, std::vector<Surfel>> groups;
  for (const Surfel& s : surfels) {
    const glm::vec3 q = glm::floor(s.position / cell);
    groups[{static_cast<int>(q.x), static_cast<int>(q.y), static_cast<int>(q.z)}].push_back(s);
  }
  std::vector<Cluster> out;
  for (const auto& [key, group] : groups) out.push_back(Aggregate(group));
  return out;
}

// Clusters() with each cluster's octree-like cell set (the cube of edge `cell` that holds it),
// as Gather returns them.
inline std::vector<Cluster> ClustersInCells(const std::vector<Surfel>& surfels, float cell) {
  std::map<std::tuple<int, int, int>, std::vector<Surfel>> groups;
  for (const Surfel& s : surfels) {
    const glm::vec3 q = glm::floor(s.position / cell);
    groups[{static_cast<int>(q.x), static_cast<int>(q.y), static_cast<int>(q.z)}].push_back(s);
  }
  std::vector<Cluster> out;
  for (const auto& [key, group] : groups) {
    Cluster c = Aggregate(group);
    const auto [x, y, z] = key;
    c.cell.lo =
        glm::vec3(static_cast<float>(x), static_cast<float>(y), static_cast<float>(z)) * cell;
    c.cell.hi = c.cell.lo + cell;
    out.push_back(c);
  }
  return out;
}

// A square [-half, half]^2 at height h facing down (-z), surfels on a grid of pitch `pitch`
// (area pitch^2 each).
inline std::vector<Surfel> SquareSurfels(float half, float h, float pitch,
                                         const glm::vec3& radiance = glm::vec3(0.0f)) {
  std::vector<Surfel> out;
  const int n = static_cast<int>(std::lround(2.0f * half / pitch));
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      Surfel s;
      s.position = glm::vec3(-half + (i + 0.5f) * pitch, -half + (j + 0.5f) * pitch, h);
      s.normal = glm::vec3(0, 0, -1);
      s.radius = pitch / std::sqrt(static_cast<float>(kPi));
      s.radiance = radiance;
      out.push_back(s);
    }
  }
  return out;
}

// The form factor from a point at the origin with normal +z to the rectangle
// [x1, x2] x [y1, y2] at height h parallel to it (the corner formula, odd in each of X and Y,
// summed with signs).
inline double RectangleFormFactor(double x1, double x2, double y1, double y2, double h) {
  auto corner = [h](double x, double y) {
    const double ax = std::sqrt(h * h + x * x), ay = std::sqrt(h * h + y * y);
    return (x / ax * std::atan(y / ax) + y / ay * std::atan(x / ay)) / (2.0 * kPi);
  };
  return corner(x2, y2) - corner(x1, y2) - corner(x2, y1) + corner(x1, y1);
}

// The fraction of n x n stratified cosine-weighted directions w (unit, z > 0: the hemisphere of
// a receiver at the origin with normal +z) for which hit(w) is true: rays cast as a reference.
template <typename Hit>
double CosineRayFraction(int n, Hit hit) {
  int hits = 0;
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const double u = (i + 0.5) / n, v = (j + 0.5) / n, r = std::sqrt(u);
      const glm::dvec3 w(r * std::cos(2.0 * kPi * v), r * std::sin(2.0 * kPi * v),
                         std::sqrt(1.0 - u));
      hits += hit(w) ? 1 : 0;
    }
  }
  return static_cast<double>(hits) / (n * n);
}

// Applies p -> rot * (scale * p) + shift to a surfel (position, normal, radius).
inline Surfel Transform(const Surfel& s, const glm::mat3& rot, float scale,
                        const glm::vec3& shift) {
  Surfel o = s;
  o.position = rot * (scale * s.position) + shift;
  o.normal = glm::normalize(rot * s.normal);
  o.radius = s.radius * scale;
  return o;
}

inline std::vector<Surfel> Transform(const std::vector<Surfel>& in, const glm::mat3& rot,
                                     float scale, const glm::vec3& shift) {
  std::vector<Surfel> out;
  out.reserve(in.size());
  for (const Surfel& s : in) out.push_back(Transform(s, rot, scale, shift));
  return out;
}

// Rotation by `angle` about unit `axis` (Rodrigues).
inline glm::mat3 Rotation(const glm::vec3& axis_in, float angle) {
  const glm::vec3 a = glm::normalize(axis_in);
  const float c = std::cos(angle), s = std::sin(angle), t = 1.0f - c;
  glm::mat3 m;
  m[0] = glm::vec3(t * a.x * a.x + c, t * a.x * a.y + s * a.z, t * a.x * a.z - s * a.y);
  m[1] = glm::vec3(t * a.x * a.y - s * a.z, t * a.y * a.y + c, t * a.y * a.z + s * a.x);
  m[2] = glm::vec3(t * a.x * a.z + s * a.y, t * a.y * a.z - s * a.x, t * a.z * a.z + c);
  return m;
}

// The six walls of the room [-half, half]^3 facing inward, on a square grid of pitch `pitch`.
inline std::vector<Surfel> RoomSurfels(float half, float pitch) {
  std::vector<Surfel> out;
  const int n = static_cast<int>(std::lround(2.0f * half / pitch));
  const float r = pitch / std::sqrt(static_cast<float>(kPi));
  for (int axis = 0; axis < 3; ++axis) {
    for (float side : {-1.0f, 1.0f}) {
      for (int j = 0; j < n; ++j) {
        for (int i = 0; i < n; ++i) {
          Surfel s;
          s.position[axis] = side * half;
          s.position[(axis + 1) % 3] = -half + (static_cast<float>(i) + 0.5f) * pitch;
          s.position[(axis + 2) % 3] = -half + (static_cast<float>(j) + 0.5f) * pitch;
          s.normal = glm::vec3(0.0f);
          s.normal[axis] = -side;
          s.radius = r;
          out.push_back(s);
        }
      }
    }
  }
  return out;
}

}  // namespace pbgi::testing_raster

#endif  // PBGI_TESTS_RASTER_SCENES_H_
