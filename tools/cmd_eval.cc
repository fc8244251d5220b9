// `pbgi eval`: run time against the error it bought. Builds the database of a scene, shades the
// same receivers with PBGI over a sweep of max_solid_angle and raster resolution, and with the
// Embree reference over a sweep of ray counts, all against a converged reference (many rays).
// Prints a table, writes eval.json and a log-log chart eval.png (error vs seconds/receiver).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <memory>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "base/stopwatch.h"
#include "oneapi/tbb/global_control.h"
#include "pbgi/build.h"
#include "pbgi/query.h"
#include "pbgi/scene.h"
#include "pbgi/shade.h"
#include "pbgi/status.h"
#include "pbgi/store.h"
#include "tools/args.h"
#include "tools/budget.h"
#include "tools/chart.h"
#include "tools/command.h"
#include "tools/footprint_flags.h"
#include "tools/mesh_flags.h"
#include "tools/progress.h"
#include "tools/reference_stats.h"
#include "tools/report.h"
#include "tools/scene_views.h"
#include "tools/sharing_flags.h"
#include "tools/view_eval.h"

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
  // Cut criteria to sweep: "cosine" (Cut::cosine_weighted, the default), "plain" and/or
  // "lobe" (--mode glossy: ShadeOptions::lobe_cut, glossy's default).
  std::vector<std::string> cuts = {"cosine"};
  std::vector<std::string> footprints = {"polygons"};      // RasterOptions::footprint
  float curved_scale = 0.3f;                               // Cut::curved_scale
  float curved_box_scale = 1.0f;                           // Cut::curved_box_scale
  float radiance_contrast = kRecommendedRadianceContrast;  // ShadeOptions::radiance_contrast
  float lobe_min_weight = CutLobe{}.min_weight;            // CutLobe::min_weight (--cuts lobe)
  std::string memory = "auto";
  std::string cache = "auto";
  int threads = 0;
  uint64_t seed = 1;
  bool keep_hidden = false;  // database surfels inside solid geometry too (the old sampler)
  // A CSV of every receiver (position, normal, reference, PBGI of the default row): where the
  // error sits, receiver by receiver.
  std::string dump_receivers;
  int size = 0;                 // scene scale (city blocks, forest trees per side); 0: default
  std::string up = "z";         // a mesh file's up axis (y: glTF)
  std::string orient = "auto";  // a mesh file: auto | none (pbgi import --orient)
  LightFlags lights;            // a mesh file's lights (pbgi import --sun, --sky, --sky-rays)
  std::string receivers_from = "surfaces";  // or "camera": the default view's primary hits
  int64_t frame = 1920 * 1080;              // receivers that one database build serves
  int repeat = 1;  // time every setting this many times, keep the median (the results repeat)
  // --view: compare a camera view pixel by pixel instead (tools/view_eval.h).
  bool view = false;
  int width = 960, height = 540;
  std::string window;
  std::string db;  // --view --db
  std::string hitsides = "front";
  double error_scale = 0.1;
  // --view: shared rows besides the exact ones (tools/view_eval.h).
  bool exact = false, shared = false;
  std::vector<int> spacings = {8};
  std::vector<float> tolerances = {0.05f};
  float radius_factor = 0.5f;
  std::string sharing_layout = "image";
  // --view: far-field sharing rows (ShadeOptions::far_sharing), one per factor.
  FarSharingFlags far;
  std::vector<float> far_factors = {8.0f};
  bool far_only = false;
  // --mode glossy: the lobes to sweep, each with each of its parameters (one eval per setting).
  std::vector<std::string> lobes = {"phong", "ggx"};
  std::vector<float> phong_exponents = {32.0f};
  std::vector<float> ggx_roughnesses = {0.3f};
  // --convergence: the finer setting on a denser database, against the default row (issue 14's
  // goal: at most half the default's error; docs/eval.md, "Convergence").
  bool convergence = false;
  int density_factor = 4;
  float fine_solid_angle = 0.005f;
  std::vector<int> fine_resolutions = {12, 16, 24};
  float fine_curved_scale = 0.0f;  // 0: --curved-scale
};

// --convergence: issue 14's goal, the finer setting's MAE over the default's.
constexpr double kConvergenceGoal = 0.5;
// The most surfels --points takes (and --convergence's denser database).
constexpr int64_t kMaxPoints = int64_t{1} << 36;

// Whether a swept setting list (--solid-angles, --raster-res) holds x, as the rows name it.
template <class T>
bool SweepHas(const std::vector<T>& v, T x) {
  return std::any_of(v.begin(), v.end(),
                     [x](T y) { return static_cast<float>(std::abs(y - x)) < 1e-6f; });
}

struct Errors {
  double mae = 0, rmse = 0, max = 0;
  double bias = 0;          // mean signed error (PBGI - truth): > 0 over-occludes
  glm::dvec3 mae_rgb{0.0};  // per channel (occlusion: the same in all three)
  double relative = 0;      // mae over the truth's mean (0 when the mean is 0)
};

// The short name of a --cuts value in a row's setting and the chart's series.
const char* CutTag(const std::string& cut) {
  return cut == "cosine" ? "cos" : cut == "lobe" ? "lobe" : "plain";
}

// A receiver's value: occlusion in all three channels, or irradiance or glossy radiance per
// channel. The scalar errors are those of the mean of the channels.
double Scalar(const glm::dvec3& v) { return (v.x + v.y + v.z) / 3.0; }

Errors Compare(const std::vector<glm::dvec3>& got, const std::vector<glm::dvec3>& truth) {
  Errors e;
  double mean = 0;
  for (size_t i = 0; i < got.size(); ++i) {
    const double d = std::abs(Scalar(got[i]) - Scalar(truth[i]));
    e.bias += Scalar(got[i]) - Scalar(truth[i]);
    e.mae += d;
    e.rmse += d * d;
    e.max = std::max(e.max, d);
    e.mae_rgb += glm::abs(got[i] - truth[i]);
    mean += Scalar(truth[i]);
  }
  const double n = double(std::max<size_t>(1, got.size()));
  e.mae /= n;
  e.bias /= n;
  e.rmse = std::sqrt(e.rmse / n);
  e.mae_rgb /= n;
  mean /= n;
  e.relative = mean > 0 ? e.mae / mean : 0.0;
  return e;
}

enum class Method { kReference, kPbgi };
const char* MethodName(Method m) { return m == Method::kPbgi ? "pbgi" : "reference"; }

struct Row {
  Method method = Method::kReference;
  std::string setting;
  int rays = 0;  // reference rows: rays per receiver
  double seconds_per_receiver = 0;
  Errors err;
  double clusters = 0, surfels = 0;
  double gather_us = 0, raster_us = 0;  // PBGI rows: thread time per receiver in each stage
  double speedup = 0;         // PBGI rows: the reference's time at this MAE over this row's time
  bool extrapolated = false;  // the MAE lies outside the reference sweep's range of MAE
};

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

// The reference rows' rays, MAE and seconds per receiver, for ReferenceSecondsAt.
std::vector<SweepPoint> ReferenceSweep(const std::vector<Row>& rows) {
  std::vector<SweepPoint> sweep;
  for (const Row& r : rows) {
    if (r.method == Method::kReference) {
      sweep.push_back({r.rays, r.err.mae, r.seconds_per_receiver});
    }
  }
  return sweep;
}

// What one eval run works on: the scene, its database, the receivers and the converged truth.
struct EvalSetup {
  std::shared_ptr<const Scene> scene;
  std::unique_ptr<Tracer> tracer;
  std::string db_path;
  BuildStats build;
  double build_seconds = 0;  // sampling, baking (shadow rays) and the build
  std::vector<Receiver> receivers;
  // The same with their glossy lobes' centres (--mode glossy: see GlossyReflections).
  std::vector<ShadeReceiver> shade_receivers;
  std::vector<glm::dvec3> truth;  // the converged reference per receiver
  double truth_mean = 0;          // the mean over receivers of the truth's mean channel
  double truth_noise = 0;         // the truth's own MAE (two halves: HalvesMae)
  int truth_rays = 0;             // its rays: --rays, rounded up to an even count
  bool truth_ready = false;       // truth, truth_mean and truth_noise hold these receivers'
  int threads = 1;
  bool occlusion = true;
  bool glossy = false;
  GlossyParams lobe;  // --mode glossy: the current setting
};

