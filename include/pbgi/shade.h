// pbgi::ShadeBatch: the library's main composition. Shades a batch of receivers from a database
// on several threads: each thread gathers the cut for a receiver (pbgi/query.h) and rasterizes it
// (pbgi/raster.h), with one Reader, one MicroBuffer and one Gathered of its own, visiting the
// receivers in Z-order in blocks of consecutive ones so that each thread's pages stay coherent
// (docs/design.md, "Shading").
//
//   auto db = pbgi::Database::Open("scene.pbgi", {.cache_bytes = 512 << 20});
//   std::vector<pbgi::ShadeResult> out(receivers.size());
//   pbgi::ShadeOptions options;                 // cut, raster options, threads, ...
//   absl::Status s = pbgi::ShadeBatch(**db, receivers, options, absl::MakeSpan(out));
//
// Two modes (ShadeOptions::mode):
//  - kExact (the default, the reference): every receiver is gathered and rasterized on its own.
//    Each result depends only on its receiver, the database and the options: not on the thread
//    count, the order or the other receivers of the batch.
//  - kShared: neighbouring receivers share the work. A sparse set is shaded exactly and the
//    others are interpolated from it where that is safe, refining where it is not (see
//    SharingOptions and docs/shade.md). A receiver is interpolated only from shaded receivers of
//    the same surface: never across a depth or normal discontinuity, an object edge (given ids)
//    or a missing neighbour, never over a cell larger than a fraction of the distance to the
//    nearest geometry its micro-buffers saw (the split-sphere rule of irradiance caching), and
//    only where the shaded receivers around it agree within a tolerance. The results depend on
//    the batch (which receivers are neighbours) but not on the thread count or the order; the
//    receivers that are shaded give exactly what kExact gives them.
//
// Thread safety: ShadeBatch may run concurrently on one Database (each call makes its own
// Readers; mind the cache budget rule of pbgi/query.h: readers * reader_cache_bytes <=
// cache_bytes, which the default per-Reader share keeps). The progress callback runs on one of
// the worker threads, never on two at once.
//
// Memory: the batch's receivers and results (the caller's), one order index per receiver, and
// per thread a Reader (its share of the cache budget), a MicroBuffer and a Gathered; kShared
// adds about 30 bytes per pixel of the image (image mode) or 70 per receiver (point sets);
// far sharing (FarSharingOptions) adds 9 bytes per receiver shaded by one call (the groups) and
// per thread a FarCut and a FarBuffer (24 bytes per pixel of the cube).
#ifndef PBGI_SHADE_H_
#define PBGI_SHADE_H_

#include <atomic>
#include <cstdint>
#include <functional>

#include "absl/status/status.h"
#include "absl/types/span.h"
#include "pbgi/query.h"
#include "pbgi/raster.h"

