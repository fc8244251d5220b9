#include "build/external_sort.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstring>
#include <utility>

#include "absl/strings/str_format.h"
#include "build/spill_codec.h"
#include "store/crc32c.h"

namespace pbgi::internal {
namespace {

constexpr int kDigitBits = 8;  // 256 places to scatter to: their cache lines stay in L1
constexpr size_t kBuckets = size_t{1} << kDigitBits;
constexpr uint64_t kMinMergeBufferBytes = 64 << 10;
constexpr size_t kWriteChunkRecords = 4096;
constexpr size_t kBlockRecords = 8192;  // merge output blocks (384 KiB)
constexpr size_t kPipeBlocks = 4;
// A run's read buffer, at most: reads of a few MiB already keep the disk streaming, and the
// rest of Options::merge_bytes would only sit resident next to LMDB's write batch and the upper
// node groups for the whole merge (docs/design.md, "Memory plan").
constexpr uint64_t kMaxReaderBytes = uint64_t{8} << 20;

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

// Buckets this small are sorted by insertion: a radix pass's 256 counters cost more.
constexpr size_t kInsertionSortMax = 48;

void InsertionSortByKey(KeyIndex* a, size_t m) {
  for (size_t i = 1; i < m; ++i) {
    const KeyIndex x = a[i];
    size_t j = i;
    for (; j > 0 && a[j - 1].key > x.key; --j) a[j] = a[j - 1];
    a[j] = x;
  }
}

// Sorts the m pairs at `src`, whose keys agree on every varying bit above `rest`, stably into
// `out` (`src` or `other`, the same range of the other array): MSD passes on the highest 8 bits
// of `rest`, from one array to the other, until a bucket is small or its keys are equal.
void SortBucket(KeyIndex* src, KeyIndex* other, KeyIndex* out, size_t m, uint64_t rest) {
  if (m <= kInsertionSortMax || rest == 0) {
    if (src != out) std::copy(src, src + m, out);
    if (rest != 0) InsertionSortByKey(out, m);
    return;
  }
  const int shift = std::max(64 - __builtin_clzll(rest) - kDigitBits, 0);
  std::array<size_t, kBuckets + 1> start{};
  for (size_t i = 0; i < m; ++i) ++start[((src[i].key >> shift) & (kBuckets - 1)) + 1];
  for (size_t b = 0; b < kBuckets; ++b) start[b + 1] += start[b];
  std::array<size_t, kBuckets> next;
  std::copy(start.begin(), start.begin() + kBuckets, next.begin());
  for (size_t i = 0; i < m; ++i) other[next[(src[i].key >> shift) & (kBuckets - 1)]++] = src[i];
  const uint64_t below = rest & ((uint64_t{1} << shift) - 1);
  for (size_t b = 0; b < kBuckets; ++b) {
    const size_t lo = start[b], mb = start[b + 1] - lo;
    if (mb == 0) continue;
    SortBucket(other + lo, src + lo, (out == src ? src : other) + lo, mb, below);
  }
}

}  // namespace

KeyIndex* RadixSortKeyIndex(absl::Span<KeyIndex> pairs, absl::Span<KeyIndex> scratch) {
  const size_t n = pairs.size();
  if (n < 2) return pairs.data();
  uint64_t any = 0, every = ~uint64_t{0};
  for (const KeyIndex& p : pairs) {
    any |= p.key;
    every &= p.key;
  }
  const uint64_t varying = any ^ every;  // bits that differ between keys: the others never sort
  if (varying == 0) return pairs.data();
  // One stable pass on the highest 8 varying bits splits the run into 256 buckets of
  // consecutive output, from `pairs` into `scratch`. Each bucket, small enough to stay in the
  // cache, is then split again on the next 8 varying bits (back into `pairs`), and so on until a
  // bucket holds at most kInsertionSortMax pairs, which an insertion sort finishes in place.
  // Whole-run LSD passes cost more next to the thread that reads the input through the same
  // caches, and an LSD sort of each bucket took a pass for every varying digit of the bucket
  // (docs/format.md, "Session 13" and "Session 15").
  const int top = std::max(64 - __builtin_clzll(varying) - kDigitBits, 0);
  const uint64_t below = varying & ((uint64_t{1} << top) - 1);
  std::array<size_t, kBuckets + 1> start{};
  for (const KeyIndex& p : pairs) ++start[((p.key >> top) & (kBuckets - 1)) + 1];
  for (size_t b = 0; b < kBuckets; ++b) start[b + 1] += start[b];
  std::array<size_t, kBuckets> next;
  std::copy(start.begin(), start.begin() + kBuckets, next.begin());
  for (const KeyIndex& p : pairs) scratch[next[(p.key >> top) & (kBuckets - 1)]++] = p;
  // The top digit held every varying bit: the pass sorted the run.
  if (below == 0) return scratch.data();
  for (size_t b = 0; b < kBuckets; ++b) {
    const size_t lo = start[b], m = start[b + 1] - lo;
    if (m == 0) continue;
    SortBucket(scratch.data() + lo, pairs.data() + lo, pairs.data() + lo, m, below);
  }
  return pairs.data();
}

// Streams one spilled run through a buffer: raw runs straight into SortRecords; compact runs
// (`dec`) through a byte buffer, one block decoded at a time (`packed`: into packed records).
class ExternalSorter::RunReader {
 public:
  RunReader(Run run, size_t buffer_records, const std::string* dir, SpillBlockReader* dec,
            const SpillCodec* codec, bool packed)
      : run_(run), dir_(dir), dec_(dec), codec_(codec), packed_(packed) {
    if (dec_ == nullptr) {
      cap_ = std::max<size_t>(buffer_records, 1);
    } else {
      cap_ = kSpillBlockRecords;
      const uint64_t budget = uint64_t{std::max<size_t>(buffer_records, 1)} * sizeof(SortRecord);
      io_cap_ = static_cast<size_t>(std::max<uint64_t>(
          codec_->max_block_bytes(),
          budget > cap_ * sizeof(SortRecord) ? budget - cap_ * sizeof(SortRecord) : 0));
      io_.reset(new uint8_t[io_cap_]);
      what_ = run_.path.empty() ? absl::StrFormat("a compact sort run in '%s'", *dir_)
                                : absl::StrFormat("compact sort run %s", run_.path);
    }
    buf_.reset(new SortRecord[cap_]);
  }
  absl::Status Refill() { return dec_ == nullptr ? RefillRaw() : RefillCompact(); }
  uint64_t buffer_bytes() const { return cap_ * sizeof(SortRecord) + io_cap_; }
  bool Valid() const { return pos_ < len_; }
  const SortRecord& Current() const { return buf_[pos_]; }
  absl::Status Advance() {
    if (++pos_ == len_) return Refill();
    return absl::OkStatus();
  }

