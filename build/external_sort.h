// External sort of SortRecords by Morton key inside a memory budget (DESIGN.md, "Build" step 2):
// runs of `run_capacity` records are radix-sorted in memory and spilled to temporary files; a
// k-way merge streams them back in key order. An input that fits one run is never spilled.
//
// The sort is stable (equal keys keep their input order), so spilled and in-memory builds of the
// same input produce identical databases. Temporary files are unlinked as soon as they are
// created and only held open: nothing is left behind on success, error, Ctrl-C or a crash.
//
// Not thread-safe.
#ifndef PBGI_BUILD_EXTERNAL_SORT_H_
#define PBGI_BUILD_EXTERNAL_SORT_H_

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "build/sort_record.h"
#include "pbgi/status.h"

namespace pbgi::internal {

struct KeyIndex {
  uint64_t key;
  uint64_t index;
};
// Sorts `pairs` by key with a stable LSD radix sort (13-bit digits, passes whose digit is the
// same for every key are skipped). `scratch` has the same size. Returns whichever of the two
// arrays holds the result.
KeyIndex* RadixSortKeyIndex(absl::Span<KeyIndex> pairs, absl::Span<KeyIndex> scratch);

// Memory per record of a run: the record plus two (key, index) arrays.
inline constexpr uint64_t kSortBytesPerRecord = sizeof(SortRecord) + 2 * sizeof(KeyIndex);

class ExternalSorter {
 public:
  struct Options {
    std::string tmp_dir;        // where spilled runs go
    uint64_t run_capacity = 0;  // records per in-memory run (> 0)
    uint64_t merge_bytes = 0;   // read buffers of the merge, all runs together
  };
  explicit ExternalSorter(const Options& options);
  ~ExternalSorter();
  ExternalSorter(const ExternalSorter&) = delete;
  ExternalSorter& operator=(const ExternalSorter&) = delete;

  absl::Status Add(const SortRecord& r) {
    if (size_ == options_.run_capacity) PBGI_RETURN_IF_ERROR(SpillRun());
    records_[size_++] = r;
    return absl::OkStatus();
  }
  // Ends the input: sorts the last run, and with spilled runs merges them down to a count the
  // merge buffers can serve at once.
  absl::Status FinishInput();
  // After FinishInput: fills `out` with the next records in key order; 0 at the end.
  absl::StatusOr<size_t> Next(absl::Span<SortRecord> out);

  uint64_t runs_spilled() const { return runs_spilled_; }
  uint64_t merge_passes() const { return merge_passes_; }
  uint64_t spill_bytes() const { return spill_bytes_; }
  uint64_t records() const { return total_; }

 private:
  struct Run {
    int fd = -1;
    uint64_t count = 0;
  };
  class RunReader;
  class Merger;

  void SortBuffer();
  absl::Status SpillRun();
  absl::StatusOr<Run> NewRunFile();
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
  uint64_t emitted_ = 0;  // in-memory mode: records returned so far
  std::unique_ptr<Merger> merger_;
};

}  // namespace pbgi::internal

#endif  // PBGI_BUILD_EXTERNAL_SORT_H_
