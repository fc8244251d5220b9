#include "build/external_sort.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <utility>

#include "absl/strings/str_format.h"

namespace pbgi::internal {
namespace {

constexpr int kDigitBits = 13;  // 8192 64-bit counters per pass stay in L2
constexpr int kPasses = 5;      // 65 bits >= 63
constexpr size_t kBuckets = size_t{1} << kDigitBits;
constexpr uint64_t kMinMergeBufferBytes = 64 << 10;
constexpr size_t kWriteChunkRecords = 4096;

absl::Status ErrnoError(const std::string& what, int err) {
  return absl::InternalError(absl::StrFormat("%s: %s", what, std::strerror(err)));
}

absl::Status WriteAll(int fd, const void* data, size_t bytes, uint64_t offset,
                      const std::string& dir) {
  const char* p = static_cast<const char*>(data);
  while (bytes > 0) {
    ssize_t w = pwrite(fd, p, bytes, static_cast<off_t>(offset));
    if (w < 0) {
      if (errno == EINTR) continue;
      return ErrnoError(absl::StrFormat("writing a sort run in '%s'", dir), errno);
    }
    p += w;
    bytes -= static_cast<size_t>(w);
    offset += static_cast<uint64_t>(w);
  }
  return absl::OkStatus();
}

absl::Status ReadAll(int fd, void* data, size_t bytes, uint64_t offset, const std::string& dir) {
  char* p = static_cast<char*>(data);
  while (bytes > 0) {
    ssize_t r = pread(fd, p, bytes, static_cast<off_t>(offset));
    if (r < 0) {
      if (errno == EINTR) continue;
      return ErrnoError(absl::StrFormat("reading a sort run in '%s'", dir), errno);
    }
    if (r == 0) {
      return absl::DataLossError(
          absl::StrFormat("sort run in '%s' is truncated at byte offset %d", dir, offset));
    }
    p += r;
    bytes -= static_cast<size_t>(r);
    offset += static_cast<uint64_t>(r);
  }
  return absl::OkStatus();
}

}  // namespace

KeyIndex* RadixSortKeyIndex(absl::Span<KeyIndex> pairs, absl::Span<KeyIndex> scratch) {
  const size_t n = pairs.size();
  if (n < 2) return pairs.data();
  std::vector<uint64_t> counts(kPasses * kBuckets, 0);
  for (const KeyIndex& p : pairs) {
    uint64_t k = p.key;
    for (int d = 0; d < kPasses; ++d) {
      ++counts[d * kBuckets + ((k >> (d * kDigitBits)) & (kBuckets - 1))];
    }
  }
  KeyIndex* src = pairs.data();
  KeyIndex* dst = scratch.data();
  for (int d = 0; d < kPasses; ++d) {
    uint64_t* c = &counts[d * kBuckets];
    const int shift = d * kDigitBits;
    if (c[(src[0].key >> shift) & (kBuckets - 1)] == n) continue;  // one bucket: no-op pass
    uint64_t sum = 0;
    for (size_t b = 0; b < kBuckets; ++b) {
      uint64_t t = c[b];
      c[b] = sum;
      sum += t;
    }
    for (size_t i = 0; i < n; ++i) {
      const KeyIndex& p = src[i];
      dst[c[(p.key >> shift) & (kBuckets - 1)]++] = p;
    }
    std::swap(src, dst);
  }
  return src;
}

// Streams one spilled run through a buffer.
class ExternalSorter::RunReader {
 public:
  RunReader(Run run, size_t buffer_records, const std::string* dir)
      : run_(run),
        buf_(new SortRecord[std::max<size_t>(buffer_records, 1)]),
        cap_(std::max<size_t>(buffer_records, 1)),
        dir_(dir) {}
  absl::Status Refill() {
    pos_ = 0;
    len_ = static_cast<size_t>(std::min<uint64_t>(cap_, run_.count - next_));
    if (len_ == 0) return absl::OkStatus();
    PBGI_RETURN_IF_ERROR(
        ReadAll(run_.fd, buf_.get(), len_ * sizeof(SortRecord), next_ * sizeof(SortRecord), *dir_));
    next_ += len_;
    return absl::OkStatus();
  }
  bool Valid() const { return pos_ < len_; }
  const SortRecord& Current() const { return buf_[pos_]; }
  absl::Status Advance() {
    if (++pos_ == len_) return Refill();
    return absl::OkStatus();
  }