 private:
  // Reads [offset, offset + bytes) of the file into `to`, checks the CRC at the run's end and
  // drops the pages from the page cache (read once; a memory cgroup counts them).
  absl::Status ReadFile(void* to, uint64_t offset, uint64_t bytes) {
    PBGI_RETURN_IF_ERROR(ReadAll(run_.fd, to, bytes, offset, *dir_));
    if (run_.checked) {
      crc_ = Crc32c(crc_, to, bytes);
      if (offset + bytes == run_.bytes && crc_ != run_.crc) {
        return absl::DataLossError(absl::StrFormat(
            "kept sort run %s does not match its checksum in the manifest (CRC-32C %08x, the "
            "manifest says %08x): it was changed or damaged; remove its directory and build "
            "again without --resume",
            run_.path, crc_, run_.crc));
      }
    }
    (void)posix_fadvise(run_.fd, static_cast<off_t>(offset), static_cast<off_t>(bytes),
                        POSIX_FADV_DONTNEED);
    return absl::OkStatus();
  }
  absl::Status RefillRaw() {
    pos_ = 0;
    len_ = static_cast<size_t>(std::min<uint64_t>(cap_, run_.count - next_));
    if (len_ == 0) return absl::OkStatus();
    PBGI_RETURN_IF_ERROR(
        ReadFile(buf_.get(), next_ * sizeof(SortRecord), len_ * sizeof(SortRecord)));
    next_ += len_;
    return absl::OkStatus();
  }
  // Makes `want` bytes available at io_[io_pos_].
  absl::Status Want(size_t want) {
    if (io_len_ - io_pos_ >= want) return absl::OkStatus();
    const size_t avail = io_len_ - io_pos_;
    std::memmove(io_.get(), io_.get() + io_pos_, avail);
    io_pos_ = 0;
    io_len_ = avail;
    const uint64_t room = std::min<uint64_t>(io_cap_ - io_len_, run_.bytes - file_next_);
    if (io_len_ + room < want) {
      return absl::DataLossError(
          absl::StrFormat("%s is truncated: %d records of %d decoded, at byte offset %d of %d",
                          what_, decoded_, run_.count, file_next_, run_.bytes));
    }
    PBGI_RETURN_IF_ERROR(ReadFile(io_.get() + io_len_, file_next_, room));
    file_next_ += room;
    io_len_ += static_cast<size_t>(room);
    return absl::OkStatus();
  }
  absl::Status RefillCompact() {
    pos_ = 0;
    len_ = 0;
    if (decoded_ == run_.count) {
      if (io_pos_ != io_len_ || file_next_ != run_.bytes) {
        return absl::DataLossError(absl::StrFormat("%s has bytes after its %d records (%d bytes)",
                                                   what_, run_.count, run_.bytes));
      }
      return absl::OkStatus();
    }
    PBGI_RETURN_IF_ERROR(Want(kSpillBlockHeaderBytes));
    uint32_t frame = 0, n = 0;
    PBGI_RETURN_IF_ERROR(
        SpillBlockReader::ParseHeader(io_.get() + io_pos_, *codec_, what_.c_str(), &frame, &n));
    if (decoded_ + n > run_.count) {
      return absl::DataLossError(
          absl::StrFormat("%s: a block of %d records after %d goes past its %d records", what_, n,
                          decoded_, run_.count));
    }
    PBGI_RETURN_IF_ERROR(Want(kSpillBlockHeaderBytes + frame));
    PBGI_RETURN_IF_ERROR(
        dec_->Decode(absl::Span<const uint8_t>(io_.get() + io_pos_ + kSpillBlockHeaderBytes, frame),
                     n, buf_.get(), what_.c_str(), packed_));
    io_pos_ += kSpillBlockHeaderBytes + frame;
    decoded_ += n;
    len_ = n;
    return absl::OkStatus();
  }

