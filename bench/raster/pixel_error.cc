// pixel_error: where in the micro-buffer PBGI's occlusion error comes from. For receivers
// sampled on a scene's visible surfaces (as `pbgi eval` samples them), each pixel's coverage
// (clamped at 1, cosine-weighted) is compared with Embree rays cast through sub-pixel samples of
// the same pixel against the scene's triangles. Prints the bias split by pixel class (PBGI
// empty / partial / full against truth empty / partial / full) and by elevation, the worst
// receivers, and with --detail the elements that close the worst receiver's pixels (each
// cluster and each leaf's surfels shaded alone) and what rays along its normal hit.
// Usage: pixel_error SCENE|MESH DATABASE [--receivers N] [--msa A] [--res R] [--sub S]
//        [--seed K] [--layout S] [--hitsides front|both] [--curved C] [--detail] [--dump F]
//        pixel_error SCENE|MESH DATABASE --at X,Y,Z --normal X,Y,Z [--msa A] [--res R] [--sub S]
//        [--hitsides front|both] [--pixel-diff D] [--pixel P] [--keep-above H] [--keep-within D]
//        [--detail] [--radiance] [--bands D1,D2,... [--band-rays N]] [--sheet S]
// The second form is one receiver pixel by pixel (a `pbgi eval --dump-receivers` row): the
// pixels whose coverage differs from the rays' by more than D, with what the rays hit there;
// --pixel P lists every element that draws on P in the whole gather, its footprint as the
// gather shaped it (Rasterizer::FootprintsOver: a footprint can depend on its neighbours), then
// each cluster and each leaf that covers P when drawn alone, and the gathered surfels on P's
// central ray; --detail the parts that occlude most alone (with their cells);
// --keep-above/--keep-within shade only the surfels that high above the receiver's plane and
// that near (no clusters); --radiance compares each pixel's radiance (the mean of the channels,
// PBGI's coverage-weighted pixel against the lighting function at the rays' front hits) instead
// of its coverage, --pixel-diff then in units of 1e-3 of the pixel's cosine-weighted share;
// --bands: occlusion and irradiance from what lies within each distance, rays against PBGI
// (RunBands). --radiance shades with the tools' radiance contrast.
// --curved C: the cut's curved_scale (the tools' 0.3). --dump F writes one CSV row per receiver
// (position, normal, truth, error): two runs on the same receivers (another --msa, --res or
// database of another density) compare receiver by receiver.
// DATABASE: one built from the same scene (`pbgi eval ... -o DIR` leaves DIR/NAME.pbgi). Meshes
// are read z-up as the file has them, or with --up y rotated as `pbgi eval --up y` does.
// docs/eval.md ("Session 8") has what it showed.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_split.h"
#include "base/math.h"
#include "pbgi/query.h"
#include "pbgi/raster.h"
#include "pbgi/scene.h"
#include "pbgi/shade.h"
#include "pbgi/status.h"
#include "raster/cube.h"
#include "raster/rasterizer.h"
#include "tools/scene_views.h"

