// `pbgi query DB --at X,Y,Z --normal X,Y,Z`: gathers the cut for one receiver and prints what
// was gathered and what it cost (nodes visited, pages touched per level, cache hits).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "base/stopwatch.h"
#include "pbgi/query.h"
#include "pbgi/raster.h"
#include "pbgi/status.h"
#include "tools/args.h"
#include "tools/budget.h"
#include "tools/command.h"
#include "tools/footprint_flags.h"
#include "tools/report.h"

namespace pbgi::tools {
namespace {

absl::StatusOr<glm::vec3> ParseVec3(const std::string& flag, const std::string& text) {
  std::vector<std::string> parts = absl::StrSplit(text, ',');
  glm::vec3 v;
  if (parts.size() != 3) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s '%s': expected three numbers X,Y,Z", flag, text));
  }
  for (int i = 0; i < 3; ++i) {
    if (!absl::SimpleAtof(parts[i], &v[i]) || !std::isfinite(v[i])) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s '%s': '%s' is not a number", flag, text, parts[i]));
    }
  }
  return v;
}

struct Args {
  std::string db;
  std::string at;
  std::string normal;
  int sheet = 0;
  float max_solid_angle = 0.03f;
  float max_distance = std::numeric_limits<float>::infinity();
  std::string cache = "auto";
  std::string cut = "cosine";
  int raster_res = 12;
  bool json = false;
  bool list = false;
  FootprintFlags footprint;
  std::string hitsides = "front";
  int blame = 0;  // list the elements whose removal lowers the occlusion most
};

// One receiver's gather, cold then warm, and what it cost.
struct QueryRun {
  Receiver receiver;
  Cut cut;
  Gathered gathered;
  QueryStats stats;  // of the cold gather
  double ms = 0, warm_ms = 0;
  std::vector<int> rows;  // levels to report: the tree's, then kPointLevel
  ShadeResult shaded;     // the gathered cut rasterized, as `pbgi shade` does
  bool radiance = false;
};

std::string LevelName(int l) {
  return l == kPointLevel ? std::string("points") : absl::StrFormat("%d", l);
}

absl::StatusOr<QueryRun> GatherColdAndWarm(Reader& reader, const Receiver& r, const Cut& cut) {
  QueryRun q{r, cut, {}, {}, 0, 0, {}, {}, false};
  internal::Stopwatch t;
  PBGI_RETURN_IF_ERROR(reader.Gather(r, cut, &q.gathered, &q.stats));
  q.ms = t.Milliseconds();
  // The same query again, warm: the cost of a gather once its pages are cached.
  QueryStats warm;
  t.Restart();
  PBGI_RETURN_IF_ERROR(reader.Gather(r, cut, &q.gathered, &warm));
  q.warm_ms = t.Milliseconds();
  int levels = 0;
  for (int l = 0; l < kMaxTreeDepth; ++l) {
    if (q.stats.nodes[l] > 0) levels = l + 1;
  }
  for (int l = 0; l < levels; ++l) q.rows.push_back(l);
  q.rows.push_back(kPointLevel);
  return q;
}

Json QueryJson(const Args& a, const QueryRun& q) {
  const Receiver& r = q.receiver;
  const glm::vec3 p = r.position;
  const Cut& cut = q.cut;
  const Gathered& g = q.gathered;
  const QueryStats& stats = q.stats;
  const std::vector<int>& rows = q.rows;
  const double ms = q.ms, warm_ms = q.warm_ms;
  Json j;
  j["db"] = a.db;
  j["receiver"] = {{"at", JsonVec3(p)}, {"normal", JsonVec3(r.normal)}};
  j["cut"] = {{"max_solid_angle", JsonFloat(cut.max_solid_angle)},
              {"max_distance", JsonFloat(cut.max_distance)}};
  j["cut"]["criterion"] = cut.cosine_weighted ? "cosine" : "plain";
  j["cut"]["radiance_contrast"] = JsonFloat(cut.radiance_contrast);
  j["cut"]["contrast_floor"] = JsonFloat(cut.contrast_floor);
  j["gathered"] = {{"clusters", g.clusters.size()}, {"surfels", g.surfels.size()}};
  j["shaded"] = {{"raster_res", a.raster_res}, {"occlusion", JsonFloat(q.shaded.occlusion)}};
  if (q.radiance) j["shaded"]["irradiance"] = JsonVec3(q.shaded.irradiance);
  j["shaded"]["coverage"] = JsonFloat(q.shaded.coverage);
  Json cost;
  cost["ms"] = ms;
  cost["warm_ms"] = warm_ms;
  cost["nodes_visited"] = stats.nodes_visited;
  cost["nodes_culled"] = stats.nodes_culled;
  cost["points_tested"] = stats.points_tested;
  cost["pages_read"] = stats.pages_read;
  cost["bytes_read"] = stats.bytes_read;
  cost["levels"] = Json::array();
  for (int l : rows) {
    Json level;
    level["level"] = LevelName(l);
    level["nodes"] = stats.nodes[l];
    level["pages_touched"] = stats.pages_touched[l];
    level["reader_hits"] = stats.reader_hits[l];
    level["shared_hits"] = stats.shared_hits[l];
    level["shared_misses"] = stats.shared_misses[l];
    cost["levels"].push_back(level);
  }
  j["cost"] = cost;
  if (a.list) {
    j["clusters"] = Json::array();
    for (const Cluster& c : g.clusters) {
      Json e;
      e["depth"] = c.depth;
      e["first_point"] = c.first_point;
      e["point_count"] = c.point_count;
      e["area"] = JsonFloat(c.area);
      e["solid_angle"] = JsonFloat(ClusterSolidAngle(c, r));
      e["lo"] = JsonVec3(c.bounds.lo);
      e["hi"] = JsonVec3(c.bounds.hi);
      j["clusters"].push_back(e);
    }
    j["surfels"] = Json::array();
    for (size_t i = 0; i < g.surfels.size(); ++i) {
      const Surfel& s = g.surfels[i];
      Json e;
      e["id"] = g.surfel_ids[i];
      e["position"] = JsonVec3(s.position);
      e["normal"] = JsonVec3(s.normal);
      e["radius"] = JsonFloat(s.radius);
      j["surfels"].push_back(e);
    }
  }
  return j;
}