  Run run_;
  std::unique_ptr<SortRecord[]> buf_;
  size_t cap_ = 0;
  size_t pos_ = 0, len_ = 0;
  uint64_t next_ = 0;  // raw: records read from the file so far
  uint32_t crc_ = 0;   // of the bytes read so far (checked runs)
  const std::string* dir_;
  // Compact runs.
  SpillBlockReader* dec_;
  const SpillCodec* codec_;
  std::unique_ptr<uint8_t[]> io_;
  size_t io_cap_ = 0, io_pos_ = 0, io_len_ = 0;
  uint64_t file_next_ = 0;  // bytes read from the file so far
  uint64_t decoded_ = 0;    // records decoded so far
  std::string what_;
  bool packed_;
};

// Writes a run file, raw or compact (blocks of kSpillBlockRecords), with its CRC-32C.
class ExternalSorter::RunWriter {
 public:
  // `packed`: the records given to Append are packed (SpillCodec::Pack).
  RunWriter(int fd, const std::optional<SpillCodec>& codec, const std::string& dir,
            bool packed = false)
      : fd_(fd), dir_(dir), packed_(packed) {
    if (codec) {
      enc_ = std::make_unique<SpillBlockWriter>(*codec);
      // Room for a flush's worth and one more block, allocated once: not zero-filled a block
      // at a time as a growing vector would be.
      out_.reset(new uint8_t[kFlushBytes + codec->max_block_bytes()]);
    }
  }
  absl::Status Append(const SortRecord* recs, size_t n) {
    if (enc_ == nullptr) return Write(recs, n * sizeof(SortRecord));
    while (n > 0) {
      const size_t k = std::min<size_t>(n, kSpillBlockRecords - pending_.size());
      pending_.insert(pending_.end(), recs, recs + k);
      recs += k;
      n -= k;
      if (pending_.size() == kSpillBlockRecords) PBGI_RETURN_IF_ERROR(EncodePending());
    }
    return absl::OkStatus();
  }
  // Appends recs[order[i].index] for i < n, in this order: compact blocks are encoded straight
  // from `recs`, raw runs go through a chunk.
  absl::Status AppendGathered(const SortRecord* recs, const KeyIndex* order, size_t n) {
    if (enc_ == nullptr || !pending_.empty()) {
      std::vector<SortRecord> chunk(std::min<size_t>(kWriteChunkRecords, n));
      for (size_t i = 0; i < n;) {
        const size_t k = std::min(chunk.size(), n - i);
        for (size_t j = 0; j < k; ++j) {
          // The gather is random access: fetch a few records ahead.
          if (i + j + 16 < n) __builtin_prefetch(&recs[order[i + j + 16].index]);
          chunk[j] = recs[order[i + j].index];
        }
        PBGI_RETURN_IF_ERROR(Append(chunk.data(), k));
        i += k;
      }
      return absl::OkStatus();
    }
    for (size_t i = 0; i < n; i += kSpillBlockRecords) {
      const size_t k = std::min<size_t>(kSpillBlockRecords, n - i);
      PBGI_ASSIGN_OR_RETURN(size_t bytes,
                            enc_->EncodeGathered(recs, absl::MakeConstSpan(order + i, k),
                                                 out_.get() + out_len_, packed_));
      PBGI_RETURN_IF_ERROR(Wrote(bytes));
    }
    return absl::OkStatus();
  }
  absl::Status Finish() {
    if (enc_ == nullptr) return absl::OkStatus();
    if (!pending_.empty()) PBGI_RETURN_IF_ERROR(EncodePending());
    return FlushOut();
  }
  uint64_t bytes() const { return offset_; }
  uint32_t crc() const { return crc_; }

