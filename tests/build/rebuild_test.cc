// Databases built over each other and from clouds that lack radii and normals: a database
// replaced by a rebuild is swapped atomically (a Reader that has the old one open keeps reading
// it, whole and unchanged; a new open sees the new one), and a build that estimates what its
// source lacks stores positive radii, unit normals and says so in its meta record.
#include <cmath>
#include <random>
#include <vector>

#include "gtest/gtest.h"
#include "pbgi/build.h"
#include "pbgi/query.h"
#include "tests/build/test_clouds.h"

namespace pbgi {
namespace {

using testing_build::ScratchDir;

std::vector<Surfel> ReadAllPoints(Reader& reader, uint64_t count) {
  std::vector<Surfel> out;
  EXPECT_TRUE(reader.ReadPoints(0, count, &out).ok());
  return out;
}

TEST(RebuildTest, ReadersOfAReplacedDatabaseKeepTheOldOne) {
  ScratchDir dir("rebuild_swap");
  const std::string path = dir.Sub("db");
  const auto a = testing_build::SurfaceCloud(20000, 1);
  const auto b = testing_build::UniformCloud(5000, 2);
  BuildOptions o;
  o.memory_bytes = 32 << 20;
  VectorSurfelSource sa(a);
  ASSERT_TRUE(BuildDatabase(sa, path, o).ok());
  auto old_db = Database::Open(path);
  ASSERT_TRUE(old_db.ok()) << old_db.status();
  auto old_reader = (*old_db)->NewReader();
  ASSERT_TRUE(old_reader.ok());
  const auto before = ReadAllPoints(**old_reader, a.size());
  ASSERT_EQ(before.size(), a.size());

  VectorSurfelSource sb(b);
  ASSERT_TRUE(BuildDatabase(sb, path, o).ok());

  // The open Reader still reads the old database, every point as it was.
  EXPECT_EQ((*old_db)->meta().point_count, a.size());
  (*old_db)->DropCache();
  const auto again = ReadAllPoints(**old_reader, a.size());
  ASSERT_EQ(again.size(), before.size());
  for (size_t i = 0; i < before.size(); ++i) {
    ASSERT_EQ(again[i].position, before[i].position) << i;
    ASSERT_EQ(again[i].radius, before[i].radius) << i;
  }
  Gathered g;
  EXPECT_TRUE((*old_reader)->Gather({glm::vec3(0, 0, 3), glm::vec3(0, 0, -1)}, Cut{}, &g).ok());
  // A new open sees the new one.
  auto new_db = Database::Open(path);
  ASSERT_TRUE(new_db.ok());
  EXPECT_EQ((*new_db)->meta().point_count, b.size());
}

TEST(RebuildTest, EstimatedRadiiAndNormalsAreStoredAndNamed) {
  ScratchDir dir("rebuild_estimate");
  // A sphere of radius 1 without radii or normals.
  std::mt19937_64 rng(5);
  std::vector<Surfel> cloud(60000);
  for (Surfel& s : cloud) {
    s.position = glm::vec3(2, 0, 0) + testing_build::RandomUnit(rng);
    s.normal = glm::vec3(0.0f);
    s.radius = 0.0f;
  }
  BuildOptions o;
  o.memory_bytes = 32 << 20;
  o.channels = Channels::kOcclusion;
  VectorSurfelSource src(cloud, false);
  // Refused as it is: the radii and normals are zero.
  auto refused = BuildDatabase(src, dir.Sub("refused"), o);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("input surfel 0"), std::string::npos);
  o.estimate.radius = o.estimate.normals = true;
  o.provenance["input"] = "sphere";
  auto st = BuildDatabase(src, dir.Sub("db"), o);
  ASSERT_TRUE(st.ok()) << st.status();
  auto db = Database::Open(dir.Sub("db"));
  ASSERT_TRUE(db.ok());
  const auto& stats = (*db)->meta().stats;
  EXPECT_EQ(stats.at("radius"), "estimated from 16 nearest neighbours");
  EXPECT_EQ(stats.at("normals"),
            "estimated from 16 nearest neighbours (PCA, away from the centre)");
  EXPECT_EQ(stats.at("input"), "sphere");
  auto reader = (*db)->NewReader();
  ASSERT_TRUE(reader.ok());
  const auto pts = ReadAllPoints(**reader, cloud.size());
  ASSERT_EQ(pts.size(), cloud.size());
  double area = 0;
  for (const Surfel& s : pts) {
    ASSERT_GT(s.radius, 0.0f);
    ASSERT_NEAR(glm::length(s.normal), 1.0f, 1e-5f);
    ASSERT_GT(glm::dot(s.normal, s.position - glm::vec3(2, 0, 0)), 0.9f);
    area += s.Area();
  }
  EXPECT_NEAR(area / (4 * 3.14159265358979), 1.0, 0.05);
}

}  // namespace
}  // namespace pbgi