// The short name of a glossy setting: "phong32", "ggx0.3".
std::string LobeTag(const GlossyParams& l) {
  return l.lobe == GlossyLobe::kPhong ? absl::StrFormat("phong%g", l.phong_exponent)
                                      : absl::StrFormat("ggx%g", l.ggx_roughness);
}

// The glossy lobes' centres: the mirror, about the receiver's normal, of the direction from the
// receiver to the eye of the scene's default camera (a viewer's reflection direction). A
// receiver that faces away from the eye takes the eye's mirror image in its tangent plane (the
// direction's component along the normal flipped), so that every lobe's centre lies above its
// receiver's horizon, as for a receiver the camera sees.
std::vector<ShadeReceiver> GlossyReceivers(const Scene& scene, const std::vector<Receiver>& in) {
  const glm::vec3 eye = DefaultCamera(scene, 960, 540).eye;
  std::vector<ShadeReceiver> out = ShadeReceiversOf(in);
  for (ShadeReceiver& r : out) {
    const glm::vec3 n = glm::normalize(r.normal);
    glm::vec3 v = eye - r.position;
    const float len = glm::length(v);
    if (!(len > 0.0f)) continue;  // at the eye: the lobe stays on the normal
    v /= len;
    const float vn = glm::dot(v, n);
    if (vn < 0.0f) v -= 2.0f * vn * n;
    r.reflection = glm::normalize(2.0f * glm::dot(v, n) * n - v);
  }
  return out;
}

// The database: what PBGI pays once per scene.
absl::Status BuildEvalDatabase(const EvalArgs& a, uint64_t memory, EvalSetup* e) {
  const internal::Stopwatch t;
  SamplerOptions sampler;
  sampler.count = a.points;
  sampler.seed = a.seed;
  sampler.bake = !e->occlusion;
  sampler.drop_hidden = !a.keep_hidden;
  PBGI_ASSIGN_OR_RETURN(auto surfels, MakeSceneSurfelSource(e->scene, sampler));
  e->db_path = a.out_dir + "/" + e->scene->name + ".pbgi";
  BuildOptions bo;
  bo.memory_bytes = memory;
  bo.channels = e->occlusion ? Channels::kOcclusion : Channels::kRadiance;
  bo.tmp_dir = a.out_dir;
  bo.provenance =
      SceneFingerprint(*e->scene, a.seed, a.size,
                       a.up == "y" || a.up == "Y" ? UpAxis::kY : UpAxis::kZ, a.orient != "none");
  bo.provenance["source"] = "pbgi eval";
  bo.provenance["tool"] = kToolVersion;
  bo.provenance["built_at"] = NowIso8601();
  Progress progress("eval: build", "points", a.points);
  std::string pass;
  bo.progress = [&](const BuildProgress& p) {
    if (pass != p.pass) {
      pass = p.pass;
      progress.Phase(absl::StrFormat("eval: build: %s", p.pass), p.points_total);
    }
    progress.Update(p.points_done, p.points_total);
  };
  PBGI_ASSIGN_OR_RETURN(e->build, BuildDatabase(*surfels, e->db_path, bo));
  progress.Finish(e->build.points);
  e->build_seconds = t.Seconds();
  std::fprintf(stderr, "eval: %s, %lld triangles placed; built %llu surfels in %.1f s\n",
               e->scene->name.c_str(), static_cast<long long>(e->scene->TriangleCount()),
               static_cast<unsigned long long>(e->build.points), e->build_seconds);
  return absl::OkStatus();
}

// Receivers: points on the scene's surfaces from an independent sample (or the default view's
// primary hits), lifted off the surface like a renderer's shading points.
absl::StatusOr<std::vector<Receiver>> MakeEvalReceivers(const EvalArgs& a, const EvalSetup& e) {
  std::vector<Receiver> receivers;
  const Tracer& tracer = *e.tracer;
  if (a.receivers_from == "camera") {
    // As a renderer has them: the primary hits of the scene's default view, on a grid of about
    // 4x the requested count, every k-th hit kept.
    const int h = std::max(1, static_cast<int>(std::sqrt(3.0 * double(a.receivers))));
    const int w = std::max(1, h * 4 / 3);
    const std::vector<CameraHit> hits = tracer.TraceCamera(DefaultCamera(*e.scene, 2 * w, 2 * h));
    std::vector<Receiver> all;
    for (const CameraHit& c : hits) {
      if (c.hit) all.push_back({c.position + tracer.epsilon() * c.normal, c.normal, c.sheet});
    }
    const size_t want = std::min(all.size(), static_cast<size_t>(a.receivers));
    for (size_t i = 0; i < want; ++i) receivers.push_back(all[i * all.size() / want]);
  } else {
    SamplerOptions rs;
    rs.count = a.receivers;
    rs.seed = a.seed + 7919;
    rs.bake = false;
    // The sampler drops samples inside solid geometry (the Cornell floor under a block, the city
    // ground under a building): no camera sees them, and the reference (which counts back
    // faces) and PBGI disagree there by construction. So the count is the request within 1%.
    rs.drop_hidden = true;
    // Anywhere on a triangle, as a renderer's shading points are: at the pieces' centres
    // (where the cloud's own surfels lie) they would never fall near an edge or a contact.
    rs.placement = SamplerOptions::Placement::kUniform;
    PBGI_ASSIGN_OR_RETURN(auto rsrc, MakeSceneSurfelSource(e.scene, rs));
    std::vector<Surfel> buf(4096);
    for (;;) {
      PBGI_ASSIGN_OR_RETURN(size_t got, rsrc->Next(absl::MakeSpan(buf)));
      if (got == 0) break;
      for (size_t i = 0; i < got; ++i) {
        receivers.push_back(
            {buf[i].position + tracer.epsilon() * buf[i].normal, buf[i].normal, buf[i].sheet});
      }
    }
  }
  if (receivers.empty()) return absl::FailedPreconditionError("no receivers");
  std::fprintf(stderr, "eval: %zu receivers from the %s\n", receivers.size(),
               a.receivers_from == "camera" ? "default camera's primary hits"
                                            : "visible surfaces (hidden samples dropped)");
  return receivers;
}

// Each receiver's value from the Embree reference (see Scalar).
std::vector<glm::dvec3> Reference(const EvalSetup& e, int rays, uint64_t seed) {
  std::vector<glm::dvec3> v(e.receivers.size());
  if (e.occlusion) {
    auto r = e.tracer->ReferenceOcclusion(e.receivers, rays, std::numeric_limits<float>::infinity(),
                                          seed);
    for (size_t i = 0; i < v.size(); ++i) v[i] = glm::dvec3(r[i]);
  } else if (e.glossy) {
    auto r = e.tracer->ReferenceGlossy(e.shade_receivers, e.lobe, rays, seed);
    for (size_t i = 0; i < v.size(); ++i) v[i] = glm::dvec3(r[i]);
  } else {
    auto r = e.tracer->ReferenceIrradiance(e.receivers, rays, seed);
    for (size_t i = 0; i < v.size(); ++i) v[i] = glm::dvec3(r[i]);
  }
  return v;
}

// The reference's sweep of ray counts, each timed a.repeat times (median).
// `step` is called after each timed run (for the progress of the sweeps).
std::vector<Row> ReferenceRows(const EvalArgs& a, const EvalSetup& e,
                               const std::function<void()>& step) {
  const double n = double(std::max<size_t>(1, e.receivers.size()));
  std::vector<Row> rows;
  for (int rays : a.ray_sweep) {
    std::vector<glm::dvec3> v;
    std::vector<double> times;
    for (int k = 0; k < a.repeat; ++k) {
      const internal::Stopwatch t;
      v = Reference(e, rays, a.seed + 2);
      times.push_back(t.Seconds() / n);
      step();
    }
    Row r;
    r.method = Method::kReference;
    r.setting = absl::StrFormat("%d rays", rays);
    r.rays = rays;
    r.seconds_per_receiver = Median(times);
    r.err = Compare(v, e.truth);
    rows.push_back(r);
  }
  return rows;
}

