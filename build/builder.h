// The builder's pipeline over any PageSink (store/page_io.h): BuildDatabase runs it over a
// PageWriter, unit tests over the in-memory store (store/mem_page_store.h).
#ifndef PBGI_BUILD_BUILDER_H_
#define PBGI_BUILD_BUILDER_H_

#include <cstdint>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "pbgi/build.h"
#include "pbgi/store.h"
#include "pbgi/surfel.h"
#include "store/page_io.h"

namespace pbgi::internal {

// How the memory budget is split (see BuildOptions::memory_bytes).
struct MemoryPlan {
  uint64_t run_capacity = 0;  // records per sorted run
  uint64_t merge_bytes = 0;   // merge read buffers
  uint64_t upper_bytes = 0;   // coherent layout: upper node groups held by the packer
  uint64_t batch_bytes = 0;   // LMDB write batch (StoreOptions::batch_bytes)
  int threads = 1;            // BuildOptions::threads resolved (1 under a small budget)
  uint64_t sort_bytes = 0;    // run buffers (and later merge buffers), all together
  uint64_t fixed_bytes = 0;   // the process and the small buffers (see PlanFor)
  bool spills = true;         // false: the input is known to fit one run
  bool fits = true;           // the budget holds the fixed part, the batch and the smallest run
};
// BuildOptions::threads, 0 resolved to the machine's.
int ThreadCount(const BuildOptions& options);
MemoryPlan PlanMemory(const BuildOptions& options, int64_t known_count);

// Runs bounds, sort and the octree pass; pages go to `sink`, and `meta` receives everything
// Finish() needs. `tmp_dir` is where sort runs go. `run_dir`: where a resumable build
// (options.resumable) keeps its runs (created or replaced; resumed from); empty: not resumable.
// The caller removes run_dir after the store is finished.
absl::StatusOr<BuildStats> BuildToSink(SurfelSource& source, PageSink& sink,
                                       const BuildOptions& options, const std::string& tmp_dir,
                                       StoreMeta* meta, const std::string& run_dir = "");

}  // namespace pbgi::internal

#endif  // PBGI_BUILD_BUILDER_H_
