// The flags that choose how `pbgi shade`, `demo` and `eval` shade a batch: the shared mode
// (ShadeMode::kShared, the commands' default) or the per-receiver reference (`--exact`), and the
// sharing's settings (include/pbgi/shade.h, SharingOptions).
#ifndef PBGI_TOOLS_SHARING_FLAGS_H_
#define PBGI_TOOLS_SHARING_FLAGS_H_

#include <cmath>
#include <string>

#include "CLI/CLI.hpp"
#include "absl/strings/str_format.h"
#include "pbgi/shade.h"

namespace pbgi::tools {

// Far-field sharing (ShadeOptions::far_sharing); the group radius is given as a fraction of the
// database's bounds diagonal, so that one value fits every scene's scale.
struct FarSharingFlags {
  FarSharingOptions options;
  float radius_fraction = 0.002f;
};

inline void AddFarSharingFlags(CLI::App* app, FarSharingFlags* f) {
  app->add_flag("--far-sharing", f->options.enabled,
                "Share the far field of groups of neighbouring shaded receivers with similar "
                "normals: one far cut and micro-buffer per group, the near field per receiver "
                "(Factorized PBGI; docs/shade.md, Session 13)");
  app->add_option("--far-factor", f->options.distance_factor,
                  "Far sharing: a node is shared when it lies at least this times the group's "
                  "radius away from the group")
      ->check(CLI::Range(1.0f, 1000.0f))
      ->capture_default_str();
  app->add_option("--far-radius", f->radius_fraction,
                  "Far sharing: the largest group radius, as a fraction of the database's "
                  "bounds diagonal")
      ->check(CLI::Range(1e-6f, 1.0f))
      ->capture_default_str();
  app->add_option("--far-members", f->options.max_members,
                  "Far sharing: the most receivers in a group")
      ->check(CLI::Range(2, 4096))
      ->capture_default_str();
  app->add_option("--far-angle", f->options.max_normal_angle_degrees,
                  "Far sharing: the largest angle (degrees) between a member's normal and the "
                  "group's")
      ->check(CLI::Range(0.0f, 89.0f))
      ->capture_default_str();
}

// options->far_sharing from the flags, with the radius for a database of bounds `bounds`.
inline void ApplyFarSharingFlags(const FarSharingFlags& f, const Bounds& bounds,
                                 ShadeOptions* options) {
  options->far_sharing = f.options;
  const glm::vec3 d = bounds.hi - bounds.lo;
  options->far_sharing.max_radius =
      f.radius_fraction * std::sqrt(d.x * d.x + d.y * d.y + d.z * d.z);
}

struct SharingFlags {
  bool exact = false;
  SharingOptions sharing;
  FarSharingFlags far;
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
  AddFarSharingFlags(app, &f->far);
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
  const std::string far =
      s.far_groups == 0
          ? ""
          : absl::StrFormat("; far field shared by %d groups of %.1f receivers (%d receivers)",
                            s.far_groups, double(s.far_members) / double(s.far_groups),
                            s.far_members);
  if (s.interpolated == 0 && s.shaded == s.receivers) {
    return absl::StrFormat("  sharing        none: %d receivers shaded on their own%s", s.shaded,
                           far);
  }
  return absl::StrFormat(
      "  sharing        %d receivers shaded (%.1f%%), %d interpolated; %.1f CPU us/receiver, "
      "%.2f s of thread time deciding and interpolating%s",
      s.shaded, 100.0 * double(s.shaded) / n, s.interpolated, s.cpu_seconds * 1e6 / n,
      s.sharing_seconds, far);
}

}  // namespace pbgi::tools

#endif  // PBGI_TOOLS_SHARING_FLAGS_H_
