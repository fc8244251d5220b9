// External sort of SortRecords by Morton key inside a memory budget (docs/design.md, "Build",
// step 2): runs of `run_capacity` records are radix-sorted in memory and spilled to temporary
// files; a k-way merge streams them back in key order. An input that fits one run is never spilled.
//
// The sort is stable (equal keys keep their input order), so spilled and in-memory builds of the
// same input produce identical databases. Temporary files are unlinked as soon as they are
// created and only held open: nothing is left behind on success, error, Ctrl-C or a crash.
// Except with Options::run_dir (a resumable build, docs/format.md "Resume"): the runs the input
// pass spills are then named files there, checksummed as they are written (not fsynced: an
// interrupted or killed process leaves them in the page cache; after a power loss a lost run
// fails its checksum instead of costing every build a wait for the disk), which
// the caller may keep (KeepRuns) and a later sorter may merge again (ResumeFrom); the merge
// checks each kept run's CRC-32C as it reads it.
//
// Threads (Options::threads > 1): a full run buffer is handed to a background thread that
// radix-sorts and spills it while the caller fills a second buffer (double buffering inside the
// same budget: see kSortBytesPerRecordThreaded), and after FinishInput a background thread merges
// (or, without spill, gathers) the sorted records into a few fixed blocks that NextBlock() hands
// out. The output is the same for any thread count: runs are consecutive input ranges and the
// merge breaks ties by run order. An error in a background thread is returned by the next call
// of the caller's thread (Add, FinishInput, NextBlock) with the file or record it concerns.
//
// Not thread-safe: one caller thread (the background threads are internal).
#ifndef PBGI_BUILD_EXTERNAL_SORT_H_
#define PBGI_BUILD_EXTERNAL_SORT_H_

#include <algorithm>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "build/sort_record.h"
#include "build/spill_codec.h"
#include "pbgi/status.h"

namespace pbgi::internal {

// Sorts `pairs` by key, stably: MSD radix passes on 8-bit digits of the bits that differ between
// the keys, the highest first, each bucket split again until it is small enough for an insertion
// sort. `scratch` has the same size. Returns whichever of the two arrays holds the result.
KeyIndex* RadixSortKeyIndex(absl::Span<KeyIndex> pairs, absl::Span<KeyIndex> scratch);

// Memory per record of a run: the record plus two (key, index) arrays.
inline constexpr uint64_t kSortBytesPerRecord = sizeof(SortRecord) + 2 * sizeof(KeyIndex);
// With a background sort thread: two record buffers (one filling, one sorting) and the pairs.
inline constexpr uint64_t kSortBytesPerRecordThreaded =
    2 * sizeof(SortRecord) + 2 * sizeof(KeyIndex);

// A single-producer single-consumer pipe of fixed record blocks between a producer thread and
// the caller: the producer fills free blocks, the consumer reads full ones in order. Memory:
// blocks x block_records records, allocated once.
class BlockPipe {
 public:
  // `produce` fills a block and returns how many records it wrote (0: the end) or an error.
  using Producer = std::function<absl::StatusOr<size_t>(absl::Span<SortRecord>)>;
  BlockPipe(size_t blocks, size_t block_records, Producer produce);
  // Stops the producer (if still running) and joins it.
  ~BlockPipe();
  BlockPipe(const BlockPipe&) = delete;
  BlockPipe& operator=(const BlockPipe&) = delete;

  // The next block in order (valid until the next call); empty at the end; the producer's error.
  absl::StatusOr<absl::Span<const SortRecord>> Next();

 private:
  void Run();

