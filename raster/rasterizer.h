// The rasterizer behind Shade(): prepares the gathered elements in the receiver's frame,
// splats them into the micro-buffer (cones for far elements, ray-sampled disks for near
// surfels) in depth layers, and integrates. One per Shade() call, over a caller's MicroBuffer.
#ifndef PBGI_RASTER_RASTERIZER_H_
#define PBGI_RASTER_RASTERIZER_H_

#include <algorithm>
#include <cstdint>

#include "absl/status/status.h"
#include "glm/geometric.hpp"
#include "glm/vec3.hpp"
#include "pbgi/raster.h"
#include "pbgi/surfel.h"

namespace pbgi::internal {

// Shades one receiver into a MicroBuffer that it borrows. Not thread-safe (neither is the
// buffer); cheap to construct: everything it keeps lives in the MicroBuffer.
class Rasterizer {
 public:
  Rasterizer(MicroBuffer* mb, const RasterOptions& o)
      : mb_(*mb),
        o_(o),
        res_(mb->res_),
        radiance_(o.compute_radiance),
        clamp_(o.clamp),
        px_(mb->pixels_.data()),
        dirs_(mb->dirs_.data()),
        omega_(mb->omega_f_.data()),
        inv_omega_(mb->inv_omega_f_.data()),
        max_width_(mb->max_width_) {}

  absl::Status Run(const Gathered& g, const ShadeReceiver& r, ShadeResult* out);

 private:
  void Reset();
  void SortByDepth();
  void SetFrame(const ShadeReceiver& r);
  glm::vec3 ToLocal(const glm::vec3& v) const {
    return glm::vec3(glm::dot(t_, v), glm::dot(b_, v), glm::dot(n_, v));
  }
  void PrepareCluster(const Cluster& c, ShadeResult* out);
  void PrepareSurfel(const Surfel& s, ShadeResult* out);
  void SplatCone(const PreparedSplat& s);
  void SplatDisk(const PreparedSplat& s);
  void Integrate(const ShadeReceiver& r, ShadeResult* out);

  // Adds a fragment of coverage `cov` to pixel p. With clamp, fragments arrive front to back:
  // one that overlaps the open layer in depth joins it (the splats of one surface tile it, and
  // their round footprints overlap and leave gaps that cancel only if they add up freely); one
  // wholly behind closes the layer first. The first layer counts in full only if nothing lies
  // behind it; otherwise it, like every later one, only fills what is left below 1: nearer
  // surfaces hide farther ones (the depth test), see Close().
  void Emit(uint32_t p, float cov, const PreparedSplat& s) {
    PixelState& px = px_[p];
    px.depth = std::min(px.depth, s.depth);
    if (!clamp_) {
      px.closed += cov;
      if (radiance_) {
        for (int ch = 0; ch < 3; ++ch) px.closed_rgb[ch] += cov * s.radiance[ch];
      }
      return;
    }
    if (px.closed >= 1.0f) return;
    if (px.open > 0.0f && s.depth - s.extent > px.far) {
      Close(px, /*behind=*/true);
      if (px.closed >= 1.0f) return;
    }
    if (px.open == 0.0f) {
      px.far = s.depth + s.extent;
    } else {
      px.far = std::max(px.far, s.depth + s.extent);
    }
    px.open += cov;
    if (radiance_) {
      for (int ch = 0; ch < 3; ++ch) px.open_rgb[ch] += cov * s.radiance[ch];
    }
  }

  // `behind`: a fragment wholly behind the layer closes it. The first layer keeps its free sum
  // only when nothing lies behind it (a lone surface whose splats' overlaps and gaps cancel);
  // with a surface behind, the gaps are filled by that surface, so the overlaps must not count
  // twice: the layer is clamped at 1 like the later ones (bug: hidden_surface_overcount).
  static void Close(PixelState& px, bool behind) {
    if (!(px.open > 0.0f)) return;
    const float e = px.closed == 0.0f && !behind
                        ? px.open
                        : std::min(px.open, std::max(0.0f, 1.0f - px.closed));
    const float scale = e / px.open;
    px.closed += e;
    for (int ch = 0; ch < 3; ++ch) {
      px.closed_rgb[ch] += scale * px.open_rgb[ch];
      px.open_rgb[ch] = 0.0f;
    }
    px.open = 0.0f;
  }

  MicroBuffer& mb_;
  const RasterOptions& o_;
  const int res_;
  const bool radiance_, clamp_;
  PixelState* px_;
  const PixelDir* dirs_;
  const float* omega_;
  const float* inv_omega_;
  const float max_width_;  // the largest pixel's angular width
  glm::vec3 origin_, t_, b_, n_;
};

}  // namespace pbgi::internal

#endif  // PBGI_RASTER_RASTERIZER_H_
