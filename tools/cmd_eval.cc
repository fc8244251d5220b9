// `pbgi eval`: run time against the error it bought. Builds the database of a scene, shades the
// same receivers with PBGI over a sweep of max_solid_angle and raster resolution, and with the
// Embree reference over a sweep of ray counts, all against a converged reference (many rays).
// Prints a table, writes eval.json and a log-log chart eval.png (error vs seconds/receiver).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "oneapi/tbb/global_control.h"
#include "pbgi/build.h"
#include "pbgi/query.h"
#include "pbgi/scene.h"
#include "pbgi/status.h"
#include "tools/chart.h"
#include "tools/command.h"
#include "tools/scene_views.h"
#include "tools/shading.h"

namespace pbgi::tools {
namespace {

struct EvalArgs {
  std::string scene = "cornell";
  std::string out_dir = "out/eval";
  std::string mode = "occlusion";
  int64_t points = 1'000'000;
  int64_t receivers = 1000;
  int truth_rays = 4096;
  std::vector<int> ray_sweep = {16, 64, 256, 1024};
  std::vector<float> solid_angles = {1.0f, 0.3f, 0.1f, 0.03f, 0.01f, 0.003f};
  std::vector<int> resolutions = {8, 12, 16};
  std::string memory = "512M";
  std::string cache = "256M";
  int threads = 0;
  uint64_t seed = 1;
};

struct Errors {
  double mae = 0, rmse = 0, max = 0;
};

using Clock = std::chrono::steady_clock;
double Since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

// One scalar per receiver: occlusion, or the mean of the irradiance's channels.
Errors Compare(const std::vector<double>& got, const std::vector<double>& truth) {
  Errors e;
  for (size_t i = 0; i < got.size(); ++i) {
    const double d = std::abs(got[i] - truth[i]);
    e.mae += d;
    e.rmse += d * d;
    e.max = std::max(e.max, d);
  }
  e.mae /= double(std::max<size_t>(1, got.size()));
  e.rmse = std::sqrt(e.rmse / double(std::max<size_t>(1, got.size())));
  return e;
}

struct Row {
  std::string method;
  std::string setting;
  double seconds_per_receiver = 0;
  Errors err;
  double clusters = 0, surfels = 0;
};

absl::Status RunEval(const EvalArgs& a) {
  const bool occlusion = a.mode == "occlusion";
  PBGI_ASSIGN_OR_RETURN(uint64_t memory, ParseBytes(a.memory));
  PBGI_ASSIGN_OR_RETURN(uint64_t cache, ParseBytes(a.cache));
  std::error_code ec;
  std::filesystem::create_directories(a.out_dir, ec);
  if (ec) return absl::UnavailableError(absl::StrFormat("cannot create %s", a.out_dir));
  const int threads = a.threads > 0 ? a.threads : DefaultThreads();
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);

  PBGI_ASSIGN_OR_RETURN(std::shared_ptr<const Scene> scene, LoadScene(a.scene, a.seed, 0));
  if (!occlusion && !scene->has_radiance) {
    return absl::FailedPreconditionError(
        absl::StrFormat("scene %s has no radiance: use --mode occlusion", scene->name));
  }
  // The database.
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
  PBGI_ASSIGN_OR_RETURN(BuildStats bs, BuildDatabase(*surfels, db_path, bo));
  std::fprintf(stderr, "eval: built %llu surfels in %.1f s\n",
               static_cast<unsigned long long>(bs.points), Since(t));

  // Receivers: points on the scene's surfaces from an independent sample, lifted off the
  // surface like a renderer's shading points.
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<Tracer> tracer, Tracer::Create(*scene));
  SamplerOptions rs;
  rs.count = a.receivers;
  rs.seed = a.seed + 7919;
  rs.bake = false;
  PBGI_ASSIGN_OR_RETURN(auto rsrc, MakeSceneSurfelSource(scene, rs));
  std::vector<Surfel> rsurf(static_cast<size_t>(a.receivers));
  PBGI_ASSIGN_OR_RETURN(size_t got, rsrc->Next(absl::MakeSpan(rsurf)));
  rsurf.resize(got);
  // A sample whose normal ray first meets the back of a face lies inside solid geometry (the
  // Cornell floor under a block, the city ground under a building): no camera sees it, and the
  // reference (which counts back faces) and PBGI disagree there by construction. Skip them.
  std::vector<Receiver> receivers;
  uint64_t hidden = 0;
  for (const Surfel& s : rsurf) {
    const glm::vec3 origin = s.position + tracer->epsilon() * s.normal;
    const Hit h = tracer->Intersect(origin, s.normal, std::numeric_limits<float>::infinity());
    if (h.hit && !h.front) {
      ++hidden;
      continue;
    }
    receivers.push_back({origin, s.normal});
  }
  if (receivers.empty()) {
    return absl::FailedPreconditionError("every receiver sample lies inside solid geometry");
  }
  std::fprintf(stderr, "eval: %zu receivers (%llu samples inside solid geometry skipped)\n",
               receivers.size(), static_cast<unsigned long long>(hidden));
  const double n = double(std::max<size_t>(1, receivers.size()));

