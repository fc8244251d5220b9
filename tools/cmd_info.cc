// `pbgi info DB [--json]`: what the meta record of a store holds.
#include <cstdio>
#include <string>

#include "absl/strings/str_format.h"
#include "pbgi/status.h"
#include "pbgi/store.h"
#include "tools/command.h"
#include "tools/report.h"
#include "tree/verify.h"

namespace pbgi::tools {
namespace {

const char* ChannelsName(Channels c) { return HasRadiance(c) ? "radiance" : "occlusion"; }

void PrintJson(const PageStore& store) {
  const StoreMeta& m = store.meta();
  Json j;
  j["path"] = store.path();
  j["magic"] = absl::StrFormat("0x%016x", m.magic);
  j["version"] = m.version;
  j["page_size"] = m.page_size;
  j["channels"] = ChannelsName(m.channels);
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
  // Build statistics are free-form text in the meta record: kept as strings.
  j["stats"] = Json::object();
  for (const auto& [k, v] : m.stats) j["stats"][k] = v;
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
  row("channels", ChannelsName(m.channels));
  row("sh order", absl::StrFormat("%d", m.sh_order));
  row("leaf size", absl::StrFormat("%d", m.leaf_size));
  row("bounds", absl::StrFormat("(%g, %g, %g) .. (%g, %g, %g)", m.bounds.lo.x, m.bounds.lo.y,
                                m.bounds.lo.z, m.bounds.hi.x, m.bounds.hi.y, m.bounds.hi.z));
  row("points", absl::StrFormat("%d in %d pages", m.point_count, m.point_pages));
  row("nodes", absl::StrFormat("%d in %d pages", m.node_count, m.node_pages));
  row("root", absl::StrFormat("page %d slot %d", m.root >> 16, m.root & 0xffff));
  row("max depth", absl::StrFormat("%d", m.max_depth));
  row("layout", m.layout);
  if (!m.stats.empty()) {
    std::printf("build statistics:\n");
    for (const auto& [k, v] : m.stats) std::printf("  %-24s %s\n", k.c_str(), v.c_str());
  }
}

CommandSetup Setup() {
  return [](CLI::App* app) -> std::function<absl::Status()> {
    auto db = std::make_shared<std::string>();
    auto json = std::make_shared<bool>(false);
    app->add_option("DB", *db, "Store directory")->required();
    app->add_flag("--json", *json, "Print JSON instead of a table");
    return [db, json]() -> absl::Status {
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
PBGI_REGISTER_COMMAND(info, "info", "Print what a store's meta record holds", Setup());
}  // namespace pbgi::tools
