// BuildDatabase and VerifyTree over the LMDB store.
#include <algorithm>
#include <condition_variable>
#include <cstring>
#include <filesystem>
#include <memory>
#include <mutex>
#include <string>
#include <system_error>
#include <thread>
#include <utility>
#include <vector>

#include "absl/strings/str_format.h"
#include "base/proc.h"
#include "base/stopwatch.h"
#include "build/builder.h"
#include "build/run_manifest.h"
#include "pbgi/build.h"
#include "pbgi/status.h"
#include "pbgi/store.h"
#include "store/page_io.h"
#include "tree/verify.h"

namespace pbgi {
namespace {

// The LMDB thread's page queue: 2 MiB (64 pages of the default 32 KiB), which PlanFor's 4 MiB
// for threads covers beside the merge's block pipe (build/builder.cc). The writer thread sleeps
// until kWriterWakePages are queued, rather than waking for every page (docs/format.md,
// "Session 15").
constexpr size_t kWriterQueueBytes = size_t{2} << 20;
constexpr size_t kWriterMinSlots = 16;
constexpr size_t kWriterWakePages = 8;

// Runs a PageWriter on a thread of its own, so that LMDB's copies and writes overlap the octree
// pass. Append copies the page into one of a few slots and returns; the writer thread appends
// the slots in order, once at least `wake` pages are queued (or the build finishes). An LMDB
// write transaction belongs to the thread that began it, so every call that may touch one
// (Append, Finish, the destructor's abort) runs on the writer thread. A writer error is
// returned by the next Append or by Finish.
class AsyncWriterSink final : public internal::PageSink {
 public:
  AsyncWriterSink(std::unique_ptr<PageWriter> writer, size_t slots, size_t wake)
      : writer_(std::move(writer)),
        page_size_(writer_->page_size()),
        slots_(slots),
        wake_(std::clamp<size_t>(wake, 1, slots)) {
    for (Slot& s : slots_) s.payload.reserve(page_size_);
    thread_ = std::thread([this] { Run(); });
  }
  ~AsyncWriterSink() override {
    {
      std::lock_guard<std::mutex> l(mu_);
      quit_ = true;
    }
    work_cv_.notify_one();
    thread_.join();
  }
  uint32_t page_size() const override { return page_size_; }

  absl::Status Append(Section section, uint64_t page_no, PageKind kind, uint32_t record_count,
                      absl::Span<const uint8_t> payload) override {
    std::unique_lock<std::mutex> l(mu_);
    done_cv_.wait(l, [&] { return count_ < slots_.size() || !status_.ok(); });
    if (!status_.ok()) return status_;
    Slot& s = slots_[(head_ + count_) % slots_.size()];
    l.unlock();  // the slot is ours until count_ covers it
    s.section = section;
    s.page_no = page_no;
    s.kind = kind;
    s.record_count = record_count;
    s.payload.assign(payload.begin(), payload.end());
    l.lock();
    ++count_;
    if (writer_idle_ && count_ >= wake_) work_cv_.notify_one();
    return absl::OkStatus();
  }

  // Writes the remaining pages, then the meta record (PageWriter::Finish), on the writer thread.
  absl::Status Finish(const StoreMeta& meta) {
    std::unique_lock<std::mutex> l(mu_);
    meta_ = &meta;
    work_cv_.notify_one();
    done_cv_.wait(l, [&] { return finished_ || !status_.ok(); });
    return status_;
  }

 private:
  struct Slot {
    Section section = Section::kNodes;
    uint64_t page_no = 0;
    PageKind kind = PageKind::kNode;
    uint32_t record_count = 0;
    std::vector<uint8_t> payload;
  };

  void Run() {
    std::unique_lock<std::mutex> l(mu_);
    for (;;) {
      writer_idle_ = true;
      work_cv_.wait(l,
                    [&] { return quit_ || count_ >= wake_ || (meta_ != nullptr && !finished_); });
      writer_idle_ = false;
      // Drains the queue, also the pages that arrive meanwhile.
      while (count_ > 0 && status_.ok() && !quit_) {
        Slot& s = slots_[head_];
        l.unlock();
        absl::Status st = writer_->Append(s.section, s.page_no, s.kind, s.record_count,
                                          absl::MakeConstSpan(s.payload));
        l.lock();
        head_ = (head_ + 1) % slots_.size();
        --count_;
        if (!st.ok() && status_.ok()) status_ = st;
        // Only a full queue (or an error) blocks Append.
        if (count_ + 1 == slots_.size() || !status_.ok()) done_cv_.notify_all();
      }
      if (!status_.ok() || quit_) count_ = 0;  // the build failed or gave up: drop the rest
      if (meta_ != nullptr && !finished_ && status_.ok() && count_ == 0) {
        const StoreMeta* meta = meta_;
        l.unlock();
        absl::Status st = writer_->Finish(*meta);
        l.lock();
        if (!st.ok()) status_ = st;
        finished_ = true;
      }
      if (finished_ || !status_.ok()) done_cv_.notify_all();
      if (quit_) break;
    }
    l.unlock();
    writer_.reset();  // aborts an open transaction on the thread that began it
  }