  auto reference = [&](int rays, uint64_t seed) -> std::vector<double> {
    std::vector<double> v(receivers.size());
    if (occlusion) {
      auto r =
          tracer->ReferenceOcclusion(receivers, rays, std::numeric_limits<float>::infinity(), seed);
      for (size_t i = 0; i < v.size(); ++i) v[i] = r[i];
    } else {
      auto r = tracer->ReferenceIrradiance(receivers, rays, seed);
      for (size_t i = 0; i < v.size(); ++i) v[i] = (r[i].x + r[i].y + r[i].z) / 3.0;
    }
    return v;
  };

  t = Clock::now();
  const std::vector<double> truth = reference(a.truth_rays, a.seed + 1);
  std::fprintf(stderr, "eval: converged reference, %d rays x %zu receivers, %.1f s\n", a.truth_rays,
               receivers.size(), Since(t));

  std::vector<Row> rows;
  for (int rays : a.ray_sweep) {
    t = Clock::now();
    std::vector<double> v = reference(rays, a.seed + 2);
    Row r;
    r.method = "reference";
    r.setting = absl::StrFormat("%d rays", rays);
    r.seconds_per_receiver = Since(t) / n;
    r.err = Compare(v, truth);
    rows.push_back(r);
  }

  DatabaseOptions dbo;
  dbo.cache_bytes = cache;
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<Database> db, Database::Open(db_path, dbo));
  size_t default_row = 0;
  for (int res : a.resolutions) {
    for (float msa : a.solid_angles) {
      ShadeJobOptions so;
      so.threads = threads;
      so.cut.max_solid_angle = msa;
      so.raster.resolution = res;
      so.raster.compute_radiance = !occlusion;
      std::vector<ShadeResult> results;
      ShadeJobStats st;
      PBGI_RETURN_IF_ERROR(ShadeReceivers(*db, receivers, {}, so, &results, &st));
      std::vector<double> v(results.size());
      for (size_t i = 0; i < v.size(); ++i) {
        v[i] = occlusion
                   ? results[i].occlusion
                   : (results[i].irradiance.x + results[i].irradiance.y + results[i].irradiance.z) /
                         3.0;
      }
      Row r;
      r.method = "pbgi";
      r.setting = absl::StrFormat("msa %.3g res %d", msa, res);
      r.seconds_per_receiver = st.seconds / n;
      r.err = Compare(v, truth);
      r.clusters = double(st.query.clusters) / n;
      r.surfels = double(st.query.surfels) / n;
      if (res == 12 && std::abs(msa - 0.03f) < 1e-6f) default_row = rows.size();
      rows.push_back(r);
    }
  }

  // Speed at equal error: the reference's error falls as rays^-1/2, so the time it needs for an
  // error e, from its row with the closest error, is t_r * (e_r / e)^2.
  const Row& def = rows[default_row];
  double ratio = 0;
  {
    double best = std::numeric_limits<double>::max();
    for (const Row& r : rows) {
      if (r.method != "reference" || !(r.err.mae > 0)) continue;
      const double d = std::abs(std::log(r.err.mae / std::max(1e-12, def.err.mae)));
      if (d < best) {
        best = d;
        const double t_equal =
            r.seconds_per_receiver * std::pow(r.err.mae / std::max(1e-12, def.err.mae), 2.0);
        ratio = t_equal / std::max(1e-12, def.seconds_per_receiver);
      }
    }
  }

  std::printf(
      "pbgi eval: scene %s, %s, %llu surfels, %zu receivers, %d threads, truth = %d "
      "rays\n",
      scene->name.c_str(), a.mode.c_str(), static_cast<unsigned long long>(bs.points),
      receivers.size(), threads, a.truth_rays);
  std::printf("%-10s %-20s %12s %10s %10s %10s %9s %9s\n", "method", "setting", "us/receiver",
              "MAE", "RMSE", "max", "clusters", "surfels");
  for (const Row& r : rows) {
    std::printf("%-10s %-20s %12.2f %10.5f %10.5f %10.5f %9.1f %9.1f\n", r.method.c_str(),
                r.setting.c_str(), r.seconds_per_receiver * 1e6, r.err.mae, r.err.rmse, r.err.max,
                r.clusters, r.surfels);
  }
  if (ratio > 0) {
    std::printf(
        "default (msa 0.03, res 12): MAE %.5f at %.2f us/receiver; the reference needs "
        "%.2fx that time for the same MAE\n",
        def.err.mae, def.seconds_per_receiver * 1e6, ratio);
  } else {
    std::printf(
        "default (msa 0.03, res 12): MAE %.5f at %.2f us/receiver; the reference is "
        "exact here at every ray count (e.g. a closed box), so no ratio\n",
        def.err.mae, def.seconds_per_receiver * 1e6);
  }

  // JSON and chart.
  const std::string json_path = a.out_dir + "/eval.json";
  std::ofstream js(json_path);
  js << absl::StrFormat(
      "{\n  \"scene\": \"%s\", \"mode\": \"%s\", \"points\": %d, \"receivers\": %d, "
      "\"threads\": %d, \"truth_rays\": %d,\n  \"default_mae\": %.6g, "
      "\"speedup_at_equal_error\": %.4g,\n  \"rows\": [\n",
      scene->name, a.mode, bs.points, receivers.size(), threads, a.truth_rays, def.err.mae, ratio);
  for (size_t i = 0; i < rows.size(); ++i) {
    const Row& r = rows[i];
    js << absl::StrFormat(
        "    {\"method\": \"%s\", \"setting\": \"%s\", \"seconds_per_receiver\": %.6g, "
        "\"mae\": %.6g, \"rmse\": %.6g, \"max\": %.6g, \"clusters\": %.4g, \"surfels\": "
        "%.4g}%s\n",
        r.method, r.setting, r.seconds_per_receiver, r.err.mae, r.err.rmse, r.err.max, r.clusters,
        r.surfels, i + 1 < rows.size() ? "," : "");
  }
  js << "  ]\n}\n";
  if (!js.good()) return absl::UnavailableError(absl::StrFormat("cannot write %s", json_path));

  std::vector<ChartSeries> series;
  ChartSeries ref{"reference", glm::vec3(0.15f, 0.35f, 0.8f), true, {}, {}};
  for (const Row& r : rows) {
    if (r.method == "reference")
      ref.x.push_back(r.err.mae), ref.y.push_back(r.seconds_per_receiver);
  }
  series.push_back(ref);
  const glm::vec3 colors[] = {
      {0.95f, 0.55f, 0.1f}, {0.85f, 0.2f, 0.2f}, {0.2f, 0.65f, 0.3f}, {0.5f, 0.3f, 0.7f}};
  for (size_t k = 0; k < a.resolutions.size(); ++k) {
    ChartSeries s{absl::StrFormat("pbgi res %d", a.resolutions[k]), colors[k % 4], true, {}, {}};
    for (const Row& r : rows) {
      if (r.method == "pbgi" &&
          r.setting.find(absl::StrFormat("res %d", a.resolutions[k])) != std::string::npos) {
        s.x.push_back(r.err.mae), s.y.push_back(r.seconds_per_receiver);
      }
    }
    series.push_back(s);
  }
  const std::string chart_path = a.out_dir + "/eval.png";
  PBGI_RETURN_IF_ERROR(WriteLogLogChart(chart_path, series));
  std::printf(
      "wrote %s and %s (x: log10 MAE, y: log10 seconds/receiver; blue = reference, "
      "then PBGI by raster resolution %s)\n",
      json_path.c_str(), chart_path.c_str(), absl::StrJoin(a.resolutions, ", ").c_str());
  return absl::OkStatus();
}

