// Processes: a writer killed with SIGKILL mid-build, and readers in threads and processes at once.
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <numeric>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "pbgi/store.h"
#include "store/crc32c.h"
#include "tests/store/store_test_util.h"

namespace pbgi {
namespace {

using ::testing::HasSubstr;
using testing_store::PagePayload;
using testing_store::ScratchDir;

constexpr uint32_t kPage = EfficientPageSize(4);

absl::Status WritePoints(const std::string& path, uint64_t pages, uint64_t seed) {
  StoreOptions opt;
  opt.page_size = kPage;
  opt.batch_bytes = 1 << 20;
  auto w = PageWriter::Create(path, opt);
  if (!w.ok()) return w.status();
  const size_t cap = (*w)->payload_capacity();
  for (uint64_t i = 0; i < pages; ++i) {
    absl::Status s = (*w)->Append(Section::kPoints, i, PageKind::kPoint, 1,
                                  PagePayload(Section::kPoints, i, cap, seed));
    if (!s.ok()) return s;
  }
  StoreMeta m;
  m.point_count = pages;
  return (*w)->Finish(m);
}

// Forks a writer that builds `path` (seed 2) and never finishes on its own in time; kills it
// with SIGKILL `delay_ms` after it reports that it committed its first batches.
void KillWriterMidBuild(const std::string& path, int delay_ms) {
  int fds[2];
  ASSERT_EQ(pipe(fds), 0);
  const pid_t pid = fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    close(fds[0]);
    StoreOptions opt;
    opt.page_size = kPage;
    opt.batch_bytes = 1 << 20;
    auto w = PageWriter::Create(path, opt);
    if (!w.ok()) _exit(3);
    const size_t cap = (*w)->payload_capacity();
    for (uint64_t i = 0;; ++i) {
      if (!(*w)->Append(Section::kPoints, i, PageKind::kPoint, 1,
                        PagePayload(Section::kPoints, i, cap, 2))
               .ok()) {
        _exit(4);
      }
      if (i == 100) (void)!write(fds[1], "x", 1);  // several batches are committed by now
      if (i == 200000) {                           // ~3 GiB: far more than the test waits for
        StoreMeta m;
        m.point_count = i + 1;
        (void)(*w)->Finish(m);
        _exit(5);
      }
    }
  }
  close(fds[1]);
  char c;
  ASSERT_EQ(read(fds[0], &c, 1), 1);
  close(fds[0]);
  std::this_thread::sleep_for(std::chrono::milliseconds(delay_ms));
  kill(pid, SIGKILL);
  int status = 0;
  ASSERT_EQ(waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL)
      << "the writer ended on its own before it was killed (status " << status << ")";
}

TEST(StoreCrashTest, KilledFirstBuildLeavesAStoreThatOpenRefusesAsIncomplete) {
  ScratchDir dir;
  for (int delay_ms : {0, 3, 20}) {
    SCOPED_TRACE(delay_ms);
    const std::string path = dir.Sub("store" + std::to_string(delay_ms));
    KillWriterMidBuild(path, delay_ms);
    auto store = PageStore::Open(path);
    ASSERT_FALSE(store.ok()) << "a killed build opened";
    EXPECT_EQ(store.status().code(), absl::StatusCode::kFailedPrecondition);
    EXPECT_THAT(store.status().message(), HasSubstr("incomplete: the build did not finish"));
    // The next build starts over cleanly.
    ASSERT_TRUE(WritePoints(path, 10, 3).ok());
    auto again = PageStore::Open(path);
    ASSERT_TRUE(again.ok()) << again.status();
    EXPECT_EQ((*again)->meta().point_pages, 10u);
  }
}

TEST(StoreCrashTest, KilledRebuildLeavesThePreviousCompleteStore) {
  ScratchDir dir;
  const std::string path = dir.Sub("store");
  constexpr uint64_t kPages = 60;
  ASSERT_TRUE(WritePoints(path, kPages, 1).ok());
  for (int delay_ms : {0, 10}) {
    SCOPED_TRACE(delay_ms);
    KillWriterMidBuild(path, delay_ms);
    auto store = PageStore::Open(path);
    ASSERT_TRUE(store.ok()) << store.status();
    EXPECT_EQ((*store)->meta().point_pages, kPages);
    auto report = CheckAllPages(**store);
    ASSERT_TRUE(report.ok());
    EXPECT_TRUE(report->ok()) << report->first_error;
    EXPECT_EQ(report->points.pages, kPages);
    auto txn = (*store)->BeginRead();
    ASSERT_TRUE(txn.ok());
    for (uint64_t i = 0; i < kPages; ++i) {
      auto v = txn->Get(Section::kPoints, i);
      ASSERT_TRUE(v.ok()) << v.status();
      const auto expect = PagePayload(Section::kPoints, i, v->payload.size(), 1);
      ASSERT_TRUE(std::equal(expect.begin(), expect.end(), v->payload.begin())) << i;
    }
  }
}

// Every page's CRC-32C, read in a shuffled order through one ReadTxn.
std::vector<uint32_t> PageDigests(const PageStore& store, uint64_t seed) {
  const uint64_t n = store.meta().point_pages;
  std::vector<uint32_t> out(n, 0);
  std::vector<uint64_t> order(n);
  std::iota(order.begin(), order.end(), 0);
  std::shuffle(order.begin(), order.end(), std::mt19937_64(seed));
  auto txn = store.BeginRead();
  if (!txn.ok()) return {};
  for (int pass = 0; pass < 3; ++pass) {
    for (uint64_t i : order) {
      auto v = txn->Get(Section::kPoints, i);
      if (!v.ok()) return {};
      out[i] = internal::Crc32c(0, v->header, store.meta().page_size);
    }
    txn->Reset();
    if (!txn->Renew().ok()) return {};
  }
  return out;
}

TEST(StoreCrashTest, EightThreadsAndTwoProcessesSeeIdenticalBytes) {
  ScratchDir dir;
  const std::string path = dir.Sub("store");
  constexpr uint64_t kPages = 400;
  ASSERT_TRUE(WritePoints(path, kPages, 7).ok());

  // Processes first, before this process has threads, so fork() is safe.
  std::vector<pid_t> pids;
  std::vector<int> pipes;
  for (int p = 0; p < 2; ++p) {
    int fds[2];
    ASSERT_EQ(pipe(fds), 0);
    const pid_t pid = fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
      close(fds[0]);
      auto store = PageStore::Open(path);
      std::vector<uint32_t> d;
      if (store.ok()) d = PageDigests(**store, 100 + p);
      const char* bytes = reinterpret_cast<const char*>(d.data());
      size_t left = d.size() * sizeof(uint32_t);
      while (left > 0) {
        const ssize_t n = write(fds[1], bytes, left);
        if (n <= 0) _exit(2);
        bytes += n;
        left -= static_cast<size_t>(n);
      }
      _exit(0);
    }
    close(fds[1]);
    pids.push_back(pid);
    pipes.push_back(fds[0]);
  }