  std::unique_ptr<PageWriter> writer_;
  const uint32_t page_size_;
  std::vector<Slot> slots_;
  const size_t wake_;
  std::mutex mu_;
  std::condition_variable work_cv_;  // the writer thread waits for pages, Finish or quit
  std::condition_variable done_cv_;  // Append waits for a free slot, Finish for the end
  size_t head_ = 0;                  // guarded by mu_
  size_t count_ = 0;                 // guarded by mu_
  bool writer_idle_ = false;         // guarded by mu_: the writer thread waits on work_cv_
  bool quit_ = false;
  bool finished_ = false;
  const StoreMeta* meta_ = nullptr;
  absl::Status status_;
  std::thread thread_;
};

uint64_t DirectoryBytes(const std::string& path) {
  std::error_code ec;
  uint64_t total = 0;
  for (const auto& e : std::filesystem::directory_iterator(path, ec)) {
    if (e.is_regular_file(ec)) total += e.file_size(ec);
  }
  return total;
}

}  // namespace

std::string BuildTempDir(const std::string& db_path, const BuildOptions& options) {
  if (!options.tmp_dir.empty()) return options.tmp_dir;
  std::error_code ec;
  // The database's parent directory, or its nearest ancestor that exists yet.
  std::filesystem::path parent = std::filesystem::absolute(db_path).parent_path();
  while (!parent.empty() && parent != parent.root_path() &&
         !std::filesystem::is_directory(parent, ec)) {
    parent = parent.parent_path();
  }
  return parent.empty() ? std::string(".") : parent.string();
}

std::string BuildRunDirectory(const std::string& db_path, const BuildOptions& options) {
  return internal::RunDirectory(BuildTempDir(db_path, options), db_path);
}

absl::StatusOr<BuildStats> BuildDatabase(SurfelSource& source, const std::string& db_path,
                                         const BuildOptions& options) {
  const std::string tmp_dir = BuildTempDir(db_path, options);
  std::error_code ec;
  if (!std::filesystem::is_directory(tmp_dir, ec)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("temporary directory '%s' does not exist", tmp_dir));
  }
  if (options.resumable.resume && options.resumable.input_identity.empty()) {
    return absl::InvalidArgumentError(
        "a build resumes only with BuildOptions::resumable.input_identity (what the kept runs "
        "were made from)");
  }
  const std::string run_dir = options.resumable.input_identity.empty()
                                  ? std::string()
                                  : internal::RunDirectory(tmp_dir, db_path);
  StoreOptions so;
  so.page_size = options.page_size;
  // Compact records compress ~3x more with zstd at a fraction of a page read's cost
  // (docs/format.md, "Format version 3").
  so.compress_pages = true;
  const internal::MemoryPlan plan = internal::PlanMemory(options, source.KnownCount());
  so.batch_bytes = plan.batch_bytes;
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PageWriter> writer, PageWriter::Create(db_path, so));
  StoreMeta meta;
  BuildStats stats;
  internal::Stopwatch finish;
  if (plan.threads > 1) {
    const size_t slots = std::max(kWriterQueueBytes / so.page_size, kWriterMinSlots);
    AsyncWriterSink sink(std::move(writer), slots, kWriterWakePages);
    PBGI_ASSIGN_OR_RETURN(stats,
                          internal::BuildToSink(source, sink, options, tmp_dir, &meta, run_dir));
    finish.Restart();
    PBGI_RETURN_IF_ERROR(sink.Finish(meta));
  } else {
    internal::StoreWriterSink sink(writer.get());
    PBGI_ASSIGN_OR_RETURN(stats,
                          internal::BuildToSink(source, sink, options, tmp_dir, &meta, run_dir));
    finish.Restart();
    PBGI_RETURN_IF_ERROR(writer->Finish(meta));
    writer.reset();
  }
  // The database is complete: the kept runs are no longer needed.
  if (!run_dir.empty()) std::filesystem::remove_all(run_dir, ec);
  stats.seconds_finish = finish.Seconds();
  stats.seconds_total += stats.seconds_finish;
  stats.bytes_on_disk = DirectoryBytes(db_path);
  stats.peak_rss_bytes = internal::PeakRssBytes();
  return stats;
}

absl::Status VerifyTree(const PageStore& store) {
  PBGI_RETURN_IF_ERROR(internal::CheckDatabaseMeta(store.meta(), store.path()));
  absl::Status s = internal::VerifyTreePages(store.meta(), *internal::BorrowStorePageSource(store));
  if (!s.ok()) {
    return absl::Status(s.code(), absl::StrFormat("%s: %s", store.path(), s.message()));
  }
  return absl::OkStatus();
}

}  // namespace pbgi
