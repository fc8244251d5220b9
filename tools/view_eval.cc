// `pbgi eval --view` (see view_eval.h).
#include "tools/view_eval.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>

#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "oneapi/tbb/global_control.h"
#include "pbgi/build.h"
#include "pbgi/query.h"
#include "pbgi/scene.h"
#include "pbgi/shade.h"
#include "pbgi/status.h"
#include "pbgi/store.h"
#include "tools/args.h"
#include "tools/footprint_flags.h"
#include "tools/outputs.h"
#include "tools/progress.h"
#include "tools/reference_stats.h"
#include "tools/scene_views.h"

namespace pbgi::tools {

ImageErrors CompareImages(int width, int height, const std::vector<double>& got,
                          const std::vector<double>& reference, const std::vector<uint8_t>& covered,
                          int tile) {
  ImageErrors e;
  std::vector<double> abs_err;
  abs_err.reserve(got.size());
  for (size_t p = 0; p < got.size(); ++p) {
    if (!covered[p]) continue;
    const double d = got[p] - reference[p];
    abs_err.push_back(std::abs(d));
    e.mae += std::abs(d);
    e.rmse += d * d;
    e.bias += d;
    e.max = std::max(e.max, std::abs(d));
    e.reference_mean += reference[p];
  }
  e.pixels = abs_err.size();
  if (e.pixels == 0) return e;
  const double n = double(e.pixels);
  e.mae /= n;
  e.rmse = std::sqrt(e.rmse / n);
  e.bias /= n;
  e.reference_mean /= n;
  const size_t k = std::min(abs_err.size() - 1, static_cast<size_t>(0.99 * n));
  std::nth_element(abs_err.begin(), abs_err.begin() + long(k), abs_err.end());
  e.p99 = abs_err[k];
  for (int ty = 0; ty < height; ty += tile) {
    for (int tx = 0; tx < width; tx += tile) {
      double sum = 0;
      int count = 0, area = 0;
      for (int y = ty; y < std::min(height, ty + tile); ++y) {
        for (int x = tx; x < std::min(width, tx + tile); ++x) {
          const size_t p = size_t(y) * size_t(width) + size_t(x);
          ++area;
          if (!covered[p]) continue;
          sum += std::abs(got[p] - reference[p]);
          ++count;
        }
      }
      if (count == 0 || 4 * count < area) continue;
      const double m = sum / count;
      if (m > e.worst_tile) e.worst_tile = m, e.worst_tile_x = tx, e.worst_tile_y = ty;
    }
  }
  return e;
}

Image ErrorHeatMap(int width, int height, const std::vector<double>& got,
                   const std::vector<double>& reference, const std::vector<uint8_t>& covered,
                   double scale) {
  Image img(width, height);
  for (size_t p = 0; p < got.size(); ++p) {
    if (!covered[p]) {
      img.pixels[p] = glm::vec3(0.35f);
      continue;
    }
    const float t = static_cast<float>(std::clamp((got[p] - reference[p]) / scale, -1.0, 1.0));
    // White at 0; towards red (too high) or blue (too low).
    img.pixels[p] =
        t >= 0 ? glm::vec3(1.0f, 1.0f - t, 1.0f - t) : glm::vec3(1.0f + t, 1.0f + t, 1.0f);
  }
  return img;
}

namespace {

using Clock = std::chrono::steady_clock;
double Since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

double Scalar(const glm::vec3& v) { return (double(v.x) + v.y + v.z) / 3.0; }

// A grey image of scalars mapped by `f` (covered pixels; the rest `background`).
Image GreyImage(int width, int height, const std::vector<double>& v,
                const std::vector<uint8_t>& covered, double scale, float background) {
  Image img(width, height);
  for (size_t p = 0; p < v.size(); ++p) {
    img.pixels[p] =
        covered[p] ? glm::vec3(static_cast<float>(v[p] * scale)) : glm::vec3(background);
  }
  return img;
}

void PrintErrors(const char* label, const ImageErrors& e, bool relative) {
  std::printf(
      "%-26s MAE %.5f  RMSE %.5f  bias %+.5f  p99 %.5f  max %.4f  worst 8x8 tile %.5f at "
      "(%d,%d)",
      label, e.mae, e.rmse, e.bias, e.p99, e.max, e.worst_tile, e.worst_tile_x, e.worst_tile_y);
  if (relative && e.reference_mean > 0) {
    std::printf("  (MAE %.2f%% of the mean %.4g)", 100.0 * e.mae / e.reference_mean,
                e.reference_mean);
  }
  std::printf("\n");
}

std::string ErrorsJson(const ImageErrors& e) {
  return absl::StrFormat(
      "{\"pixels\": %d, \"mae\": %.6g, \"rmse\": %.6g, \"bias\": %.6g, \"p99\": %.6g, "
      "\"max\": %.6g, \"worst_tile\": %.6g, \"worst_tile_x\": %d, \"worst_tile_y\": %d, "
      "\"reference_mean\": %.6g}",
      e.pixels, e.mae, e.rmse, e.bias, e.p99, e.max, e.worst_tile, e.worst_tile_x, e.worst_tile_y,
      e.reference_mean);
}

}  // namespace

absl::Status RunViewEval(const ViewEvalArgs& a) {
  const bool occlusion = a.mode == "occlusion";
  const bool glossy = a.mode == "glossy";
  const uint64_t memory = a.memory_bytes, cache = a.cache_bytes;
  PBGI_RETURN_IF_ERROR(CheckOutsideStores(a.out_dir));
  std::error_code ec;
  std::filesystem::create_directories(a.out_dir, ec);
  if (ec) return absl::UnavailableError(absl::StrFormat("cannot create %s", a.out_dir));
  const int threads = ResolveThreads(a.threads);
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);