  size_t block_records_;
  Producer produce_;
  std::unique_ptr<SortRecord[]> storage_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::vector<SortRecord*> free_;                     // guarded by mu_
  std::vector<std::pair<SortRecord*, size_t>> full_;  // FIFO, guarded by mu_
  size_t full_head_ = 0;                              // guarded by mu_
  bool done_ = false;                                 // producer finished; guarded by mu_
  bool stop_ = false;                                 // consumer gone; guarded by mu_
  absl::Status status_;                               // producer's error; guarded by mu_
  SortRecord* held_ = nullptr;                        // block the consumer holds
  std::thread thread_;
};

// A sorted run kept as a named file (Options::run_dir).
struct KeptRun {
  std::string name;  // file name inside run_dir
  uint64_t records = 0;
  uint32_t crc = 0;    // CRC-32C of its bytes
  uint64_t bytes = 0;  // its size on disk (raw runs: records x 48)
};

class ExternalSorter {
 public:
  struct Options {
    std::string tmp_dir;        // where spilled runs go
    uint64_t run_capacity = 0;  // records per in-memory run (> 0)
    uint64_t merge_bytes = 0;   // read buffers of the merge, all runs together (at most
                                // 8 MiB a run: merge_resident_bytes())
    int threads = 1;            // > 1: background sort/spill and merge threads (see above)
    // Set: every spilled run, the input's and the merge passes', is written compact
    // (build/spill_codec.h: point records + key, zstd blocks) instead of as raw 48-byte records.
    std::optional<SpillCodec> compact = std::nullopt;
    // With `compact`: the records given to Add and Reserve are packed (SpillCodec::Pack), and
    // the sorter hands them back unpacked. Moves the encoding off the sort thread.
    bool packed_input = false;
    // With `compact`: Next and NextBlock hand out packed records, spilled or not. A compact run
    // holds the stored point records, so the merge copies them instead of decoding them, and
    // the octree pass copies them into its pages instead of encoding them again
    // (docs/format.md, "Session 13").
    bool packed_output = false;
  };
  // REQUIRES: options.compact when options.packed_input or options.packed_output.
  explicit ExternalSorter(const Options& options);
  ~ExternalSorter();
  ExternalSorter(const ExternalSorter&) = delete;
  ExternalSorter& operator=(const ExternalSorter&) = delete;

  using RunsWritten = std::function<absl::Status(const std::vector<KeptRun>&)>;
  // Before any Add (or ResumeFrom): the input pass's runs become named files in `dir` (an
  // existing directory), removed by the destructor unless kept. Intermediate merge outputs stay
  // unlinked. `runs_written` is called by FinishInput once every input run is on disk, before
  // any merge; when it succeeds the runs are kept (KeepRuns).
  void SetRunDirectory(std::string dir, RunsWritten runs_written) {
    run_dir_ = std::move(dir);
    runs_written_ = std::move(runs_written);
  }

  absl::Status Add(const SortRecord& r) {
    if (size_ == options_.run_capacity) PBGI_RETURN_IF_ERROR(SpillRun());
    records_[size_++] = r;
    return absl::OkStatus();
  }
  // Free slots for up to `want` records (at least one; spills first when the buffer is full),
  // to be filled in place and then committed with Commit(k), k <= the span's size: saves a
  // copy per record. No Add between Reserve and Commit.
  absl::StatusOr<absl::Span<SortRecord>> Reserve(size_t want) {
    if (size_ == options_.run_capacity) PBGI_RETURN_IF_ERROR(SpillRun());
    const uint64_t room = options_.run_capacity - size_;
    return absl::Span<SortRecord>(
        &records_[size_], static_cast<size_t>(std::min<uint64_t>(room, std::max<size_t>(want, 1))));
  }
  void Commit(size_t n) { size_ += n; }
  uint64_t run_capacity() const { return options_.run_capacity; }
  // Ends the input: sorts the last run, and with spilled runs merges them down to a count the
  // merge buffers can serve at once.
  absl::Status FinishInput();
  // Instead of any Add and FinishInput: merges the runs a previous sorter kept in
  // Options::run_dir (opened read-only; a size that is not the manifest's (raw runs: records x
  // 48 bytes) is refused at once,
  // a checksum mismatch when the merge reaches the run's end). REQUIRES: SetRunDirectory.
  absl::Status ResumeFrom(const std::vector<KeptRun>& runs);
  // The named runs survive the sorter (the caller removes run_dir when it no longer needs them).
  void KeepRuns() { keep_runs_ = true; }

  // After FinishInput: fills `out` with the next records in key order; 0 at the end. Use either
  // Next or NextBlock to drain a sorter, not both.
  absl::StatusOr<size_t> Next(absl::Span<SortRecord> out);
  // After FinishInput: the next block of records in key order, valid until the next call of
  // NextBlock or Next; empty at the end. With threads, produced ahead by a background thread.
  absl::StatusOr<absl::Span<const SortRecord>> NextBlock();

  // The merge's read buffers (decoded blocks included), all readers together: at most
  // Options::merge_bytes, and at most 8 MiB a run.
  uint64_t merge_resident_bytes() const;

  // After FinishInput (or ResumeFrom): every record that Next and NextBlock give went through a
  // compact run, so it is Decode(Encode(r)) on Options::compact's grid (build/spill_codec.h).
  // Packed input is quantized too, spilled or not.
  bool output_quantized() const {
    return options_.compact.has_value() && (merger_ != nullptr || options_.packed_input);
  }
  // Next and NextBlock hand out packed records (Options::packed_output).
  bool output_packed() const { return options_.compact.has_value() && options_.packed_output; }

