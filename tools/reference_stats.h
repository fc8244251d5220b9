// What `pbgi eval` says about its Embree reference (tools/cmd_eval.cc): the truth's own error,
// measured from two independent halves of its rays, and the reference's time per receiver at a
// given error along its sweep of ray counts (docs/eval.md, "Session 31").
#ifndef PBGI_TOOLS_REFERENCE_STATS_H_
#define PBGI_TOOLS_REFERENCE_STATS_H_

#include <vector>

#include "absl/types/span.h"

namespace pbgi::tools {

// The mean absolute error of the mean of two independent estimates a[i] and b[i] of the same
// values: half their mean absolute difference. Exact in expectation for independent errors of
// one symmetric law (a - b and a + b - 2 truth then have the same law), whatever the rate at
// which the estimates converge: the reference's rays are a randomly rotated Hammersley set,
// whose error falls faster than rays^-1/2, so a Monte Carlo law from fewer rays overstates it
// (by 2.3x to 9x on the convergence runs' receivers).
double HalvesMae(absl::Span<const double> a, absl::Span<const double> b);

// One row of the reference's sweep: its rays per receiver, its MAE against the truth and its
// seconds per receiver.
struct SweepPoint {
  int rays = 0;
  double mae = 0;
  double seconds = 0;
};

// How the reference's time at an error was found (ReferenceSecondsAt).
struct SweepReading {
  bool extrapolated = false;  // outside the sweep's range of errors
  bool below = false;         // below its smallest error (extrapolated too)
  double exponent = 0;        // k of time ~ MAE^-k where extrapolated
  bool from_sweep = false;    // k is the sweep's last segment's, not the Monte Carlo law
};

// The seconds per receiver that the reference needs for a mean error `mae`: log(time)
// interpolated linearly in log(MAE) between the two rows around it. Below the smallest error of
// the sweep, the row of smallest error's time scaled by the rays it would need, as the error
// falls along the sweep's last segment: MAE ~ rays^-p between the two rows of smallest error,
// so time ~ MAE^-k with k = 1 / p, kept between 1 (an error falling as 1 / rays) and 2 (the
// Monte Carlo law, rays^-1/2); with a single row, 2. (The rows' times are not used for the
// slope: at few rays they are mostly the fixed cost of a receiver.) Above the largest error, the
// Monte Carlo law. Rows without positive rays, error and time are ignored; 0 when none is left
// or `mae` is not positive.
double ReferenceSecondsAt(absl::Span<const SweepPoint> sweep, double mae,
                          SweepReading* reading = nullptr);

}  // namespace pbgi::tools

#endif  // PBGI_TOOLS_REFERENCE_STATS_H_
