// `pbgi info DB [--json]`: what the meta record of a store holds.
#include <cstdio>
#include <string>

#include "absl/strings/str_format.h"
#include "pbgi/status.h"
#include "pbgi/store.h"
#include "tools/command.h"

namespace pbgi::tools {
namespace {

std::string JsonString(const std::string& s) {
  std::string out = "\"";
  for (unsigned char c : s) {
    switch (c) {
      case '"':
        out += "\\\"";
        break;
      case '\\':
        out += "\\\\";
        break;
      case '\n':
        out += "\\n";
        break;
      case '\t':
        out += "\\t";
        break;
      default:
        if (c < 0x20) {
          out += absl::StrFormat("\\u%04x", c);
        } else {
          out += static_cast<char>(c);
        }
    }
  }
  return out + "\"";
}

// JSON has no inf or nan: an empty box's float limits are printed as they are (finite).
std::string JsonNumber(float v) { return absl::StrFormat("%.9g", v); }

const char* ChannelsName(Channels c) { return HasRadiance(c) ? "radiance" : "occlusion"; }

void PrintJson(const PageStore& store) {
  const StoreMeta& m = store.meta();
  std::string out = "{\n";
  out += absl::StrFormat("  \"path\": %s,\n", JsonString(store.path()));
  out += absl::StrFormat("  \"magic\": \"0x%016x\",\n", m.magic);
  out += absl::StrFormat("  \"version\": %d,\n", m.version);
  out += absl::StrFormat("  \"page_size\": %d,\n", m.page_size);
  out += absl::StrFormat("  \"channels\": \"%s\",\n", ChannelsName(m.channels));
  out += absl::StrFormat("  \"sh_order\": %d,\n", m.sh_order);
  out += absl::StrFormat("  \"leaf_size\": %d,\n", m.leaf_size);
  out += absl::StrFormat("  \"bounds\": {\"lo\": [%s, %s, %s], \"hi\": [%s, %s, %s]},\n",
                         JsonNumber(m.bounds.lo.x), JsonNumber(m.bounds.lo.y),
                         JsonNumber(m.bounds.lo.z), JsonNumber(m.bounds.hi.x),
                         JsonNumber(m.bounds.hi.y), JsonNumber(m.bounds.hi.z));
  out += absl::StrFormat("  \"point_count\": %d,\n", m.point_count);
  out += absl::StrFormat("  \"node_count\": %d,\n", m.node_count);
  out += absl::StrFormat("  \"node_pages\": %d,\n", m.node_pages);
  out += absl::StrFormat("  \"point_pages\": %d,\n", m.point_pages);
  out += absl::StrFormat("  \"root\": %d,\n", m.root);
  out += absl::StrFormat("  \"max_depth\": %d,\n", m.max_depth);
  out += absl::StrFormat("  \"layout\": %s,\n", JsonString(m.layout));
  out += absl::StrFormat("  \"file_bytes\": %d,\n", store.FileBytes());
  out += "  \"stats\": {";
  bool first = true;
  for (const auto& [k, v] : m.stats) {
    out += absl::StrFormat("%s\n    %s: %s", first ? "" : ",", JsonString(k), JsonString(v));
    first = false;
  }
  out += first ? "}\n}\n" : "\n  }\n}\n";
  std::fputs(out.c_str(), stdout);
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
      if (absl::Status s = CheckDatabaseMeta(store->meta(), store->path()); !s.ok()) {
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
