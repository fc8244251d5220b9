// `pbgi info` and `pbgi verify` run as a person would run them.
#include <sys/wait.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "pbgi/store.h"
#include "tests/store/store_test_util.h"

namespace pbgi {
namespace {

using ::testing::HasSubstr;
using ::testing::Not;
using testing_store::PagePayload;
using testing_store::ScratchDir;

struct Result {
  int exit_code = -1;
  std::string output;  // stdout and stderr
};

Result RunPbgi(const std::string& args) {
  Result r;
  const std::string cmd = std::string(PBGI_CLI_PATH) + " " + args + " 2>&1";
  FILE* p = popen(cmd.c_str(), "r");
  if (p == nullptr) return r;
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof(buf), p)) > 0) r.output.append(buf, n);
  const int status = pclose(p);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

// 30 point pages with one record each; page 11 carries a marker to find in the file.
void MakeStore(const std::string& path, const std::string& marker) {
  StoreOptions opt;
  opt.page_size = EfficientPageSize(1);
  opt.sync = false;
  auto w = PageWriter::Create(path, opt);
  ASSERT_TRUE(w.ok());
  for (uint64_t i = 0; i < 30; ++i) {
    std::vector<uint8_t> p = PagePayload(Section::kPoints, i, 500);
    if (i == 11) std::copy(marker.begin(), marker.end(), p.begin() + 100);
    ASSERT_TRUE((*w)->Append(Section::kPoints, i, PageKind::kPoint, 1, p).ok());
  }
  StoreMeta m;
  m.point_count = 30;
  m.layout = "breadth-first";
  m.stats["seconds \"total\""] = "1.25";
  ASSERT_TRUE((*w)->Finish(m).ok());
}

TEST(StoreToolsTest, InfoPrintsTheMetaRecordAsTableAndJson) {
  ScratchDir dir;
  const std::string path = dir.Sub("db");
  MakeStore(path, "unused-marker");
  Result table = RunPbgi("info " + path);
  EXPECT_EQ(table.exit_code, 0) << table.output;
  EXPECT_THAT(table.output, HasSubstr("page size      4080 bytes"));
  EXPECT_THAT(table.output, HasSubstr("30 in 30 pages"));
  EXPECT_THAT(table.output, HasSubstr("breadth-first"));

  Result json = RunPbgi("info --json " + path);
  EXPECT_EQ(json.exit_code, 0) << json.output;
  EXPECT_THAT(json.output, HasSubstr("\"page_size\": 4080,"));
  EXPECT_THAT(json.output, HasSubstr("\"point_pages\": 30,"));
  EXPECT_THAT(json.output, HasSubstr("\"layout\": \"breadth-first\","));
  EXPECT_THAT(json.output, HasSubstr("\"seconds \\\"total\\\"\": \"1.25\""));
  EXPECT_EQ(json.output.front(), '{');

  Result missing = RunPbgi("info " + dir.Sub("nope"));
  EXPECT_EQ(missing.exit_code, 1);
  EXPECT_THAT(missing.output, HasSubstr("does not exist"));
}

TEST(StoreToolsTest, VerifyPassesAGoodStoreAndNamesTheDamagedPage) {
  ScratchDir dir;
  const std::string path = dir.Sub("db");
  const std::string marker = "[[tools-test-marker-11]]";
  MakeStore(path, marker);
  Result good = RunPbgi("verify --pages-only " + path);
  EXPECT_EQ(good.exit_code, 0) << good.output;
  EXPECT_THAT(good.output, HasSubstr("point pages           30"));
  EXPECT_THAT(good.output, HasSubstr("pages: OK"));

  // Flip one byte of page 11's payload in data.mdb.
  std::fstream f(path + "/data.mdb", std::ios::in | std::ios::out | std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(f)), {});
  const size_t at = bytes.find(marker);
  ASSERT_NE(at, std::string::npos);
  f.seekp(static_cast<std::streamoff>(at + 3));
  f.put(static_cast<char>(bytes[at + 3] ^ 0x01));
  f.close();

  Result bad = RunPbgi("verify --pages-only " + path);
  EXPECT_EQ(bad.exit_code, 1) << bad.output;
  EXPECT_THAT(bad.output, HasSubstr("damaged pages 1"));
  EXPECT_THAT(bad.output, HasSubstr("points page 11 is corrupt: checksum mismatch"));
  EXPECT_THAT(bad.output, Not(HasSubstr("pages: OK")));
}

// Issue 17: a killed build's data.mdb.tmp was silent; info and verify now name it.
TEST(StoreToolsTest, InfoAndVerifyMentionWhatABuildLeftBehind) {
  ScratchDir dir;
  const std::string path = dir.Sub("db");
  MakeStore(path, "unused-marker");
  {
    std::ofstream tmp(path + "/data.mdb.tmp", std::ios::binary);
    tmp << std::string(5000, 'x');
  }
  Result info = RunPbgi("info " + path);
  EXPECT_EQ(info.exit_code, 0) << info.output;
  EXPECT_THAT(info.output, HasSubstr(path + "/data.mdb.tmp (4.9 KiB) is left over from a build "
                                            "that did not finish"));
  Result verify = RunPbgi("verify --pages-only " + path);
  EXPECT_EQ(verify.exit_code, 0) << verify.output;
  EXPECT_THAT(verify.output, HasSubstr("is left over from a build that did not finish"));
  EXPECT_THAT(verify.output, HasSubstr("pages: OK"));

  std::filesystem::remove(path + "/data.mdb");
  Result incomplete = RunPbgi("info " + path);
  EXPECT_EQ(incomplete.exit_code, 1);
  EXPECT_THAT(incomplete.output, HasSubstr("incomplete: the build did not finish"));
}

}  // namespace
}  // namespace pbgi
