// Test scenes shared by the shading tests.
#ifndef PBGI_TESTS_SHADE_SCENES_H_
#define PBGI_TESTS_SHADE_SCENES_H_

#include <vector>

#include "glm/vec3.hpp"
#include "pbgi/surfel.h"

namespace pbgi::testing_shade {

// A floor [0, 1]^2 (z = 0, facing up, radiance 1) and a wall across it at x = 0.5, 0.3 high,
// both faces (facing -x and +x, radiance 2 on the +x face): the floor's occlusion and irradiance
// change smoothly away from the wall and jump across it.
inline std::vector<Surfel> FloorAndWall() {
  std::vector<Surfel> s;
  const int n = 120;
  const float step = 1.0f / float(n), radius = 0.6f * step;
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      s.push_back({{(float(i) + 0.5f) * step, (float(j) + 0.5f) * step, 0.0f},
                   {0, 0, 1},
                   radius,
                   glm::vec3(1.0f)});
    }
  }
  for (int k = 0; k < 36; ++k) {
    for (int j = 0; j < n; ++j) {
      const float y = (float(j) + 0.5f) * step, z = (float(k) + 0.5f) * step;
      s.push_back({{0.4995f, y, z}, {-1, 0, 0}, radius, glm::vec3(0.5f)});
      s.push_back({{0.5005f, y, z}, {1, 0, 0}, radius, glm::vec3(2.0f)});
    }
  }
  return s;
}

}  // namespace pbgi::testing_shade

#endif  // PBGI_TESTS_SHADE_SCENES_H_