 private:
  static constexpr size_t kFlushBytes = 1 << 20;
  absl::Status Write(const void* p, size_t bytes) {
    crc_ = Crc32c(crc_, p, bytes);
    PBGI_RETURN_IF_ERROR(WriteAll(fd_, p, bytes, offset_, dir_));
    offset_ += bytes;
    return absl::OkStatus();
  }
  // A block of `bytes` was encoded at out_ + out_len_.
  absl::Status Wrote(size_t bytes) {
    out_len_ += bytes;
    if (out_len_ >= kFlushBytes) return FlushOut();
    return absl::OkStatus();
  }
  absl::Status EncodePending() {
    PBGI_ASSIGN_OR_RETURN(
        size_t bytes, enc_->Encode(absl::MakeConstSpan(pending_), out_.get() + out_len_, packed_));
    pending_.clear();
    return Wrote(bytes);
  }
  absl::Status FlushOut() {
    if (out_len_ == 0) return absl::OkStatus();
    PBGI_RETURN_IF_ERROR(Write(out_.get(), out_len_));
    out_len_ = 0;
    return absl::OkStatus();
  }
  int fd_;
  const std::string& dir_;
  bool packed_;
  std::unique_ptr<SpillBlockWriter> enc_;
  std::vector<SortRecord> pending_;
  std::unique_ptr<uint8_t[]> out_;  // compact: encoded blocks not yet written
  size_t out_len_ = 0;
  uint64_t offset_ = 0;
  uint32_t crc_ = 0;
};

// k-way merge with a binary min-heap ordered by (key, run index): ties go to the earlier run,
// which keeps the sort stable. Heap entries cache their key, so sifting touches only the heap.
class ExternalSorter::Merger {
 public:
  static absl::StatusOr<std::unique_ptr<Merger>> Create(const std::vector<Run>& runs,
                                                        size_t buffer_records,
                                                        const std::string* dir,
                                                        const std::optional<SpillCodec>& codec,
                                                        bool packed) {
    auto m = std::unique_ptr<Merger>(new Merger());
    if (codec) {
      m->codec_ = *codec;
      m->dec_ = std::make_unique<SpillBlockReader>(*codec);  // one zstd context for all runs
    }
    m->readers_.reserve(runs.size());
    for (const Run& r : runs) {
      m->readers_.emplace_back(r, buffer_records, dir, m->dec_.get(), &m->codec_,
                               packed && codec.has_value());
      RunReader& rr = m->readers_.back();
      PBGI_RETURN_IF_ERROR(rr.Refill());
      if (rr.Valid()) m->heap_.push_back({rr.Current().key, m->readers_.size() - 1});
    }
    for (size_t i = m->heap_.size(); i-- > 0;) m->SiftDown(i);
    return m;
  }

