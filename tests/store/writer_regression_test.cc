// Regressions of issue 17, "Writers and outputs": two writers to one store directory mixed their
// files (the second unlinked the first's data.mdb.tmp, the first renamed the second's
// half-written file into place); killed builds left data.mdb.tmp behind and failed builds left
// empty directories; a store written in place under a reader went unnoticed until SIGBUS.
#include <fcntl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <csignal>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "pbgi/store.h"
#include "tests/store/store_test_util.h"

namespace pbgi {
namespace {

using ::testing::HasSubstr;
using testing_store::PagePayload;
using testing_store::ScratchDir;

StoreOptions Fast() {
  StoreOptions o;
  o.page_size = EfficientPageSize(1);
  o.sync = false;
  return o;
}

// Appends `pages` point pages whose payload depends on `seed`.
void AppendPages(PageWriter& w, uint64_t pages, uint64_t seed) {
  for (uint64_t i = 0; i < pages; ++i) {
    ASSERT_TRUE(
        w.Append(Section::kPoints, i, PageKind::kPoint, 1, PagePayload(Section::kPoints, i, 300, seed))
            .ok());
  }
}

StoreMeta MetaFor(uint64_t seed, uint64_t pages) {
  StoreMeta m;
  m.point_count = pages;  // one record per page
  m.stats["seed"] = std::to_string(seed);
  return m;
}

// The seed of the store at `path` (from its meta record), after checking every page.
std::string SeedOf(const std::string& path) {
  auto store = PageStore::Open(path);
  if (!store.ok()) return std::string(store.status().message());
  auto report = CheckAllPages(**store);
  if (!report.ok() || !report->ok()) return "damaged";
  auto txn = (*store)->BeginRead();
  if (!txn.ok()) return std::string(txn.status().message());
  const std::string seed = (*store)->meta().stats.at("seed");
  auto page = txn->Get(Section::kPoints, 0);
  if (!page.ok()) return std::string(page.status().message());
  const std::vector<uint8_t> want = PagePayload(Section::kPoints, 0, 300, std::stoull(seed));
  if (!std::equal(want.begin(), want.end(), page->payload.begin())) return "pages of another build";
  return seed;
}

TEST(WriterRegressionTest, SecondWriterToOnePathIsRefusedAndTheFirstFinishes) {
  ScratchDir dir;
  const std::string path = dir.Sub("db");
  auto first = PageWriter::Create(path, Fast());
  ASSERT_TRUE(first.ok()) << first.status();
  AppendPages(**first, 20, 1);

  auto second = PageWriter::Create(path, Fast());
  ASSERT_FALSE(second.ok());
  EXPECT_EQ(second.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(second.status().message(), HasSubstr("being written by another build"));
  EXPECT_THAT(second.status().message(), HasSubstr("pid " + std::to_string(getpid())));
  EXPECT_THAT(second.status().message(), HasSubstr(path));
  // The loser touched nothing: the first writer's file is still there and finishes.
  EXPECT_TRUE(std::filesystem::exists(path + "/data.mdb.tmp"));
  ASSERT_TRUE((*first)->Finish(MetaFor(1, 20)).ok());
  first->reset();
  EXPECT_EQ(SeedOf(path), "1");
  EXPECT_FALSE(std::filesystem::exists(path + "/writer.lock"));

  // Once the first is gone, the next writer gets the directory.
  auto third = PageWriter::Create(path, Fast());
  ASSERT_TRUE(third.ok()) << third.status();
  AppendPages(**third, 5, 3);
  ASSERT_TRUE((*third)->Finish(MetaFor(3, 5)).ok());
  third->reset();
  EXPECT_EQ(SeedOf(path), "3");
}

TEST(WriterRegressionTest, WriterInAnotherProcessExcludesThisOneAndReadersCarryOn) {
  ScratchDir dir;
  const std::string path = dir.Sub("db");
  {
    auto w = PageWriter::Create(path, Fast());
    ASSERT_TRUE(w.ok());
    AppendPages(**w, 10, 7);
    ASSERT_TRUE((*w)->Finish(MetaFor(7, 10)).ok());
  }
  // A reader of the previous store, open across the whole rebuild.
  auto reader_store = PageStore::Open(path);
  ASSERT_TRUE(reader_store.ok());
  auto reader = (*reader_store)->BeginRead();
  ASSERT_TRUE(reader.ok());

  int ready[2], go[2];
  ASSERT_EQ(pipe(ready), 0);
  ASSERT_EQ(pipe(go), 0);
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    auto w = PageWriter::Create(path, Fast());
    if (!w.ok()) _exit(2);
    for (uint64_t i = 0; i < 30; ++i) {
      if (!(*w)->Append(Section::kPoints, i, PageKind::kPoint, 1,
                        PagePayload(Section::kPoints, i, 300, 8))
               .ok()) {
        _exit(3);
      }
    }
    char c = 'r';
    (void)!write(ready[1], &c, 1);
    (void)!read(go[0], &c, 1);
    _exit((*w)->Finish(MetaFor(8, 30)).ok() ? 0 : 4);
  }
  char c;
  ASSERT_EQ(read(ready[0], &c, 1), 1);
  auto loser = PageWriter::Create(path, Fast());
  ASSERT_FALSE(loser.ok());
  EXPECT_THAT(loser.status().message(), HasSubstr("pid " + std::to_string(child)));
  const StoreLeftovers during = FindStoreLeftovers(path);
  EXPECT_EQ(during.active_writer, std::to_string(child));
  // The reader of the old store does not notice the build.
  auto old_page = reader->Get(Section::kPoints, 9);
  ASSERT_TRUE(old_page.ok()) << old_page.status();
  (void)!write(go[1], &c, 1);
  int status = 0;
  ASSERT_EQ(waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << status;
  EXPECT_EQ(SeedOf(path), "8");
  // Still the old file behind the open reader, unchanged.
  old_page = reader->Get(Section::kPoints, 9);
  ASSERT_TRUE(old_page.ok()) << old_page.status();
  const std::vector<uint8_t> want = PagePayload(Section::kPoints, 9, 300, 7);
  EXPECT_TRUE(std::equal(want.begin(), want.end(), old_page->payload.begin()));
  for (int fd : {ready[0], ready[1], go[0], go[1]}) close(fd);
}

TEST(WriterRegressionTest, KilledBuildsFilesAreNamedThenRemovedByTheNextBuild) {
  ScratchDir dir;
  const std::string path = dir.Sub("db");
  {
    auto w = PageWriter::Create(path, Fast());
    ASSERT_TRUE(w.ok());
    AppendPages(**w, 4, 1);
    ASSERT_TRUE((*w)->Finish(MetaFor(1, 4)).ok());
  }
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    auto w = PageWriter::Create(path, Fast());
    if (!w.ok()) _exit(2);
    for (uint64_t i = 0; i < 200; ++i) {
      (void)(*w)->Append(Section::kPoints, i, PageKind::kPoint, 1,
                         PagePayload(Section::kPoints, i, 300, 2));
    }
    raise(SIGKILL);  // dies holding the lock, with pages written
  }
  int status = 0;
  ASSERT_EQ(waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFSIGNALED(status));

  const StoreLeftovers left = FindStoreLeftovers(path);
  EXPECT_TRUE(left.active_writer.empty()) << "the kernel drops a dead process's lock";
  ASSERT_FALSE(left.files.empty());
  EXPECT_EQ(left.files.front(), path + "/data.mdb.tmp");
  EXPECT_GT(left.bytes, 0u);
  EXPECT_EQ(SeedOf(path), "1") << "the previous store is intact";

  auto next = PageWriter::Create(path, Fast());
  ASSERT_TRUE(next.ok()) << next.status();
  AppendPages(**next, 3, 5);
  ASSERT_TRUE((*next)->Finish(MetaFor(5, 3)).ok());
  next->reset();
  EXPECT_TRUE(FindStoreLeftovers(path).empty());
  EXPECT_EQ(SeedOf(path), "5");
  for (const auto& e : std::filesystem::directory_iterator(path)) {
    EXPECT_EQ(e.path().filename(), "data.mdb") << "nothing else is left";
  }
}

TEST(WriterRegressionTest, FailedBuildRemovesTheDirectoriesItMadeAndOnlyThose) {
  ScratchDir dir;
  const std::string deep = dir.Sub("a/b/c");
  {
    auto w = PageWriter::Create(deep, Fast());
    ASSERT_TRUE(w.ok());
    AppendPages(**w, 3, 1);
    // Destroyed without Finish (the build failed).
  }
  EXPECT_FALSE(std::filesystem::exists(dir.Sub("a")));

  // A directory that existed before stays, with whatever else it holds.
  std::filesystem::create_directories(dir.Sub("mine"));
  {
    auto w = PageWriter::Create(dir.Sub("mine"), Fast());
    ASSERT_TRUE(w.ok());
  }
  EXPECT_TRUE(std::filesystem::is_directory(dir.Sub("mine")));
  EXPECT_TRUE(std::filesystem::is_empty(dir.Sub("mine")));
}

TEST(WriterRegressionTest, StoreWrittenInPlaceUnderAReaderIsAnErrorNotAFault) {
  ScratchDir dir;
  const std::string path = dir.Sub("db");
  {
    auto w = PageWriter::Create(path, Fast());
    ASSERT_TRUE(w.ok());
    AppendPages(**w, 40, 1);
    ASSERT_TRUE((*w)->Finish(MetaFor(1, 40)).ok());
  }
  for (const bool truncate : {false, true}) {
    SCOPED_TRACE(truncate ? "truncated" : "overwritten in place");
    auto store = PageStore::Open(path);
    ASSERT_TRUE(store.ok());
    auto txn = (*store)->BeginRead();
    ASSERT_TRUE(txn.ok());
    const std::string file = path + "/data.mdb";
    const int fd = open(file.c_str(), O_WRONLY);
    ASSERT_GE(fd, 0);
    if (truncate) {
      ASSERT_EQ(ftruncate(fd, (*store)->FileBytes() / 2), 0);
    } else {
      // The same size, other bytes, a later modification time.
      struct timespec later[2] = {{0, UTIME_OMIT}, {0, 0}};
      ASSERT_EQ(clock_gettime(CLOCK_REALTIME, &later[1]), 0);
      later[1].tv_sec += 10;
      const char junk[16] = "overwritten";
      ASSERT_EQ(pwrite(fd, junk, sizeof(junk), 5 * 4096 + 100), 16);
      ASSERT_EQ(futimens(fd, later), 0);
    }
    close(fd);
    // Reading through the map now could fault; a new or renewed transaction refuses instead.
    auto again = (*store)->BeginRead();
    ASSERT_FALSE(again.ok());
    EXPECT_EQ(again.status().code(), absl::StatusCode::kDataLoss);
    EXPECT_THAT(again.status().message(), HasSubstr("modified in place"));
    EXPECT_THAT(again.status().message(), HasSubstr(path));
    txn->Reset();
    absl::Status renew = txn->Renew();
    EXPECT_EQ(renew.code(), absl::StatusCode::kDataLoss) << renew;
    auto report = CheckAllPages(**store);
    EXPECT_FALSE(report.ok());
    // Rebuild for the next round.
    auto w = PageWriter::Create(path, Fast());
    ASSERT_TRUE(w.ok());
    AppendPages(**w, 40, 1);
    ASSERT_TRUE((*w)->Finish(MetaFor(1, 40)).ok());
  }
}

}  // namespace
}  // namespace pbgi
