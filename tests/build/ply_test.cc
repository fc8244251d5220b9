// PLY writer and reader: round trips (binary, ASCII, with and without colour), integer colours,
// extra properties, and malformed files with the record, line or byte offset in the error.
#include "pbgi/ply.h"

#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "pbgi/build.h"
#include "tests/build/test_clouds.h"

namespace pbgi {
namespace {

using testing_build::ScratchDir;

std::vector<Surfel> ReadAll(SurfelSource& src, size_t batch = 1000) {
  std::vector<Surfel> out, buf(batch);
  for (;;) {
    auto n = src.Next(absl::MakeSpan(buf));
    EXPECT_TRUE(n.ok()) << n.status();
    if (!n.ok() || *n == 0) break;
    out.insert(out.end(), buf.begin(), buf.begin() + *n);
  }
  return out;
}

void WriteFile(const std::string& path, const std::string& bytes) {
  std::ofstream f(path, std::ios::binary);
  f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

TEST(PlyTest, RoundTripsBinaryAndAsciiWithAndWithoutColour) {
  ScratchDir dir("ply_rt");
  const auto cloud = testing_build::UniformCloud(2500, 9, 3.0f, glm::vec3(100, -5, 0.25f));
  for (bool ascii : {false, true}) {
    for (bool colour : {true, false}) {
      SCOPED_TRACE(std::string(ascii ? "ascii" : "binary") + (colour ? " rgb" : " no rgb"));
      const std::string path = dir.Sub("c.ply");
      auto w = PlyWriter::Create(path, {ascii, colour});
      ASSERT_TRUE(w.ok()) << w.status();
      // Several writes of uneven sizes.
      ASSERT_TRUE((*w)->Write(absl::MakeConstSpan(cloud).subspan(0, 1)).ok());
      ASSERT_TRUE((*w)->Write(absl::MakeConstSpan(cloud).subspan(1, 1234)).ok());
      ASSERT_TRUE((*w)->Write(absl::MakeConstSpan(cloud).subspan(1235)).ok());
      EXPECT_EQ((*w)->count(), cloud.size());
      ASSERT_TRUE((*w)->Close().ok());

      auto src = OpenPly(path);
      ASSERT_TRUE(src.ok()) << src.status();
      EXPECT_EQ((*src)->KnownCount(), static_cast<int64_t>(cloud.size()));
      EXPECT_EQ((*src)->HasRadiance(), colour);
      for (int pass = 0; pass < 2; ++pass) {  // and again after Rewind
        auto got = ReadAll(**src, 777);
        ASSERT_EQ(got.size(), cloud.size());
        for (size_t i = 0; i < cloud.size(); ++i) {
          ASSERT_EQ(got[i].position, cloud[i].position) << i;
          ASSERT_EQ(got[i].normal, cloud[i].normal) << i;
          ASSERT_EQ(got[i].radius, cloud[i].radius) << i;
          ASSERT_EQ(got[i].radiance, colour ? cloud[i].radiance : glm::vec3(0.0f)) << i;
        }
        ASSERT_TRUE((*src)->Rewind().ok());
      }
    }
  }
}

TEST(PlyTest, ReadsUcharColoursExtraPropertiesAndOtherTypes) {
  ScratchDir dir("ply_types");
  const std::string path = dir.Sub("t.ply");
  WriteFile(path,
            "ply\nformat ascii 1.0\ncomment hand made\nelement vertex 2\n"
            "property double x\nproperty float y\nproperty int z\nproperty float confidence\n"
            "property float nx\nproperty float ny\nproperty float nz\nproperty float radius\n"
            "property uchar red\nproperty uchar green\nproperty uchar blue\n"
            "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
            "1.5 2 -3 0.9 0 0 1 0.25 255 0 51\n\n"
            "4 5 6 0.1 0 1 0 2 0 255 255\n"
            "3 0 1 0\n");
  auto src = OpenPly(path);
  ASSERT_TRUE(src.ok()) << src.status();
  EXPECT_TRUE((*src)->HasRadiance());
  auto got = ReadAll(**src);
  ASSERT_EQ(got.size(), 2u);
  EXPECT_EQ(got[0].position, glm::vec3(1.5f, 2.0f, -3.0f));
  EXPECT_EQ(got[0].radius, 0.25f);
  EXPECT_NEAR(got[0].radiance.x, 1.0f, 1e-6f);
  EXPECT_NEAR(got[0].radiance.z, 0.2f, 1e-6f);
  EXPECT_EQ(got[1].normal, glm::vec3(0, 1, 0));
}

absl::Status OpenAndRead(const std::string& path) {
  auto src = OpenPly(path);
  if (!src.ok()) return src.status();
  std::vector<Surfel> buf(64);
  for (;;) {
    auto n = (*src)->Next(absl::MakeSpan(buf));
    if (!n.ok()) return n.status();
    if (*n == 0) return absl::OkStatus();
  }
}

TEST(PlyTest, MalformedFilesAreErrorsThatSayWhere) {
  ScratchDir dir("ply_bad");
  const std::string p = dir.Sub("bad.ply");
  const std::string head7 =
      "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
      "property float nx\nproperty float ny\nproperty float nz\nproperty float radius\n"
      "end_header\n";
  struct Case {
    std::string body;
    std::string expect;
  } cases[] = {
      {"", "not a PLY"},
      {"hello\n", "not a PLY"},
      {"ply\nformat binary_big_endian 1.0\n" + head7, "unsupported format"},
      {"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n",
       "no 'y' property"},
      {"ply\nformat ascii 1.0\n" + head7 + "0 0 0 0 0 1 1\n0 0 0 0 0 1\n", "line 13 (record 1)"},
      {"ply\nformat ascii 1.0\n" + head7 + "0 0 0 0 0 1 1\n0 0 zero 0 0 1 1\n",
       "'zero' is not a number"},
      {"ply\nformat ascii 1.0\n" + head7 + "0 0 0 0 0 1 1\n", "after 1 of 3 records"},
      {"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n", "no end_header"},
      {"ply\nformat ascii 1.0\nelement face 1\nelement vertex 3\nend_header\n",
       "vertex element must come first"},
  };
  for (const Case& c : cases) {
    WriteFile(p, c.body);
    absl::Status s = OpenAndRead(p);
    ASSERT_FALSE(s.ok()) << c.body;
    EXPECT_NE(s.message().find(c.expect), std::string::npos) << s << "\nwanted: " << c.expect;
    EXPECT_NE(s.message().find(p), std::string::npos) << s;
  }
  EXPECT_FALSE(OpenPly(dir.Sub("missing.ply")).ok());
}

TEST(PlyTest, TruncatedBinaryNamesTheByteOffset) {
  ScratchDir dir("ply_trunc");
  const std::string path = dir.Sub("t.ply");
  const auto cloud = testing_build::UniformCloud(100, 3);
  {
    auto w = PlyWriter::Create(path);
    ASSERT_TRUE(w.ok());
    ASSERT_TRUE((*w)->Write(cloud).ok());
    ASSERT_TRUE((*w)->Close().ok());
  }
  const auto size = std::filesystem::file_size(path);
  std::filesystem::resize_file(path, size - 50);  // cuts record 98 (40 bytes each)
  absl::Status s = OpenAndRead(path);
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss);
  EXPECT_NE(s.message().find("byte offset " + std::to_string(size - 50)), std::string::npos) << s;
  EXPECT_NE(s.message().find("record 98 of 100"), std::string::npos) << s;
}

TEST(PlyTest, BuildRefusesAnInvalidRecordByNumberOrSkipsIt) {
  ScratchDir dir("ply_invalid");
  const std::string path = dir.Sub("i.ply");
  auto cloud = testing_build::UniformCloud(300, 4);
  cloud[123].normal = glm::vec3(0.0f);
  cloud[200].radius = -1.0f;
  cloud[250].position.x = INFINITY;
  {
    auto w = PlyWriter::Create(path);
    ASSERT_TRUE(w.ok());
    ASSERT_TRUE((*w)->Write(cloud).ok());
    ASSERT_TRUE((*w)->Close().ok());
  }
  auto src = OpenPly(path);
  ASSERT_TRUE(src.ok());
  BuildOptions o;
  auto b = BuildDatabase(**src, dir.Sub("db"), o);
  ASSERT_FALSE(b.ok());
  EXPECT_NE(b.status().message().find("surfel 123"), std::string::npos) << b.status();
  EXPECT_NE(b.status().message().find("normal is zero"), std::string::npos) << b.status();
  o.skip_invalid = true;
  auto ok = BuildDatabase(**src, dir.Sub("db"), o);
  ASSERT_TRUE(ok.ok()) << ok.status();
  EXPECT_EQ(ok->skipped, 3u);
  EXPECT_EQ(ok->points, 297u);
  auto store = PageStore::Open(dir.Sub("db"));
  ASSERT_TRUE(store.ok()) << store.status();
  EXPECT_TRUE(VerifyTree(**store).ok());
}

}  // namespace
}  // namespace pbgi