void PrintQuery(const Args& a, const Database& db, const QueryRun& q) {
  const Receiver& r = q.receiver;
  const glm::vec3 p = r.position;
  const Cut& cut = q.cut;
  const Gathered& g = q.gathered;
  const QueryStats& stats = q.stats;
  const double ms = q.ms, warm_ms = q.warm_ms;
  std::printf("%s: %llu points, %llu nodes, layout %s\n", a.db.c_str(),
              static_cast<unsigned long long>(db.meta().point_count),
              static_cast<unsigned long long>(db.meta().node_count), db.meta().layout.c_str());
  std::printf("receiver (%g, %g, %g) normal (%g, %g, %g), max_solid_angle %g, max_distance %g\n",
              p.x, p.y, p.z, r.normal.x, r.normal.y, r.normal.z, cut.max_solid_angle,
              cut.max_distance);
  std::printf("gathered %zu clusters + %zu surfels in %.3f ms cold, %.3f ms warm (%s cut",
              g.clusters.size(), g.surfels.size(), ms, warm_ms,
              cut.cosine_weighted ? "cosine" : "plain");
  if (cut.radiance_contrast > 0.0f) {
    std::printf(", radiance contrast %g over a floor of %g", cut.radiance_contrast,
                cut.contrast_floor);
  }
  std::printf(")\n");
  std::printf("shaded (raster %d): occlusion %.6g", a.raster_res, q.shaded.occlusion);
  if (q.radiance) {
    std::printf(", irradiance (%.6g, %.6g, %.6g)", q.shaded.irradiance.x, q.shaded.irradiance.y,
                q.shaded.irradiance.z);
  }
  std::printf(", coverage %.4g\n", q.shaded.coverage);
  std::printf("nodes visited %llu (culled %llu), points tested %llu, pages read %llu (%s)\n",
              static_cast<unsigned long long>(stats.nodes_visited),
              static_cast<unsigned long long>(stats.nodes_culled),
              static_cast<unsigned long long>(stats.points_tested),
              static_cast<unsigned long long>(stats.pages_read),
              FormatBytes(stats.bytes_read).c_str());
  std::printf("%-7s %10s %10s %10s %10s %10s\n", "level", "nodes", "pages", "reader-hit",
              "shared-hit", "read");
  for (int l : q.rows) {
    std::printf("%-7s %10llu %10llu %10llu %10llu %10llu\n", LevelName(l).c_str(),
                static_cast<unsigned long long>(stats.nodes[l]),
                static_cast<unsigned long long>(stats.pages_touched[l]),
                static_cast<unsigned long long>(stats.reader_hits[l]),
                static_cast<unsigned long long>(stats.shared_hits[l]),
                static_cast<unsigned long long>(stats.shared_misses[l]));
  }
  if (a.list) {
    for (const Cluster& c : g.clusters) {
      std::printf("cluster depth %u points [%llu, +%llu) area %g solid angle %g\n", c.depth,
                  static_cast<unsigned long long>(c.first_point),
                  static_cast<unsigned long long>(c.point_count), c.area, ClusterSolidAngle(c, r));
    }
    for (size_t i = 0; i < g.surfels.size(); ++i) {
      const Surfel& s = g.surfels[i];
      std::printf("surfel %llu at (%g, %g, %g) radius %g\n",
                  static_cast<unsigned long long>(g.surfel_ids[i]), s.position.x, s.position.y,
                  s.position.z, s.radius);
    }
  }
}