// `cut`: a --cuts value (cosine, plain, lobe: ShadeOptions::lobe_cut, glossy only).
ShadeOptions EvalShadeOptions(const EvalArgs& a, const EvalSetup& e, float msa, int res,
                              const std::string& cut) {
  ShadeOptions so;
  so.cut.curved_scale = a.curved_scale;
  so.cut.curved_box_scale = a.curved_box_scale;
  so.radiance_contrast = a.radiance_contrast;
  so.cut.lobe.min_weight = a.lobe_min_weight;
  so.raster.footprint = ParseFootprint(a.footprints.front());
  so.threads = e.threads;
  so.cut.max_solid_angle = msa;
  so.cut.cosine_weighted = cut == "cosine";
  so.lobe_cut = cut == "lobe";
  so.raster.resolution = res;
  so.raster.compute_radiance = !e.occlusion;
  if (e.glossy) {
    so.raster.lobe = e.lobe.lobe;
    so.raster.phong_exponent = e.lobe.phong_exponent;
    so.raster.ggx_roughness = e.lobe.ggx_roughness;
  }
  so.raster.hitsides = a.hitsides == "back"   ? HitSides::kBack
                       : a.hitsides == "both" ? HitSides::kBoth
                                              : HitSides::kFront;
  return so;
}

// Writes one CSV line per receiver: position, normal, the converged reference, `pbgi` (the
// mean of the three channels), and the receiver's sheet tag (0: none; pixel_error --sheet).
absl::Status DumpReceivers(const std::string& path, const EvalSetup& e,
                           const std::vector<glm::dvec3>& pbgi, const std::string& setting) {
  std::FILE* f = std::fopen(path.c_str(), "w");
  if (f == nullptr) return absl::InternalError(absl::StrFormat("cannot write %s", path));
  std::fprintf(f, "i,x,y,z,nx,ny,nz,reference,pbgi,error,sheet\n");
  for (size_t i = 0; i < e.receivers.size(); ++i) {
    const Receiver& r = e.receivers[i];
    const double t = (e.truth[i].x + e.truth[i].y + e.truth[i].z) / 3.0;
    const double p = (pbgi[i].x + pbgi[i].y + pbgi[i].z) / 3.0;
    std::fprintf(f, "%zu,%.9g,%.9g,%.9g,%.6g,%.6g,%.6g,%.6f,%.6f,%+.6f,%u\n", i, r.position.x,
                 r.position.y, r.position.z, r.normal.x, r.normal.y, r.normal.z, t, p, p - t,
                 static_cast<unsigned>(r.sheet));
  }
  const bool ok = std::fclose(f) == 0;
  if (!ok) return absl::InternalError(absl::StrFormat("cannot write %s", path));
  std::fprintf(stderr, "eval: wrote %s (every receiver at %s)\n", path.c_str(), setting.c_str());
  return absl::OkStatus();
}

// PBGI's sweep of cut, resolution and max_solid_angle, appended to `rows`; returns the index of
// the default row (the first of the default settings, or the first PBGI row when the sweep
// lacks the default).
absl::StatusOr<size_t> PbgiRows(const EvalArgs& a, const EvalSetup& e, Database& db,
                                const std::function<void()>& step, std::vector<Row>* rows) {
  const double n = double(std::max<size_t>(1, e.receivers.size()));
  const std::vector<ShadeReceiver>& shade_receivers = e.shade_receivers;
  // One untimed pass at the finest plain cut first (it touches every page the others do), so
  // that every timed row finds the pages decoded in the cache, as they are for all but the
  // first of a frame's receivers (the database is built for this run and fits the cache).
  {
    std::vector<ShadeResult> results(e.receivers.size());
    const float finest = *std::min_element(a.solid_angles.begin(), a.solid_angles.end());
    PBGI_RETURN_IF_ERROR(ShadeBatch(db, shade_receivers,
                                    EvalShadeOptions(a, e, finest, a.resolutions.front(), "plain"),
                                    absl::MakeSpan(results)));
    // The lobe cut reads deeper than the plain one in the lobe's core.
    if (std::find(a.cuts.begin(), a.cuts.end(), "lobe") != a.cuts.end()) {
      PBGI_RETURN_IF_ERROR(ShadeBatch(db, shade_receivers,
                                      EvalShadeOptions(a, e, finest, a.resolutions.front(), "lobe"),
                                      absl::MakeSpan(results)));
    }
  }
  size_t default_row = 0;
  bool found_default = false;
  // --dump-receivers: the default cut's receivers, or the first cut's when it is not swept.
  const std::string default_cut = e.glossy ? "lobe" : "cosine";
  const std::string dump_cut = std::find(a.cuts.begin(), a.cuts.end(), default_cut) != a.cuts.end()
                                   ? default_cut
                                   : a.cuts.front();
  // ... at the default msa and resolution, or the first ones swept when the default is not.
  const float dump_msa = SweepHas(a.solid_angles, 0.03f) ? 0.03f : a.solid_angles.front();
  const int dump_res = SweepHas(a.resolutions, 12) ? 12 : a.resolutions.front();
  for (const std::string& cut : a.cuts) {
    for (int res : a.resolutions) {
      for (float msa : a.solid_angles) {
        const ShadeOptions so = EvalShadeOptions(a, e, msa, res, cut);
        std::vector<ShadeResult> results(e.receivers.size());
        ShadeStats st;
        std::vector<double> times, gather, raster;
        for (int k = 0; k < a.repeat; ++k) {
          PBGI_RETURN_IF_ERROR(ShadeBatch(db, shade_receivers, so, absl::MakeSpan(results), &st));
          times.push_back(st.seconds / n);
          gather.push_back(st.gather_seconds / n * 1e6);
          raster.push_back(st.raster_seconds / n * 1e6);
          step();
        }
        std::vector<glm::dvec3> v(results.size());
        for (size_t i = 0; i < v.size(); ++i) {
          const ShadeResult& s = results[i];
          v[i] = e.occlusion ? glm::dvec3(s.occlusion)
                             : glm::dvec3(e.glossy ? s.glossy : s.irradiance);
        }
        Row r;
        r.method = Method::kPbgi;
        r.setting = absl::StrFormat("msa %.3g res %d %s", msa, res, CutTag(cut));
        r.seconds_per_receiver = Median(times);
        r.gather_us = Median(gather);
        r.raster_us = Median(raster);
        r.err = Compare(v, e.truth);
        r.clusters = double(st.query.clusters) / n;
        r.surfels = double(st.query.surfels) / n;
        rows->push_back(r);
        if (!a.dump_receivers.empty() && res == dump_res && std::abs(msa - dump_msa) < 1e-6f &&
            cut == dump_cut) {
          PBGI_RETURN_IF_ERROR(DumpReceivers(a.dump_receivers, e, v, r.setting));
        }
        // Glossy's default cut is the lobe-aware one (as `pbgi shade`'s: ShadeOptions::lobe_cut).
        const bool is_default =
            res == 12 && std::abs(msa - 0.03f) < 1e-6f && cut == (e.glossy ? "lobe" : "cosine");
        if (!found_default && (is_default || (*rows)[default_row].method != Method::kPbgi)) {
          default_row = rows->size() - 1;
          found_default = is_default;
        }
      }
    }
  }
  return default_row;
}

// The speed of every PBGI row at equal error, on the reference's log-log curve, and the summary.
struct EvalSummary {
  size_t default_row = 0, best_row = 0;
  double ratio = 0;             // the default row's speedup
  double ratio_with_build = 0;  // the same with the build shared by a frame of receivers
  // The exponent k of time ~ MAE^-k where a row's ratio is extrapolated below the sweep's
  // errors (0: no row is), and whether it is the sweep's (SweepReading::from_sweep).
  double exponent_below = 0;
  bool below_from_sweep = false;
  bool above = false;  // a row's ratio is extrapolated above them (the Monte Carlo law)
};

