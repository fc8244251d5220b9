// Point clouds and a brute-force reference octree for the builder's tests.
#ifndef PBGI_TESTS_BUILD_TEST_CLOUDS_H_
#define PBGI_TESTS_BUILD_TEST_CLOUDS_H_

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "glm/geometric.hpp"
#include "pbgi/surfel.h"
#include "tests/common/scratch_dir.h"

namespace pbgi::testing_build {

inline Surfel MakeSurfel(glm::vec3 p, glm::vec3 n, float r, glm::vec3 l) {
  Surfel s;
  s.position = p;
  s.normal = glm::normalize(n);
  s.radius = r;
  s.radiance = l;
  return s;
}

inline glm::vec3 RandomUnit(std::mt19937_64& rng) {
  std::normal_distribution<float> g(0.0f, 1.0f);
  for (;;) {
    glm::vec3 v(g(rng), g(rng), g(rng));
    if (glm::length(v) > 1e-3f) return glm::normalize(v);
  }
}

inline std::vector<Surfel> UniformCloud(size_t n, uint64_t seed, float scale = 1.0f,
                                        glm::vec3 offset = glm::vec3(0.0f)) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f), c(0.0f, 1.0f);
  std::vector<Surfel> out;
  out.reserve(n);
  for (size_t i = 0; i < n; ++i) {
    glm::vec3 p = offset + scale * glm::vec3(u(rng), u(rng), u(rng));
    out.push_back(MakeSurfel(p, RandomUnit(rng), 0.01f * scale * (0.5f + c(rng)),
                             glm::vec3(c(rng), c(rng), c(rng))));
  }
  return out;
}

inline std::vector<Surfel> ClusteredCloud(size_t n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(-10.0f, 10.0f), c(0.0f, 1.0f);
  std::normal_distribution<float> g(0.0f, 0.05f);
  std::vector<glm::vec3> centers(7);
  for (auto& ctr : centers) ctr = glm::vec3(u(rng), u(rng), u(rng));
  std::vector<Surfel> out;
  for (size_t i = 0; i < n; ++i) {
    const glm::vec3& ctr = centers[i % centers.size()];
    out.push_back(MakeSurfel(ctr + glm::vec3(g(rng), g(rng), g(rng)), RandomUnit(rng), 0.002f,
                             glm::vec3(c(rng), 0.5f, 2.0f * c(rng))));
  }
  return out;
}

// Points on a sphere with outward normals, plus a ground plane: what a surfel sampler makes.
inline std::vector<Surfel> SurfaceCloud(size_t n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(-3.0f, 3.0f), c(0.0f, 1.0f);
  std::vector<Surfel> out;
  for (size_t i = 0; i < n; ++i) {
    if (i % 2 == 0) {
      glm::vec3 d = RandomUnit(rng);
      out.push_back(MakeSurfel(glm::vec3(0, 0, 1) + d, d, 0.02f, glm::vec3(0.8f, 0.2f, 0.1f)));
    } else {
      out.push_back(MakeSurfel(glm::vec3(u(rng), u(rng), 0.0f), glm::vec3(0, 0, 1), 0.03f,
                               glm::vec3(c(rng))));
    }
  }
  return out;
}

using ::pbgi::testing_common::ScratchDir;

}  // namespace pbgi::testing_build

#endif  // PBGI_TESTS_BUILD_TEST_CLOUDS_H_
