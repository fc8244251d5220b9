#include "tools/report.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "tools/command.h"

namespace pbgi::tools {

Json JsonFloat(float v) {
  if (!std::isfinite(v)) return nullptr;
  double d = 0;
  (void)absl::SimpleAtod(absl::StrFormat("%.9g", v), &d);
  return d;
}

Json JsonVec3(const glm::vec3& v) {
  return Json::array({JsonFloat(v.x), JsonFloat(v.y), JsonFloat(v.z)});
}

std::string DumpJson(const Json& j) {
  return j.dump(2, ' ', false, Json::error_handler_t::replace) + "\n";
}

namespace {
double PointsPerSecond(const BuildStats& s) {
  return s.seconds_total > 0 ? double(s.points) / s.seconds_total : 0;
}
double BytesPerPoint(const BuildStats& s) {
  return s.points ? double(s.bytes_on_disk) / double(s.points) : 0.0;
}
}  // namespace

Json BuildStatsJson(const BuildStats& s, const BuildOptions& o, const std::string& input,
                    const std::string& output, const std::string& channels) {
  Json j;
  j["input"] = input;
  j["output"] = output;
  j["layout"] = LayoutName(o.layout);
  j["channels"] = channels;
  j["threads"] = s.threads;
  j["memory_bytes"] = o.memory_bytes;
  j["leaf_size"] = o.leaf_size;
  j["page_size"] = o.page_size;
  j["points"] = s.points;
  j["skipped"] = s.skipped;
  j["nodes"] = s.nodes;
  j["leaves"] = s.leaves;
  j["node_pages"] = s.node_pages;
  j["point_pages"] = s.point_pages;
  j["max_depth"] = s.max_depth;
  j["max_leaf_points"] = s.max_leaf_points;
  j["node_page_fill"] = s.node_page_fill;
  j["bytes_on_disk"] = s.bytes_on_disk;
  j["bytes_per_point"] = BytesPerPoint(s);
  j["seconds_bounds"] = s.seconds_bounds;
  j["seconds_sort"] = s.seconds_sort;
  j["seconds_merge"] = s.seconds_merge;
  j["seconds_finish"] = s.seconds_finish;
  j["seconds_total"] = s.seconds_total;
  j["points_per_second"] = PointsPerSecond(s);
  j["runs_spilled"] = s.runs_spilled;
  j["merge_passes"] = s.merge_passes;
  j["run_capacity"] = s.run_capacity;
  j["spill_bytes"] = s.spill_bytes;
  j["peak_rss_bytes"] = s.peak_rss_bytes;
  j["upper_records"] = s.upper_records;
  j["early_upper_writes"] = s.early_upper_writes;
  return j;
}

void PrintBuildStats(const BuildStats& s, const BuildOptions& o, const std::string& input,
                     const std::string& output, const std::string& channels) {
  auto u = [](uint64_t v) { return static_cast<unsigned long long>(v); };
  std::printf("built %s from %s (%s layout, %s)\n", output.c_str(), input.c_str(),
              LayoutName(o.layout), channels.c_str());
  std::printf("  points      %14llu  (%llu invalid skipped)\n", u(s.points), u(s.skipped));
  std::printf("  nodes       %14llu  (%llu leaves, depth %u, largest leaf %llu points)\n",
              u(s.nodes), u(s.leaves), s.max_depth, u(s.max_leaf_points));
  std::printf("  pages       %14llu node (%.0f%% full) + %llu point, %u bytes each\n",
              u(s.node_pages), 100.0 * s.node_page_fill, u(s.point_pages), o.page_size);
  std::printf("  on disk     %14s  (%.1f bytes/point)\n", FormatBytes(s.bytes_on_disk).c_str(),
              BytesPerPoint(s));
  std::printf("  time        %13.2fs  (bounds %.2f, sort %.2f, merge+octree %.2f, commit %.2f)\n",
              s.seconds_total, s.seconds_bounds, s.seconds_sort, s.seconds_merge, s.seconds_finish);
  std::printf("  throughput  %12.2f M points/s\n", PointsPerSecond(s) / 1e6);
  std::printf("  threads     %14d\n", s.threads);
  std::printf("  sort        %14llu runs spilled (%s), %llu extra merge passes\n",
              u(s.runs_spilled), FormatBytes(s.spill_bytes).c_str(), u(s.merge_passes));
  std::printf("  peak memory %14s  (budget %s)\n", FormatBytes(s.peak_rss_bytes).c_str(),
              FormatBytes(o.memory_bytes).c_str());
}

std::string CacheSummary(const CacheStats& cs, uint64_t distinct_pages, uint64_t receivers) {
  const uint64_t lookups = cs.reader.hits + cs.reader.misses;
  return absl::StrFormat(
      "reader hits %.2f%%, shared hits %.2f%%, %d pages read (%s; %d distinct, %.2f per receiver)",
      lookups ? 100.0 * double(cs.reader.hits) / double(lookups) : 100.0,
      100.0 * cs.shared.HitRate(), cs.shared.pages_read, FormatBytes(cs.shared.bytes_read),
      distinct_pages, double(distinct_pages) / double(std::max<uint64_t>(1, receivers)));
}

}  // namespace pbgi::tools
