// PLY from a stream (path "-", standard input; docs/format.md "Streamed input"): the header's
// bounds line, read once without a spill, refused Rewind after the first record, the spill to a
// directory read twice, truncation; and the writer's bounds line and fixed vertex count.
// Standard input is a pipe fed by a thread, in a forked child (the test's own stdin stays).
#include <fcntl.h>
#include <unistd.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "gtest/gtest.h"
#include "pbgi/build.h"
#include "pbgi/ply.h"
#include "tests/build/test_clouds.h"
#include "tests/common/child_process.h"

namespace pbgi {
namespace {

using testing_build::ScratchDir;

std::string ReadBytes(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

// Writes `cloud` to `path` with `bounds` declared (empty: none).
void WritePly(const std::string& path, const std::vector<Surfel>& cloud, const Bounds& bounds) {
  PlyWriterOptions wo;
  wo.bounds = bounds;
  auto w = PlyWriter::Create(path, wo);
  ASSERT_TRUE(w.ok()) << w.status();
  ASSERT_TRUE((*w)->Write(cloud).ok());
  ASSERT_TRUE((*w)->Close().ok());
}

// Runs `body` in a child whose standard input is a pipe that a thread fills with `bytes`.
std::string WithStdin(const std::string& bytes, const std::function<std::string()>& body) {
  const testing_common::ChildResult r = testing_common::RunInChild([&]() -> std::string {
    int fds[2];
    if (pipe(fds) != 0) return "pipe failed";
    std::thread feeder([&] {
      size_t off = 0;
      while (off < bytes.size()) {
        const ssize_t w = write(fds[1], bytes.data() + off, bytes.size() - off);
        if (w <= 0) break;  // the reader is gone
        off += static_cast<size_t>(w);
      }
      close(fds[1]);
    });
    dup2(fds[0], 0);
    close(fds[0]);
    std::string report = body();
    close(0);  // unblocks a feeder whose reader stopped early
    feeder.join();
    return report;
  });
  if (!r.exited) return absl::StrCat("child killed by signal ", r.signal);
  return r.report;
}

bool Same(const std::vector<Surfel>& a, const std::vector<Surfel>& b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i) {
    if (std::memcmp(&a[i].position, &b[i].position, sizeof(glm::vec3)) != 0 ||
        std::memcmp(&a[i].normal, &b[i].normal, sizeof(glm::vec3)) != 0 ||
        a[i].radius != b[i].radius) {
      return false;
    }
  }
  return true;
}

std::vector<Surfel> Drain(SurfelSource& src, std::string* error) {
  std::vector<Surfel> out, buf(1000);
  for (;;) {
    auto n = src.Next(absl::MakeSpan(buf));
    if (!n.ok()) {
      *error = std::string(n.status().message());
      break;
    }
    if (*n == 0) break;
    out.insert(out.end(), buf.begin(), buf.begin() + *n);
  }
  return out;
}

class PlyStreamTest : public ::testing::Test {
 protected:
  void SetUp() override {
    cloud_ = testing_build::UniformCloud(5000, 17, 2.0f, glm::vec3(1, -3, 0.5f));
    for (const Surfel& s : cloud_) box_.Extend(s.position);
  }
  ScratchDir dir_{"ply_stream"};
  std::vector<Surfel> cloud_;
  Bounds box_;
};

TEST_F(PlyStreamTest, HeaderBoundsRoundTripExactlyAndAStreamReadsOnce) {
  const std::string path = dir_.Sub("b.ply");
  Bounds declared = box_;
  declared.lo -= glm::vec3(0.1f, 0.2f, 0.3f);  // not round numbers: %.9g must round-trip
  WritePly(path, cloud_, declared);
  auto h = ReadPlyHeader(path);
  ASSERT_TRUE(h.ok()) << h.status();
  EXPECT_EQ(std::memcmp(&h->bounds, &declared, sizeof(Bounds)), 0);
  auto file = OpenPlyFile(path);
  ASSERT_TRUE(file.ok());
  const Bounds known = (*file)->KnownBounds();
  EXPECT_EQ(std::memcmp(&known, &declared, sizeof(Bounds)), 0);

  const std::string report = WithStdin(ReadBytes(path), [&]() -> std::string {
    auto src = OpenPlyFile("-");
    if (!src.ok()) return std::string(src.status().message());
    const Bounds got = (*src)->KnownBounds();
    if (std::memcmp(&got, &declared, sizeof(Bounds)) != 0) return "bounds";
    if (!(*src)->Rewind().ok()) return "a Rewind before the first record failed";
    std::string error;
    if (!Same(Drain(**src, &error), cloud_)) return "records differ: " + error;
    const absl::Status again = (*src)->Rewind();
    if (again.ok()) return "a second Rewind of a pipe succeeded";
    if (again.message().find("cannot read a stream twice") == std::string::npos) {
      return std::string(again.message());
    }
    return "ok";
  });
  EXPECT_EQ(report, "ok");
}

TEST_F(PlyStreamTest, WithoutBoundsTheBodyIsSpilledAndReadTwice) {
  const std::string path = dir_.Sub("nb.ply");
  WritePly(path, cloud_, Bounds{});
  const std::string spill = dir_.Sub("spill");
  std::filesystem::create_directories(spill);
  const std::string report = WithStdin(ReadBytes(path), [&]() -> std::string {
    PlyReadOptions ro;
    ro.spill_dir = spill;
    auto src = OpenPlyFile("-", ro);
    if (!src.ok()) return std::string(src.status().message());
    if (!(*src)->KnownBounds().Empty()) return "bounds from nowhere";
    if ((*src)->header().spilled_bytes != cloud_.size() * 43) return "spilled bytes";
    for (int pass = 0; pass < 2; ++pass) {
      if (!(*src)->Rewind().ok()) return "Rewind of the spill failed";
      std::string error;
      if (!Same(Drain(**src, &error), cloud_)) return "records differ: " + error;
    }
    return "ok";
  });
  EXPECT_EQ(report, "ok");
  EXPECT_TRUE(std::filesystem::is_empty(spill)) << "the spill is not unlinked";
}

TEST_F(PlyStreamTest, TruncatedStreamAndMalformedBoundsAreNamed) {
  const std::string path = dir_.Sub("t.ply");
  WritePly(path, cloud_, box_);
  const std::string bytes = ReadBytes(path);
  const std::string cut = bytes.substr(0, bytes.size() - 100);
  const std::string report = WithStdin(cut, [&]() -> std::string {
    auto src = OpenPlyFile("-");
    if (!src.ok()) return std::string(src.status().message());
    std::string error;
    Drain(**src, &error);
    return error;
  });
  EXPECT_NE(report.find(absl::StrCat("standard input: truncated at byte offset ", cut.size())),
            std::string::npos)
      << report;

  std::string bad = bytes;
  const size_t at = bad.find("comment pbgi bounds ");
  ASSERT_NE(at, std::string::npos);
  bad.replace(at, std::strlen("comment pbgi bounds "), "comment pbgi bounds 9e9 ");
  const std::string bad_path = dir_.Sub("bad.ply");
  std::ofstream(bad_path, std::ios::binary) << bad;
  auto h = OpenPlyFile(bad_path);
  ASSERT_FALSE(h.ok());
  EXPECT_NE(h.status().message().find("malformed bounds comment"), std::string::npos)
      << h.status();
}

TEST_F(PlyStreamTest, WriterToStandardOutputNeedsItsCountAndAFixedCountIsChecked) {
  auto no_count = PlyWriter::Create("-");
  ASSERT_FALSE(no_count.ok());
  EXPECT_NE(no_count.status().message().find("vertex count in advance"), std::string::npos);

  const std::string path = dir_.Sub("fixed.ply");
  PlyWriterOptions wo;
  wo.vertex_count = static_cast<int64_t>(cloud_.size());
  auto w = PlyWriter::Create(path, wo);
  ASSERT_TRUE(w.ok());
  ASSERT_TRUE((*w)->Write(absl::MakeConstSpan(cloud_).subspan(1)).ok());
  const absl::Status closed = (*w)->Close();
  EXPECT_FALSE(closed.ok());
  EXPECT_NE(closed.message().find("the header promised"), std::string::npos) << closed;
  EXPECT_FALSE(std::filesystem::exists(path)) << "a short file replaced the output";
}

}  // namespace
}  // namespace pbgi
