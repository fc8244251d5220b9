// After warm-up, Shade() allocates nothing: this binary counts every operator new.
#include <atomic>
#include <cstdlib>
#include <new>

#include "gtest/gtest.h"
#include "pbgi/raster.h"
#include "tests/raster/scenes.h"

namespace {
std::atomic<long> g_allocations{0};
}  // namespace

// g++ 12 with -fsanitize=address inlines gtest's `new TestClass` into a sized delete below and
// takes the replaced pair for a mismatch (-Wmismatched-new-delete, an error in the ASan suite):
// operator new and every delete here are malloc and free, which match.
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
#endif
void* operator new(std::size_t n) {
  g_allocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(n == 0 ? 1 : n)) return p;
  throw std::bad_alloc();
}
void* operator new[](std::size_t n) { return ::operator new(n); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }

namespace pbgi {
namespace {

TEST(RasterAllocTest, NoAllocationPerReceiverAfterWarmUp) {
  using testing_raster::Clusters;
  using testing_raster::DiskSurfels;
  Gathered g;
  g.surfels = DiskSurfels(glm::vec3(0, 0, 1), glm::vec3(0, 0, -1), 0.5f, 0.02f, glm::vec3(1.0f));
  g.clusters = Clusters(
      DiskSurfels(glm::vec3(0, 0, 2), glm::vec3(0, 0, -1), 2.0f, 0.05f, glm::vec3(0.5f)), 0.3f);
  // A near surfel for the exact-disk path.
  Surfel near;
  near.position = glm::vec3(0.1f, 0, 0.2f);
  near.normal = glm::vec3(0, 0, -1);
  near.radius = 0.1f;
  g.surfels.push_back(near);
  MicroBuffer mb;
  RasterOptions o;
  o.lobe = GlossyLobe::kGgx;
  ShadeReceiver r;
  r.reflection = glm::normalize(glm::vec3(1, 0, 1));
  ShadeResult out;
  ASSERT_TRUE(Shade(g, r, o, &mb, &out).ok());  // warm-up
  ASSERT_GT(out.near_disks_drawn, 0u);
  const long before = g_allocations.load();
  for (int i = 0; i < 20; ++i) {
    r.position = glm::vec3(0.01f * i, 0.0f, 0.0f);
    ASSERT_TRUE(Shade(g, r, o, &mb, &out).ok());
  }
  EXPECT_EQ(g_allocations.load() - before, 0);
  EXPECT_GT(out.occlusion, 0.4f);  // it really drew: the far disk alone gives 0.5
}

}  // namespace
}  // namespace pbgi
