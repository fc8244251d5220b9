// The flags that choose how `pbgi shade`, `demo` and `eval` shade a batch: the shared mode
// (ShadeMode::kShared, the commands' default) or the per-receiver reference (`--exact`), and the
// sharing's settings (include/pbgi/shade.h, SharingOptions).
#ifndef PBGI_TOOLS_SHARING_FLAGS_H_
#define PBGI_TOOLS_SHARING_FLAGS_H_

#include <string>

#include "CLI/CLI.hpp"
#include "absl/strings/str_format.h"
#include "pbgi/shade.h"

namespace pbgi::tools {

struct SharingFlags {
  bool exact = false;
  SharingOptions sharing;
};

inline void AddSharingFlags(CLI::App* app, SharingFlags* f) {
  app->add_flag("--exact", f->exact,
                "Shade every receiver on its own (the reference mode) instead of sharing the work "
                "of neighbouring receivers");
  app->add_option("--spacing", f->sharing.spacing,
                  "Sharing: pixels between the sparse set's receivers (a power of two)")
      ->check(CLI::IsMember({2, 4, 8, 16, 32, 64}))
      ->capture_default_str();
  app->add_option("--tolerance", f->sharing.tolerance,
                  "Sharing: largest spread of the shaded neighbours' occlusion (radiance: "
                  "relative to its mean) that is interpolated")
      ->check(CLI::Range(0.0f, 10.0f))
      ->capture_default_str();
  app->add_option("--radius-factor", f->sharing.radius_factor,
                  "Sharing: largest cell extent over the harmonic distance to the geometry")
      ->check(CLI::Range(0.0f, 100.0f))
      ->capture_default_str();
}

// `options` in the flags' mode. The image layout, if any, is the caller's to set.
inline void ApplySharingFlags(const SharingFlags& f, ShadeOptions* options) {
  options->mode = f.exact ? ShadeMode::kExact : ShadeMode::kShared;
  const ImageLayout image = options->sharing.image;
  options->sharing = f.sharing;
  options->sharing.image = image;
}

// One line for a command's summary: how many receivers were shaded and interpolated.
inline std::string SharingSummary(const ShadeStats& s) {
  const double n = double(s.receivers > 0 ? s.receivers : 1);
  if (s.interpolated == 0 && s.shaded == s.receivers) {
    return absl::StrFormat("  sharing        none: %d receivers shaded on their own", s.shaded);
  }
  return absl::StrFormat(
      "  sharing        %d receivers shaded (%.1f%%), %d interpolated; %.1f CPU us/receiver, "
      "%.2f s of thread time deciding and interpolating",
      s.shaded, 100.0 * double(s.shaded) / n, s.interpolated, s.cpu_seconds * 1e6 / n,
      s.sharing_seconds);
}

}  // namespace pbgi::tools

#endif  // PBGI_TOOLS_SHARING_FLAGS_H_