CommandSetup Setup() {
  return [](CLI::App* app) -> std::function<absl::Status()> {
    auto a = std::make_shared<EvalArgs>();
    app->add_option("scene", a->scene, "Procedural scene or mesh file")->capture_default_str();
    app->add_option("-o,--out", a->out_dir, "Output directory")->capture_default_str();
    app->add_option("--mode", a->mode, "occlusion or irradiance")
        ->check(CLI::IsMember({"occlusion", "irradiance"}))
        ->capture_default_str();
    app->add_option("--points", a->points)
        ->check(CLI::Range(int64_t{1}, int64_t{1} << 36))
        ->capture_default_str();
    app->add_option("--receivers", a->receivers)
        ->check(CLI::Range(int64_t{1}, int64_t{1} << 24))
        ->capture_default_str();
    app->add_option("--rays", a->truth_rays, "Rays of the converged reference")
        ->check(CLI::Range(16, 1 << 20))
        ->capture_default_str();
    app->add_option("--ray-sweep", a->ray_sweep, "Ray counts of the reference sweep")
        ->capture_default_str();
    app->add_option("--solid-angles", a->solid_angles, "max_solid_angle sweep")
        ->capture_default_str();
    app->add_option("--raster-res", a->resolutions, "Raster resolution sweep")
        ->capture_default_str();
    app->add_option("--memory", a->memory)->check(BytesValidator())->capture_default_str();
    app->add_option("--cache", a->cache)->check(BytesValidator())->capture_default_str();
    app->add_option("--threads", a->threads, "0: all cores")->capture_default_str();
    app->add_option("--seed", a->seed)->capture_default_str();
    return [a]() { return RunEval(*a); };
  };
}

}  // namespace
PBGI_REGISTER_COMMAND(eval, "eval", "Run time against error: PBGI sweeps vs the Embree reference",
                      Setup());
}  // namespace pbgi::tools