// Which elements make the occlusion: the cut shaded once without each cluster, and once
// without each leaf's surfels; the `a.blame` largest drops are listed.
absl::Status PrintBlame(const Args& a, const QueryRun& q, const ShadeReceiver& sr,
                        const RasterOptions& ro) {
  const Gathered& g = q.gathered;
  struct Blame {
    double drop;
    std::string what;
  };
  std::vector<Blame> blames;
  MicroBuffer buffer;
  Gathered without;
  ShadeResult res;
  for (size_t i = 0; i < g.clusters.size(); ++i) {
    without = g;
    without.clusters.erase(without.clusters.begin() + static_cast<std::ptrdiff_t>(i));
    PBGI_RETURN_IF_ERROR(Shade(without, sr, ro, &buffer, &res));
    const Cluster& c = g.clusters[i];
    const glm::vec3 n(c.sh_area[3], c.sh_area[1], c.sh_area[2]);  // band 1: y, z, x
    blames.push_back(
        {q.shaded.occlusion - res.occlusion,
         absl::StrFormat("cluster depth %u points [%llu, +%llu) area %g band0 %g band1 (%g %g "
                         "%g) centre (%g, %g, %g) extent (%g, %g, %g) distance %g",
                         c.depth, static_cast<unsigned long long>(c.first_point),
                         static_cast<unsigned long long>(c.point_count), c.area, c.sh_area[0], n.x,
                         n.y, n.z, c.bounds.Center().x, c.bounds.Center().y, c.bounds.Center().z,
                         c.bounds.Extent().x, c.bounds.Extent().y, c.bounds.Extent().z,
                         glm::length(c.bounds.Center() - sr.position))});
  }
  // Leaves: surfels that share surfel_leaf (or each surfel, without leaf cells).
  std::vector<uint32_t> leaf(g.surfels.size());
  for (size_t i = 0; i < leaf.size(); ++i) {
    leaf[i] = g.surfel_leaf.empty() ? static_cast<uint32_t>(i) : g.surfel_leaf[i];
  }
  std::vector<uint32_t> leaves = leaf;
  std::sort(leaves.begin(), leaves.end());
  leaves.erase(std::unique(leaves.begin(), leaves.end()), leaves.end());
  for (uint32_t l : leaves) {
    without = g;
    without.surfels.clear();
    without.surfel_ids.clear();
    without.surfel_leaf.clear();
    std::string list;
    for (size_t i = 0; i < g.surfels.size(); ++i) {
      if (leaf[i] == l) {
        const Surfel& s = g.surfels[i];
        const glm::vec3 rel = s.position - sr.position;
        list += absl::StrFormat(
            "\n    surfel (%g, %g, %g) n (%.3f %.3f %.3f) r %g %s distance %g side %g",
            s.position.x, s.position.y, s.position.z, s.normal.x, s.normal.y, s.normal.z, s.radius,
            s.two_sided ? "two-sided" : "one-sided", glm::length(rel),
            -glm::dot(glm::normalize(s.normal), rel));
        continue;
      }
      without.surfels.push_back(g.surfels[i]);
      without.surfel_ids.push_back(g.surfel_ids[i]);
      if (!g.surfel_leaf.empty()) without.surfel_leaf.push_back(g.surfel_leaf[i]);
    }
    PBGI_RETURN_IF_ERROR(Shade(without, sr, ro, &buffer, &res));
    blames.push_back({q.shaded.occlusion - res.occlusion, absl::StrFormat("leaf %u:%s", l, list)});
  }
  std::sort(blames.begin(), blames.end(),
            [](const Blame& x, const Blame& y) { return x.drop > y.drop; });
  std::printf("blame (occlusion without the element, largest drops first):\n");
  for (size_t i = 0; i < blames.size() && i < static_cast<size_t>(a.blame); ++i) {
    std::printf("  %+.5f %s\n", -blames[i].drop, blames[i].what.c_str());
  }
  return absl::OkStatus();
}

