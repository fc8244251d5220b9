// The query-level test harness: what a renderer developer needs to unit-test gathers
// (docs/query.md has an example).
//
// - TempDatabase builds a small database from a vector of surfels in a temporary directory and
//   removes it when destroyed.
// - SurfelsInFront is the brute-force oracle: which surfels a gather must represent.
// - CheckValidCut checks one gather result against brute force: every surfel in front of the
//   receiver and within max_distance is represented exactly once (by itself, or by one cluster
//   whose point range covers it), nothing is represented twice, no surfel wholly behind the
//   tangent plane or beyond max_distance is emitted, and every cluster obeys the cut (the
//   receiver is outside its near field, its solid angle, with Cut::cosine_weighted times its
//   cosine weight, with Cut::lobe times its lobe weight, is below max_solid_angle, and, not
//   flat, its box too with Cut::curved_box_scale; it is not wholly behind or beyond, its bounds
//   hold its surfels).
// - CheckFinerCutNotSmaller checks that a finer cut refines a coarser one and never gathers
//   fewer elements than the coarse elements that stand for something in front.
//
// The checks return absl::OkStatus() or an error that names the receiver and the first
// violation, so they work with any test framework:
//   EXPECT_TRUE(s.ok()) << s;   // GoogleTest
//
// Thread safety: the functions are; a TempDatabase is like the Database it holds.
#ifndef PBGI_TESTING_H_
#define PBGI_TESTING_H_

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "pbgi/build.h"
#include "pbgi/query.h"
#include "pbgi/surfel.h"

namespace pbgi::testing {

// Global point indices of the surfels that are not SurfelWhollyBehind() the receiver and not
// SurfelBeyond() cut.max_distance. `surfels` must be in database order (see ReadAllSurfels).
std::vector<uint64_t> SurfelsInFront(absl::Span<const Surfel> surfels, const Receiver& receiver,
                                     const Cut& cut);

// Checks `result` of Gather(receiver, cut) against all surfels of the database, in database
// order.
absl::Status CheckValidCut(const Gathered& result, absl::Span<const Surfel> surfels,
                           const Receiver& receiver, const Cut& cut);

// Checks that `fine` (gathered with fine_cut.max_solid_angle <= coarse_cut's, same receiver and
// max_distance) refines `coarse`: every fine element lies inside one coarse element, and there
// are at least as many fine elements as coarse elements that represent a surfel in front.
absl::Status CheckFinerCutNotSmaller(const Gathered& coarse, const Gathered& fine,
                                     absl::Span<const Surfel> surfels, const Receiver& receiver,
                                     const Cut& coarse_cut, const Cut& fine_cut);

// All surfels of a database in database order (index = global point index).
absl::StatusOr<std::vector<Surfel>> ReadAllSurfels(Database& db);

// Random test scenes: `count` surfels on four randomly placed and oriented square patches and
// a sphere, all inside the unit cube, radii about the sample spacing, random radiance.
// Deterministic for a seed.
std::vector<Surfel> RandomSceneSurfels(size_t count, uint64_t seed);
// Random receivers: positions in [-0.2, 1.2]^3, random unit normals.
std::vector<Receiver> RandomReceivers(size_t count, uint64_t seed);

// A database built from a vector of surfels in a fresh temporary directory (under
// $PBGI_TEST_TMPDIR, else $TMPDIR, else /tmp), removed with everything in it on destruction.
class TempDatabase {
 public:
  static absl::StatusOr<std::unique_ptr<TempDatabase>> Create(absl::Span<const Surfel> surfels,
                                                              const BuildOptions& build = {},
                                                              const DatabaseOptions& open = {});
  ~TempDatabase();
  TempDatabase(const TempDatabase&) = delete;
  TempDatabase& operator=(const TempDatabase&) = delete;

  const std::string& path() const { return db_path_; }
  Database& db() { return *db_; }
  const BuildStats& build_stats() const { return stats_; }
  // The surfels in database order (index = global point index), as read back from the store.
  const std::vector<Surfel>& surfels() const { return surfels_; }

 private:
  TempDatabase() = default;
  std::string dir_;
  std::string db_path_;
  std::unique_ptr<Database> db_;
  BuildStats stats_;
  std::vector<Surfel> surfels_;
};

}  // namespace pbgi::testing

#endif  // PBGI_TESTING_H_