EvalSummary Summarize(const EvalArgs& a, const EvalSetup& e, size_t default_row,
                      std::vector<Row>* rows) {
  EvalSummary s;
  s.default_row = s.best_row = default_row;
  const std::vector<SweepPoint> sweep = ReferenceSweep(*rows);
  for (size_t i = 0; i < rows->size(); ++i) {
    Row& r = (*rows)[i];
    if (r.method != Method::kPbgi) continue;
    SweepReading reading;
    r.speedup =
        ReferenceSecondsAt(sweep, r.err.mae, &reading) / std::max(1e-12, r.seconds_per_receiver);
    r.extrapolated = reading.extrapolated;
    if (reading.below) {
      s.exponent_below = reading.exponent;
      s.below_from_sweep = reading.from_sweep;
    } else if (reading.extrapolated) {
      s.above = true;
    }
    if (r.speedup > (*rows)[s.best_row].speedup) s.best_row = i;
  }
  const Row& def = (*rows)[default_row];
  s.ratio = def.speedup;
  const double amortized = e.build_seconds / double(std::max<int64_t>(1, a.frame));
  s.ratio_with_build = ReferenceSecondsAt(sweep, def.err.mae) /
                       std::max(1e-12, def.seconds_per_receiver + amortized);
  return s;
}

std::string RatioText(const Row& r) {
  return absl::StrFormat("%.3gx%s", r.speedup, r.extrapolated ? "*" : "");
}

void PrintEval(const EvalArgs& a, const EvalSetup& e, const std::vector<Row>& rows,
               const EvalSummary& s) {
  std::printf(
      "pbgi eval: scene %s, %s%s, %llu surfels, %zu receivers, %d threads, truth = %d "
      "rays (its own MAE %.2g, from two halves, mean %.5g), times = median of %d\n",
      e.scene->name.c_str(), a.mode.c_str(),
      e.glossy ? absl::StrFormat(" %s", LobeTag(e.lobe)).c_str() : "",
      static_cast<unsigned long long>(e.build.points), e.receivers.size(), e.threads, e.truth_rays,
      e.truth_noise, e.truth_mean, a.repeat);
  // "rel" (MAE over the truth's mean) last: scripts read the columns before it by position.
  std::printf("%-10s %-20s %12s %10s %10s %10s %10s %9s %9s %9s %9s %9s %8s\n", "method", "setting",
              "us/receiver", "MAE", "bias", "RMSE", "max", "clusters", "surfels", "gather_us",
              "raster_us", "speedup", "rel");
  for (const Row& r : rows) {
    const bool pbgi = r.method == Method::kPbgi;
    std::printf("%-10s %-20s %12.2f %10.5f %+10.5f %10.5f %10.5f %9s %9s %9s %9s %9s %7.2f%%\n",
                MethodName(r.method), r.setting.c_str(), r.seconds_per_receiver * 1e6, r.err.mae,
                r.err.bias, r.err.rmse, r.err.max,
                pbgi ? absl::StrFormat("%.1f", r.clusters).c_str() : "",
                pbgi ? absl::StrFormat("%.1f", r.surfels).c_str() : "",
                pbgi ? absl::StrFormat("%.1f", r.gather_us).c_str() : "",
                pbgi ? absl::StrFormat("%.1f", r.raster_us).c_str() : "",
                pbgi ? RatioText(r).c_str() : "", 100.0 * r.err.relative);
  }
  std::printf(
      "(us/receiver: wall time over %d threads; gather_us, raster_us: thread time per receiver "
      "in Gather and Shade)\n",
      e.threads);
  if (s.exponent_below > 0) {
    std::printf(
        "* the MAE lies below the reference sweep's: the reference's time there is extrapolated "
        "by time ~ MAE^-%.2f, %s (widen --ray-sweep to measure it)\n",
        s.exponent_below,
        s.below_from_sweep
            ? "the error's fall with the rays over the sweep's last segment, kept within [1, 2]"
            : "the Monte Carlo law (the sweep gives no slope)");
  }
  if (s.above) {
    std::printf(
        "* the MAE lies above the reference sweep's: the reference's time there is extrapolated "
        "by the Monte Carlo law, time ~ MAE^-2 (widen --ray-sweep to measure it)\n");
  }
  for (const Row& r : rows) {
    if (r.method == Method::kPbgi && r.err.mae < 2.0 * e.truth_noise) {
      std::printf(
          "note: PBGI MAE %.3g (%s) is within 2x of the truth's own error ~%.2g: raise --rays\n",
          r.err.mae, r.setting.c_str(), e.truth_noise);
    }
  }
  const Row& def = rows[s.default_row];
  const Row& best = rows[s.best_row];
  if (!e.occlusion) {
    std::printf(
        "default (%s): MAE per channel %.5f %.5f %.5f, relative MAE %.2f%% of the mean %s "
        "%.5g\n",
        def.setting.c_str(), def.err.mae_rgb.x, def.err.mae_rgb.y, def.err.mae_rgb.z,
        100.0 * def.err.relative, e.glossy ? "glossy radiance" : "irradiance", e.truth_mean);
  }
  if (s.ratio > 0) {
    std::printf(
        "default (%s): MAE %.5f at %.2f us/receiver; the reference needs %.3gx that time for the "
        "same MAE\n",
        def.setting.c_str(), def.err.mae, def.seconds_per_receiver * 1e6, s.ratio);
    std::printf(
        "PBGI vs reference at equal error: %s at the default, best %s (%s, MAE %.5f); "
        "with the database build (%.1f s) shared by %lld receivers: %.3gx\n",
        RatioText(def).c_str(), RatioText(best).c_str(), best.setting.c_str(), best.err.mae,
        e.build_seconds, static_cast<long long>(a.frame), s.ratio_with_build);
  } else {
    std::printf(
        "default (%s): MAE %.5f at %.2f us/receiver; the reference is exact here at every ray "
        "count (e.g. a closed box), so no ratio\n",
        def.setting.c_str(), def.err.mae, def.seconds_per_receiver * 1e6);
  }
}

Json EvalJson(const EvalArgs& a, const EvalSetup& e, const std::vector<Row>& rows,
              const EvalSummary& s) {
  const Row& def = rows[s.default_row];
  const Row& best = rows[s.best_row];
  Json j;
  j["scene"] = e.scene->name;
  j["mode"] = a.mode;
  j["points"] = e.build.points;
  j["receivers"] = e.receivers.size();
  j["threads"] = e.threads;
  j["truth_rays"] = e.truth_rays;
  j["default_mae"] = def.err.mae;
  j["speedup_at_equal_error"] = s.ratio;
  j["default_setting"] = def.setting;
  j["best_speedup"] = best.speedup;
  j["best_setting"] = best.setting;
  j["build_seconds"] = e.build_seconds;
  j["frame_receivers"] = a.frame;
  j["speedup_with_build"] = s.ratio_with_build;
  j["receivers_from"] = a.receivers_from;
  j["size"] = a.size;
  j["triangles"] = e.scene->TriangleCount();
  j["repeat"] = a.repeat;
  j["truth_noise_mae"] = e.truth_noise;
  // k of time ~ MAE^-k for rows below the sweep's errors (0: none is).
  j["reference_exponent_below_sweep"] = s.exponent_below;
  j["default_extrapolated"] = def.extrapolated;
  j["truth_mean"] = e.truth_mean;
  j["default_relative_mae"] = def.err.relative;
  j["default_mae_rgb"] = {def.err.mae_rgb.x, def.err.mae_rgb.y, def.err.mae_rgb.z};
  if (e.glossy) {
    j["lobe"] = e.lobe.lobe == GlossyLobe::kPhong ? "phong" : "ggx";
    if (e.lobe.lobe == GlossyLobe::kPhong) {
      j["phong_exponent"] = e.lobe.phong_exponent;
    } else {
      j["ggx_roughness"] = e.lobe.ggx_roughness;
    }
    j["reflection"] = "mirror of the direction to the default camera's eye";
  }
  j["rows"] = Json::array();
  for (const Row& r : rows) {
    Json row;
    row["method"] = MethodName(r.method);
    row["setting"] = r.setting;
    row["seconds_per_receiver"] = r.seconds_per_receiver;
    row["mae"] = r.err.mae;
    row["bias"] = r.err.bias;
    row["rmse"] = r.err.rmse;
    row["max"] = r.err.max;
    row["clusters"] = r.clusters;
    row["surfels"] = r.surfels;
    row["gather_us"] = r.gather_us;
    row["raster_us"] = r.raster_us;
    row["speedup"] = r.speedup;
    row["extrapolated"] = r.extrapolated;
    row["relative_mae"] = r.err.relative;
    row["mae_rgb"] = {r.err.mae_rgb.x, r.err.mae_rgb.y, r.err.mae_rgb.z};
    j["rows"].push_back(row);
  }
  return j;
}