absl::Status Run(const Args& a) {
  PBGI_ASSIGN_OR_RETURN(glm::vec3 p, ParseVec3("--at", a.at));
  PBGI_ASSIGN_OR_RETURN(glm::vec3 n, ParseVec3("--normal", a.normal));
  if (glm::length(n) == 0.0f) return absl::InvalidArgumentError("--normal must not be 0,0,0");
  if (!(a.max_solid_angle >= 0)) {
    return absl::InvalidArgumentError("--max-solid-angle must be >= 0");
  }
  PBGI_ASSIGN_OR_RETURN(uint64_t cache,
                        ResolveBudget("query", "--cache", a.cache, uint64_t{256} << 20,
                                      kMinCacheBytes, "a few pages"));
  DatabaseOptions options;
  options.cache_bytes = cache;
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<Database> db, Database::Open(a.db, options));
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<Reader> reader, db->NewReader());
  Cut cut{a.max_solid_angle, a.max_distance};
  cut.cosine_weighted = a.cut == "cosine";
  ShadeOptions so;
  ApplyFootprintFlags(a.footprint, &so);
  cut.curved_scale = so.cut.curved_scale;
  cut.curved_box_scale = so.cut.curved_box_scale;
  // The radiance contrast as `pbgi shade` sets it (EffectiveCut).
  so.cut = cut;
  so.raster.compute_radiance = HasRadiance(db->meta().channels);
  PBGI_ASSIGN_OR_RETURN(cut, EffectiveCut(*db, so));
  const Receiver receiver{p, glm::normalize(n)};
  PBGI_ASSIGN_OR_RETURN(QueryRun q, GatherColdAndWarm(*reader, receiver, cut));
  // The values `pbgi shade` writes for this receiver, from the same cut.
  RasterOptions ro;
  ro.resolution = a.raster_res;
  ro.max_distance = a.max_distance;
  q.radiance = HasRadiance(db->meta().channels);
  ro.compute_radiance = q.radiance;
  ro.footprint = so.raster.footprint;
  ro.hitsides = a.hitsides == "back"   ? HitSides::kBack
                : a.hitsides == "both" ? HitSides::kBoth
                                       : HitSides::kFront;
  MicroBuffer buffer;
  const ShadeReceiver sr{p, receiver.normal, receiver.normal, static_cast<uint8_t>(a.sheet)};
  PBGI_RETURN_IF_ERROR(Shade(q.gathered, sr, ro, &buffer, &q.shaded));
  if (a.json) {
    std::fputs(DumpJson(QueryJson(a, q)).c_str(), stdout);
  } else {
    PrintQuery(a, *db, q);
  }
  if (a.blame > 0) PBGI_RETURN_IF_ERROR(PrintBlame(a, q, sr, ro));
  return absl::OkStatus();
}

CommandSetup Setup() {
  return [](CLI::App* app) -> std::function<absl::Status()> {
    auto args = std::make_shared<Args>();
    app->add_option("db", args->db, "Database directory")->required();
    app->add_option("--at", args->at, "Receiver position X,Y,Z")->required();
    app->add_option("--normal", args->normal, "Receiver normal X,Y,Z")->required();
    app->add_option(
           "--sheet", args->sheet,
           "The receiver's sheet tag, 1-255, 0 unknown (a thin surface's Surfel::sheet, as "
           "`pbgi export` writes it): another sheet crossing it is not taken for its fold")
        ->check(CLI::Range(0, 255))
        ->capture_default_str();
    app->add_option("--max-solid-angle", args->max_solid_angle,
                    "Accept a node as a cluster below this solid angle (sr)")
        ->capture_default_str();
    app->add_option("--max-distance", args->max_distance, "Ignore what is farther than this");
    app->add_option("--cache", args->cache, "Cache budget (both levels), e.g. 256M, or auto")
        ->check(BudgetValidator())
        ->capture_default_str();
    app->add_option("--cut", args->cut,
                    "cosine: the solid angle weighted by the cosine to the normal (as `pbgi "
                    "shade` by default), or plain")
        ->check(CLI::IsMember({"cosine", "plain"}))
        ->capture_default_str();
    app->add_option("--raster-res", args->raster_res,
                    "Micro-buffer pixels per cube face edge of the shaded values")
        ->check(CLI::Range(4, 64))
        ->capture_default_str();
    app->add_flag("--json", args->json, "Print JSON");
    app->add_flag("--list", args->list, "Also list every cluster and surfel");
    AddFootprintFlags(app, &args->footprint);
    app->add_option("--hitsides", args->hitsides, "Sides of one-sided surfels that occlude")
        ->check(CLI::IsMember({"front", "back", "both"}))
        ->capture_default_str();
    app->add_option("--blame", args->blame,
                    "List the N elements (clusters, leaves' surfels) whose removal lowers the "
                    "occlusion most");
    return [args]() { return Run(*args); };
  };
}

}  // namespace
PBGI_REGISTER_COMMAND(query, "query",
                      "Gather the cut for one receiver; print what it gathered, cost and shades to",
                      Setup());
}  // namespace pbgi::tools