  auto store = PageStore::Open(path);
  ASSERT_TRUE(store.ok()) << store.status();
  std::vector<std::vector<uint32_t>> results(8 + 2);
  std::vector<std::thread> threads;
  for (int t = 0; t < 8; ++t) {
    threads.emplace_back([&, t] { results[t] = PageDigests(**store, t); });
  }
  for (int p = 0; p < 2; ++p) {
    std::vector<uint32_t> d(kPages);
    char* bytes = reinterpret_cast<char*>(d.data());
    size_t got = 0;
    ssize_t n;
    while (got < kPages * 4 && (n = read(pipes[p], bytes + got, kPages * 4 - got)) > 0) {
      got += static_cast<size_t>(n);
    }
    close(pipes[p]);
    if (got == kPages * 4) results[8 + p] = d;
    int status = 0;
    waitpid(pids[p], &status, 0);
    EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << "reader process " << p;
  }
  for (auto& th : threads) th.join();

  // The truth, computed independently of the store: header fields and the generated payload.
  std::vector<uint32_t> expected(kPages);
  for (uint64_t i = 0; i < kPages; ++i) {
    std::vector<uint8_t> page(kPage, 0);
    PageHeader h{};
    h.kind = static_cast<uint16_t>(PageKind::kPoint);
    h.format = kStoreFormatVersion;
    h.record_count = 1;
    h.payload_bytes = kPage - sizeof(PageHeader);
    h.page_no = i;
    std::memcpy(page.data(), &h, sizeof(h));
    const auto payload = PagePayload(Section::kPoints, i, h.payload_bytes, 7);
    std::memcpy(page.data() + sizeof(h), payload.data(), payload.size());
    h.checksum = internal::Crc32c(0, page.data() + 4, kPage - 4);
    std::memcpy(page.data(), &h.checksum, 4);
    expected[i] = internal::Crc32c(0, page.data(), kPage);
  }
  for (size_t r = 0; r < results.size(); ++r) {
    EXPECT_EQ(results[r], expected) << (r < 8 ? "thread " : "process ") << (r < 8 ? r : r - 8);
  }
}

}  // namespace
}  // namespace pbgi