  uint64_t runs_spilled() const { return runs_spilled_; }
  // Input runs whose spill the caller shared (HelpSpill): each made two runs.
  uint64_t spills_shared() const { return spills_shared_; }
  uint64_t merge_passes() const { return merge_passes_; }
  uint64_t spill_bytes() const { return spill_bytes_; }
  uint64_t records() const { return total_; }

 private:
  struct Run {
    int fd = -1;
    uint64_t count = 0;
    uint64_t bytes = 0;    // its size on disk
    std::string path;      // a named run (run_dir), else empty
    uint32_t crc = 0;      // of its bytes, when `checked`
    bool checked = false;  // compare the CRC as the run is read back
  };
  class RunReader;
  class RunWriter;
  class Merger;

  // Sorts recs[0, n) into sorted_ (pairs_ / scratch_).
  void SortBuffer(const SortRecord* recs, uint64_t n);
  absl::Status SpillRun();
  // Sorts and writes recs[0, n) as a new run (caller's thread or the sort thread). `share`
  // (the sort thread, compact runs): the caller may take the second half of the blocks left
  // (HelpSpill), which it writes as a run of its own right after this one.
  absl::Status SpillBuffer(const SortRecord* recs, uint64_t n, bool share = false);
  // The caller, its run buffer full while the sort thread spills: encodes and writes the last
  // half of the spill's blocks not yet taken, if there are enough, instead of waiting idle
  // (docs/format.md, "Session 17").
  void HelpSpill();
  // Sort thread: waits until it is idle and returns its error, if any.
  absl::Status WaitSpiller();
  void SpillerLoop();
  void StopSpiller();
  absl::StatusOr<size_t> Produce(absl::Span<SortRecord> out);
  absl::StatusOr<Run> NewRunFile(bool named);
  // The merge passes and the final merger over runs_ (after the input, or ResumeFrom).
  absl::Status MergeSpilled();
  absl::Status MergeRuns(std::vector<Run> in, size_t buffer_records, Run* out);
  void FreeBuffers();

  Options options_;
  std::unique_ptr<SortRecord[]> records_;
  std::unique_ptr<KeyIndex[]> pairs_, scratch_;
  KeyIndex* sorted_ = nullptr;  // pairs_ or scratch_, after SortBuffer()
  uint64_t size_ = 0;
  uint64_t total_ = 0;
  std::vector<Run> runs_;
  uint64_t runs_spilled_ = 0;
  uint64_t merge_passes_ = 0;
  uint64_t spill_bytes_ = 0;
  bool finished_ = false;
  bool keep_runs_ = false;
  std::string run_dir_;
  RunsWritten runs_written_;
  std::vector<std::string> named_;  // paths of the named runs, to remove unless kept
  uint64_t emitted_ = 0;            // in-memory mode: records returned so far
  std::unique_ptr<Merger> merger_;
  // NextBlock without threads: a block of the in-memory gather.
  std::vector<SortRecord> block_;
  // Threads: the buffer being sorted and spilled in the background, and its thread.
  std::unique_ptr<SortRecord[]> spare_;
  std::thread spiller_;
  std::mutex spill_mu_;
  std::condition_variable spill_cv_;
  uint64_t spill_job_ = 0;     // records in spare_ to spill; guarded by spill_mu_
  bool spill_busy_ = false;    // guarded by spill_mu_
  bool spill_quit_ = false;    // guarded by spill_mu_
  absl::Status spill_status_;  // guarded by spill_mu_
  // The sort thread's spill that the caller may share, blocks of kSpillBlockRecords in sorted
  // order: the sort thread takes them from the front up to `split`, the caller [split, blocks).
  struct SharedSpill {
    const SortRecord* recs = nullptr;
    const KeyIndex* order = nullptr;
    uint64_t n = 0;
    uint64_t blocks = 0;
    uint64_t front = 0;  // blocks the sort thread has taken
    uint64_t split = 0;
    bool open = false;     // the caller may claim
    bool claimed = false;  // the caller took [split, blocks)
    bool back_done = false;
    Run back;  // the caller's run
    absl::Status back_status;
  };
  SharedSpill shared_;  // guarded by spill_mu_
  uint64_t spills_shared_ = 0;
  std::unique_ptr<BlockPipe> pipe_;
  absl::Span<const SortRecord> cur_;  // Next() over the pipe: the block being copied out
  size_t cur_pos_ = 0;
};

}  // namespace pbgi::internal

#endif  // PBGI_BUILD_EXTERNAL_SORT_H_