 private:
  Run run_;
  std::unique_ptr<SortRecord[]> buf_;
  size_t cap_;
  size_t pos_ = 0, len_ = 0;
  uint64_t next_ = 0;  // records read from the file so far
  const std::string* dir_;
};

// k-way merge with a binary min-heap ordered by (key, run index): ties go to the earlier run,
// which keeps the sort stable. Heap entries cache their key, so sifting touches only the heap.
class ExternalSorter::Merger {
 public:
  static absl::StatusOr<std::unique_ptr<Merger>> Create(const std::vector<Run>& runs,
                                                        size_t buffer_records,
                                                        const std::string* dir) {
    auto m = std::unique_ptr<Merger>(new Merger());
    m->readers_.reserve(runs.size());
    for (const Run& r : runs) {
      m->readers_.emplace_back(r, buffer_records, dir);
      RunReader& rr = m->readers_.back();
      PBGI_RETURN_IF_ERROR(rr.Refill());
      if (rr.Valid()) m->heap_.push_back({rr.Current().key, m->readers_.size() - 1});
    }
    for (size_t i = m->heap_.size(); i-- > 0;) m->SiftDown(i);
    return m;
  }

  absl::StatusOr<size_t> Next(absl::Span<SortRecord> out) {
    size_t n = 0;
    while (n < out.size() && !heap_.empty()) {
      RunReader& r = readers_[heap_[0].run];
      out[n++] = r.Current();
      PBGI_RETURN_IF_ERROR(r.Advance());
      if (r.Valid()) {
        heap_[0].key = r.Current().key;
      } else {
        heap_[0] = heap_.back();
        heap_.pop_back();
      }
      if (!heap_.empty()) SiftDown(0);
    }
    return n;
  }