absl::Status WriteJsonFile(const std::string& path, const Json& j) {
  std::ofstream js(path);
  js << DumpJson(j);
  if (!js.good()) return absl::UnavailableError(absl::StrFormat("cannot write %s", path));
  return absl::OkStatus();
}

// Log-log chart of error against time per receiver: the reference's ray sweep, then PBGI by
// raster resolution and cut (one line over the max_solid_angle sweep each), the default ringed.
absl::Status WriteEvalChart(const std::string& path, const EvalArgs& a, const EvalSetup& e,
                            const std::vector<Row>& rows, const EvalSummary& summary) {
  std::vector<ChartSeries> series;
  ChartSeries ref{"Embree reference (rays)", glm::vec3(0.15f, 0.35f, 0.8f), true, {}, {}, {}};
  for (const Row& r : rows) {
    if (r.method == Method::kReference) {
      ref.x.push_back(r.err.mae), ref.y.push_back(r.seconds_per_receiver);
      ref.labels.push_back(r.setting);
    }
  }
  series.push_back(ref);
  const glm::vec3 colors[] = {
      {0.95f, 0.55f, 0.1f}, {0.85f, 0.2f, 0.2f}, {0.2f, 0.65f, 0.3f}, {0.5f, 0.3f, 0.7f}};
  size_t color = 0;
  for (const std::string& cut : a.cuts) {
    for (int res : a.resolutions) {
      const std::string tag = absl::StrFormat("res %d %s", res, CutTag(cut));
      ChartSeries s{absl::StrFormat("PBGI raster %d, %s cut", res, cut),
                    colors[color++ % 4],
                    true,
                    {},
                    {},
                    {}};
      for (const Row& r : rows) {
        if (r.method == Method::kPbgi && absl::EndsWith(r.setting, tag)) {
          s.x.push_back(r.err.mae), s.y.push_back(r.seconds_per_receiver);
          // "msa 0.03 res 12 cos": the point's label is its max solid angle.
          s.labels.push_back(r.setting.substr(0, r.setting.find(" res")));
        }
      }
      series.push_back(s);
    }
  }
  ChartOptions o;
  o.title =
      absl::StrFormat("%s, %s%s: error against time (%zu receivers, %d threads)", e.scene->name,
                      a.mode, e.glossy ? absl::StrFormat(" %s", LobeTag(e.lobe)) : std::string(),
                      e.receivers.size(), e.threads);
  o.legend_title = "labels: rays, max solid angle (sr)";
  o.x_label = absl::StrFormat("mean absolute error of %s against %d rays (log scale)",
                              e.occlusion ? "occlusion"
                              : e.glossy  ? "glossy radiance"
                                          : "irradiance",
                              e.truth_rays);
  o.y_label = "wall time per receiver, seconds (log scale)";
  const Row& def = rows[summary.default_row];
  if (def.method == Method::kPbgi) {
    o.highlight = ChartPoint{def.err.mae, def.seconds_per_receiver,
                             absl::StrFormat("default: %s", def.setting)};
  }
  return WriteLogLogChart(path, series, o);
}

// --memory (the build's cap) and --cache of both eval modes (tools/budget.h).
absl::StatusOr<std::pair<uint64_t, uint64_t>> EvalBudgets(const EvalArgs& a) {
  PBGI_ASSIGN_OR_RETURN(uint64_t memory,
                        ResolveBudget("eval", "--memory", a.memory, uint64_t{512} << 20,
                                      MinimumBuildMemory(BuildOptions{}),
                                      "fixed buffers, one write batch and the smallest sort run"));
  PBGI_ASSIGN_OR_RETURN(
      uint64_t cache, ResolveBudget("eval", "--cache", a.cache, uint64_t{256} << 20, kMinCacheBytes,
                                    "a few pages per thread"));
  return std::make_pair(memory, cache);
}

// The truth of EvalOneSetting: the mean of two independent halves of the rays, and its own error
// measured from their difference (tools/reference_stats.h HalvesMae).
absl::Status ComputeTruth(const EvalArgs& a, EvalSetup& e) {
  const internal::Stopwatch t;
  const int half = std::max(1, (a.truth_rays + 1) / 2);
  const std::vector<glm::dvec3> first = Reference(e, half, a.seed + 1);
  const std::vector<glm::dvec3> second = Reference(e, half, a.seed + 3);
  e.truth.resize(first.size());
  std::vector<double> first_scalar(first.size()), second_scalar(first.size());
  for (size_t i = 0; i < first.size(); ++i) {
    e.truth[i] = 0.5 * (first[i] + second[i]);
    first_scalar[i] = Scalar(first[i]);
    second_scalar[i] = Scalar(second[i]);
  }
  e.truth_noise = HalvesMae(first_scalar, second_scalar);
  e.truth_rays = 2 * half;
  e.truth_mean = 0;
  for (const glm::dvec3& v : e.truth) e.truth_mean += Scalar(v);
  e.truth_mean /= double(std::max<size_t>(1, e.truth.size()));
  std::fprintf(stderr,
               "eval: converged reference%s, 2 x %d rays x %zu receivers, its own MAE %.2g, "
               "%.1f s\n",
               e.glossy ? absl::StrFormat(" (%s)", LobeTag(e.lobe)).c_str() : "", half,
               e.receivers.size(), e.truth_noise, t.Seconds());
  e.truth_ready = true;
  return absl::OkStatus();
}

// The truth, both sweeps and the outputs for the setup's current mode (and lobe); returns the
// JSON it wrote to `stem`.json (beside `stem`.png). A truth already computed for these receivers
// is kept: --convergence's finer setting is measured against the same one.
absl::StatusOr<Json> EvalOneSetting(const EvalArgs& a, uint64_t cache, const std::string& stem,
                                    EvalSetup& e) {
  if (!e.truth_ready) PBGI_RETURN_IF_ERROR(ComputeTruth(a, e));

  Progress sweeps(
      "eval: sweeps", "timed runs",
      int64_t(a.repeat) * int64_t(a.ray_sweep.size() +
                                  a.cuts.size() * a.resolutions.size() * a.solid_angles.size()));
  uint64_t runs = 0;
  const std::function<void()> step = [&] { sweeps.Update(++runs); };
  std::vector<Row> rows = ReferenceRows(a, e, step);
  DatabaseOptions dbo;
  dbo.cache_bytes = cache;
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<Database> db, Database::Open(e.db_path, dbo));
  PBGI_ASSIGN_OR_RETURN(size_t default_row, PbgiRows(a, e, *db, step, &rows));
  sweeps.Finish(runs);
  const EvalSummary summary = Summarize(a, e, default_row, &rows);
  PrintEval(a, e, rows, summary);

  const Json j = EvalJson(a, e, rows, summary);
  const std::string json_path = stem + ".json";
  PBGI_RETURN_IF_ERROR(WriteJsonFile(json_path, j));
  const std::string chart_path = stem + ".png";
  PBGI_RETURN_IF_ERROR(WriteEvalChart(chart_path, a, e, rows, summary));
  std::printf(
      "wrote %s and %s (log-log chart of MAE against seconds per receiver: the reference, "
      "then PBGI by raster resolution %s and cut %s, the default ringed)\n",
      json_path.c_str(), chart_path.c_str(), absl::StrJoin(a.resolutions, ", ").c_str(),
      absl::StrJoin(a.cuts, ", ").c_str());
  return j;
}

