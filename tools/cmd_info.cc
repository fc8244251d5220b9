// `pbgi info DB|FILE.ply [--json]`: what the meta record of a store holds, or what a PLY point
// file holds (like `pdal info`: count, properties, bounds, radius statistics).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "pbgi/ply.h"
#include "pbgi/status.h"
#include "pbgi/store.h"
#include "tools/args.h"
#include "tools/command.h"
#include "tools/progress.h"
#include "tools/report.h"
#include "tree/verify.h"

namespace pbgi::tools {
namespace {

const char* ChannelsName(Channels c) { return HasRadiance(c) ? "radiance" : "occlusion"; }

// A meta record's free-form value as the JSON type it reads as: a whole number, a number, or
// the string.
Json TypedValue(const std::string& v) {
  int64_t i = 0;
  if (absl::SimpleAtoi(v, &i)) return i;
  double d = 0;
  if (absl::SimpleAtod(v, &d) && std::isfinite(d) && v.find_first_of("0123456789") == 0) return d;
  return v;
}

// Who wrote the record (and when), and where its points came from, out of the build's stats.
bool IsProvenanceKey(const std::string& k) {
  return k == "input" || k == "tool" || k == "built_at" || k == "source" || k == "radius" ||
         k == "normals" || k.rfind("scene.", 0) == 0 || k.rfind("light.", 0) == 0;
}

Json InfoJsonHeader(const std::string& what, const std::string& input) {
  Json j;
  j["kind"] = what;
  j["path"] = input;
  j["info"] = {{"tool", kToolVersion}, {"date", NowIso8601()}};
  return j;
}

void PrintJson(const PageStore& store) {
  const StoreMeta& m = store.meta();
  Json j = InfoJsonHeader("database", store.path());
  j["magic"] = absl::StrFormat("0x%016x", m.magic);
  j["version"] = m.version;
  j["page_size"] = m.page_size;
  j["channels"] = ChannelsName(m.channels);
  j["back_radiance"] = m.channels == Channels::kRadianceBothSides;
  j["sh_order"] = m.sh_order;
  j["leaf_size"] = m.leaf_size;
  // An empty box's float limits are finite, so they print as they are.
  j["bounds"] = {{"lo", JsonVec3(m.bounds.lo)}, {"hi", JsonVec3(m.bounds.hi)}};
  j["point_count"] = m.point_count;
  j["node_count"] = m.node_count;
  j["node_pages"] = m.node_pages;
  j["point_pages"] = m.point_pages;
  j["root"] = m.root;
  j["max_depth"] = m.max_depth;
  j["layout"] = m.layout;
  j["file_bytes"] = store.FileBytes();
  j["provenance"] = Json::object();
  j["stats"] = Json::object();
  for (const auto& [k, v] : m.stats) {
    (IsProvenanceKey(k) ? j["provenance"] : j["stats"])[k] = TypedValue(v);
  }
  std::fputs(DumpJson(j).c_str(), stdout);
}

void PrintTable(const PageStore& store) {
  const StoreMeta& m = store.meta();
  auto row = [](const char* name, const std::string& value) {
    std::printf("%-14s %s\n", name, value.c_str());
  };
  row("store", store.path());
  row("format", absl::StrFormat("version %d (magic 0x%016x)", m.version, m.magic));
  row("file", absl::StrFormat("%s (%d bytes)", FormatBytes(store.FileBytes()), store.FileBytes()));
  row("page size", absl::StrFormat("%d bytes", m.page_size));
  row("channels", m.channels == Channels::kRadianceBothSides
                      ? "radiance, and a back radiance on two-sided surfels"
                      : ChannelsName(m.channels));
  row("sh order", absl::StrFormat("%d", m.sh_order));
  row("leaf size", absl::StrFormat("%d", m.leaf_size));
  row("bounds", absl::StrFormat("(%g, %g, %g) .. (%g, %g, %g)", m.bounds.lo.x, m.bounds.lo.y,
                                m.bounds.lo.z, m.bounds.hi.x, m.bounds.hi.y, m.bounds.hi.z));
  row("points", absl::StrFormat("%d in %d pages", m.point_count, m.point_pages));
  row("nodes", absl::StrFormat("%d in %d pages", m.node_count, m.node_pages));
  row("root", absl::StrFormat("page %d slot %d", m.root >> 16, m.root & 0xffff));
  row("max depth", absl::StrFormat("%d", m.max_depth));
  row("layout", m.layout);
  bool any = false;
  for (const auto& [k, v] : m.stats) {
    if (!IsProvenanceKey(k)) continue;
    if (!any) std::printf("provenance:\n");
    any = true;
    std::printf("  %-24s %s\n", k.c_str(), v.c_str());
  }
  any = false;
  for (const auto& [k, v] : m.stats) {
    if (IsProvenanceKey(k)) continue;
    if (!any) std::printf("build statistics:\n");
    any = true;
    std::printf("  %-24s %s\n", k.c_str(), v.c_str());
  }
}

// One pass over a PLY's points: bounds, radius statistics, invalid records.
struct PlySummary {
  PlyHeader header;
  Bounds bounds;
  uint64_t points = 0;
  double radius_min = 0, radius_max = 0, radius_mean = 0, radius_median = 0;
  uint64_t zero_normals = 0, non_finite = 0, bad_radius = 0;
  bool has_radiance = false;
};

absl::StatusOr<PlySummary> SummarizePly(const std::string& path) {
  PlyReadOptions ro;
  ro.allow_missing_radius = true;
  ro.allow_missing_normals = true;
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PlySource> src, OpenPlyFile(path, ro));
  PlySummary s;
  s.header = src->header();
  s.has_radiance = src->HasRadiance();
  std::vector<Surfel> buf(1 << 16);
  // The median from a fixed-size reservoir of radii: memory stays bounded whatever the file.
  std::vector<float> sample;
  constexpr size_t kSample = 1 << 16;
  uint64_t seen = 0, rng = 0x9e3779b97f4a7c15ull;
  double sum = 0;
  s.radius_min = std::numeric_limits<double>::infinity();
  s.radius_max = 0;
  Progress progress("info", "points", src->KnownCount());
  for (;;) {
    PBGI_ASSIGN_OR_RETURN(size_t n, src->Next(absl::MakeSpan(buf)));
    if (n == 0) break;
    for (size_t i = 0; i < n; ++i) {
      const Surfel& p = buf[i];
      const bool finite =
          std::isfinite(p.position.x) && std::isfinite(p.position.y) && std::isfinite(p.position.z);
      if (!finite) {
        ++s.non_finite;
        continue;
      }
      s.bounds.Extend(p.position);
      if (s.header.has_normals && glm::dot(p.normal, p.normal) == 0.0f) ++s.zero_normals;
      if (s.header.has_radius) {
        if (!(p.radius > 0) || !std::isfinite(p.radius)) {
          ++s.bad_radius;
        } else {
          sum += p.radius;
          s.radius_min = std::min<double>(s.radius_min, p.radius);
          s.radius_max = std::max<double>(s.radius_max, p.radius);
          ++seen;
          if (sample.size() < kSample) {
            sample.push_back(p.radius);
          } else {
            rng ^= rng << 13, rng ^= rng >> 7, rng ^= rng << 17;
            const uint64_t j = rng % seen;
            if (j < kSample) sample[j] = p.radius;
          }
        }
      }
    }
    s.points += n;
    progress.Update(s.points);
  }
  progress.Abandon();
  if (seen > 0) {
    s.radius_mean = sum / double(seen);
    std::nth_element(sample.begin(), sample.begin() + sample.size() / 2, sample.end());
    s.radius_median = sample[sample.size() / 2];
  } else {
    s.radius_min = 0;
  }
  return s;
}

std::string Properties(const PlyHeader& h) {
  std::vector<std::string> p;
  for (const auto& q : h.vertex_properties) p.push_back(q.type + " " + q.name);
  return absl::StrJoin(p, ", ");
}

std::string BuildAdvice(const PlySummary& s) {
  if (s.header.FaceCount() > 0) {
    return absl::StrFormat("a mesh (%d faces): sample its surfaces with `pbgi import`",
                           s.header.FaceCount());
  }
  std::vector<std::string> missing;
  if (!s.header.has_normals) missing.push_back("normals");
  if (!s.header.has_radius) missing.push_back("radii");
  if (missing.empty()) return "surfels: `pbgi build` reads them as they are";
  return absl::StrFormat("points without %s: `pbgi build` estimates them from neighbours",
                         absl::StrJoin(missing, " or "));
}

void PrintPly(const PlySummary& s, bool json) {
  const PlyHeader& h = s.header;
  if (json) {
    Json j = InfoJsonHeader("ply", h.path);
    j["format"] = h.format;
    j["vertex_count"] = h.vertex_count;
    j["properties"] = Json::array();
    for (const auto& q : h.vertex_properties) {
      j["properties"].push_back({{"name", q.name}, {"type", q.type}});
    }
    j["other_elements"] = Json::object();
    for (const auto& [name, count] : h.other_elements) j["other_elements"][name] = count;
    j["has_normals"] = h.has_normals;
    j["has_radius"] = h.has_radius;
    j["has_color"] = h.has_color;
    j["has_reflection"] = h.has_reflection;
    j["bounds"] = {{"lo", JsonVec3(s.bounds.lo)}, {"hi", JsonVec3(s.bounds.hi)}};
    if (h.has_radius) {
      j["radius"] = {{"min", s.radius_min},
                     {"max", s.radius_max},
                     {"mean", s.radius_mean},
                     {"median", s.radius_median},
                     {"invalid", s.bad_radius}};
    }
    j["zero_normals"] = s.zero_normals;
    j["non_finite_positions"] = s.non_finite;
    j["provenance"] = Json::object();
    for (const auto& [k, v] : h.Provenance()) j["provenance"][k] = TypedValue(v);
    j["comments"] = h.comments;
    j["notes"] = h.notes;
    j["for_build"] = BuildAdvice(s);
    std::fputs(DumpJson(j).c_str(), stdout);
    return;
  }
  auto row = [](const char* name, const std::string& value) {
    std::printf("%-14s %s\n", name, value.c_str());
  };
  row("file", h.path);
  row("format", h.format);
  row("points", absl::StrFormat("%d", h.vertex_count));
  row("properties", Properties(h));
  for (const auto& [name, count] : h.other_elements) {
    row("element", absl::StrFormat("%s: %d", name, count));
  }
  row("bounds", absl::StrFormat("(%g, %g, %g) .. (%g, %g, %g)", s.bounds.lo.x, s.bounds.lo.y,
                                s.bounds.lo.z, s.bounds.hi.x, s.bounds.hi.y, s.bounds.hi.z));
  if (h.has_radius) {
    row("radius", absl::StrFormat("min %g, median %g, mean %g, max %g%s", s.radius_min,
                                  s.radius_median, s.radius_mean, s.radius_max,
                                  s.bad_radius ? absl::StrFormat(" (%d <= 0 or NaN)", s.bad_radius)
                                               : std::string()));
  } else {
    row("radius", "none");
  }
  row("normals", h.has_normals ? (s.zero_normals ? absl::StrFormat("yes (%d zero)", s.zero_normals)
                                                 : std::string("yes"))
                               : std::string("none"));
  row("colour", s.has_radiance ? "yes" : "none");
  if (s.non_finite) row("invalid", absl::StrFormat("%d NaN or infinite positions", s.non_finite));
  for (const auto& [k, v] : h.Provenance()) row(("  " + k).c_str(), v);
  for (const std::string& n : h.notes) row("note", n);
  row("for build", BuildAdvice(s));
}

CommandSetup Setup() {
  return [](CLI::App* app) -> std::function<absl::Status()> {
    auto db = std::make_shared<std::string>();
    auto json = std::make_shared<bool>(false);
    app->add_option("DB", *db, "Store directory, or a PLY point file")->required();
    app->add_flag("--json", *json, "Print JSON (typed values, provenance) instead of a table");
    return [db, json]() -> absl::Status {
      std::error_code ec;
      if (!std::filesystem::is_directory(*db, ec) && absl::EndsWithIgnoreCase(*db, ".ply")) {
        PBGI_ASSIGN_OR_RETURN(PlySummary s, SummarizePly(*db));
        PrintPly(s, *json);
        return absl::OkStatus();
      }
      NoteStoreLeftovers("info", *db);
      PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PageStore> store, PageStore::Open(*db));
      if (*json) {
        PrintJson(*store);
      } else {
        PrintTable(*store);
      }
      // info shows what the record holds, even when it is no database (a bare store of pages);
      // verify and shade refuse such a record.
      if (absl::Status s = internal::CheckDatabaseMeta(store->meta(), store->path()); !s.ok()) {
        std::fflush(stdout);
        std::fprintf(stderr, "pbgi info: warning: %s\n", std::string(s.message()).c_str());
      }
      return absl::OkStatus();
    };
  };
}

}  // namespace
PBGI_REGISTER_COMMAND(info, "info",
                      "Print what a store's meta record holds, or what a PLY point file holds",
                      Setup());
}  // namespace pbgi::tools