 private:
  struct Entry {
    uint64_t key;
    size_t run;
  };
  Merger() = default;
  static bool Less(const Entry& a, const Entry& b) {
    return a.key < b.key || (a.key == b.key && a.run < b.run);
  }
  void SiftDown(size_t i) {
    const size_t n = heap_.size();
    const Entry e = heap_[i];
    for (;;) {
      size_t l = 2 * i + 1;
      if (l >= n) break;
      if (l + 1 < n && Less(heap_[l + 1], heap_[l])) ++l;
      if (!Less(heap_[l], e)) break;
      heap_[i] = heap_[l];
      i = l;
    }
    heap_[i] = e;
  }
  std::vector<RunReader> readers_;
  std::vector<Entry> heap_;
};

ExternalSorter::ExternalSorter(const Options& options) : options_(options) {
  if (options_.run_capacity == 0) options_.run_capacity = 1;
  // new[] of trivial types leaves the memory untouched: only the pages a run uses become
  // resident, so a small input under a big budget costs little.
  records_.reset(new SortRecord[options_.run_capacity]);
  pairs_.reset(new KeyIndex[options_.run_capacity]);
  scratch_.reset(new KeyIndex[options_.run_capacity]);
}

ExternalSorter::~ExternalSorter() {
  merger_.reset();
  for (Run& r : runs_) {
    if (r.fd >= 0) close(r.fd);
  }
}

void ExternalSorter::SortBuffer() {
  for (uint64_t i = 0; i < size_; ++i) pairs_[i] = KeyIndex{records_[i].key, i};
  sorted_ = RadixSortKeyIndex(absl::Span<KeyIndex>(pairs_.get(), size_),
                              absl::Span<KeyIndex>(scratch_.get(), size_));
}

absl::StatusOr<ExternalSorter::Run> ExternalSorter::NewRunFile() {
  const std::string& dir = options_.tmp_dir.empty() ? std::string(".") : options_.tmp_dir;
  int fd = open(dir.c_str(), O_TMPFILE | O_RDWR | O_CLOEXEC, 0600);
  if (fd < 0) {
    // No O_TMPFILE on this file system: create and unlink at once.
    std::string path = dir + "/pbgi-sort-XXXXXX";
    fd = mkostemp(path.data(), O_CLOEXEC);
    if (fd < 0) {
      return ErrnoError(absl::StrFormat("cannot create a temporary sort run in '%s'", dir), errno);
    }
    unlink(path.c_str());
  }
  Run r;
  r.fd = fd;
  return r;
}

absl::Status ExternalSorter::SpillRun() {
  if (size_ == 0) return absl::OkStatus();
  SortBuffer();
  PBGI_ASSIGN_OR_RETURN(Run run, NewRunFile());
  runs_.push_back(run);
  std::vector<SortRecord> chunk(std::min<uint64_t>(kWriteChunkRecords, size_));
  uint64_t offset = 0;
  for (uint64_t i = 0; i < size_;) {
    size_t n = static_cast<size_t>(std::min<uint64_t>(chunk.size(), size_ - i));
    for (size_t j = 0; j < n; ++j) {
      // The gather is random access: fetch a few records ahead.
      if (i + j + 16 < size_) __builtin_prefetch(&records_[sorted_[i + j + 16].index]);
      chunk[j] = records_[sorted_[i + j].index];
    }
    PBGI_RETURN_IF_ERROR(
        WriteAll(run.fd, chunk.data(), n * sizeof(SortRecord), offset, options_.tmp_dir));
    offset += n * sizeof(SortRecord);
    i += n;
  }
  runs_.back().count = size_;
  spill_bytes_ += offset;
  ++runs_spilled_;
  total_ += size_;
  size_ = 0;
  return absl::OkStatus();
}

void ExternalSorter::FreeBuffers() {
  records_.reset();
  pairs_.reset();
  scratch_.reset();
  sorted_ = nullptr;
}

absl::Status ExternalSorter::MergeRuns(std::vector<Run> in, size_t buffer_records, Run* out) {
  PBGI_ASSIGN_OR_RETURN(auto merger, Merger::Create(in, buffer_records, &options_.tmp_dir));
  PBGI_ASSIGN_OR_RETURN(*out, NewRunFile());
  std::vector<SortRecord> chunk(std::max<size_t>(buffer_records, 1));
  uint64_t offset = 0;
  for (;;) {
    PBGI_ASSIGN_OR_RETURN(size_t n, merger->Next(absl::MakeSpan(chunk)));
    if (n == 0) break;
    PBGI_RETURN_IF_ERROR(
        WriteAll(out->fd, chunk.data(), n * sizeof(SortRecord), offset, options_.tmp_dir));
    offset += n * sizeof(SortRecord);
  }
  out->count = offset / sizeof(SortRecord);
  spill_bytes_ += offset;
  return absl::OkStatus();
}

absl::Status ExternalSorter::FinishInput() {
  if (finished_) return absl::FailedPreconditionError("ExternalSorter::FinishInput called twice");
  finished_ = true;
  if (runs_.empty()) {
    SortBuffer();
    total_ = size_;
    return absl::OkStatus();
  }
  PBGI_RETURN_IF_ERROR(SpillRun());
  FreeBuffers();
  const uint64_t fan_in = std::max<uint64_t>(2, options_.merge_bytes / kMinMergeBufferBytes);
  while (runs_.size() > fan_in) {
    // Merge consecutive groups, in order, so that ties still resolve to the earlier input.
    const size_t buffer_records =
        std::max<size_t>(64, options_.merge_bytes / (fan_in + 1) / sizeof(SortRecord));
    std::vector<Run> next;
    for (size_t i = 0; i < runs_.size(); i += fan_in) {
      std::vector<Run> group(runs_.begin() + i,
                             runs_.begin() + std::min<size_t>(runs_.size(), i + fan_in));
      Run merged;
      absl::Status s = MergeRuns(group, buffer_records, &merged);
      for (size_t j = i; j < std::min<size_t>(runs_.size(), i + fan_in); ++j) {
        close(runs_[j].fd);
        runs_[j].fd = -1;
      }
      if (!s.ok()) {
        if (merged.fd >= 0) close(merged.fd);
        for (Run& r : next) close(r.fd);
        return s;
      }
      next.push_back(merged);
    }
    runs_ = std::move(next);
    ++merge_passes_;
  }
  const size_t buffer_records =
      std::max<size_t>(64, options_.merge_bytes / runs_.size() / sizeof(SortRecord));
  PBGI_ASSIGN_OR_RETURN(merger_, Merger::Create(runs_, buffer_records, &options_.tmp_dir));
  return absl::OkStatus();
}

absl::StatusOr<size_t> ExternalSorter::Next(absl::Span<SortRecord> out) {
  if (!finished_) return absl::FailedPreconditionError("ExternalSorter::Next before FinishInput");
  if (merger_ != nullptr) return merger_->Next(out);
  size_t n = static_cast<size_t>(std::min<uint64_t>(out.size(), size_ - emitted_));
  for (size_t i = 0; i < n; ++i) {
    if (emitted_ + i + 16 < size_) __builtin_prefetch(&records_[sorted_[emitted_ + i + 16].index]);
    out[i] = records_[sorted_[emitted_ + i].index];
  }
  emitted_ += n;
  return n;
}

}  // namespace pbgi::internal
