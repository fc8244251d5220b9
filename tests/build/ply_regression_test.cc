// Regressions of issue 17, "Parsers": a header count smaller than the body dropped records
// without a word; a comment line over 4,095 characters was refused with a false message (its
// tail read as a keyword); a record too large for the read buffer was called truncated; an
// ASCII body under a binary header was read as floats and shaded with exit 0; ASCII uchar 300
// was accepted. Each is now a clear error or a correct reading.
#include <cstring>
#include <fstream>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "pbgi/ply.h"
#include "tests/build/test_clouds.h"

namespace pbgi {
namespace {

using ::testing::HasSubstr;
using testing_build::ScratchDir;

void WriteFile(const std::string& path, const std::string& bytes) {
  std::ofstream f(path, std::ios::binary);
  f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// Reads everything; the surfels read, or the first error.
absl::StatusOr<std::vector<Surfel>> ReadAll(const std::string& path) {
  auto src = OpenPly(path);
  if (!src.ok()) return src.status();
  std::vector<Surfel> out, buf(7);
  for (;;) {
    auto n = (*src)->Next(absl::MakeSpan(buf));
    if (!n.ok()) return n.status();
    if (*n == 0) return out;
    out.insert(out.end(), buf.begin(), buf.begin() + *n);
  }
}

const char kProps[] =
    "property float x\nproperty float y\nproperty float z\nproperty float nx\n"
    "property float ny\nproperty float nz\nproperty float radius\n";

std::string BinaryBody(int records) {
  std::string body;
  for (int i = 0; i < records; ++i) {
    const float v[7] = {float(i), 0, 0, 0, 0, 1, 0.5f};
    body.append(reinterpret_cast<const char*>(v), sizeof(v));
  }
  return body;
}

std::string AsciiBody(int records) {
  std::string body;
  for (int i = 0; i < records; ++i) body += absl::StrCat(i, " 0 0 0 0 1 0.5\n");
  return body;
}

TEST(PlyRegressionTest, HeaderCountSmallerThanTheBodyIsAnError) {
  ScratchDir dir("plyreg_count");
  const std::string bin = dir.Sub("b.ply"), asc = dir.Sub("a.ply");
  WriteFile(bin, absl::StrCat("ply\nformat binary_little_endian 1.0\nelement vertex 10\n", kProps,
                              "end_header\n", BinaryBody(12)));
  auto b = ReadAll(bin);
  ASSERT_FALSE(b.ok()) << "2 records dropped without a word";
  EXPECT_THAT(b.status().message(), HasSubstr("the header says 10 vertices of 28 bytes"));
  EXPECT_THAT(b.status().message(), HasSubstr("(56 more)"));
  EXPECT_THAT(b.status().message(), HasSubstr(bin));

  WriteFile(asc, absl::StrCat("ply\nformat ascii 1.0\nelement vertex 10\n", kProps, "end_header\n",
                              AsciiBody(12)));
  auto a = ReadAll(asc);
  ASSERT_FALSE(a.ok());
  EXPECT_THAT(a.status().message(), HasSubstr("the header says 10 vertices but more records"));
  EXPECT_THAT(std::string(a.status().message()), HasSubstr("line 22")) << a.status();

  // Trailing blank lines are no records; a later element's records legitimately follow.
  WriteFile(asc, absl::StrCat("ply\nformat ascii 1.0\nelement vertex 10\n", kProps, "end_header\n",
                              AsciiBody(10), "\n  \n\n"));
  auto blank = ReadAll(asc);
  ASSERT_TRUE(blank.ok()) << blank.status();
  EXPECT_EQ(blank->size(), 10u);
  WriteFile(bin, absl::StrCat("ply\nformat binary_little_endian 1.0\nelement vertex 10\n", kProps,
                              "element face 1\nproperty list uchar int vertex_indices\n",
                              "end_header\n", BinaryBody(10), std::string("\x03\0\0\0\0\1\0\0\0\2\0\0\0", 13)));
  auto faces = ReadAll(bin);
  ASSERT_TRUE(faces.ok()) << faces.status();
  EXPECT_EQ(faces->size(), 10u);
}

TEST(PlyRegressionTest, LongCommentLinesAreRead) {
  ScratchDir dir("plyreg_comment");
  const std::string path = dir.Sub("c.ply");
  for (size_t len : {4095, 4096, 5000, 300000}) {
    SCOPED_TRACE(len);
    // The tail of the comment spells a keyword: read as a line of its own, it was "unexpected".
    const std::string comment = "comment " + std::string(len - 20, 'c') + " element face 7";
    WriteFile(path, absl::StrCat("ply\nformat binary_little_endian 1.0\n", comment,
                                 "\nelement vertex 3\n", kProps, "end_header\n", BinaryBody(3)));
    auto r = ReadAll(path);
    ASSERT_TRUE(r.ok()) << r.status();
    EXPECT_EQ(r->size(), 3u);
  }
  // A header "line" of megabytes is not a PLY header: a clear error, not a huge allocation.
  WriteFile(path, "ply\nformat ascii 1.0\ncomment " + std::string(3 << 20, 'x'));
  auto r = ReadAll(path);
  ASSERT_FALSE(r.ok());
  EXPECT_THAT(r.status().message(), HasSubstr("PLY header line 3: longer than 1048576 bytes"));
}

TEST(PlyRegressionTest, LargeRecordsAreReadOrRefusedWithTheRealReason) {
  ScratchDir dir("plyreg_record");
  const std::string path = dir.Sub("r.ply");
  // A binary record of 4096 doubles (32 KiB + 28 bytes) is read, and so is an ASCII line of
  // 2 MiB (the read buffer is 1 MiB).
  std::string header = "ply\nformat binary_little_endian 1.0\nelement vertex 40\n";
  header += kProps;
  for (int i = 0; i < 4089; ++i) header += absl::StrCat("property double extra", i, "\n");
  header += "end_header\n";
  std::string body;
  for (int r = 0; r < 40; ++r) {
    const float v[7] = {float(r), 1, 2, 0, 1, 0, 0.25f};
    body.append(reinterpret_cast<const char*>(v), sizeof(v));
    body.append(4089 * 8, '\0');
  }
  WriteFile(path, header + body);
  auto big = ReadAll(path);
  ASSERT_TRUE(big.ok()) << big.status();
  ASSERT_EQ(big->size(), 40u);
  EXPECT_EQ((*big)[39].position.x, 39.0f);
  EXPECT_EQ((*big)[39].radius, 0.25f);

  WriteFile(path, absl::StrCat("ply\nformat ascii 1.0\nelement vertex 2\n", kProps, "end_header\n",
                               "1 2 3", std::string(2 << 20, ' '), "0 0 1 0.5\n4 5 6 0 1 0 0.5\n"));
  auto wide = ReadAll(path);
  ASSERT_TRUE(wide.ok()) << wide.status();
  ASSERT_EQ(wide->size(), 2u);
  EXPECT_EQ((*wide)[0].position.z, 3.0f);
  EXPECT_EQ((*wide)[1].position.x, 4.0f);

  // Beyond 4096 properties: refused for that reason, not called truncated.
  std::string many = "ply\nformat binary_little_endian 1.0\nelement vertex 1\n";
  many += kProps;
  for (int i = 0; i < 300000; ++i) many += absl::StrCat("property float e", i, "\n");
  WriteFile(path, many + "end_header\n" + std::string(300007 * 4, '\0'));
  auto refused = ReadAll(path);
  ASSERT_FALSE(refused.ok());
  EXPECT_THAT(refused.status().message(), HasSubstr("more than 4096 properties"));
  EXPECT_THAT(refused.status().message(), ::testing::Not(HasSubstr("truncated")));
}

TEST(PlyRegressionTest, AsciiBodyUnderABinaryHeaderIsRefused) {
  ScratchDir dir("plyreg_mislabel");
  const std::string path = dir.Sub("m.ply");
  for (int records : {1, 7, 100}) {
    SCOPED_TRACE(records);
    WriteFile(path, absl::StrCat("ply\nformat binary_little_endian 1.0\nelement vertex ", records,
                                 "\n", kProps, "end_header\n", AsciiBody(records)));
    auto r = ReadAll(path);
    ASSERT_FALSE(r.ok()) << "ASCII text read as floats";
    EXPECT_THAT(std::string(r.status().message()),
                HasSubstr("the body looks like ASCII text: it is not binary_little_endian"));
  }
}

TEST(PlyRegressionTest, AsciiValuesOutsideTheirTypeAreRefused) {
  ScratchDir dir("plyreg_range");
  const std::string path = dir.Sub("u.ply");
  const std::string header =
      absl::StrCat("ply\nformat ascii 1.0\nelement vertex 1\n", kProps,
                   "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n");
  struct Case {
    const char* rgb;
    bool ok;
  } cases[] = {{"255 0 12", true}, {"300 0 0", false}, {"-1 0 0", false},
               {"12.5 0 0", false}, {"0 0 256", false}, {"0 0 1e3", false}};
  for (const Case& c : cases) {
    SCOPED_TRACE(c.rgb);
    WriteFile(path, header + "0 0 0 0 0 1 0.5 " + c.rgb + "\n");
    auto r = ReadAll(path);
    EXPECT_EQ(r.ok(), c.ok) << r.status();
    if (!r.ok()) {
      EXPECT_THAT(r.status().message(), HasSubstr("is not a value of the property's type uchar"));
      EXPECT_THAT(std::string(r.status().message()), HasSubstr("line 15 (record 0)"));
    } else {
      EXPECT_FLOAT_EQ((*r)[0].radiance.x, 1.0f);
    }
  }
  // A float property holds what float can: 1e39 is not a float.
  WriteFile(path, absl::StrCat("ply\nformat ascii 1.0\nelement vertex 1\n", kProps, "end_header\n",
                               "1e39 0 0 0 0 1 0.5\n"));
  auto f = ReadAll(path);
  ASSERT_FALSE(f.ok());
  EXPECT_THAT(f.status().message(), HasSubstr("type float"));
}

}  // namespace
}  // namespace pbgi