namespace pbgi {
namespace {

struct Args {
  std::string scene, db;
  int receivers = 300, res = 12, sub = 8;
  float msa = 0.03f;
  uint64_t layout = 1;  // --layout S: the scene's seed (pbgi eval --seed S)
  // --seed K: the receivers' seed; unset, pbgi eval's receivers for --seed S, S + 7919.
  std::optional<uint64_t> seed;
  HitSides sides = HitSides::kFront;
  bool detail = false;
  bool one = false;   // --at/--normal: one receiver, pixel by pixel
  uint8_t sheet = 0;  // --sheet S: that receiver's sheet tag (pbgi eval --dump-receivers' column)
  glm::vec3 at{0.0f}, normal{0.0f, 0.0f, 1.0f};
  float pixel_diff = 0.05f;
  int pixel = -1;             // --pixel: the gathered surfels whose disks its central ray crosses
  float keep_above = -1e30f;  // --keep-above H: shade only the surfels at least H above
  float keep_within = 1e30f;  // --keep-within D: and within D of the receiver
  bool up_y = false;          // --up y: the mesh is y-up (pbgi eval --up y rotates it)
  bool radiance = false;      // --radiance: compare the pixels' radiance (irradiance mode)
  std::vector<float> bands;   // --bands D1,D2,...: what lies within each distance (one receiver)
  int band_rays = 16384;      // --band-rays N: the reference's rays per band
  float curved = 0.3f;        // --curved C: Cut::curved_scale
  std::string dump;           // --dump F: per-receiver CSV
};

struct Worst {
  float error;  // pixel sum minus truth
  glm::vec3 p, n;
  float truth;
  uint8_t sheet = 0;  // the receiver's sheet tag (ShadeReceiver::sheet)
};

int Fail(const absl::Status& s) {
  std::fprintf(stderr, "pixel_error: %s\n", s.ToString().c_str());
  return 1;
}

// The gathered leaf l alone: its cell and its surfels.
Gathered LeafAlone(const Gathered& g, size_t l) {
  Gathered one;
  one.leaf_cells.push_back(g.leaf_cells[l]);
  for (size_t i = 0; i < g.surfels.size(); ++i) {
    if (g.surfel_leaf[i] != l) continue;
    one.surfels.push_back(g.surfels[i]);
    one.surfel_ids.push_back(g.surfel_ids[i]);
    one.surfel_leaf.push_back(0);
  }
  return one;
}

void Detail(const Worst& w, Reader& reader, const Tracer& tracer, const Cut& cut,
            const RasterOptions& ro, MicroBuffer& mb) {
  std::printf("worst receiver at %.6f,%.6f,%.6f normal %.4f,%.4f,%.4f: truth %.4f\n", w.p.x, w.p.y,
              w.p.z, w.n.x, w.n.y, w.n.z, w.truth);
  for (float sign : {-1.0f, 1.0f}) {
    glm::vec3 o = w.p;
    for (int k = 0; k < 3; ++k) {
      const Hit h = tracer.Intersect(o, sign * w.n, 1e30f);
      if (!h.hit) break;
      std::printf("  ray along %+g normal: surface at %.6f, %s side, normals' cosine %+.3f\n", sign,
                  glm::dot(h.position - w.p, sign * w.n), h.front ? "front" : "back",
                  glm::dot(h.normal, w.n));
      o = h.position + 1e-5f * sign * w.n;
    }
  }
  Gathered g;
  if (!reader.Gather({w.p, w.n}, cut, &g).ok()) return;
  const ShadeReceiver r{w.p, w.n, w.n, w.sheet};
  struct Part {
    float occlusion;
    bool leaf;
    size_t index;
  };
  std::vector<Part> parts;
  for (size_t i = 0; i < g.clusters.size(); ++i) {
    Gathered one;
    one.clusters.push_back(g.clusters[i]);
    ShadeResult out;
    if (Shade(one, r, ro, &mb, &out).ok()) parts.push_back({out.occlusion, false, i});
  }
  for (size_t l = 0; l < g.leaf_cells.size(); ++l) {
    const Gathered one = LeafAlone(g, l);
    ShadeResult out;
    if (Shade(one, r, ro, &mb, &out).ok()) parts.push_back({out.occlusion, true, l});
  }
  std::sort(parts.begin(), parts.end(),
            [](const Part& a, const Part& b) { return a.occlusion > b.occlusion; });
  std::printf("  %zu clusters, %zu surfels in %zu leaves; the largest parts alone:\n",
              g.clusters.size(), g.surfels.size(), g.leaf_cells.size());
  for (size_t k = 0; k < std::min<size_t>(8, parts.size()); ++k) {
    const Part& part = parts[k];
    if (!part.leaf) {
      const Cluster& c = g.clusters[part.index];
      const glm::vec3 centre = 0.5f * (c.bounds.lo + c.bounds.hi);
      std::printf(
          "  cluster: occlusion %.4f, depth %u, %llu points, centre at %.4f, bounds "
          "%.3f,%.3f,%.3f-%.3f,%.3f,%.3f, area %.5f\n",
          part.occlusion, c.depth, static_cast<unsigned long long>(c.point_count),
          glm::length(centre - w.p), c.bounds.lo.x, c.bounds.lo.y, c.bounds.lo.z, c.bounds.hi.x,
          c.bounds.hi.y, c.bounds.hi.z, c.area);
      continue;
    }
    const Bounds& lc = g.leaf_cells[part.index];
    std::printf("  leaf %zu: occlusion %.4f, cell %.3f,%.3f,%.3f-%.3f,%.3f,%.3f\n", part.index,
                part.occlusion, lc.lo.x, lc.lo.y, lc.lo.z, lc.hi.x, lc.hi.y, lc.hi.z);
    int shown = 0;
    for (size_t i = 0; i < g.surfels.size() && shown < 6; ++i) {
      if (g.surfel_leaf[i] != part.index) continue;
      const Surfel& s = g.surfels[i];
      ++shown;
      std::printf(
          "    surfel at %.5f, above the receiver's plane %+.5f, receiver above its "
          "plane %+.5f, normals' cosine %+.3f, radius %.4f%s; at %.4f,%.4f,%.4f n %.3f,%.3f,%.3f\n",
          glm::length(s.position - w.p), glm::dot(s.position - w.p, w.n),
          glm::dot(w.p - s.position, s.normal), glm::dot(s.normal, w.n), s.radius,
          s.two_sided ? ", two-sided" : "", s.position.x, s.position.y, s.position.z, s.normal.x,
          s.normal.y, s.normal.z);
    }
  }
}

// The unit direction `u` (receiver frame) of sub-sample (i, j) of `sub` x `sub` in pixel (col,
// row) of cube face `face` (pixels `step` wide on the face's plane at distance 1), and its
// weight: cosine times solid angle per plane area. False below the horizon.
bool SubPixelRay(const internal::FaceAxes& face, int col, int row, int i, int j, int sub,
                 double step, glm::dvec3* u, double* wt) {
  glm::dvec3 v(0.0);
  v[face.k] = face.sign;
  v[face.k1] = -1.0 + (col + (i + 0.5) / sub) * step;
  v[face.k2] = -1.0 + (row + (j + 0.5) / sub) * step;
  const double len = glm::length(v);
  *u = v / len;
  if (u->z <= 0.0) return false;
  *wt = u->z / (len * len * len);
  return true;
}

// The tools' default cut and raster options (`pbgi shade`), at the sweep's msa, resolution and
// hitsides.
Cut ToolCut(const Args& a) {
  Cut cut;
  cut.max_solid_angle = a.msa;
  cut.cosine_weighted = true;
  cut.curved_scale = a.curved;
  cut.curved_box_scale = 1.0f;
  return cut;
}
RasterOptions ToolRaster(const Args& a) {
  RasterOptions ro;
  ro.resolution = a.res;
  ro.footprint = Footprint::kPolygons;
  ro.compute_radiance = a.radiance;
  ro.hitsides = a.sides;
  return ro;
}

// The tools' radiance contrast (`--radiance-contrast` 16, its floor from the database's mean
// radiance, as ShadeBatch sets it) where radiance is compared.
absl::Status ApplyToolContrast(const Args& a, Reader& reader, Cut* cut) {
  if (!a.radiance) return absl::OkStatus();
  PBGI_ASSIGN_OR_RETURN(const float mean, reader.MeanRadiance());
  cut->radiance_contrast = 16.0f;
  cut->contrast_floor = kContrastFloorScale * mean;
  return absl::OkStatus();
}

// One receiver, band by band (--bands): its occlusion and irradiance from what lies within each
// distance D, rays (Tracer::ReferenceOcclusion / ReferenceIrradiance with max_distance D)
// against PBGI (Cut::max_distance and RasterOptions::max_distance D: elements whose centre lies
// within D), and what each band between two distances adds. Coverage right in a band but
// irradiance not says its clusters' radiance is off, not their coverage (docs/eval.md, Session
// 22, the tall walls).
int RunBands(const Args& a, Reader& reader, const Tracer& tracer) {
  const glm::vec3 n = glm::normalize(a.normal);
  const glm::vec3 p = a.at;
  MicroBuffer mb;
  if (absl::Status s = mb.Prepare(a.res); !s.ok()) return Fail(s);
  std::printf("receiver %.6f,%.6f,%.6f normal %.4f,%.4f,%.4f, %d rays, msa %g, res %d\n", p.x, p.y,
              p.z, n.x, n.y, n.z, a.band_rays, a.msa, a.res);
  std::printf("%10s %10s %10s %10s %10s | %-12s %10s %10s %10s %10s\n", "within", "occ rays",
              "occ pbgi", "irr rays", "irr pbgi", "band", "occ rays", "occ pbgi", "irr rays",
              "irr pbgi");
  double prev[4] = {0, 0, 0, 0};
  float prev_d = 0.0f;
  std::vector<float> bands = a.bands;
  bands.push_back(std::numeric_limits<float>::infinity());
  Cut cut = ToolCut(a);
  if (absl::Status s = ApplyToolContrast(a, reader, &cut); !s.ok()) return Fail(s);
  RasterOptions ro = ToolRaster(a);
  ro.compute_radiance = true;
  for (float d : bands) {
    cut.max_distance = d;
    ro.max_distance = d;
    Gathered g;
    if (absl::Status s = reader.Gather({p, n}, cut, &g); !s.ok()) return Fail(s);
    ShadeResult r;
    if (absl::Status s = Shade(g, ShadeReceiver{p, n, n, a.sheet}, ro, &mb, &r); !s.ok())
      return Fail(s);
    const glm::vec3 e = tracer.ReferenceIrradiance(p, n, a.band_rays, 5, d);
    const double now[4] = {tracer.ReferenceOcclusion(p, n, a.band_rays, d, 5), r.occlusion,
                           (e.x + e.y + e.z) / 3.0,
                           (r.irradiance.x + r.irradiance.y + r.irradiance.z) / 3.0};
    std::printf("%10g %10.4f %10.4f %10.4f %10.4f | %5g-%-6g %10.4f %10.4f %10.4f %10.4f\n", d,
                now[0], now[1], now[2], now[3], prev_d, d, now[0] - prev[0], now[1] - prev[1],
                now[2] - prev[2], now[3] - prev[3]);
    std::copy(now, now + 4, prev);
    prev_d = d;
  }
  return 0;
}

// One receiver, pixel by pixel: every pixel whose coverage differs from the rays' by more than
// `a.pixel_diff`, with its direction in the receiver's frame, what PBGI drew there (coverage,
// nearest depth) and what its central rays hit first (distance, side, normals' cosine,
// triangle).
int RunOne(const Args& a, Reader& reader, const Tracer& tracer) {
  const glm::vec3 n = glm::normalize(a.normal);
  const glm::vec3 p = a.at;
  Cut cut = ToolCut(a);
  if (absl::Status s = ApplyToolContrast(a, reader, &cut); !s.ok()) return Fail(s);
  const RasterOptions ro = ToolRaster(a);
  MicroBuffer mb;
  if (absl::Status s = mb.Prepare(a.res); !s.ok()) return Fail(s);
  Gathered g;
  if (absl::Status st = reader.Gather({p, n}, cut, &g); !st.ok()) return Fail(st);
  if (a.keep_above > -1e29f || a.keep_within < 1e29f) {
    Gathered k;
    k.position_tolerance = g.position_tolerance;
    k.leaf_cells = g.leaf_cells;
    for (size_t i = 0; i < g.surfels.size(); ++i) {
      const glm::vec3 rel = g.surfels[i].position - p;
      if (glm::dot(rel, n) < a.keep_above || glm::length(rel) > a.keep_within) continue;
      k.surfels.push_back(g.surfels[i]);
      k.surfel_ids.push_back(g.surfel_ids[i]);
      k.surfel_leaf.push_back(g.surfel_leaf[i]);
    }
    g = std::move(k);
  }
  ShadeResult r;
  if (absl::Status st = Shade(g, {p, n, n, a.sheet}, ro, &mb, &r); !st.ok()) return Fail(st);
  glm::vec3 t, b;
  internal::OrthonormalBasis(n, &t, &b);
  const double step = 2.0 / a.res;
  double got = 0, want = 0, weight = 0;
  std::printf(
      "receiver %.6f,%.6f,%.6f normal %.4f,%.4f,%.4f: shade %.5f (%zu clusters, %zu "
      "surfels)\n",
      p.x, p.y, p.z, n.x, n.y, n.z, r.occlusion, g.clusters.size(), g.surfels.size());
  std::printf(
      "   px  elev   azim    w*1e3  pbgi  rays  diff*w  depth  | rays' first hit: dist "
      "back cos tri\n");
  for (int f = 0; f < 6; ++f) {
    const internal::FaceAxes face = internal::Face(f);
    for (int row = 0; row < a.res; ++row) {
      for (int col = 0; col < a.res; ++col) {
        const int q = (f * a.res + row) * a.res + col;
        const double w = mb.PixelCosineWeight(q);
        if (!(w > 0.0)) continue;
        double hit = 0, all = 0, dist = 0, back = 0, cosn = 0, lsum = 0;
        int hits = 0;
        uint32_t tri = 0;
        for (int i = 0; i < a.sub; ++i) {
          for (int j = 0; j < a.sub; ++j) {
            glm::dvec3 u;
            double wt;
            if (!SubPixelRay(face, col, row, i, j, a.sub, step, &u, &wt)) continue;
            all += wt;
            const glm::vec3 d = float(u.x) * t + float(u.y) * b + float(u.z) * n;
            const Hit h = tracer.Intersect(p, d, 1e30f);
            if (!h.hit) continue;
            hit += wt;
            ++hits;
            if (a.radiance && h.front) {
              const glm::vec3 l = tracer.SurfaceRadiance(h.position, h.normal, h.material,
                                                         uint64_t(q) * 4099 + i * 64 + j);
              lsum += wt * (l.x + l.y + l.z) / 3.0;
            }
            dist += h.distance;
            back += h.front ? 0.0 : 1.0;
            cosn += glm::dot(h.normal, n);
            tri = h.triangle;
          }
        }
        if (a.radiance) {
          // Radiance (mean of the channels): PBGI's coverage-weighted pixel against the rays'
          // lighting function at their front hits.
          const glm::vec3 pl = mb.PixelRadiance(q);
          const double c = (pl.x + pl.y + pl.z) / 3.0;
          const double truth = all > 0.0 ? lsum / all : 0.0;
          got += w * c, want += w * truth, weight += w;
          if (std::fabs(c - truth) * w * 1e3 <= a.pixel_diff) continue;
          const glm::vec3 dir = glm::normalize(mb.PixelDirection(q));
          std::printf("%5d %5.1f %6.1f %8.3f %5.3f %5.3f %+8.5f %7.4f cov %.3f | ", q,
                      std::asin(std::min(1.0f, dir.z)) * 180.0 / sh::kPi,
                      std::atan2(dir.y, dir.x) * 180.0 / sh::kPi, w * 1e3, c, truth,
                      w * (c - truth), mb.PixelDepth(q), mb.PixelCoverage(q));
          if (hits > 0) {
            std::printf("%.4f %.2f %+.3f %u\n", dist / hits, back / hits, cosn / hits, tri);
          } else {
            std::printf("-\n");
          }
          continue;
        }
        const double truth = all > 0.0 ? hit / all : 0.0;
        const double c = std::min(1.0f, mb.PixelCoverage(q));
        got += w * c, want += w * truth, weight += w;
        if (std::fabs(c - truth) <= a.pixel_diff) continue;
        const glm::vec3 dir = glm::normalize(mb.PixelDirection(q));
        std::printf("%5d %5.1f %6.1f %8.3f %5.3f %5.3f %+8.5f %7.4f | ", q,
                    std::asin(std::min(1.0f, dir.z)) * 180.0 / sh::kPi,
                    std::atan2(dir.y, dir.x) * 180.0 / sh::kPi, w * 1e3, c, truth, w * (c - truth),
                    mb.PixelDepth(q));
        if (hits > 0) {
          std::printf("%.4f %.2f %+.3f %u\n", dist / hits, back / hits, cosn / hits, tri);
        } else {
          std::printf("-\n");
        }
      }
    }
  }
  std::printf("pixels: PBGI %.5f, rays %.5f (diff %+.5f)\n", got / weight, want / weight,
              (got - want) / weight);
  if (a.detail)
    Detail({float(got - want), p, n, float(want / weight), a.sheet}, reader, tracer, cut, ro, mb);
  if (a.pixel >= 0 && a.pixel < mb.pixel_count()) {
    const glm::vec3 l = glm::normalize(mb.PixelDirection(a.pixel));
    const glm::vec3 d = l.x * t + l.y * b + l.z * n;
    std::printf("pixel %d: direction %.4f,%.4f,%.4f (world)\n", a.pixel, d.x, d.y, d.z);
    // The elements that draw on the pixel as the whole gather shaped their footprints (a
    // footprint can depend on its neighbours: SheetCell, the junction clips), nearest first.
    MicroBuffer trace_mb;
    ShadeResult trace_r;
    std::vector<internal::Rasterizer::FootprintOver> over;
    if (trace_mb.Prepare(a.res).ok() &&
        Shade(g, {p, n, n, a.sheet}, ro, &trace_mb, &trace_r).ok()) {
      internal::Rasterizer::FootprintsOver(trace_mb, a.pixel, &over);
    }
    std::printf("  %zu elements draw on it in the whole gather (PBGI %.3f)%s\n", over.size(),
                trace_mb.PixelCoverage(a.pixel), over.size() > 32 ? ", the nearest 32:" : ":");
    for (size_t i = 0; i < over.size() && i < 32; ++i) {
      const internal::Rasterizer::FootprintOver& f = over[i];
      using Kind = internal::Rasterizer::FootprintOver::Kind;
      const glm::vec3 fn = f.normal.x * t + f.normal.y * b + f.normal.z * n;
      std::printf("    depth %.5f %s", f.depth,
                  f.kind == Kind::kDisk   ? "disk"
                  : f.kind == Kind::kCone ? "cone"
                                          : "polygon");
      if (f.kind == Kind::kPolygon)
        std::printf(" covering %.3f at alpha %.3f", f.coverage, f.alpha);
      std::printf("%s%s, normal %.3f,%.3f,%.3f",
                  (f.flags & internal::kSplatPorous) ? " porous" : "",
                  (f.flags & internal::kSplatBack) ? " back" : "", fn.x, fn.y, fn.z);
      if (f.cluster >= 0) {
        std::printf(", cluster %d\n", f.cluster);
      } else {
        std::printf(", surfels\n");
      }
    }
    // Each cluster and each leaf alone: its coverage of the pixel.
    MicroBuffer one_mb;
    if (one_mb.Prepare(a.res).ok()) {
      for (size_t i = 0; i < g.clusters.size(); ++i) {
        Gathered one;
        one.clusters.push_back(g.clusters[i]);
        ShadeResult out;
        if (!Shade(one, {p, n, n, a.sheet}, ro, &one_mb, &out).ok()) continue;
        const float c = one_mb.PixelCoverage(a.pixel);
        if (!(c > 0.02f)) continue;
        const Cluster& cl = g.clusters[i];
        std::printf(
            "  cluster %zu covers %.3f: depth %u, %llu points, area %.4f, bounds "
            "%.3f,%.3f,%.3f-%.3f,%.3f,%.3f, cell %.3f,%.3f,%.3f-%.3f,%.3f,%.3f\n",
            i, c, cl.depth, static_cast<unsigned long long>(cl.point_count), cl.area,
            cl.bounds.lo.x, cl.bounds.lo.y, cl.bounds.lo.z, cl.bounds.hi.x, cl.bounds.hi.y,
            cl.bounds.hi.z, cl.cell.lo.x, cl.cell.lo.y, cl.cell.lo.z, cl.cell.hi.x, cl.cell.hi.y,
            cl.cell.hi.z);
      }
      for (size_t l = 0; l < g.leaf_cells.size(); ++l) {
        const Gathered one = LeafAlone(g, l);
        ShadeResult out;
        if (!Shade(one, {p, n, n, a.sheet}, ro, &one_mb, &out).ok()) continue;
        const float c = one_mb.PixelCoverage(a.pixel);
        if (!(c > 0.02f)) continue;
        const Bounds& lc = g.leaf_cells[l];
        std::printf("  leaf %zu covers %.3f: %zu surfels, cell %.3f,%.3f,%.3f-%.3f,%.3f,%.3f\n", l,
                    c, one.surfels.size(), lc.lo.x, lc.lo.y, lc.lo.z, lc.hi.x, lc.hi.y, lc.hi.z);
        for (const Surfel& s : one.surfels) {
          std::printf("    at %.4f,%.4f,%.4f n %.3f,%.3f,%.3f r %.4f%s\n", s.position.x,
                      s.position.y, s.position.z, s.normal.x, s.normal.y, s.normal.z, s.radius,
                      s.two_sided ? " 2s" : "");
        }
      }
    }
    for (size_t i = 0; i < g.surfels.size(); ++i) {
      const Surfel& s = g.surfels[i];
      const float dn = glm::dot(d, s.normal);
      if (std::fabs(dn) < 1e-6f) continue;
      const float tt = glm::dot(s.position - p, s.normal) / dn;
      if (!(tt > 0.0f)) continue;
      const glm::vec3 x = p + tt * d - s.position;
      const float off = glm::length(x);
      if (off > 2.0f * s.radius) continue;
      const Bounds& cell = g.leaf_cells[g.surfel_leaf[i]];
      std::printf(
          "  t %.4f off/r %.2f surfel %llu at %.5f,%.5f,%.5f n %.3f,%.3f,%.3f r %.5f%s "
          "leaf %u cell %.4f,%.4f,%.4f-%.4f,%.4f,%.4f\n",
          tt, off / s.radius, static_cast<unsigned long long>(g.surfel_ids[i]), s.position.x,
          s.position.y, s.position.z, s.normal.x, s.normal.y, s.normal.z, s.radius,
          s.two_sided ? " 2s" : "", g.surfel_leaf[i], cell.lo.x, cell.lo.y, cell.lo.z, cell.hi.x,
          cell.hi.y, cell.hi.z);
    }
  }
  return 0;
}

int Run(const Args& a) {
  auto db = Database::Open(a.db);
  if (!db.ok()) return Fail(db.status());
  // The scene as pbgi eval has it: a mesh oriented (its open parts thin, two-sided) and lit as
  // the database recorded it (a white sky unless it says otherwise), `--up y` turned z-up.
  ImportReport report;
  auto scene = tools::LoadLitScene(
      a.scene, /*seed=*/a.layout, /*size=*/0, a.up_y ? tools::UpAxis::kY : tools::UpAxis::kZ,
      /*orient=*/true, tools::LightFlags{}, "pixel_error", &report, &(*db)->meta().stats);
  if (!scene.ok()) return Fail(scene.status());
  std::shared_ptr<const Scene> shared = *std::move(scene);
  auto tracer = Tracer::Create(*shared);
  if (!tracer.ok()) return Fail(tracer.status());
  auto reader = (*db)->NewReader();
  if (!reader.ok()) return Fail(reader.status());
  if (a.one && !a.bands.empty()) return RunBands(a, **reader, **tracer);
  if (a.one) return RunOne(a, **reader, **tracer);
  SamplerOptions rs;
  rs.count = a.receivers;
  rs.seed = a.seed.value_or(a.layout + 7919);
  rs.bake = false;
  rs.placement = SamplerOptions::Placement::kUniform;  // receivers as pbgi eval draws them
  auto src = MakeSceneSurfelSource(shared, rs);
  if (!src.ok()) return Fail(src.status());
  std::vector<Surfel> buf(1024), samples;
  for (;;) {
    auto got = (*src)->Next(absl::MakeSpan(buf));
    if (!got.ok()) return Fail(got.status());
    if (*got == 0) break;
    samples.insert(samples.end(), buf.begin(), buf.begin() + *got);
  }
  const Cut cut = ToolCut(a);
  const RasterOptions ro = ToolRaster(a);
  MicroBuffer mb;
  if (absl::Status s = mb.Prepare(a.res); !s.ok()) return Fail(s);
  double cls[3][3] = {}, cls_w[3][3] = {}, elev[6] = {}, elev_w[6] = {}, all_w = 0;
  double sum_pbgi = 0, sum_truth = 0, sum_abs = 0;
  std::vector<Worst> worst;
  const double step = 2.0 / a.res;
  for (const Surfel& s : samples) {
    const glm::vec3 n = glm::normalize(s.normal);
    const glm::vec3 p = s.position + (*tracer)->epsilon() * n;
    Gathered g;
    if (absl::Status st = (*reader)->Gather({p, n}, cut, &g); !st.ok()) return Fail(st);
    ShadeResult r;
    if (absl::Status st = Shade(g, {p, n, n, s.sheet}, ro, &mb, &r); !st.ok()) return Fail(st);
    glm::vec3 t, b;
    internal::OrthonormalBasis(n, &t, &b);
    double got = 0, want = 0, weight = 0;
    for (int f = 0; f < 6; ++f) {
      const internal::FaceAxes face = internal::Face(f);
      for (int row = 0; row < a.res; ++row) {
        for (int col = 0; col < a.res; ++col) {
          const int q = (f * a.res + row) * a.res + col;
          const double w = mb.PixelCosineWeight(q);
          if (!(w > 0.0)) continue;
          double hit = 0, all = 0;
          for (int i = 0; i < a.sub; ++i) {
            for (int j = 0; j < a.sub; ++j) {
              glm::dvec3 u;
              double wt;
              if (!SubPixelRay(face, col, row, i, j, a.sub, step, &u, &wt)) continue;
              all += wt;
              const glm::vec3 d = float(u.x) * t + float(u.y) * b + float(u.z) * n;
              if ((*tracer)->Occluded(p, d, 1e30f)) hit += wt;
            }
          }
          const double truth = all > 0.0 ? hit / all : 0.0;
          const double c = std::min(1.0f, mb.PixelCoverage(q));
          const int ci = c <= 0.001 ? 0 : c >= 0.999 ? 2 : 1;
          const int ti = truth <= 0.001 ? 0 : truth >= 0.999 ? 2 : 1;
          cls[ci][ti] += w * (c - truth);
          cls_w[ci][ti] += w;
          const double z = std::min(1.0, double(glm::normalize(mb.PixelDirection(q)).z));
          const int e = std::min(5, int(std::asin(z) / (sh::kPi / 2.0) * 6.0));
          elev[e] += w * (c - truth);
          elev_w[e] += w;
          all_w += w;
          got += w * c, want += w * truth, weight += w;
        }
      }
    }
    got /= weight, want /= weight;
    sum_pbgi += got, sum_truth += want, sum_abs += std::fabs(got - want);
    worst.push_back({float(got - want), p, n, float(want), s.sheet});
  }
  if (!a.dump.empty()) {
    std::FILE* f = std::fopen(a.dump.c_str(), "w");
    if (f == nullptr) {
      std::fprintf(stderr, "pixel_error: cannot write %s\n", a.dump.c_str());
      return 1;
    }
    std::fprintf(f, "x,y,z,nx,ny,nz,truth,error\n");
    for (const Worst& w : worst) {
      std::fprintf(f, "%.6f,%.6f,%.6f,%.5f,%.5f,%.5f,%.6f,%+.6f\n", w.p.x, w.p.y, w.p.z, w.n.x,
                   w.n.y, w.n.z, w.truth, w.error);
    }
    if (std::fclose(f) != 0) {
      std::fprintf(stderr, "pixel_error: cannot write %s\n", a.dump.c_str());
      return 1;
    }
  }
  const double count = static_cast<double>(samples.size());
  std::printf(
      "%zu receivers, msa %g, res %d, %d x %d rays per pixel: PBGI %.5f, truth %.5f, "
      "bias %+.5f, MAE %.5f\n",
      samples.size(), a.msa, a.res, a.sub, a.sub, sum_pbgi / count, sum_truth / count,
      (sum_pbgi - sum_truth) / count, sum_abs / count);
  const char* name[3] = {"empty", "partial", "full"};
  std::printf("bias by pixel class (share of the cosine weight, contribution to the bias):\n");
  for (int ci = 0; ci < 3; ++ci) {
    for (int ti = 0; ti < 3; ++ti) {
      std::printf("  PBGI %-7s truth %-7s  %6.3f  %+.5f\n", name[ci], name[ti],
                  cls_w[ci][ti] / all_w, cls[ci][ti] / all_w);
    }
  }
  std::printf("bias by elevation:\n");
  for (int e = 0; e < 6; ++e) {
    std::printf("  %2d-%2d degrees  %6.3f  %+.5f\n", 15 * e, 15 * e + 15, elev_w[e] / all_w,
                elev[e] / all_w);
  }
  std::sort(worst.begin(), worst.end(),
            [](const Worst& x, const Worst& y) { return std::fabs(x.error) > std::fabs(y.error); });
  std::printf("worst receivers:\n");
  for (size_t i = 0; i < std::min<size_t>(8, worst.size()); ++i) {
    const Worst& w = worst[i];
    std::printf("  %+.4f (truth %.4f) at %.5f,%.5f,%.5f normal %.4f,%.4f,%.4f\n", w.error, w.truth,
                w.p.x, w.p.y, w.p.z, w.n.x, w.n.y, w.n.z);
  }
  if (a.detail && !worst.empty()) Detail(worst[0], **reader, **tracer, cut, ro, mb);
  return 0;
}

}  // namespace
}  // namespace pbgi