  uint64_t buffer_bytes() const {
    uint64_t b = 0;
    for (const RunReader& r : readers_) b += r.buffer_bytes();
    return b;
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
  SpillCodec codec_;
  std::unique_ptr<SpillBlockReader> dec_;
  std::vector<RunReader> readers_;
  std::vector<Entry> heap_;
};

BlockPipe::BlockPipe(size_t blocks, size_t block_records, Producer produce)
    : block_records_(std::max<size_t>(block_records, 1)), produce_(std::move(produce)) {
  blocks = std::max<size_t>(blocks, 2);
  storage_.reset(new SortRecord[blocks * block_records_]);
  for (size_t i = 0; i < blocks; ++i) free_.push_back(storage_.get() + i * block_records_);
  full_.reserve(blocks);
  thread_ = std::thread([this] { Run(); });
}

BlockPipe::~BlockPipe() {
  {
    std::lock_guard<std::mutex> l(mu_);
    stop_ = true;
  }
  cv_.notify_all();
  thread_.join();
}

void BlockPipe::Run() {
  for (;;) {
    SortRecord* b = nullptr;
    {
      std::unique_lock<std::mutex> l(mu_);
      cv_.wait(l, [&] { return stop_ || !free_.empty(); });
      if (stop_) return;
      b = free_.back();
      free_.pop_back();
    }
    absl::StatusOr<size_t> n = produce_(absl::Span<SortRecord>(b, block_records_));
    bool done = false;
    {
      std::lock_guard<std::mutex> l(mu_);
      if (!n.ok()) {
        status_ = n.status();
        done = true;
      } else if (*n == 0) {
        done = true;
      } else {
        full_.push_back({b, *n});
      }
      done_ = done;
    }
    cv_.notify_all();
    if (done) return;
  }
}

absl::StatusOr<absl::Span<const SortRecord>> BlockPipe::Next() {
  std::unique_lock<std::mutex> l(mu_);
  if (held_ != nullptr) {
    free_.push_back(held_);
    held_ = nullptr;
    cv_.notify_all();
  }
  cv_.wait(l, [&] { return full_head_ < full_.size() || done_; });
  if (full_head_ < full_.size()) {
    auto [b, n] = full_[full_head_++];
    if (full_head_ == full_.size()) {
      full_.clear();
      full_head_ = 0;
    }
    held_ = b;
    return absl::Span<const SortRecord>(b, n);
  }
  if (!status_.ok()) return status_;
  return absl::Span<const SortRecord>();
}

ExternalSorter::ExternalSorter(const Options& options) : options_(options) {
  if (options_.run_capacity == 0) options_.run_capacity = 1;
  // new[] of trivial types leaves the memory untouched: only the pages a run uses become
  // resident, so a small input under a big budget costs little.
  records_.reset(new SortRecord[options_.run_capacity]);
  pairs_.reset(new KeyIndex[options_.run_capacity]);
  scratch_.reset(new KeyIndex[options_.run_capacity]);
}

ExternalSorter::~ExternalSorter() {
  pipe_.reset();  // its thread may be using merger_ or the buffers
  StopSpiller();
  merger_.reset();
  for (Run& r : runs_) {
    if (r.fd >= 0) close(r.fd);
  }
  if (!keep_runs_) {
    for (const std::string& p : named_) unlink(p.c_str());
  }
}

void ExternalSorter::SortBuffer(const SortRecord* recs, uint64_t n) {
  for (uint64_t i = 0; i < n; ++i) pairs_[i] = KeyIndex{recs[i].key, i};
  sorted_ = RadixSortKeyIndex(absl::Span<KeyIndex>(pairs_.get(), n),
                              absl::Span<KeyIndex>(scratch_.get(), n));
}

absl::StatusOr<ExternalSorter::Run> ExternalSorter::NewRunFile(bool named) {
  if (named) {
    Run r;
    r.path = absl::StrFormat("%s/run-%06d", run_dir_, named_.size());
    r.fd = open(r.path.c_str(), O_CREAT | O_TRUNC | O_RDWR | O_CLOEXEC, 0600);
    if (r.fd < 0) {
      return ErrnoError(absl::StrFormat("cannot create the sort run %s", r.path), errno);
    }
    named_.push_back(r.path);
    return r;
  }
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
  if (options_.threads <= 1) {
    absl::Status s = SpillBuffer(records_.get(), size_);
    size_ = 0;
    return s;
  }
  // Hand the full buffer to the sort thread and go on filling the other one.
  HelpSpill();
  PBGI_RETURN_IF_ERROR(WaitSpiller());
  if (!spiller_.joinable()) {
    spare_.reset(new SortRecord[options_.run_capacity]);
    spiller_ = std::thread([this] { SpillerLoop(); });
  }
  std::swap(records_, spare_);
  {
    std::lock_guard<std::mutex> l(spill_mu_);
    spill_job_ = size_;
    spill_busy_ = true;
  }
  spill_cv_.notify_all();
  size_ = 0;
  return absl::OkStatus();
}

absl::Status ExternalSorter::WaitSpiller() {
  std::unique_lock<std::mutex> l(spill_mu_);
  spill_cv_.wait(l, [&] { return !spill_busy_; });
  return spill_status_;
}

void ExternalSorter::SpillerLoop() {
  for (;;) {
    uint64_t n = 0;
    {
      std::unique_lock<std::mutex> l(spill_mu_);
      spill_cv_.wait(l, [&] { return spill_quit_ || spill_busy_; });
      if (spill_quit_) return;
      n = spill_job_;
    }
    absl::Status s = spill_status_.ok() ? SpillBuffer(spare_.get(), n, options_.compact.has_value())
                                        : absl::OkStatus();
    {
      std::lock_guard<std::mutex> l(spill_mu_);
      if (spill_status_.ok()) spill_status_ = s;
      spill_busy_ = false;
    }
    spill_cv_.notify_all();
  }
}

void ExternalSorter::StopSpiller() {
  if (!spiller_.joinable()) return;
  {
    std::lock_guard<std::mutex> l(spill_mu_);
    spill_quit_ = true;
  }
  spill_cv_.notify_all();
  spiller_.join();
}

absl::Status ExternalSorter::SpillBuffer(const SortRecord* recs, uint64_t n, bool share) {
  if (n == 0) return absl::OkStatus();
  SortBuffer(recs, n);
  PBGI_ASSIGN_OR_RETURN(Run run, NewRunFile(!run_dir_.empty()));
  runs_.push_back(run);
  RunWriter writer(run.fd, options_.compact, options_.tmp_dir, options_.packed_input);
  absl::Status s;
  uint64_t front_records = n;
  if (!share) {
    s = writer.AppendGathered(recs, sorted_, static_cast<size_t>(n));
  } else {
    const uint64_t blocks = (n + kSpillBlockRecords - 1) / kSpillBlockRecords;
    {
      std::lock_guard<std::mutex> l(spill_mu_);
      shared_ = SharedSpill{};
      shared_.recs = recs;
      shared_.order = sorted_;
      shared_.n = n;
      shared_.blocks = blocks;
      shared_.split = blocks;
      shared_.open = true;
    }
    spill_cv_.notify_all();
    for (;;) {
      uint64_t b = 0;
      {
        std::lock_guard<std::mutex> l(spill_mu_);
        if (!s.ok() || shared_.front >= shared_.split) {
          shared_.open = false;
          front_records = std::min(n, shared_.split * kSpillBlockRecords);
          break;
        }
        b = shared_.front++;
      }
      const uint64_t at = b * kSpillBlockRecords;
      s = writer.AppendGathered(
          recs, sorted_ + at, static_cast<size_t>(std::min<uint64_t>(kSpillBlockRecords, n - at)));
    }
    // The caller reads `recs` until its part is written.
    std::unique_lock<std::mutex> l(spill_mu_);
    spill_cv_.wait(l, [&] { return !shared_.claimed || shared_.back_done; });
  }
  if (s.ok()) s = writer.Finish();
  const size_t front = runs_.size() - 1;
  runs_[front].count = front_records;
  runs_[front].bytes = writer.bytes();
  runs_[front].crc = writer.crc();
  bool shared = false;
  if (share) {
    std::lock_guard<std::mutex> l(spill_mu_);
    shared = shared_.claimed;
    // The caller's run holds the sorted records after front_records, so it follows this one
    // (the merge breaks ties by run order). Kept in runs_ on error too, to be closed.
    if (shared && shared_.back.fd >= 0) runs_.push_back(shared_.back);
    if (shared && s.ok()) s = shared_.back_status;
    shared_ = SharedSpill{};
  }
  if (!s.ok()) {
    return absl::Status(
        s.code(), absl::StrFormat("sort run %d (input records %d..%d), byte "
                                  "offset %d: %s",
                                  front, total_, total_ + n - 1, writer.bytes(), s.message()));
  }
  for (size_t r = front; r < runs_.size(); ++r) {
    spill_bytes_ += runs_[r].bytes;
    ++runs_spilled_;
  }
  if (shared) ++spills_shared_;
  total_ += n;
  return absl::OkStatus();
}

void ExternalSorter::HelpSpill() {
  // Fewer blocks than this are not worth a run of their own.
  constexpr uint64_t kMinSharedBlocks = 16;
  const SortRecord* recs = nullptr;
  const KeyIndex* order = nullptr;
  uint64_t n = 0, from = 0;
  {
    std::unique_lock<std::mutex> l(spill_mu_);
    spill_cv_.wait(l, [&] { return !spill_busy_ || shared_.open; });
    if (!spill_busy_ || !shared_.open || shared_.claimed) return;
    const uint64_t left = shared_.split - shared_.front;
    if (left < 2 * kMinSharedBlocks) return;
    shared_.split = shared_.front + (left + 1) / 2;
    shared_.claimed = true;
    recs = shared_.recs;
    order = shared_.order;
    n = shared_.n;
    from = shared_.split * kSpillBlockRecords;
  }
  Run back;
  absl::Status s;
  absl::StatusOr<Run> file = NewRunFile(!run_dir_.empty());
  if (!file.ok()) {
    s = file.status();
  } else {
    back = *file;
    RunWriter writer(back.fd, options_.compact, options_.tmp_dir, options_.packed_input);
    s = writer.AppendGathered(recs, order + from, static_cast<size_t>(n - from));
    if (s.ok()) s = writer.Finish();
    back.count = n - from;
    back.bytes = writer.bytes();
    back.crc = writer.crc();
    if (!s.ok()) {
      s = absl::Status(s.code(), absl::StrFormat("the second part of a sort run (its sorted "
                                                 "records from %d on), byte offset %d: %s",
                                                 from, writer.bytes(), s.message()));
    }
  }
  {
    std::lock_guard<std::mutex> l(spill_mu_);
    shared_.back = back;
    shared_.back_status = s;
    shared_.back_done = true;
  }
  spill_cv_.notify_all();
}

void ExternalSorter::FreeBuffers() {
  records_.reset();
  spare_.reset();
  pairs_.reset();
  scratch_.reset();
  sorted_ = nullptr;
}

absl::Status ExternalSorter::MergeRuns(std::vector<Run> in, size_t buffer_records, Run* out) {
  // Compact runs pass through a merge pass as packed records: neither decoded nor encoded again.
  const bool packed = options_.compact.has_value();
  PBGI_ASSIGN_OR_RETURN(
      auto merger, Merger::Create(in, buffer_records, &options_.tmp_dir, options_.compact, packed));
  PBGI_ASSIGN_OR_RETURN(*out, NewRunFile(/*named=*/false));
  RunWriter writer(out->fd, options_.compact, options_.tmp_dir, packed);
  std::vector<SortRecord> chunk(std::max<size_t>(buffer_records, 1));
  uint64_t count = 0;
  for (;;) {
    PBGI_ASSIGN_OR_RETURN(size_t n, merger->Next(absl::MakeSpan(chunk)));
    if (n == 0) break;
    PBGI_RETURN_IF_ERROR(writer.Append(chunk.data(), n));
    count += n;
  }
  PBGI_RETURN_IF_ERROR(writer.Finish());
  out->count = count;
  out->bytes = writer.bytes();
  spill_bytes_ += writer.bytes();
  return absl::OkStatus();
}

absl::Status ExternalSorter::FinishInput() {
  if (finished_) return absl::FailedPreconditionError("ExternalSorter::FinishInput called twice");
  finished_ = true;
  if (options_.threads > 1) {
    HelpSpill();
    PBGI_RETURN_IF_ERROR(WaitSpiller());
  }
  if (runs_.empty()) {
    SortBuffer(records_.get(), size_);
    total_ = size_;
    if (options_.threads > 1 && size_ > kBlockRecords) {
      // The gather runs ahead of the consumer.
      pipe_ = std::make_unique<BlockPipe>(
          kPipeBlocks, kBlockRecords, [this](absl::Span<SortRecord> out) { return Produce(out); });
    }
    return absl::OkStatus();
  }
  if (spiller_.joinable()) {
    // The last run goes to the sort thread as the others did, and the caller shares its spill.
    PBGI_RETURN_IF_ERROR(SpillRun());
    HelpSpill();
    PBGI_RETURN_IF_ERROR(WaitSpiller());
  } else {
    PBGI_RETURN_IF_ERROR(SpillBuffer(records_.get(), size_));
  }
  StopSpiller();
  size_ = 0;
  FreeBuffers();
  if (!run_dir_.empty() && runs_written_) {
    std::vector<KeptRun> kept;
    for (const Run& r : runs_) {
      kept.push_back({r.path.substr(r.path.rfind('/') + 1), r.count, r.crc, r.bytes});
    }
    PBGI_RETURN_IF_ERROR(runs_written_(kept));
    keep_runs_ = true;
  }
  return MergeSpilled();
}

absl::Status ExternalSorter::ResumeFrom(const std::vector<KeptRun>& runs) {
  if (finished_) return absl::FailedPreconditionError("ExternalSorter::ResumeFrom after input");
  if (runs.empty()) return absl::InvalidArgumentError("no sort runs to resume from");
  finished_ = true;
  keep_runs_ = true;  // until the caller removes them: an interrupted resume can resume again
  FreeBuffers();
  for (const KeptRun& k : runs) {
    Run r;
    r.path = run_dir_ + "/" + k.name;
    r.count = k.records;
    r.crc = k.crc;
    r.checked = true;
    r.fd = open(r.path.c_str(), O_RDONLY | O_CLOEXEC);
    if (r.fd < 0) {
      return ErrnoError(absl::StrFormat("cannot open the kept sort run %s", r.path), errno);
    }
    runs_.push_back(r);
    named_.push_back(r.path);
    struct stat st;
    if (fstat(r.fd, &st) != 0) return ErrnoError("fstat of " + r.path, errno);
    const uint64_t want = options_.compact ? k.bytes : k.records * sizeof(SortRecord);
    if (uint64_t(st.st_size) != want) {
      return absl::DataLossError(absl::StrFormat(
          "kept sort run %s holds %d bytes, the manifest says %d records in %d bytes: remove its "
          "directory and build again without --resume",
          r.path, st.st_size, k.records, want));
    }
    runs_.back().bytes = want;
    total_ += k.records;
  }
  runs_spilled_ = runs.size();
  return MergeSpilled();
}

absl::Status ExternalSorter::MergeSpilled() {
  // A compact run's reader holds a decoded block and at least one stored block.
  const uint64_t min_reader_bytes = options_.compact ? kSpillBlockRecords * sizeof(SortRecord) +
                                                           options_.compact->max_block_bytes()
                                                     : kMinMergeBufferBytes;
  const uint64_t fan_in = std::max<uint64_t>(2, options_.merge_bytes / min_reader_bytes);
  while (runs_.size() > fan_in) {
    // Merge consecutive groups, in order, so that ties still resolve to the earlier input.
    const size_t buffer_records = std::max<size_t>(
        64, std::min(options_.merge_bytes / (fan_in + 1), kMaxReaderBytes) / sizeof(SortRecord));
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
  const size_t buffer_records = std::max<size_t>(
      64, std::min(options_.merge_bytes / runs_.size(), kMaxReaderBytes) / sizeof(SortRecord));
  PBGI_ASSIGN_OR_RETURN(merger_, Merger::Create(runs_, buffer_records, &options_.tmp_dir,
                                                options_.compact, options_.packed_output));
  if (options_.threads > 1) {
    pipe_ = std::make_unique<BlockPipe>(
        kPipeBlocks, kBlockRecords, [this](absl::Span<SortRecord> out) { return Produce(out); });
  }
  return absl::OkStatus();
}

uint64_t ExternalSorter::merge_resident_bytes() const {
  return merger_ == nullptr ? 0 : merger_->buffer_bytes();
}

absl::StatusOr<size_t> ExternalSorter::Produce(absl::Span<SortRecord> out) {
  if (merger_ != nullptr) return merger_->Next(out);
  size_t n = static_cast<size_t>(std::min<uint64_t>(out.size(), size_ - emitted_));
  for (size_t i = 0; i < n; ++i) {
    if (emitted_ + i + 16 < size_) __builtin_prefetch(&records_[sorted_[emitted_ + i + 16].index]);
    out[i] = records_[sorted_[emitted_ + i].index];
  }
  if (options_.packed_input && !options_.packed_output) {
    for (size_t i = 0; i < n; ++i) out[i] = options_.compact->Unpack(out[i]);
  } else if (!options_.packed_input && options_.packed_output) {
    for (size_t i = 0; i < n; ++i) options_.compact->Pack(SortRecord(out[i]), &out[i]);
  }
  emitted_ += n;
  return n;
}

absl::StatusOr<size_t> ExternalSorter::Next(absl::Span<SortRecord> out) {
  if (!finished_) return absl::FailedPreconditionError("ExternalSorter::Next before FinishInput");
  if (pipe_ == nullptr) return Produce(out);
  size_t n = 0;
  while (n < out.size()) {
    if (cur_pos_ == cur_.size()) {
      PBGI_ASSIGN_OR_RETURN(cur_, pipe_->Next());
      cur_pos_ = 0;
      if (cur_.empty()) break;
    }
    const size_t k = std::min(out.size() - n, cur_.size() - cur_pos_);
    std::copy(cur_.begin() + cur_pos_, cur_.begin() + cur_pos_ + k, out.begin() + n);
    n += k;
    cur_pos_ += k;
  }
  return n;
}

absl::StatusOr<absl::Span<const SortRecord>> ExternalSorter::NextBlock() {
  if (!finished_) {
    return absl::FailedPreconditionError("ExternalSorter::NextBlock before FinishInput");
  }
  if (pipe_ != nullptr) return pipe_->Next();
  if (block_.empty()) block_.resize(kBlockRecords);
  PBGI_ASSIGN_OR_RETURN(size_t n, Produce(absl::MakeSpan(block_)));
  return absl::Span<const SortRecord>(block_.data(), n);
}

}  // namespace pbgi::internal