// --mode glossy: every lobe with each of its parameters, in the order given.
std::vector<GlossyParams> GlossySettings(const EvalArgs& a) {
  std::vector<GlossyParams> out;
  for (const std::string& lobe : a.lobes) {
    if (lobe == "phong") {
      for (float e : a.phong_exponents) out.push_back({GlossyLobe::kPhong, e, 0.2f});
    } else {
      for (float r : a.ggx_roughnesses) out.push_back({GlossyLobe::kGgx, 32.0f, r});
    }
  }
  return out;
}

// --convergence: a database of density_factor x --points, shaded at the finer setting (one
// row per fine resolution) against the same receivers and truth; each row's MAE over the
// default row's (`base`). Prints the ratios and writes convergence.json beside eval.json.
absl::Status EvalConvergence(const EvalArgs& a, uint64_t memory, uint64_t cache, const Json& base,
                             EvalSetup& e) {
  EvalArgs f = a;
  f.points = a.points * a.density_factor;
  f.solid_angles = {a.fine_solid_angle};
  f.resolutions = a.fine_resolutions;
  f.cuts = {"cosine"};
  if (a.fine_curved_scale > 0.0f) f.curved_scale = a.fine_curved_scale;
  f.out_dir = a.out_dir + "/finer";
  if (!a.dump_receivers.empty()) {
    const std::string& d = a.dump_receivers;
    f.dump_receivers =
        (absl::EndsWithIgnoreCase(d, ".csv") ? d.substr(0, d.size() - 4) : d) + ".finer.csv";
  }
  std::error_code ec;
  std::filesystem::create_directories(f.out_dir, ec);
  if (ec) return absl::UnavailableError(absl::StrFormat("cannot create %s", f.out_dir));
  std::fprintf(stderr, "eval --convergence: the finer setting, %lld surfels, msa %g, res %s\n",
               static_cast<long long>(f.points), f.fine_solid_angle,
               absl::StrJoin(f.resolutions, " ").c_str());
  PBGI_RETURN_IF_ERROR(BuildEvalDatabase(f, memory, &e));
  PBGI_ASSIGN_OR_RETURN(const Json fine, EvalOneSetting(f, cache, f.out_dir + "/eval", e));

  const double def_mae = base["default_mae"].get<double>();
  const std::string def_setting = base["default_setting"].get<std::string>();
  Json j;
  j["scene"] = e.scene->name;
  j["mode"] = a.mode;
  j["receivers"] = e.receivers.size();
  j["truth_rays"] = e.truth_rays;
  j["truth_noise_mae"] = e.truth_noise;
  j["default_points"] = base["points"];
  j["default_setting"] = def_setting;
  j["default_curved_scale"] = std::stod(absl::StrFormat("%g", a.curved_scale));
  j["default_mae"] = def_mae;
  j["finer_points"] = fine["points"];
  // As typed (a float's nearest double prints 0.004999999888).
  j["finer_solid_angle"] = std::stod(absl::StrFormat("%g", f.fine_solid_angle));
  j["finer_curved_scale"] = std::stod(absl::StrFormat("%g", f.curved_scale));
  j["goal_ratio"] = kConvergenceGoal;
  j["rows"] = Json::array();
  std::printf("convergence (%s, %zu receivers, truth %d rays, its own MAE %.2g):\n",
              e.scene->name.c_str(), e.receivers.size(), e.truth_rays, e.truth_noise);
  std::printf("  default  %10lld surfels, %-32s MAE %.5f\n",
              static_cast<long long>(base["points"].get<uint64_t>()), def_setting.c_str(), def_mae);
  double best = std::numeric_limits<double>::infinity();
  std::string best_setting;
  for (const Json& r : fine["rows"]) {
    if (r["method"].get<std::string>() != "pbgi") continue;
    const double mae = r["mae"].get<double>();
    const double ratio = def_mae > 0.0 ? mae / def_mae : std::numeric_limits<double>::infinity();
    const std::string setting =
        absl::StrFormat("%s curved %g", r["setting"].get<std::string>(), f.curved_scale);
    std::printf("  finer    %10lld surfels, %-32s MAE %.5f (bias %+.5f)  x%.4f  %.1f us/receiver\n",
                static_cast<long long>(fine["points"].get<uint64_t>()), setting.c_str(), mae,
                r["bias"].get<double>(), ratio, 1e6 * r["seconds_per_receiver"].get<double>());
    Json row;
    row["setting"] = setting;
    row["mae"] = mae;
    row["bias"] = r["bias"];
    row["ratio"] = ratio;
    row["seconds_per_receiver"] = r["seconds_per_receiver"];
    row["clusters"] = r["clusters"];
    row["surfels"] = r["surfels"];
    j["rows"].push_back(row);
    if (ratio < best) best = ratio, best_setting = setting;
  }
  const bool met = best <= kConvergenceGoal;
  j["best_ratio"] = best;
  j["best_setting"] = best_setting;
  j["met"] = met;
  std::printf("  best: x%.4f (%s): the goal, at most x%.1f, is %s\n", best, best_setting.c_str(),
              kConvergenceGoal, met ? "met" : "not met");
  const std::string path = a.out_dir + "/convergence.json";
  PBGI_RETURN_IF_ERROR(WriteJsonFile(path, j));
  std::printf("wrote %s\n", path.c_str());
  return absl::OkStatus();
}

absl::Status RunEval(const EvalArgs& a) {
  PBGI_RETURN_IF_ERROR(CheckOutsideStores(a.out_dir));
  EvalSetup e;
  e.occlusion = a.mode == "occlusion";
  e.glossy = a.mode == "glossy";
  std::vector<GlossyParams> lobes;
  if (e.glossy) {
    lobes = GlossySettings(a);
    if (lobes.empty()) {
      return absl::InvalidArgumentError(
          "eval --mode glossy: no lobe to evaluate (--lobes, --phong-exponents, "
          "--ggx-roughnesses are empty)");
    }
    for (const GlossyParams& l : lobes) {
      RasterOptions ro;
      ro.lobe = l.lobe;
      ro.phong_exponent = l.phong_exponent;
      ro.ggx_roughness = l.ggx_roughness;
      PBGI_RETURN_IF_ERROR(ValidateRasterOptions(ro));
    }
  }
  PBGI_ASSIGN_OR_RETURN(const auto budgets, EvalBudgets(a));
  const auto [memory, cache] = budgets;
  std::error_code ec;
  std::filesystem::create_directories(a.out_dir, ec);
  if (ec) return absl::UnavailableError(absl::StrFormat("cannot create %s", a.out_dir));
  e.threads = ResolveThreads(a.threads);
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, e.threads);

  PBGI_ASSIGN_OR_RETURN(const UpAxis up, ParseUpAxis(a.up));
  PBGI_ASSIGN_OR_RETURN(const bool orient, ParseOrient(a.orient));
  ImportReport import;
  PBGI_ASSIGN_OR_RETURN(
      e.scene, LoadLitScene(a.scene, a.seed, a.size, up, orient, a.lights, "pbgi eval", &import));
  if (import.oriented) {
    std::printf("%s: orientation: %s\n", a.scene.c_str(),
                DescribeOrientation(import.orientation).c_str());
  }
  if (!e.occlusion && !e.scene->has_radiance) {
    return absl::FailedPreconditionError(
        absl::StrFormat("scene %s has no radiance: use --mode occlusion", e.scene->name));
  }
  PBGI_RETURN_IF_ERROR(BuildEvalDatabase(a, memory, &e));
  PBGI_ASSIGN_OR_RETURN(e.tracer, Tracer::Create(*e.scene));
  PBGI_ASSIGN_OR_RETURN(e.receivers, MakeEvalReceivers(a, e));
  e.shade_receivers =
      e.glossy ? GlossyReceivers(*e.scene, e.receivers) : ShadeReceiversOf(e.receivers);
  if (!e.glossy) {
    PBGI_ASSIGN_OR_RETURN(const Json base, EvalOneSetting(a, cache, a.out_dir + "/eval", e));
    if (!a.convergence) return absl::OkStatus();
    return EvalConvergence(a, memory, cache, base, e);
  }
  // One eval per lobe setting (eval-<lobe>.json, .png), and eval.json with all of them.
  Json all;
  all["scene"] = e.scene->name;
  all["mode"] = a.mode;
  all["lobes"] = Json::array();
  std::vector<std::string> lines;
  for (const GlossyParams& l : lobes) {
    e.lobe = l;
    e.truth_ready = false;  // each lobe has its own truth
    PBGI_ASSIGN_OR_RETURN(Json j, EvalOneSetting(a, cache, a.out_dir + "/eval-" + LobeTag(l), e));
    lines.push_back(absl::StrFormat(
        "  %-10s default %s: MAE %.5f = %.2f%% of the mean %.5g", LobeTag(l),
        j["default_setting"].get<std::string>(), j["default_mae"].get<double>(),
        100.0 * j["default_relative_mae"].get<double>(), j["truth_mean"].get<double>()));
    all["lobes"].push_back(std::move(j));
  }
  std::printf("glossy summary (%s, %zu receivers):\n%s\n", e.scene->name.c_str(),
              e.receivers.size(), absl::StrJoin(lines, "\n").c_str());
  const std::string json_path = a.out_dir + "/eval.json";
  PBGI_RETURN_IF_ERROR(WriteJsonFile(json_path, all));
  std::printf("wrote %s (every lobe's eval)\n", json_path.c_str());
  return absl::OkStatus();
}