namespace pbgi {

// Where a batch is, for ShadeOptions::progress.
struct ShadeProgress {
  uint64_t done = 0;   // receivers shaded so far
  uint64_t total = 0;  // receivers in the batch
};

enum class ShadeMode : uint8_t {
  kExact,   // every receiver shaded on its own: the reference
  kShared,  // a sparse set shaded, the rest interpolated under error control (SharingOptions)
};

// Where the receivers of a camera view lie in its image: receiver i is pixel pixel_of[i]
// (row-major, y * width + x) of a width x height image; pixels without a receiver (sky) are
// simply absent. Pixels next to each other are the neighbours that share work.
struct ImageLayout {
  int width = 0, height = 0;
  absl::Span<const uint32_t> pixel_of;  // one distinct pixel per receiver
  // Optional (empty, or one per receiver): an id of each receiver's surface (object, material):
  // receivers with different ids are never interpolated from each other (an object edge that
  // position and normal do not show, e.g. two coplanar objects).
  absl::Span<const uint32_t> surface_id;
};

// How kShared shares work. With an image layout, the image is cut into square cells of
// `spacing` pixels whose corners are shaded; a cell is interpolated (bilinearly, from its four
// corners) when every test below passes, else it is split into four with its five midpoints
// shaded, down to single pixels, which are all shaded. Without a layout, the receivers are
// treated as a point set: the same hierarchy over a grid of cells in space (docs/shade.md).
struct SharingOptions {
  ImageLayout image;
  // Pixels between the sparse set's receivers, a power of two in [2, 64]; point sets: the
  // receivers per coarsest cell are about spacing^2.
  int spacing = 8;
  // The shaded corners of an interpolated cell agree within this: max - min of occlusion (and
  // coverage), and of each channel of irradiance and glossy over the mean of that channel in
  // the sparse set (a relative tolerance, so that it has the same meaning in any unit). The
  // default keeps a camera view's error against a ray-traced reference at kExact's
  // (docs/shade.md).
  float tolerance = 0.05f;
  // The split-sphere rule: a cell is interpolated only if its extent in space is at most
  // radius_factor times the smallest harmonic-mean distance that its corners' micro-buffers saw
  // (the distance at which occlusion and irradiance change: Ward's R_i).
  float radius_factor = 0.5f;
  // Every receiver of the cell has a normal within this angle of each corner's (a crease) ...
  float max_normal_angle_degrees = 20.0f;
  // ... and lies within this fraction of the cell's extent off the corners' surface (a depth
  // step, a surface seen through a gap).
  float max_plane_distance = 0.05f;
};

// Far-field sharing (Wang et al., "Factorized Point Based Global Illumination", EGSR 2013;
// docs/shade.md, "Session 13"), in either mode: the receivers that are shaded are cut into
// groups of up to max_members consecutive ones in Z-order, within max_radius of the group's
// first member and with normals within max_normal_angle_degrees of its normal. A group gathers
// and rasterizes its far field once (Reader::GatherFar, ShadeFar) and each member only its near
// field (Reader::GatherNear, ShadeWithFar), in the frame of the group's normal (the first
// member's). A group of one is shaded as kExact shades it. Needs a cut without a lobe (no
// glossy lobe cut) and an infinite Cut::max_distance. The groups depend on the batch's
// receivers (and, in kShared, on which are shaded) but not on the thread count.
struct FarSharingOptions {
  bool enabled = false;
  int max_members = 16;  // 2..4096
  // World units, > 0 when enabled: the largest distance of a member from the group's first.
  float max_radius = 0.0f;
  // A node is shared when it lies at least this times the group's radius from the group's
  // sphere (and passes the cut from all of it): a far element's direction is then off by at
  // most 1 / distance_factor radians for a member. >= 1.
  float distance_factor = 8.0f;
  float max_normal_angle_degrees = 1.0f;  // [0, 90)
};

// How to shade a batch. New ways of shading come as new fields whose defaults keep the
// behaviour of the fields before them.
struct ShadeOptions {
  Cut cut;
  RasterOptions raster;
  int threads = 0;      // 0: all cores (DefaultShadeThreads())
  bool z_order = true;  // visit receivers in Z-order (coherence); false: in the given order
  // Called from one worker thread at most every progress_interval_seconds, and once at the end
  // of a batch that succeeds (done == total).
  std::function<void(const ShadeProgress&)> progress;
  double progress_interval_seconds = 1.0;
  // When set and it becomes true (a renderer's abort, a SIGINT handler), the batch stops at the
  // next block of receivers with a Cancelled error; the results are then incomplete.
  const std::atomic<bool>* cancel = nullptr;
  ShadeMode mode = ShadeMode::kExact;
  SharingOptions sharing;  // kShared only
  // With a glossy lobe (raster.lobe), gather the lobe-aware cut (Cut::lobe): each receiver's
  // cut refines by raster's lobe around its reflection direction, finer in the lobe's core and
  // coarser outside it, instead of `cut`'s plain or cosine-weighted test. false: `cut` as given,
  // the cut that knows nothing of the lobe (for comparison). Ignored without a lobe, when
  // cut.lobe is set (the caller's lobe, for every receiver) and for a receiver whose reflection
  // is zero (its glossy is 0). Occlusion and irradiance come from the same gather, so with it
  // they are those of a cut made for the lobe, not for the cosine. The lobe's min_weight is
  // cut.lobe.min_weight.
  bool lobe_cut = true;
  FarSharingOptions far_sharing;
  // Where the shading computes radiance (raster.compute_radiance) from a radiance database and
  // cut.radiance_contrast is 0: the cut that sees radiance with this factor
  // (Cut::radiance_contrast), its floor kContrastFloorScale times the database's mean radiance
  // (Reader::MeanRadiance). 0 (the default, the behaviour before it) turns it off; the tools
  // use kRecommendedRadianceContrast. Occlusion alone never uses it.
  float radiance_contrast = 0.0f;
};

// ShadeOptions::radiance_contrast as `pbgi shade`, `demo` and `eval` use it, and the floor's
// scale (docs/design.md, "A cut that sees radiance": cornell's irradiance 3.5 % -> 2.0 % of the
// mean for 17 % more clusters).
inline constexpr float kRecommendedRadianceContrast = 16.0f;
inline constexpr float kContrastFloorScale = 3.0f;

// The cut that ShadeBatch starts every receiver's from: options.cut, with the radiance
// contrast of options.radiance_contrast and its floor from the database where they apply.
absl::StatusOr<Cut> EffectiveCut(Database& db, const ShadeOptions& options);

// What a batch cost.
struct ShadeStats {
  uint64_t receivers = 0;
  double seconds = 0;  // wall time
  // CPU time of the process during the batch (all threads; a busy machine's waits excluded).
  double cpu_seconds = 0;
  QueryStats query;            // summed over threads
  CacheStats cache;            // the batch's Readers' counters, summed
  double gather_seconds = 0;   // summed over threads (thread time in Gather)
  double raster_seconds = 0;   // summed over threads (thread time in Shade)
  uint64_t shaded = 0;         // receivers gathered and rasterized (all of them in kExact)
  uint64_t interpolated = 0;   // kShared: receivers interpolated from shaded ones
  double sharing_seconds = 0;  // kShared: thread time deciding cells and interpolating
  // Far-field sharing: groups of two or more that shared a far field, and their members.
  uint64_t far_groups = 0;
  uint64_t far_members = 0;
  // Sums another batch's figures into these.
  void Add(const ShadeStats& o);
};

// Shades every receiver: out[i] belongs to receivers[i] (out.size() must equal
// receivers.size()). Errors: InvalidArgument naming the receiver for a non-finite position or
// a zero or non-finite normal, and for invalid options or layout (before anything is shaded);
// the first error of any thread otherwise (a damaged page, ...), after which the other threads
// stop at their next receiver; Cancelled when options.cancel is raised. On error `out` is
// incomplete. `stats`, when not null, is overwritten with what the batch cost. `shaded`, when
// not empty (size = receivers.size()), is set to 1 for each receiver that was shaded on its own
// and 0 for each that was interpolated (kShared; all 1 in kExact). An interpolated result has
// zero element counts (clusters_drawn, ...).
absl::Status ShadeBatch(Database& db, absl::Span<const ShadeReceiver> receivers,
                        const ShadeOptions& options, absl::Span<ShadeResult> out,
                        ShadeStats* stats = nullptr, absl::Span<uint8_t> shaded = {});

// OK, or InvalidArgument naming the field of SharingOptions (or of its layout) that is wrong for
// a batch of `receivers` receivers.
absl::Status ValidateSharingOptions(const SharingOptions& sharing, size_t receivers);

// OK, or InvalidArgument naming the field of FarSharingOptions that is wrong, or the option of
// ShadeOptions that far sharing cannot work with (a lobe cut, a finite max_distance).
absl::Status ValidateFarSharingOptions(const ShadeOptions& options);

// The default thread count: the number of cores.
int DefaultShadeThreads();

}  // namespace pbgi

#endif  // PBGI_SHADE_H_
