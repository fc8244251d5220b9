// PLY writer and reader: round trips (binary, ASCII, with and without colour), integer colours,
// extra properties, and malformed files with the record, line or byte offset in the error.
#include "pbgi/ply.h"

#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "gmock/gmock.h"
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
      PlyWriterOptions wo;
      wo.ascii = ascii;
      wo.radiance = colour;
      auto w = PlyWriter::Create(path, wo);
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

// Surfel::two_sided and Surfel::sheet round-trip through the optional `uchar two_sided` and
// `uchar sheet` properties (binary and ASCII, with and without colour and extras); files
// without them read as one-sided, any nonzero value of another type counts as two-sided, and a
// tag means something on two-sided surfels only.
TEST(PlyTest, TwoSidedFlagRoundTrips) {
  ScratchDir dir("ply_two_sided");
  auto cloud = testing_build::UniformCloud(1500, 4, 2.0f, glm::vec3(0.0f));
  for (size_t i = 0; i < cloud.size(); ++i) {
    cloud[i].two_sided = (i * 7) % 3 == 0;
    cloud[i].sheet = cloud[i].two_sided ? static_cast<uint8_t>(i % 256) : 0;
    if (cloud[i].two_sided) cloud[i].back_radiance = glm::vec3(0.125f * (i % 5), 0.3f, 7.0f);
  }
  for (bool ascii : {false, true}) {
    for (bool colour : {true, false}) {
      for (bool flag : {true, false}) {
        SCOPED_TRACE(std::string(ascii ? "ascii" : "binary") + (colour ? " rgb" : " no rgb") +
                     (flag ? " flag" : " no flag"));
        const std::string path = dir.Sub("t.ply");
        PlyWriterOptions wo;
        wo.ascii = ascii;
        wo.radiance = colour;
        wo.two_sided = flag;
        wo.extra = {"occlusion"};
        auto w = PlyWriter::Create(path, wo);
        ASSERT_TRUE(w.ok()) << w.status();
        std::vector<float> extra(cloud.size(), 0.25f);
        ASSERT_TRUE((*w)->Write(cloud, extra).ok());
        ASSERT_TRUE((*w)->Close().ok());
        auto src = OpenPlyFile(path);
        ASSERT_TRUE(src.ok()) << src.status();
        EXPECT_EQ((*src)->header().has_two_sided, flag);
        auto got = ReadAll(**src, 333);
        ASSERT_EQ(got.size(), cloud.size());
        for (size_t i = 0; i < cloud.size(); ++i) {
          ASSERT_EQ(got[i].position, cloud[i].position) << i;
          ASSERT_EQ(got[i].radius, cloud[i].radius) << i;
          ASSERT_EQ(got[i].two_sided, flag && cloud[i].two_sided) << i;
          ASSERT_EQ(got[i].sheet, flag ? cloud[i].sheet : 0) << i;
          // The back radiance travels with the flag and the radiance (`back_r back_g
          // back_b`); a two-sided surfel without it shows its radiance on both sides.
          const glm::vec3 back = !(flag && cloud[i].two_sided) ? glm::vec3(0.0f)
                                 : colour                      ? cloud[i].back_radiance
                                                               : got[i].radiance;
          ASSERT_EQ(got[i].back_radiance, back) << i;
        }
        EXPECT_EQ((*src)->header().has_back_radiance, flag && colour);
      }
    }
  }
  const std::string path = dir.Sub("f.ply");
  WriteFile(path,
            "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            "property float z\nproperty float nx\nproperty float ny\nproperty float nz\n"
            "property float radius\nproperty float two_sided\nproperty int sheet\nend_header\n"
            "0 0 0 0 0 1 1 0 4\n1 0 0 0 0 1 1 0.5 300\n2 0 0 0 0 1 1 1 17\n");
  auto src = OpenPly(path);
  ASSERT_TRUE(src.ok()) << src.status();
  const auto got = ReadAll(**src);
  ASSERT_EQ(got.size(), 3u);
  EXPECT_FALSE(got[0].two_sided);
  EXPECT_TRUE(got[1].two_sided);
  EXPECT_TRUE(got[2].two_sided);
  EXPECT_EQ(got[0].sheet, 0);  // one-sided
  EXPECT_EQ(got[1].sheet, 0);  // out of range
  EXPECT_EQ(got[2].sheet, 17);
  // A back radiance needs all three channels.
  const std::string part = dir.Sub("g.ply");
  WriteFile(part,
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
            "property float z\nproperty float nx\nproperty float ny\nproperty float nz\n"
            "property float radius\nproperty uchar two_sided\nproperty float back_r\n"
            "property float back_g\nend_header\n0 0 0 0 0 1 1 1 0.5 0.5\n");
  auto bad = OpenPly(part);
  ASSERT_FALSE(bad.ok());
  EXPECT_THAT(bad.status().message(), ::testing::HasSubstr("back_r back_g back_b"));
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
      {"ply\nformat binary_middle_endian 1.0\n" + head7, "unsupported format"},
      {"ply\nformat ascii 1.0\n" + head7.substr(0, 17) + "bogus line\n" + head7.substr(17),
       "unexpected keyword 'bogus'"},
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

namespace pbgi {
namespace {

using testing_build::ScratchDir;

std::string BigEndianFloats(const std::vector<float>& v) {
  std::string out;
  for (float f : v) {
    uint32_t b;
    std::memcpy(&b, &f, 4);
    for (int k = 3; k >= 0; --k) out.push_back(static_cast<char>((b >> (8 * k)) & 0xff));
  }
  return out;
}

TEST(PlyRegressionTest, BigEndianBinaryIsReadLikeLittleEndian) {
  ScratchDir dir("ply_be");
  const std::string path = dir.Sub("be.ply");
  std::string body = BigEndianFloats({1.5f, -2.0f, 3.25f, 0, 0, 1, 0.125f});
  body += std::string("\x00\x80", 2);  // ushort 128, big-endian
  body += BigEndianFloats({-4.0f, 5.0f, 6.0f, 1, 0, 0, 2.0f});
  body += std::string("\xff\xff", 2);
  WriteFile(path,
            "ply\nformat binary_big_endian 1.0\nelement vertex 2\nproperty float x\n"
            "property float y\nproperty float z\nproperty float nx\nproperty float ny\n"
            "property float nz\nproperty float radius\nproperty ushort quality\nend_header\n" +
                body);
  auto src = OpenPlyFile(path);
  ASSERT_TRUE(src.ok()) << src.status();
  EXPECT_EQ((*src)->header().format, "binary_big_endian");
  auto got = ReadAll(**src);
  ASSERT_EQ(got.size(), 2u);
  EXPECT_EQ(got[0].position, glm::vec3(1.5f, -2.0f, 3.25f));
  EXPECT_EQ(got[0].radius, 0.125f);
  EXPECT_EQ(got[1].position, glm::vec3(-4.0f, 5.0f, 6.0f));
  EXPECT_EQ(got[1].normal, glm::vec3(1, 0, 0));
  EXPECT_EQ(got[1].radius, 2.0f);
}

TEST(PlyRegressionTest, FreeTextHeaderLineWithoutCommentIsAComment) {
  // As Blender 2.47 wrote it (assimp-testmodels' Wuson.ply).
  ScratchDir dir("ply_text");
  const std::string path = dir.Sub("t.ply");
  WriteFile(path,
            "ply\nformat ascii 1.0\nCreated by Blender3D 247 - www.blender.org, source file: \n"
            "element vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
            "property float nx\nproperty float ny\nproperty float nz\nproperty float radius\n"
            "end_header\n1 2 3 0 0 1 0.5\n");
  auto src = OpenPlyFile(path);
  ASSERT_TRUE(src.ok()) << src.status();
  ASSERT_EQ((*src)->header().notes.size(), 1u);
  EXPECT_NE((*src)->header().notes[0].find("line 3 is free text"), std::string::npos);
  EXPECT_EQ(ReadAll(**src).size(), 1u);
}

TEST(PlyRegressionTest, OwnOutputsWithColoursAndExtrasReadBack) {
  ScratchDir dir("ply_own");
  const std::string path = dir.Sub("o.ply");
  const auto cloud = testing_build::UniformCloud(300, 4);
  for (bool ascii : {false, true}) {
    PlyWriterOptions wo;
    wo.ascii = ascii;
    wo.extra = {"occlusion", "weight"};
    wo.comments = {"pbgi scene.name cornell", "pbgi scene.seed 3"};
    auto w = PlyWriter::Create(path, wo);
    ASSERT_TRUE(w.ok()) << w.status();
    std::vector<float> extra;
    for (size_t i = 0; i < cloud.size(); ++i) extra.insert(extra.end(), {0.5f, float(i)});
    ASSERT_TRUE((*w)->Write(cloud, extra).ok());
    ASSERT_TRUE((*w)->Close().ok());
    auto src = OpenPlyFile(path);
    ASSERT_TRUE(src.ok()) << src.status();
    const PlyHeader& h = (*src)->header();
    EXPECT_EQ(h.Provenance().at("scene.name"), "cornell");
    EXPECT_EQ(h.Provenance().at("scene.seed"), "3");
    std::vector<std::string> names;
    for (const auto& p : h.vertex_properties) names.push_back(p.name + ":" + p.type);
    EXPECT_EQ(names, (std::vector<std::string>{
                         "x:float", "y:float", "z:float", "nx:float", "ny:float", "nz:float",
                         "radius:float", "r:float", "g:float", "b:float", "occlusion:float",
                         "weight:float", "red:uchar", "green:uchar", "blue:uchar"}));
    // The float radiance wins over the tone-mapped uchar colours.
    auto got = ReadAll(**src);
    ASSERT_EQ(got.size(), cloud.size());
    for (size_t i = 0; i < cloud.size(); ++i) {
      ASSERT_EQ(got[i].position, cloud[i].position);
      ASSERT_EQ(got[i].radius, cloud[i].radius);
      ASSERT_EQ(got[i].radiance, cloud[i].radiance);
    }
  }
  // The uchar colours are the tone-mapped radiance.
  EXPECT_EQ(ToneMap8(0.0f), 0);
  EXPECT_EQ(ToneMap8(1.0f), 188);  // 0.5 in sRGB
  EXPECT_EQ(ToneMap8(1e30f), 255);
  EXPECT_EQ(ToneMap8(std::nanf("")), 0);
}

TEST(PlyRegressionTest, MissingRadiusAndNormalsAreRefusedOrAllowed) {
  ScratchDir dir("ply_missing");
  const std::string path = dir.Sub("m.ply");
  WriteFile(path,
            "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
            "property float z\nproperty float rx\nproperty float ry\nproperty float rz\n"
            "end_header\n0 0 0 0 0 1\n1 1 1 0 1 0\n");
  auto refused = OpenPlyFile(path);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("no 'nx' property"), std::string::npos);
  PlyReadOptions o;
  o.allow_missing_normals = true;
  EXPECT_NE(OpenPlyFile(path, o).status().message().find("no 'radius' property"),
            std::string::npos);
  o.allow_missing_radius = true;
  o.uniform_radius = 0.25f;
  auto src = OpenPlyFile(path, o);
  ASSERT_TRUE(src.ok()) << src.status();
  EXPECT_TRUE((*src)->header().has_reflection);
  EXPECT_FALSE((*src)->header().has_normals);
  std::vector<Surfel> s(4);
  std::vector<glm::vec3> r(4);
  auto n = (*src)->NextWithReflections(absl::MakeSpan(s), absl::MakeSpan(r));
  ASSERT_TRUE(n.ok()) << n.status();
  ASSERT_EQ(*n, 2u);
  EXPECT_EQ(s[1].radius, 0.25f);
  EXPECT_EQ(s[1].normal, glm::vec3(0.0f));
  EXPECT_EQ(r[1], glm::vec3(0, 1, 0));
  // The header alone, with nothing required.
  auto h = ReadPlyHeader(path);
  ASSERT_TRUE(h.ok()) << h.status();
  EXPECT_EQ(h->vertex_count, 2u);
}

TEST(PlyRegressionTest, AWriterWithoutCloseLeavesThePreviousFile) {
  ScratchDir dir("ply_atomic");
  const std::string path = dir.Sub("keep.ply");
  WriteFile(path, "previous contents");
  {
    auto w = PlyWriter::Create(path);
    ASSERT_TRUE(w.ok());
    ASSERT_TRUE((*w)->Write(testing_build::UniformCloud(10, 1)).ok());
    // Destroyed without Close(): an interrupted job.
  }
  std::ifstream f(path);
  std::string got((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  EXPECT_EQ(got, "previous contents");
  for (const auto& e : std::filesystem::directory_iterator(dir.path())) {
    EXPECT_EQ(e.path().filename(), "keep.ply") << "left behind: " << e.path();
  }
}

}  // namespace
}  // namespace pbgi