  PBGI_ASSIGN_OR_RETURN(const UpAxis up, ParseUpAxis(a.up));
  PBGI_ASSIGN_OR_RETURN(const bool orient, ParseOrient(a.orient));
  ImportReport import;
  // --db: a database that is already built (a 128 M-surfel city takes minutes to build and
  // fits the disk once), checked below to be of this scene; its recorded lights light a mesh
  // file (which brings none). Closed again before the view opens it with its cache.
  std::unique_ptr<Database> built;
  if (!a.db.empty()) {
    PBGI_ASSIGN_OR_RETURN(built, Database::Open(a.db, {}));
  }
  PBGI_ASSIGN_OR_RETURN(
      std::shared_ptr<const Scene> scene,
      LoadLitScene(a.scene, a.seed, a.size, up, orient, a.lights, "pbgi eval --view", &import,
                   built != nullptr ? &built->meta().stats : nullptr));
  if (import.oriented) {
    std::printf("%s: orientation: %s\n", a.scene.c_str(),
                DescribeOrientation(import.orientation).c_str());
  }
  if (!occlusion && !scene->has_radiance) {
    return absl::FailedPreconditionError(
        absl::StrFormat("scene %s has no radiance: use --mode occlusion", scene->name));
  }
  auto t = Clock::now();
  // Without --db, a database is built from the scene.
  std::string db_path = a.out_dir + "/" + scene->name + ".pbgi";
  uint64_t points = 0;
  if (built != nullptr) {
    db_path = a.db;
    std::string warning;
    PBGI_RETURN_IF_ERROR(CheckSceneMatchesDatabase(
        *scene, SpecFingerprint(*scene, a.scene, a.seed, a.size, up, orient), built->meta(),
        db_path, &warning));
    if (!warning.empty()) std::fprintf(stderr, "eval --view: warning: %s\n", warning.c_str());
    if (!occlusion && !HasRadiance(built->meta().channels)) {
      return absl::FailedPreconditionError(absl::StrFormat(
          "--db %s stores occlusion only: --mode %s needs radiance", db_path, a.mode));
    }
    points = built->meta().point_count;
    built.reset();
    std::fprintf(stderr, "eval --view: %s, %llu surfels from %s (not rebuilt)\n",
                 scene->name.c_str(), static_cast<unsigned long long>(points), db_path.c_str());
  } else {
    SamplerOptions sampler;
    sampler.count = a.points;
    sampler.seed = a.seed;
    sampler.bake = !occlusion;
    PBGI_ASSIGN_OR_RETURN(auto surfels, MakeSceneSurfelSource(scene, sampler));
    BuildOptions bo;
    bo.memory_bytes = memory;
    bo.channels = occlusion ? Channels::kOcclusion : Channels::kRadiance;
    bo.tmp_dir = a.out_dir;
    bo.provenance = SceneFingerprint(*scene, a.seed, a.size, up, orient);
    // The lights that bake it, so that a later --db view lights the scene the same way.
    if (!occlusion) {
      for (const auto& [k, v] : LightsProvenance(scene->lights)) bo.provenance[k] = v;
    }
    bo.provenance["source"] = "pbgi eval --view";
    bo.provenance["tool"] = kToolVersion;
    bo.provenance["built_at"] = NowIso8601();
    Progress build_progress("eval --view: build", "points", a.points);
    std::string pass;
    bo.progress = [&](const BuildProgress& p) {
      if (pass != p.pass) {
        pass = p.pass;
        build_progress.Phase(absl::StrFormat("eval --view: build: %s", p.pass), p.points_total);
      }
      build_progress.Update(p.points_done, p.points_total);
    };
    PBGI_ASSIGN_OR_RETURN(const BuildStats bs, BuildDatabase(*surfels, db_path, bo));
    build_progress.Finish(bs.points);
    points = bs.points;
    std::fprintf(stderr, "eval --view: %s, built %llu surfels in %.1f s\n", scene->name.c_str(),
                 static_cast<unsigned long long>(points), Since(t));
  }

  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<Tracer> tracer, Tracer::Create(*scene));
  const Camera camera = DefaultCamera(*scene, a.width, a.height);
  CameraReceivers cr = MakeCameraReceivers(*tracer, camera);
  const size_t pixels = size_t(a.width) * size_t(a.height);
  std::string window_tag;
  if (!a.window.empty()) {
    const std::vector<std::string> f = absl::StrSplit(a.window, ',');
    int w[4] = {0, 0, 0, 0};
    bool ok = f.size() == 4;
    for (size_t i = 0; ok && i < 4; ++i) ok = absl::SimpleAtoi(f[i], &w[i]) && w[i] >= 0;
    if (!ok || w[2] == 0 || w[3] == 0 || w[0] + w[2] > a.width || w[1] + w[3] > a.height) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "--window '%s': expected X,Y,WIDTH,HEIGHT of a non-empty window inside the %dx%d "
          "image",
          a.window, a.width, a.height));
    }
    size_t kept = 0;
    for (size_t i = 0; i < cr.pixel_of.size(); ++i) {
      const int x = int(cr.pixel_of[i] % uint32_t(a.width)),
                y = int(cr.pixel_of[i] / uint32_t(a.width));
      if (x < w[0] || x >= w[0] + w[2] || y < w[1] || y >= w[1] + w[3]) continue;
      cr.receivers[kept] = cr.receivers[i];
      cr.shade[kept] = cr.shade[i];
      cr.pixel_of[kept] = cr.pixel_of[i];
      if (i < cr.surface.size()) cr.surface[kept] = cr.surface[i];
      ++kept;
    }
    cr.receivers.resize(kept);
    cr.shade.resize(kept);
    cr.pixel_of.resize(kept);
    if (cr.surface.size() > kept) cr.surface.resize(kept);
    window_tag = absl::StrFormat("_win%d-%d-%d-%d", w[0], w[1], w[2], w[3]);
  }
  std::vector<uint8_t> covered(pixels, 0);
  for (uint32_t p : cr.pixel_of) covered[p] = 1;
  std::fprintf(stderr, "eval --view: %dx%d view, %zu receivers\n", a.width, a.height,
               cr.receivers.size());

  // The reference: two independent halves of the rays; their mean is the reference and half
  // their mean absolute difference estimates its own MAE (for Gaussian noise, E|a - b| / 2 is
  // E|mean - truth|).
  t = Clock::now();
  const int half_rays = std::max(16, a.rays / 2);
  std::vector<double> ref(pixels, 0.0), ref_a(pixels, 0.0), ref_b(pixels, 0.0);
  // The reference depends only on the scene, the view and the rays: it is kept in the output
  // directory and reused by the next run with the same ones (a reference of a 960x540 view with
  // 4096 rays per pixel takes minutes).
  // (a glossy reference also on its lobe)
  const std::string mode_tag = !glossy ? a.mode
                               : a.lobe.lobe == GlossyLobe::kPhong
                                   ? absl::StrFormat("glossy-phong%g", a.lobe.phong_exponent)
                                   : absl::StrFormat("glossy-ggx%g", a.lobe.ggx_roughness);
  // The receivers' hash names it too: a reference of other shading points (a tracer that
  // places them differently, a changed scene) is not reused.
  uint64_t receivers_hash = 1469598103934665603ull;  // FNV-1a over positions and normals
  for (const Receiver& r : cr.receivers) {
    const float v[6] = {r.position.x, r.position.y, r.position.z,
                        r.normal.x,   r.normal.y,   r.normal.z};
    unsigned char bytes[sizeof(v)];
    std::memcpy(bytes, v, sizeof(v));
    for (unsigned char c : bytes) receivers_hash = (receivers_hash ^ c) * 1099511628211ull;
  }
  // And the lights, which --sun and --sky change (they light what the rays hit).
  if (!occlusion) {
    const Lights& l = scene->lights;
    const float v[11] = {l.has_sun ? 1.0f : 0.0f,
                         l.sun.direction.x,
                         l.sun.direction.y,
                         l.sun.direction.z,
                         l.sun.radiance.x,
                         l.sun.radiance.y,
                         l.sun.radiance.z,
                         l.sky.x,
                         l.sky.y,
                         l.sky.z,
                         static_cast<float>(l.sky_rays)};
    unsigned char bytes[sizeof(v)];
    std::memcpy(bytes, v, sizeof(v));
    for (unsigned char c : bytes) receivers_hash = (receivers_hash ^ c) * 1099511628211ull;
  }
  const std::string ref_cache = absl::StrFormat(
      "%s/reference_%s_%s_s%d_size%d_%dx%d%s_%d_%016x.bin", a.out_dir, scene->name, mode_tag,
      a.seed, a.size, a.width, a.height, window_tag, 2 * half_rays, receivers_hash);
  // Every pixel's reference value (see Scalar) with `rays` rays from `seed`.
  auto reference = [&](int rays, uint64_t seed, std::vector<double>* dst) {
    if (occlusion) {
      const auto r = tracer->ReferenceOcclusion(cr.receivers, rays,
                                                std::numeric_limits<float>::infinity(), seed);
      for (size_t i = 0; i < r.size(); ++i) (*dst)[cr.pixel_of[i]] = r[i];
    } else {
      const auto r = glossy ? tracer->ReferenceGlossy(cr.shade, a.lobe, rays, seed)
                            : tracer->ReferenceIrradiance(cr.receivers, rays, seed);
      for (size_t i = 0; i < r.size(); ++i) (*dst)[cr.pixel_of[i]] = Scalar(r[i]);
    }
  };
  bool cached = false;
  {
    std::ifstream in(ref_cache, std::ios::binary);
    if (in) {
      in.read(reinterpret_cast<char*>(ref_a.data()), std::streamsize(pixels * sizeof(double)));
      in.read(reinterpret_cast<char*>(ref_b.data()), std::streamsize(pixels * sizeof(double)));
      cached = in.good();
    }
  }
  for (int k = 0; k < 2 && !cached; ++k) {
    reference(half_rays, a.seed + 101 + uint64_t(k), k == 0 ? &ref_a : &ref_b);
  }
  if (!cached) {
    const std::string tmp = ref_cache + ".tmp";
    std::ofstream out(tmp, std::ios::binary);
    out.write(reinterpret_cast<const char*>(ref_a.data()),
              std::streamsize(pixels * sizeof(double)));
    out.write(reinterpret_cast<const char*>(ref_b.data()),
              std::streamsize(pixels * sizeof(double)));
    out.close();
    if (out.good()) std::filesystem::rename(tmp, ref_cache, ec);
  }
  double ref_noise = 0;
  for (size_t p = 0; p < pixels; ++p) {
    ref[p] = 0.5 * (ref_a[p] + ref_b[p]);
    ref_noise += covered[p] ? 0.5 * std::abs(ref_a[p] - ref_b[p]) : 0.0;
  }
  ref_noise /= double(std::max<size_t>(1, cr.receivers.size()));
  const double ref_seconds = Since(t);
  std::fprintf(stderr, "eval --view: reference %d rays per pixel %s in %.1f s (own MAE ~%.2g)\n",
               2 * half_rays, (cached ? "read from " + ref_cache : std::string("traced")).c_str(),
               ref_seconds, ref_noise);

  // What the reference images look like: occlusion as 1 - occlusion (white = open), irradiance
  // scaled so that its mean is mid-grey.
  double ref_mean = 0;
  for (size_t p = 0; p < pixels; ++p) ref_mean += covered[p] ? ref[p] : 0.0;
  ref_mean /= double(std::max<size_t>(1, cr.receivers.size()));
  auto picture = [&](const std::vector<double>& v) {
    if (occlusion) {
      std::vector<double> open(v.size());
      for (size_t p = 0; p < v.size(); ++p) open[p] = 1.0 - std::clamp(v[p], 0.0, 1.0);
      return GreyImage(a.width, a.height, open, covered, 1.0, 1.0f);
    }
    return GreyImage(a.width, a.height, v, covered, ref_mean > 0 ? 0.5 / ref_mean : 1.0, 0.0f);
  };
  PBGI_RETURN_IF_ERROR(WritePng(a.out_dir + "/reference.png", picture(ref), 1.0f, false));
  const double scale = occlusion ? a.error_scale : a.error_scale * std::max(1e-9, ref_mean);

  DatabaseOptions dbo;
  dbo.cache_bytes = cache;
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<Database> db, Database::Open(db_path, dbo));
  const HitSides sides = a.hitsides == "back"   ? HitSides::kBack
                         : a.hitsides == "both" ? HitSides::kBoth
                                                : HitSides::kFront;
  std::printf(
      "pbgi eval --view: scene %s, %s, %llu surfels, %dx%d, %zu receivers, reference %d rays "
      "(own MAE ~%.2g), hitsides %s\n",
      scene->name.c_str(), mode_tag.c_str(), static_cast<unsigned long long>(points), a.width,
      a.height, cr.receivers.size(), 2 * half_rays, ref_noise, a.hitsides.c_str());
  std::string rows_json;
  bool dumped = false;  // --dump-receivers: the first PBGI row
  auto add_json = [&](const std::string& row) {
    rows_json += (rows_json.empty() ? "    " : ",\n    ") + row;
  };
  // The reference at fewer rays: its time and error against the converged one, the curve that
  // PBGI's rows are compared on at equal MAE.
  std::vector<SweepPoint> ref_sweep;  // rays, MAE, us per receiver
  for (int rays : a.ray_sweep) {
    std::vector<double> got(pixels, 0.0);
    std::vector<double> times;
    for (int rep = 0; rep < a.repeat; ++rep) {
      const auto t0 = Clock::now();
      reference(rays, a.seed + 1000 + uint64_t(rays), &got);
      times.push_back(Since(t0));
    }
    std::sort(times.begin(), times.end());
    const double us =
        times[times.size() / 2] / double(std::max<size_t>(1, cr.receivers.size())) * 1e6;
    const ImageErrors e = CompareImages(a.width, a.height, got, ref, covered);
    PrintErrors(absl::StrFormat("reference %d rays:", rays).c_str(), e, !occlusion);
    std::printf("%-26s %.3f us/receiver (%d threads)\n", "", us, threads);
    if (e.mae > 0) ref_sweep.push_back({rays, e.mae, us});
    const std::string tag = absl::StrFormat("reference_%d", rays);
    PBGI_RETURN_IF_ERROR(WritePng(a.out_dir + "/error_" + tag + ".png",
                                  ErrorHeatMap(a.width, a.height, got, ref, covered, scale), 1.0f,
                                  false));
    add_json(
        absl::StrFormat("{\"setting\": \"%s\", \"method\": \"reference\", \"rays\": %d, "
                        "\"us_per_receiver\": %.4g, \"errors\": %s}",
                        tag, rays, us, ErrorsJson(e)));
  }
  // The reference's time at `mae`, interpolated in log-log on its sweep (0 outside it:
  // tools/reference_stats.h).
  auto reference_us_at = [&](double mae) {
    if (ref_sweep.size() < 2) return 0.0;
    SweepReading reading;
    const double us = ReferenceSecondsAt(ref_sweep, mae, &reading);
    return reading.extrapolated ? 0.0 : us;
  };

  struct ModeRow {
    bool shared = false;
    int spacing = 0;
    float tolerance = 0;
    float far_factor = 0;  // > 0: far-field sharing at this distance factor
  };
  std::vector<ModeRow> plain_modes;
  if (!a.shared_only) plain_modes.push_back({});
  if (!a.exact_only) {
    for (int sp : a.spacings) {
      for (float tol : a.tolerances) plain_modes.push_back({true, sp, tol});
    }
  }
  std::vector<ModeRow> modes;
  for (const ModeRow& m : plain_modes) {
    if (!a.far_only || a.far_factors.empty()) modes.push_back(m);
    for (float k : a.far_factors) {
      ModeRow f = m;
      f.far_factor = k;
      modes.push_back(f);
    }
  }
  for (const std::string& footprint : a.footprints) {
    for (const std::string& cut : a.cuts) {
      for (int res : a.resolutions) {
        for (float msa : a.solid_angles) {
          for (const ModeRow& m : modes) {
            ShadeOptions so;
            so.threads = threads;
            so.cut.max_solid_angle = msa;
            so.cut.cosine_weighted = cut == "cosine";
            so.lobe_cut = cut == "lobe";
            so.raster.resolution = res;
            so.raster.compute_radiance = !occlusion;
            so.raster.hitsides = sides;
            so.cut.curved_scale = a.curved_scale;
            so.cut.curved_box_scale = a.curved_box_scale;
            so.radiance_contrast = a.radiance_contrast;
            so.raster.footprint = ParseFootprint(footprint);
            if (glossy) {
              so.raster.lobe = a.lobe.lobe;
              so.raster.phong_exponent = a.lobe.phong_exponent;
              so.raster.ggx_roughness = a.lobe.ggx_roughness;
            }
            if (m.shared) {
              so.mode = ShadeMode::kShared;
              if (a.layout == "image") so = cr.WithLayout(so);
              so.sharing.spacing = m.spacing;
              so.sharing.tolerance = m.tolerance;
              so.sharing.radius_factor = a.radius_factor;
            }
            if (m.far_factor > 0) {
              ApplyFarSharingFlags(a.far, db->meta().bounds, &so);
              so.far_sharing.enabled = true;
              so.far_sharing.distance_factor = m.far_factor;
              so.lobe_cut = false;
            }
            std::vector<ShadeResult> results(cr.shade.size());
            std::vector<uint8_t> shaded(cr.shade.size());
            std::vector<ShadeStats> runs;
            Progress progress(absl::StrFormat("eval --view: shade msa %g res %d %s", msa, res, cut),
                              "receivers", int64_t(cr.shade.size()) * a.repeat);
            int64_t done_before = 0;
            so.progress = [&](const ShadeProgress& p) {
              progress.Update(done_before + int64_t(p.done), int64_t(cr.shade.size()) * a.repeat);
            };
            for (int rep = 0; rep < a.repeat; ++rep) {
              ShadeStats st;
              PBGI_RETURN_IF_ERROR(ShadeBatch(*db, cr.shade, so, absl::MakeSpan(results), &st,
                                              absl::MakeSpan(shaded)));
              runs.push_back(st);
              done_before += int64_t(cr.shade.size());
            }
            progress.Finish(int64_t(cr.shade.size()) * a.repeat);
            std::sort(runs.begin(), runs.end(), [](const ShadeStats& x, const ShadeStats& y) {
              return x.seconds < y.seconds;
            });
            const ShadeStats& st = runs[runs.size() / 2];
            std::vector<double> got(pixels, 0.0);
            for (size_t i = 0; i < results.size(); ++i) {
              got[cr.pixel_of[i]] =
                  occlusion ? results[i].occlusion
                            : Scalar(glossy ? results[i].glossy : results[i].irradiance);
            }
            if (!a.dump_receivers.empty() && !dumped) {
              dumped = true;
              std::string csv = "px,py,x,y,z,nx,ny,nz,reference,pbgi,error\n";
              for (size_t i = 0; i < results.size(); ++i) {
                const uint32_t p = cr.pixel_of[i];
                const Receiver& r = cr.receivers[i];
                absl::StrAppendFormat(&csv, "%u,%u,%.9g,%.9g,%.9g,%.6g,%.6g,%.6g,%.6f,%.6f,%+.6f\n",
                                      p % uint32_t(a.width), p / uint32_t(a.width), r.position.x,
                                      r.position.y, r.position.z, r.normal.x, r.normal.y,
                                      r.normal.z, ref[p], got[p], got[p] - ref[p]);
              }
              PBGI_RETURN_IF_ERROR(WriteFileAtomically(a.dump_receivers, csv));
            }
            const ImageErrors e = CompareImages(a.width, a.height, got, ref, covered);
            std::string tag =
                absl::StrFormat("msa%g_res%d_%s", msa, res, cut == "cosine" ? "cos" : cut);
            std::string label = absl::StrFormat("msa %g res %d %s", msa, res, cut);
            if (footprint == "splats") {
              // The default footprints' tags are the setting alone.
              tag += "_splat";
              label += " splats";
            }
            if (a.curved_scale != 1.0f) label += absl::StrFormat(" curved %g", a.curved_scale);
            if (a.curved_box_scale != 1.0f) {
              label += absl::StrFormat(" box %g", a.curved_box_scale);
            }
            if (m.shared) {
              tag += absl::StrFormat("_shared%s_s%d_t%g", a.layout == "image" ? "" : "pts",
                                     m.spacing, m.tolerance);
              label += absl::StrFormat(" shared%s s%d t%g", a.layout == "image" ? "" : " (points)",
                                       m.spacing, m.tolerance);
            } else {
              label += " exact";  // the tag of the reference mode stays the setting alone
            }
            if (m.far_factor > 0) {
              tag += absl::StrFormat("_far%g", m.far_factor);
              label += absl::StrFormat(" far k%g", m.far_factor);
            }
            const double n = double(std::max<size_t>(1, results.size()));
            const double us = st.seconds / n * 1e6;
            const double thread_us =
                (st.gather_seconds + st.raster_seconds + st.sharing_seconds) / n * 1e6;
            const double cpu_us = st.cpu_seconds / n * 1e6;
            const double ref_us = reference_us_at(e.mae);
            PrintErrors((label + ":").c_str(), e, !occlusion);
            std::printf(
                "%-26s %.2f us/receiver (%d threads), %.2f thread-us/receiver (%.2f CPU us), "
                "%.1f%% "
                "shaded, %.1f clusters + %.1f surfels per shaded receiver",
                "", us, threads, thread_us, cpu_us, 100.0 * double(st.shaded) / n,
                double(st.query.clusters) / double(std::max<uint64_t>(1, st.shaded)),
                double(st.query.surfels) / double(std::max<uint64_t>(1, st.shaded)));
            if (ref_us > 0) std::printf(", %.3gx the reference at equal MAE", ref_us / us);
            std::printf("\n");
            const double per_shaded = 1e6 / double(std::max<uint64_t>(1, st.shaded));
            std::printf(
                "%-26s per shaded receiver: gather %.1f + raster %.1f thread-us, %.1f CPU us", "",
                st.gather_seconds * per_shaded, st.raster_seconds * per_shaded,
                st.cpu_seconds * per_shaded);
            if (st.far_groups > 0) {
              std::printf(
                  "; far field shared by %llu groups of %.2f receivers (%.1f%% of shaded)",
                  static_cast<unsigned long long>(st.far_groups),
                  double(st.far_members) / double(st.far_groups),
                  100.0 * double(st.far_members) / double(std::max<uint64_t>(1, st.shaded)));
            }
            std::printf("\n");
            PBGI_RETURN_IF_ERROR(
                WritePng(a.out_dir + "/pbgi_" + tag + ".png", picture(got), 1.0f, false));
            PBGI_RETURN_IF_ERROR(WritePng(a.out_dir + "/error_" + tag + ".png",
                                          ErrorHeatMap(a.width, a.height, got, ref, covered, scale),
                                          1.0f, false));
            // Raw values for other tools: channel 0 PBGI, 1 the reference, 2 the coverage mask.
            Image raw(a.width, a.height);
            for (size_t p = 0; p < pixels; ++p) {
              raw.pixels[p] = glm::vec3(float(got[p]), float(ref[p]), float(covered[p]));
            }
            PBGI_RETURN_IF_ERROR(WriteExr(a.out_dir + "/values_" + tag + ".exr", raw));
            if (m.shared) {
              // Which receivers were shaded (black) and which interpolated (white).
              Image mask(a.width, a.height);
              for (size_t p = 0; p < pixels; ++p) mask.pixels[p] = glm::vec3(0.35f);
              for (size_t i = 0; i < shaded.size(); ++i) {
                mask.pixels[cr.pixel_of[i]] = glm::vec3(shaded[i] ? 0.0f : 1.0f);
              }
              PBGI_RETURN_IF_ERROR(
                  WritePng(a.out_dir + "/shaded_" + tag + ".png", mask, 1.0f, false));
            }
            add_json(absl::StrFormat(
                "{\"setting\": \"%s\", \"method\": \"pbgi\", \"mode\": \"%s\", "
                "\"max_solid_angle\": %g, \"raster_res\": %d, \"cut\": \"%s\", "
                "\"footprint\": \"%s\", \"curved_scale\": %g, \"curved_box_scale\": %g, "
                "\"spacing\": %d, \"tolerance\": %g, \"us_per_receiver\": %.4g, "
                "\"thread_us_per_receiver\": %.4g, \"cpu_us_per_receiver\": %.4g, \"shaded\": %d, "
                "\"interpolated\": %d, \"far_factor\": %g, \"far_groups\": %d, "
                "\"far_members\": %d, \"gather_seconds\": %.4g, \"raster_seconds\": %.4g, "
                "\"clusters\": %.4g, \"surfels\": %.4g, \"speed_ratio\": %.4g, \"errors\": %s}",
                tag, m.shared ? (a.layout == "image" ? "shared" : "shared_points") : "exact", msa,
                res, cut, footprint, a.curved_scale, a.curved_box_scale, m.spacing, m.tolerance, us,
                thread_us, cpu_us, st.shaded, st.interpolated, m.far_factor, st.far_groups,
                st.far_members, st.gather_seconds, st.raster_seconds, double(st.query.clusters) / n,
                double(st.query.surfels) / n, ref_us > 0 ? ref_us / us : 0.0, ErrorsJson(e)));
          }
        }
      }
    }
  }
  const std::string json_path = a.out_dir + "/view.json";
  PBGI_RETURN_IF_ERROR(WriteFileAtomically(
      json_path,
      absl::StrFormat("{\n  \"scene\": \"%s\", \"mode\": \"%s\", \"points\": %d, \"width\": %d, "
                      "\"height\": %d, "
                      "\"receivers\": %d, \"reference_rays\": %d, \"reference_noise_mae\": %.4g, "
                      "\"reference_seconds\": %.4g, \"hitsides\": \"%s\", \"threads\": %d,\n  "
                      "\"rows\": [\n%s\n  "
                      "]\n}\n",
                      scene->name, a.mode, points, a.width, a.height, cr.receivers.size(),
                      2 * half_rays, ref_noise, ref_seconds, a.hitsides, threads, rows_json)));
  std::printf(
      "wrote %s/{reference,pbgi_*,error_*}.png (error: red = PBGI too high, blue = too low, "
      "saturated at %.3g), values_*.exr and view.json\n",
      a.out_dir.c_str(), scale);
  return absl::OkStatus();
}

}  // namespace pbgi::tools