CommandSetup Setup() {
  return [](CLI::App* app) -> std::function<absl::Status()> {
    auto a = std::make_shared<EvalArgs>();
    app->add_option("scene", a->scene, "Procedural scene or mesh file")->capture_default_str();
    AddMeshFlags(app, &a->up, &a->orient);
    AddLightFlags(
        app, &a->lights,
        " (a mesh file: neither gives a white sky; a procedural scene: replaces its own)");
    app->add_option("-o,--output", a->out_dir, "Output directory (database, eval.json, eval.png)")
        ->capture_default_str();
    app->add_option("--mode", a->mode,
                    "occlusion, irradiance or glossy (the lobes of --lobes around the mirror of "
                    "the direction to the default camera's eye)")
        ->check(CLI::IsMember({"occlusion", "irradiance", "glossy"}))
        ->capture_default_str();
    app->add_option("--lobes", a->lobes, "--mode glossy: phong and/or ggx (pbgi/raster.h)")
        ->check(CLI::IsMember({"phong", "ggx"}))
        ->capture_default_str();
    app->add_option("--phong-exponents", a->phong_exponents,
                    "--mode glossy: Phong exponents, one eval each")
        ->capture_default_str();
    app->add_option("--ggx-roughnesses", a->ggx_roughnesses,
                    "--mode glossy: GGX roughnesses (alpha), one eval each")
        ->capture_default_str();
    app->add_option("--points", a->points, "Surfels in the database (e.g. 500k, 1M)")
        ->transform(CountValidator(1, kMaxPoints))
        ->capture_default_str();
    app->add_option("--receivers", a->receivers, "Receivers compared with the reference (e.g. 1k)")
        ->transform(CountValidator(1, int64_t{1} << 24))
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
    app->add_option("--cuts", a->cuts,
                    "Cut criteria to sweep: cosine (solid angle weighted by the cosine to the "
                    "normal, the default), plain, and/or lobe (--mode glossy: weighted by the "
                    "glossy lobe, Cut::lobe; glossy's default)")
        ->check(CLI::IsMember({"cosine", "plain", "lobe"}))
        ->capture_default_str();
    app->add_option("--footprints", a->footprints,
                    "How elements cover the micro-buffer: splats and/or polygons (tiling "
                    "footprints, see pbgi/raster.h); --view sweeps them, the receiver sweep "
                    "takes the first")
        ->check(CLI::IsMember({"splats", "polygons"}))
        ->capture_default_str();
    app->add_option("--lobe-min-weight", a->lobe_min_weight,
                    "--cuts lobe: CutLobe::min_weight, the smallest lobe weight (1: never coarser "
                    "than the plain cut)")
        ->check(CLI::Range(1e-3, 1e3))
        ->capture_default_str();
    app->add_option("--curved-scale", a->curved_scale,
                    "Cut::curved_scale: curved nodes are taken whole only below this times the "
                    "max solid angle")
        ->check(CLI::Range(1e-3f, 1.0f))
        ->capture_default_str();
    app->add_option("--curved-box-scale", a->curved_box_scale,
                    "Cut::curved_box_scale: curved nodes are taken whole only when their box, "
                    "too, subtends below this times the max solid angle (0: off)")
        ->check(CLI::Range(0.0f, 1e3f))
        ->capture_default_str();
    AddRadianceContrastFlag(app, &a->radiance_contrast);
    app->add_option("--memory", a->memory, "Memory cap of the build, with a unit (512M), or auto")
        ->check(BudgetValidator())
        ->capture_default_str();
    app->add_option("--cache", a->cache, "Page cache of shading, with a unit (256M), or auto")
        ->check(BudgetValidator())
        ->capture_default_str();
    app->add_option("--threads", a->threads, "Threads (0: all cores)")
        ->check(CLI::Range(0, 1024))
        ->capture_default_str();
    app->add_option("--seed", a->seed, "Seed of the scene, its sampling and the receivers")
        ->capture_default_str();
    app->add_option("--size", a->size,
                    "Scene scale: city blocks or forest trees per side (0: default)")
        ->capture_default_str();
    app->add_option("--receivers-from", a->receivers_from,
                    "surfaces (samples on the visible surfaces) or camera (the default view's "
                    "primary hits, as a renderer has them)")
        ->check(CLI::IsMember({"surfaces", "camera"}))
        ->capture_default_str();
    app->add_option("--frame", a->frame,
                    "Receivers that one database build serves, for the ratio with the build")
        ->transform(CountValidator(1, int64_t{1} << 40))
        ->capture_default_str();
    app->add_option("--repeat", a->repeat,
                    "Time every setting this many times and report the median")
        ->check(CLI::Range(1, 100))
        ->capture_default_str();
    app->add_option("--dump-receivers", a->dump_receivers,
                    "A CSV of every receiver at the default setting (msa 0.03, res 12), or at the "
                    "first msa and resolution swept when those are not: position, normal, "
                    "reference, PBGI, error (and for receiver sets, the sheet tag); with "
                    "--convergence also NAME.finer.csv, at the finer setting's first resolution");
    app->add_flag("--keep-hidden", a->keep_hidden,
                  "Keep database surfels inside solid geometry (receivers never are)");
    app->add_flag("--view", a->view,
                  "Compare the scene's default camera view pixel by pixel: reference, PBGI and "
                  "signed error images, MAE, RMSE, bias, 99th percentile, worst 8x8 tile "
                  "(defaults then: 4M points, msa 0.03, res 12, cosine cut, 4096 rays)");
    app->add_option("--width", a->width, "--view: image width")
        ->check(CLI::Range(16, 8192))
        ->capture_default_str();
    app->add_option("--db", a->db,
                    "--view: shade this database, built from the same scene and seed (e.g. by "
                    "pbgi demo), instead of building one from --points");
    app->add_option("--window", a->window,
                    "--view: shade and compare only the pixels of this window, X,Y,WIDTH,HEIGHT "
                    "(to look at one artifact closely; the images keep the view's size)");
    app->add_option("--height", a->height, "--view: image height")
        ->check(CLI::Range(16, 8192))
        ->capture_default_str();
    app->add_option("--hitsides", a->hitsides,
                    "sides of one-sided surfels that occlude and emit: front, back or both "
                    "(two-sided surfels show both; the reference counts any side)")
        ->check(CLI::IsMember({"front", "back", "both"}))
        ->capture_default_str();
    app->add_option("--error-scale", a->error_scale,
                    "--view: |error| at which the heat map saturates (relative to the mean "
                    "irradiance in irradiance mode)")
        ->capture_default_str();
    app->add_flag("--exact", a->exact,
                  "--view: only the per-receiver rows (no shared rows, ShadeMode::kShared)");
    app->add_flag("--shared", a->shared, "--view: only the shared rows");
    app->add_option("--spacings", a->spacings,
                    "--view: sparse-set spacings of the shared rows (powers of two)")
        ->check(CLI::IsMember({2, 4, 8, 16, 32, 64}))
        ->capture_default_str();
    app->add_option("--tolerances", a->tolerances,
                    "--view: sharing tolerances of the shared rows (SharingOptions::tolerance)")
        ->capture_default_str();
    app->add_option("--radius-factor", a->radius_factor,
                    "--view: SharingOptions::radius_factor of the shared rows")
        ->capture_default_str();
    AddFarSharingFlags(app, &a->far);
    app->add_option("--far-factors", a->far_factors,
                    "--view --far-sharing: the distance factors of the far-sharing rows")
        ->capture_default_str();
    app->add_flag("--far-only", a->far_only, "--view --far-sharing: only the far-sharing rows");
    app->add_flag("--convergence", a->convergence,
                  "Also build a database of --density-factor times --points and shade the same "
                  "receivers at the finer setting (--fine-solid-angle, each --fine-raster-res); "
                  "report each one's MAE over the default setting's (the goal: at most half) "
                  "and write convergence.json (occlusion and irradiance)");
    app->add_option("--density-factor", a->density_factor,
                    "--convergence: surfels of the finer setting's database over --points")
        ->check(CLI::Range(1, 64))
        ->capture_default_str();
    app->add_option("--fine-solid-angle", a->fine_solid_angle,
                    "--convergence: the finer setting's max_solid_angle")
        ->check(CLI::Range(1e-5, 10.0))
        ->capture_default_str();
    app->add_option("--fine-raster-res", a->fine_resolutions,
                    "--convergence: the finer setting's raster resolutions, one row each")
        ->check(CLI::Range(4, 64))
        ->capture_default_str();
    app->add_option("--fine-curved-scale", a->fine_curved_scale,
                    "--convergence: the finer setting's Cut::curved_scale (0: --curved-scale)")
        ->check(CLI::Range(0.0, 1.0))
        ->capture_default_str();
    app->add_option("--sharing-layout", a->sharing_layout,
                    "--view: the shared rows see the receivers as an image or as a point set")
        ->check(CLI::IsMember({"image", "points"}))
        ->capture_default_str();
    return [a, app]() -> absl::Status {
      // The cosine-weighted cut suits integrals against the cosine, not a glossy lobe (see
      // Cut::cosine_weighted): glossy sweeps the lobe-aware cut (Cut::lobe) unless --cuts says
      // otherwise (`--cuts plain lobe` compares it with the cut that knows nothing of the lobe).
      if (a->mode == "glossy" && !app->count("--cuts")) a->cuts = {"lobe"};
      if (a->mode != "glossy" &&
          std::find(a->cuts.begin(), a->cuts.end(), "lobe") != a->cuts.end()) {
        return absl::InvalidArgumentError("--cuts lobe is for --mode glossy (a glossy lobe)");
      }
      if (!a->view && !a->db.empty()) {
        return absl::InvalidArgumentError("--db is for --view (a camera view of a built database)");
      }
      if (a->convergence && (a->view || a->mode == "glossy")) {
        return absl::InvalidArgumentError(
            "--convergence compares receiver sets in occlusion or irradiance: not with --view or "
            "--mode glossy");
      }
      if (!a->convergence) {
        for (const char* flag : {"--density-factor", "--fine-solid-angle", "--fine-raster-res",
                                 "--fine-curved-scale"}) {
          if (app->count(flag)) {
            return absl::InvalidArgumentError(absl::StrFormat("%s is for --convergence", flag));
          }
        }
      }
      // The ratio is against the default setting: a coarser row in its place would flatter it.
      if (a->convergence &&
          !(SweepHas(a->solid_angles, 0.03f) && SweepHas(a->resolutions, 12) &&
            std::find(a->cuts.begin(), a->cuts.end(), "cosine") != a->cuts.end())) {
        return absl::InvalidArgumentError(
            "--convergence compares with the default setting (msa 0.03, res 12, the cosine cut): "
            "--solid-angles, --raster-res and --cuts must include it");
      }
      if (a->convergence && a->points > kMaxPoints / a->density_factor) {
        return absl::InvalidArgumentError(absl::StrFormat(
            "--convergence: --points %d x --density-factor %d exceeds the %d surfels --points "
            "takes",
            a->points, a->density_factor, kMaxPoints));
      }
      if (a->convergence && a->fine_curved_scale > 0.0f && a->fine_curved_scale < 0.001f) {
        return absl::InvalidArgumentError(
            absl::StrFormat("--fine-curved-scale %g: must be 0 (--curved-scale) or in [0.001, 1]",
                            a->fine_curved_scale));
      }
      if (!a->view) return RunEval(*a);
      ViewEvalArgs v;
      if (a->mode == "glossy") {
        // One lobe per view (the reference of a view is its costly part).
        const std::vector<GlossyParams> lobes = GlossySettings(*a);
        if (lobes.size() != 1) {
          return absl::InvalidArgumentError(
              absl::StrFormat("eval --view --mode glossy takes one lobe setting, got %d (--lobes, "
                              "--phong-exponents, --ggx-roughnesses)",
                              lobes.size()));
        }
        RasterOptions ro;
        ro.lobe = lobes[0].lobe;
        ro.phong_exponent = lobes[0].phong_exponent;
        ro.ggx_roughness = lobes[0].ggx_roughness;
        PBGI_RETURN_IF_ERROR(ValidateRasterOptions(ro));
        v.lobe = lobes[0];
        v.cuts = a->cuts;  // the lobe cut unless --cuts says otherwise (above)
      }
      v.scene = app->count("scene") ? a->scene : std::string("city");
      v.out_dir = app->count("--output") ? a->out_dir : std::string("out/eval-view");
      v.mode = a->mode;
      if (app->count("--points")) v.points = a->points;
      if (app->count("--rays")) v.rays = a->truth_rays;
      if (app->count("--solid-angles")) v.solid_angles = a->solid_angles;
      if (app->count("--raster-res")) v.resolutions = a->resolutions;
      if (app->count("--cuts")) v.cuts = a->cuts;
      v.footprints = a->footprints;
      v.curved_scale = a->curved_scale;
      v.curved_box_scale = a->curved_box_scale;
      v.radiance_contrast = a->radiance_contrast;
      v.width = a->width;
      v.height = a->height;
      v.window = a->window;
      v.db = a->db;
      v.dump_receivers = a->dump_receivers;
      v.hitsides = a->hitsides;
      PBGI_ASSIGN_OR_RETURN(const auto budgets, EvalBudgets(*a));
      std::tie(v.memory_bytes, v.cache_bytes) = budgets;
      v.threads = a->threads;
      v.seed = a->seed;
      v.size = a->size;
      v.up = a->up;
      v.orient = a->orient;
      v.lights = a->lights;
      v.error_scale = a->error_scale;
      v.exact_only = a->exact;
      v.shared_only = a->shared;
      v.spacings = a->spacings;
      v.tolerances = a->tolerances;
      v.radius_factor = a->radius_factor;
      v.layout = a->sharing_layout;
      v.far = a->far;
      if (a->far.options.enabled) v.far_factors = a->far_factors;
      v.far_only = a->far_only;
      if (app->count("--ray-sweep")) v.ray_sweep = a->ray_sweep;
      v.repeat = a->repeat;
      return RunViewEval(v);
    };
  };
}

}  // namespace
PBGI_REGISTER_COMMAND(eval, "eval", "Run time against error: PBGI sweeps vs the Embree reference",
                      Setup());
}  // namespace pbgi::tools