int main(int argc, char** argv) {
  pbgi::Args a;
  int positional = 0;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    auto value = [&]() -> const char* {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "pixel_error: %s needs a value\n", arg.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (arg == "--receivers")
      a.receivers = std::atoi(value());
    else if (arg == "--msa")
      a.msa = std::strtof(value(), nullptr);
    else if (arg == "--res")
      a.res = std::atoi(value());
    else if (arg == "--sub")
      a.sub = std::atoi(value());
    else if (arg == "--seed")
      a.seed = std::strtoull(value(), nullptr, 10);
    else if (arg == "--layout")
      a.layout = std::strtoull(value(), nullptr, 10);
    else if (arg == "--hitsides")
      a.sides = std::strcmp(value(), "both") == 0 ? pbgi::HitSides::kBoth : pbgi::HitSides::kFront;
    else if (arg == "--radiance")
      a.radiance = true;
    else if (arg == "--detail")
      a.detail = true;
    else if (arg == "--at" || arg == "--normal") {
      glm::vec3& v = arg == "--at" ? a.at : a.normal;
      if (std::sscanf(value(), "%f,%f,%f", &v.x, &v.y, &v.z) != 3) {
        std::fprintf(stderr, "pixel_error: %s needs X,Y,Z\n", arg.c_str());
        return 2;
      }
      a.one = true;
    } else if (arg == "--up")
      a.up_y = std::strcmp(value(), "y") == 0;
    else if (arg == "--keep-above")
      a.keep_above = std::strtof(value(), nullptr);
    else if (arg == "--keep-within")
      a.keep_within = std::strtof(value(), nullptr);
    else if (arg == "--pixel")
      a.pixel = std::atoi(value());
    else if (arg == "--sheet")
      a.sheet = static_cast<uint8_t>(std::clamp(std::atoi(value()), 0, 255));
    else if (arg == "--pixel-diff")
      a.pixel_diff = std::strtof(value(), nullptr);
    else if (arg == "--bands") {
      for (absl::string_view part : absl::StrSplit(value(), ',')) {
        float d = 0.0f;
        if (!absl::SimpleAtof(part, &d) || !(d > 0.0f)) {
          std::fprintf(stderr, "pixel_error: --bands wants positive distances D1,D2,...\n");
          return 2;
        }
        a.bands.push_back(d);
      }
      std::sort(a.bands.begin(), a.bands.end());
    } else if (arg == "--band-rays")
      a.band_rays = std::atoi(value());
    else if (arg == "--curved")
      a.curved = std::strtof(value(), nullptr);
    else if (arg == "--dump")
      a.dump = value();
    else if (positional == 0)
      a.scene = arg, ++positional;
    else if (positional == 1)
      a.db = arg, ++positional;
    else {
      std::fprintf(stderr, "pixel_error: unexpected argument %s\n", arg.c_str());
      return 2;
    }
  }
  if (positional != 2 || a.receivers < 1 || a.res < 4 || a.res > 64 || a.sub < 1 ||
      !(a.msa > 0.0f) || !(a.curved > 0.0f && a.curved <= 1.0f)) {
    std::fprintf(stderr,
                 "usage: pixel_error SCENE|MESH DATABASE [--receivers N] [--msa A] [--res R] "
                 "[--sub S] [--seed K] [--layout S] [--hitsides front|both] [--curved C in (0, "
                 "1]] [--detail] [--dump F]\n");
    return 2;
  }
  return pbgi::Run(a);
}
