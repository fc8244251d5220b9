// The manifest of a resumable build's kept sort runs (docs/format.md, "Resume"): what the runs
// were made from (the input's identity and the options that decide the records and their keys),
// what the input pass counted, and each run's size and CRC-32C. Written atomically (a
// temporary file, fsync, rename, fsync of the directory) once every run is on disk; a later
// build with BuildOptions::Resumable::resume merges the runs again instead of reading the input.
#ifndef PBGI_BUILD_RUN_MANIFEST_H_
#define PBGI_BUILD_RUN_MANIFEST_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "build/external_sort.h"
#include "pbgi/build.h"
#include "pbgi/surfel.h"

namespace pbgi::internal {

struct RunManifest {
  // What decides the records: compared field by field on resume.
  std::string input;          // BuildOptions::Resumable::input_identity
  uint32_t record_bytes = 0;  // 48: raw runs; 22 or 34: compact runs (key + point record)
  Bounds key_bounds;
  bool declared_bounds = false;  // the source's KnownBounds (else a bounds pass)
  bool radiance = false;
  bool estimate_radius = false;
  bool estimate_normals = false;
  bool skip_invalid = false;
  // What the input pass found.
  bool back_radiance = false;  // a two-sided surfel whose back differs (kRadianceBothSides)
  uint64_t records = 0;
  uint64_t skipped = 0;
  int64_t known_count = -1;
  uint64_t run_capacity = 0;
  double seconds_bounds = 0;
  double seconds_sort = 0;
  std::vector<KeptRun> runs;
};

// Whether a build spills compact runs (build/spill_codec.h): all but those that estimate radii
// or normals, which read the unquantized positions after the sort.
inline bool CompactSpill(const BuildOptions& o) {
  return !o.estimate.radius && !o.estimate.normals;
}

// The channels of a build's compact runs: a radiance build's carry the back radiance, as the
// input pass does not know yet whether the database will store it (one-sided records leave it
// zero, which zstd takes to almost nothing).
inline Channels SpillChannels(const BuildOptions& o) {
  return HasRadiance(o.channels) ? Channels::kRadianceBothSides : Channels::kOcclusion;
}

// The manifest of the records `options` would make from an input with these bounds.
RunManifest ManifestFor(const BuildOptions& options, const Bounds& key_bounds,
                        bool declared_bounds);

// The directory of a database's kept runs inside `tmp_dir`: one per database path, so that
// builds of different databases sharing a --tmp do not meet.
std::string RunDirectory(const std::string& tmp_dir, const std::string& db_path);

inline constexpr char kManifestName[] = "manifest";

absl::Status WriteManifest(const std::string& dir, const RunManifest& m);
// NotFound when `dir` holds no manifest.
absl::StatusOr<RunManifest> ReadManifest(const std::string& dir);

// FailedPrecondition naming the first field in which `kept` differs from `want` (what this
// build would make), and how to go on.
absl::Status CheckResumable(const RunManifest& kept, const RunManifest& want,
                            const std::string& dir);

}  // namespace pbgi::internal

#endif  // PBGI_BUILD_RUN_MANIFEST_H_
