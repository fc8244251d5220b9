// `pbgi query DB --at X,Y,Z --normal X,Y,Z`: gathers the cut for one receiver and prints what
// was gathered and what it cost (nodes visited, pages touched per level, cache hits).
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "pbgi/query.h"
#include "pbgi/status.h"
#include "tools/command.h"

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
  float max_solid_angle = 0.03f;
  float max_distance = std::numeric_limits<float>::infinity();
  std::string cache = "256M";
  bool json = false;
  bool list = false;
};

std::string Json(float v) {
  return std::isfinite(v) ? absl::StrFormat("%.9g", v) : std::string("null");
}

absl::Status Run(const Args& a) {
  PBGI_ASSIGN_OR_RETURN(glm::vec3 p, ParseVec3("--at", a.at));
  PBGI_ASSIGN_OR_RETURN(glm::vec3 n, ParseVec3("--normal", a.normal));
  if (glm::length(n) == 0.0f) return absl::InvalidArgumentError("--normal must not be 0,0,0");
  if (!(a.max_solid_angle >= 0)) {
    return absl::InvalidArgumentError("--max-solid-angle must be >= 0");
  }
  PBGI_ASSIGN_OR_RETURN(uint64_t cache, ParseBytes(a.cache));
  DatabaseOptions options;
  options.cache_bytes = cache;
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<Database> db, Database::Open(a.db, options));
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<Reader> reader, db->NewReader());
  const Receiver r{p, glm::normalize(n)};
  const Cut cut{a.max_solid_angle, a.max_distance};
  Gathered g;
  QueryStats stats;
  const auto t0 = std::chrono::steady_clock::now();
  PBGI_RETURN_IF_ERROR(reader->Gather(r, cut, &g, &stats));
  const double ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  // The same query again, warm: the cost of a gather once its pages are cached.
  QueryStats warm;
  const auto t1 = std::chrono::steady_clock::now();
  PBGI_RETURN_IF_ERROR(reader->Gather(r, cut, &g, &warm));
  const double warm_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t1).count();

  int levels = 0;
  for (int l = 0; l < kMaxTreeDepth; ++l) {
    if (stats.nodes[l] > 0) levels = l + 1;
  }
  std::vector<int> rows;
  for (int l = 0; l < levels; ++l) rows.push_back(l);
  rows.push_back(kPointLevel);
  const auto level_name = [](int l) {
    return l == kPointLevel ? std::string("points") : absl::StrFormat("%d", l);
  };

  if (a.json) {
    std::string out = "{\n";
    absl::StrAppendFormat(&out, "  \"db\": \"%s\",\n", a.db);
    absl::StrAppendFormat(
        &out, "  \"receiver\": {\"at\": [%s, %s, %s], \"normal\": [%s, %s, %s]},\n", Json(p.x),
        Json(p.y), Json(p.z), Json(r.normal.x), Json(r.normal.y), Json(r.normal.z));
    absl::StrAppendFormat(&out, "  \"cut\": {\"max_solid_angle\": %s, \"max_distance\": %s},\n",
                          Json(cut.max_solid_angle), Json(cut.max_distance));
    absl::StrAppendFormat(&out,
                          "  \"gathered\": {\"clusters\": %d, \"surfels\": %d},\n"
                          "  \"cost\": {\"ms\": %.4f, \"warm_ms\": %.4f, \"nodes_visited\": %d, "
                          "\"nodes_culled\": %d, \"points_tested\": %d, \"pages_read\": %d, "
                          "\"bytes_read\": %d,\n    \"levels\": [",
                          g.clusters.size(), g.surfels.size(), ms, warm_ms, stats.nodes_visited,
                          stats.nodes_culled, stats.points_tested, stats.pages_read,
                          stats.bytes_read);
    for (size_t i = 0; i < rows.size(); ++i) {
      const int l = rows[i];
      absl::StrAppendFormat(&out,
                            "%s\n      {\"level\": \"%s\", \"nodes\": %d, \"pages_touched\": %d, "
                            "\"reader_hits\": %d, \"shared_hits\": %d, \"shared_misses\": %d}",
                            i == 0 ? "" : ",", level_name(l), stats.nodes[l],
                            stats.pages_touched[l], stats.reader_hits[l], stats.shared_hits[l],
                            stats.shared_misses[l]);
    }
    out += "]}";
    if (a.list) {
      out += ",\n  \"clusters\": [";
      for (size_t i = 0; i < g.clusters.size(); ++i) {
        const Cluster& c = g.clusters[i];
        absl::StrAppendFormat(&out,
                              "%s\n    {\"depth\": %d, \"first_point\": %d, \"point_count\": %d, "
                              "\"area\": %s, \"solid_angle\": %s, \"lo\": [%s, %s, %s], "
                              "\"hi\": [%s, %s, %s]}",
                              i == 0 ? "" : ",", c.depth, c.first_point, c.point_count,
                              Json(c.area), Json(ClusterSolidAngle(c, r)), Json(c.bounds.lo.x),
                              Json(c.bounds.lo.y), Json(c.bounds.lo.z), Json(c.bounds.hi.x),
                              Json(c.bounds.hi.y), Json(c.bounds.hi.z));
      }
      out += "],\n  \"surfels\": [";
      for (size_t i = 0; i < g.surfels.size(); ++i) {
        const Surfel& s = g.surfels[i];
        absl::StrAppendFormat(&out,
                              "%s\n    {\"id\": %d, \"position\": [%s, %s, %s], "
                              "\"normal\": [%s, %s, %s], \"radius\": %s}",
                              i == 0 ? "" : ",", g.surfel_ids[i], Json(s.position.x),
                              Json(s.position.y), Json(s.position.z), Json(s.normal.x),
                              Json(s.normal.y), Json(s.normal.z), Json(s.radius));
      }
      out += "]";
    }
    out += "\n}\n";
    std::fputs(out.c_str(), stdout);
    return absl::OkStatus();
  }

  std::printf("%s: %llu points, %llu nodes, layout %s\n", a.db.c_str(),
              static_cast<unsigned long long>(db->meta().point_count),
              static_cast<unsigned long long>(db->meta().node_count), db->meta().layout.c_str());
  std::printf("receiver (%g, %g, %g) normal (%g, %g, %g), max_solid_angle %g, max_distance %g\n",
              p.x, p.y, p.z, r.normal.x, r.normal.y, r.normal.z, cut.max_solid_angle,
              cut.max_distance);
  std::printf("gathered %zu clusters + %zu surfels in %.3f ms cold, %.3f ms warm\n",
              g.clusters.size(), g.surfels.size(), ms, warm_ms);
  std::printf("nodes visited %llu (culled %llu), points tested %llu, pages read %llu (%s)\n",
              static_cast<unsigned long long>(stats.nodes_visited),
              static_cast<unsigned long long>(stats.nodes_culled),
              static_cast<unsigned long long>(stats.points_tested),
              static_cast<unsigned long long>(stats.pages_read),
              FormatBytes(stats.bytes_read).c_str());
  std::printf("%-7s %10s %10s %10s %10s %10s\n", "level", "nodes", "pages", "reader-hit",
              "shared-hit", "read");
  for (int l : rows) {
    std::printf("%-7s %10llu %10llu %10llu %10llu %10llu\n", level_name(l).c_str(),
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
  return absl::OkStatus();
}

CommandSetup Setup() {
  return [](CLI::App* app) -> std::function<absl::Status()> {
    auto args = std::make_shared<Args>();
    app->add_option("db", args->db, "Database directory")->required();
    app->add_option("--at", args->at, "Receiver position X,Y,Z")->required();
    app->add_option("--normal", args->normal, "Receiver normal X,Y,Z")->required();
    app->add_option("--max-solid-angle", args->max_solid_angle,
                    "Accept a node as a cluster below this solid angle (sr)")
        ->capture_default_str();
    app->add_option("--max-distance", args->max_distance, "Ignore what is farther than this");
    app->add_option("--cache", args->cache, "Cache budget (both levels)")
        ->check(BytesValidator())
        ->capture_default_str();
    app->add_flag("--json", args->json, "Print JSON");
    app->add_flag("--list", args->list, "Also list every cluster and surfel");
    return [args]() { return Run(*args); };
  };
}

}  // namespace
PBGI_REGISTER_COMMAND(query, "query",
                      "Gather the cut for one receiver and print what it gathered and cost",
                      Setup());
}  // namespace pbgi::tools
