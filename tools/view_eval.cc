// `pbgi eval --view` (see view_eval.h).
#include "tools/view_eval.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>

#include "absl/strings/str_format.h"
#include "oneapi/tbb/global_control.h"
#include "pbgi/build.h"
#include "pbgi/query.h"
#include "pbgi/scene.h"
#include "pbgi/shade.h"
#include "pbgi/status.h"
#include "pbgi/store.h"
#include "tools/args.h"
#include "tools/outputs.h"
#include "tools/progress.h"
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
  const uint64_t memory = a.memory_bytes, cache = a.cache_bytes;
  PBGI_RETURN_IF_ERROR(CheckOutsideStores(a.out_dir));
  std::error_code ec;
  std::filesystem::create_directories(a.out_dir, ec);
  if (ec) return absl::UnavailableError(absl::StrFormat("cannot create %s", a.out_dir));
  const int threads = ResolveThreads(a.threads);
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);

  PBGI_ASSIGN_OR_RETURN(std::shared_ptr<const Scene> scene, LoadScene(a.scene, a.seed, a.size));
  if (!occlusion && !scene->has_radiance) {
    return absl::FailedPreconditionError(
        absl::StrFormat("scene %s has no radiance: use --mode occlusion", scene->name));
  }
  auto t = Clock::now();
  SamplerOptions sampler;
  sampler.count = a.points;
  sampler.seed = a.seed;
  sampler.bake = !occlusion;
  PBGI_ASSIGN_OR_RETURN(auto surfels, MakeSceneSurfelSource(scene, sampler));
  const std::string db_path = a.out_dir + "/" + scene->name + ".pbgi";
  BuildOptions bo;
  bo.memory_bytes = memory;
  bo.channels = occlusion ? Channels::kOcclusion : Channels::kRadiance;
  bo.tmp_dir = a.out_dir;
  bo.provenance = SceneFingerprint(*scene, a.seed, a.size, UpAxis::kZ);
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
  PBGI_ASSIGN_OR_RETURN(BuildStats bs, BuildDatabase(*surfels, db_path, bo));
  build_progress.Finish(bs.points);
  std::fprintf(stderr, "eval --view: %s, built %llu surfels in %.1f s\n", scene->name.c_str(),
               static_cast<unsigned long long>(bs.points), Since(t));

  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<Tracer> tracer, Tracer::Create(*scene));
  const Camera camera = DefaultCamera(*scene, a.width, a.height);
  const CameraReceivers cr = MakeCameraReceivers(*tracer, camera);
  const size_t pixels = size_t(a.width) * size_t(a.height);
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
  const std::string ref_cache =
      absl::StrFormat("%s/reference_%s_%s_s%d_size%d_%dx%d_%d.bin", a.out_dir, scene->name, a.mode,
                      a.seed, a.size, a.width, a.height, 2 * half_rays);
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
    std::vector<double>& dst = k == 0 ? ref_a : ref_b;
    const uint64_t seed = a.seed + 101 + uint64_t(k);
    if (occlusion) {
      const auto r = tracer->ReferenceOcclusion(cr.receivers, half_rays,
                                                std::numeric_limits<float>::infinity(), seed);
      for (size_t i = 0; i < r.size(); ++i) dst[cr.pixel_of[i]] = r[i];
    } else {
      const auto r = tracer->ReferenceIrradiance(cr.receivers, half_rays, seed);
      for (size_t i = 0; i < r.size(); ++i) dst[cr.pixel_of[i]] = Scalar(r[i]);
    }
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
      scene->name.c_str(), a.mode.c_str(), static_cast<unsigned long long>(bs.points), a.width,
      a.height, cr.receivers.size(), 2 * half_rays, ref_noise, a.hitsides.c_str());
  std::string rows_json;
  for (const std::string& footprint : a.footprints) {
  for (const std::string& cut : a.cuts) {
    for (int res : a.resolutions) {
      for (float msa : a.solid_angles) {
        ShadeOptions so;
        so.threads = threads;
        so.cut.max_solid_angle = msa;
        so.cut.cosine_weighted = cut == "cosine";
        so.raster.resolution = res;
        so.raster.compute_radiance = !occlusion;
        so.raster.hitsides = sides;
        so.cut.curved_scale = a.curved_scale;
        so.raster.footprint =
            footprint == "polygons" ? Footprint::kPolygons : Footprint::kSplats;
        std::vector<ShadeResult> results(cr.shade.size());
        ShadeStats st;
        Progress progress(absl::StrFormat("eval --view: shade msa %g res %d %s", msa, res, cut),
                          "receivers", int64_t(cr.shade.size()));
        so.progress = [&](const ShadeProgress& p) { progress.Update(p.done, int64_t(p.total)); };
        PBGI_RETURN_IF_ERROR(ShadeBatch(*db, cr.shade, so, absl::MakeSpan(results), &st));
        progress.Finish(results.size());
        std::vector<double> got(pixels, 0.0);
        for (size_t i = 0; i < results.size(); ++i) {
          got[cr.pixel_of[i]] = occlusion ? results[i].occlusion : Scalar(results[i].irradiance);
        }
        const ImageErrors e = CompareImages(a.width, a.height, got, ref, covered);
        const std::string tag =
            absl::StrFormat("msa%g_res%d_%s%s", msa, res, cut == "cosine" ? "cos" : "plain",
                            footprint == "polygons" ? "_poly" : "");
        const double n = double(std::max<size_t>(1, results.size()));
        const double us = st.seconds / n * 1e6;
        PrintErrors(absl::StrFormat("msa %g res %d %s %s:", msa, res, cut, footprint).c_str(), e,
                    !occlusion);
        std::printf("%-26s %.2f us/receiver (%d threads), %.1f clusters + %.1f surfels\n", "",
                    us, threads, double(st.query.clusters) / n, double(st.query.surfels) / n);
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
        rows_json += absl::StrFormat(
            "%s    {\"setting\": \"%s\", \"max_solid_angle\": %g, \"raster_res\": %d, "
            "\"cut\": \"%s\", \"footprint\": \"%s\", \"curved_scale\": %g, "
            "\"us_per_receiver\": %.4g, \"clusters\": %.4g, \"surfels\": %.4g, "
            "\"errors\": %s}",
            rows_json.empty() ? "" : ",\n", tag, msa, res, cut, footprint, a.curved_scale, us,
            double(st.query.clusters) / n, double(st.query.surfels) / n, ErrorsJson(e));
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
                      scene->name, a.mode, bs.points, a.width, a.height, cr.receivers.size(),
                      2 * half_rays, ref_noise, ref_seconds, a.hitsides, threads, rows_json)));
  std::printf(
      "wrote %s/{reference,pbgi_*,error_*}.png (error: red = PBGI too high, blue = too low, "
      "saturated at %.3g), values_*.exr and view.json\n",
      a.out_dir.c_str(), scale);
  return absl::OkStatus();
}

}  // namespace pbgi::tools
