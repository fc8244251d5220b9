// Shading many receivers from a database: gather (query/) then rasterize (raster/), on several
// threads with one Reader, one MicroBuffer and one Gathered per thread, receivers visited in
// Z-order for cache coherence. This is how a renderer embeds the two layers; the `pbgi shade`,
// `eval` and `demo` commands share it.
#ifndef PBGI_TOOLS_SHADING_H_
#define PBGI_TOOLS_SHADING_H_

#include <cstdint>
#include <functional>
#include <vector>

#include "absl/status/status.h"
#include "absl/types/span.h"
#include "pbgi/query.h"
#include "pbgi/raster.h"
#include "pbgi/surfel.h"

namespace pbgi::tools {

struct ShadeJobOptions {
  Cut cut;
  RasterOptions raster;
  int threads = 0;      // 0: all cores
  bool z_order = true;  // visit receivers in Z-order (coherence); false: in the given order
  // Called now and then from one thread with the number of receivers shaded so far.
  std::function<void(uint64_t done)> progress;
};

struct ShadeJobStats {
  uint64_t receivers = 0;
  double seconds = 0;
  QueryStats query;           // summed over threads
  CacheStats cache;           // the readers' counters, summed
  double gather_seconds = 0;  // summed over threads (CPU time in Gather)
  double raster_seconds = 0;  // summed over threads (CPU time in Shade)
};

// Shades every receiver; results[i] belongs to receivers[i]. `reflections` (optional, same size
// as receivers) are the glossy lobes' centres.
absl::Status ShadeReceivers(Database& db, absl::Span<const Receiver> receivers,
                            absl::Span<const glm::vec3> reflections, const ShadeJobOptions& options,
                            std::vector<ShadeResult>* results, ShadeJobStats* stats);

// Default worker count: the number of cores.
int DefaultThreads();

}  // namespace pbgi::tools

#endif  // PBGI_TOOLS_SHADING_H_
