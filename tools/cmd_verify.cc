// `pbgi verify DB`: reads every page of a store, checks it, prints a summary, and fails on the
// first inconsistency it can name.
#include <chrono>
#include <cstdio>
#include <memory>
#include <string>

#include "absl/strings/str_format.h"
#include "pbgi/build.h"
#include "pbgi/status.h"
#include "pbgi/store.h"
#include "tools/command.h"

namespace pbgi::tools {
namespace {

// Checks beyond the pages themselves: the octree that the builder wrote into them. Each check
// is one call that returns the first inconsistency as an error; add new ones here.
absl::Status CheckStructure(const PageStore& store) {
  PBGI_RETURN_IF_ERROR(VerifyTree(store));  // build/: tree invariants (pbgi/build.h)
  return absl::OkStatus();
}

CommandSetup Setup() {
  return [](CLI::App* app) -> std::function<absl::Status()> {
    auto db = std::make_shared<std::string>();
    auto pages_only = std::make_shared<bool>(false);
    app->add_option("DB", *db, "Store directory")->required();
    app->add_flag("--pages-only", *pages_only,
                  "Check pages and counts only, not the octree stored in them");
    return [db, pages_only]() -> absl::Status {
      const auto start = std::chrono::steady_clock::now();
      NoteStoreLeftovers("verify", *db);
      StoreOptions options;
      options.read_ahead = true;  // one sequential pass
      PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PageStore> store, PageStore::Open(*db, options));
      PBGI_ASSIGN_OR_RETURN(StoreCheckReport report, CheckAllPages(*store));
      const StoreMeta& m = store->meta();
      std::printf("store %s: format version %d, page size %d bytes, %s on disk\n",
                  store->path().c_str(), m.version, m.page_size,
                  FormatBytes(store->FileBytes()).c_str());
      std::printf("  node pages  %12llu  records %14llu  payload %s\n",
                  static_cast<unsigned long long>(report.nodes.pages),
                  static_cast<unsigned long long>(report.nodes.records),
                  FormatBytes(report.nodes.payload_bytes).c_str());
      std::printf("  point pages %12llu  records %14llu  payload %s\n",
                  static_cast<unsigned long long>(report.points.pages),
                  static_cast<unsigned long long>(report.points.records),
                  FormatBytes(report.points.payload_bytes).c_str());
      std::printf("  damaged pages %llu\n", static_cast<unsigned long long>(report.bad_pages));
      if (!report.ok()) return report.first_error;
      std::printf("  pages: OK (checksums, kinds, numbers, counts)\n");
      if (!*pages_only) {
        PBGI_RETURN_IF_ERROR(CheckStructure(*store));
        std::printf("  tree: OK\n");
      }
      const double secs =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      std::printf(
          "verified in %.2f s (%s/s)\n", secs,
          FormatBytes(static_cast<uint64_t>(store->FileBytes() / std::max(secs, 1e-9))).c_str());
      return absl::OkStatus();
    };
  };
}

}  // namespace
PBGI_REGISTER_COMMAND(verify, "verify", "Check every page of a store; fail on the first problem",
                      Setup());
}  // namespace pbgi::tools
