// TempDatabase (include/pbgi/testing.h): builds with BuildDatabase, in its own file so the
// oracle and checks link without the builder.
#include <stdlib.h>

#include <filesystem>
#include <system_error>

#include "absl/strings/str_format.h"
#include "pbgi/testing.h"

namespace pbgi::testing {

absl::StatusOr<std::unique_ptr<TempDatabase>> TempDatabase::Create(absl::Span<const Surfel> surfels,
                                                                   const BuildOptions& build,
                                                                   const DatabaseOptions& open) {
  std::string base;
  for (const char* var : {"PBGI_TEST_TMPDIR", "TMPDIR"}) {
    if (const char* v = getenv(var); v != nullptr && v[0] != '\0') {
      base = v;
      break;
    }
  }
  if (base.empty()) base = "/tmp";
  std::error_code ec;
  std::filesystem::create_directories(base, ec);
  std::string templ = base + "/pbgi-testdb-XXXXXX";
  if (mkdtemp(templ.data()) == nullptr) {
    return absl::InternalError(absl::StrFormat("cannot make a temporary directory in %s", base));
  }
  std::unique_ptr<TempDatabase> t(new TempDatabase);
  t->dir_ = templ;
  t->db_path_ = templ + "/db";
  VectorSurfelSource source(surfels);
  BuildOptions options = build;
  if (options.tmp_dir.empty()) options.tmp_dir = templ;
  absl::StatusOr<BuildStats> stats = BuildDatabase(source, t->db_path_, options);
  if (!stats.ok()) return stats.status();
  t->stats_ = *stats;
  absl::StatusOr<std::unique_ptr<Database>> db = Database::Open(t->db_path_, open);
  if (!db.ok()) return db.status();
  t->db_ = std::move(*db);
  absl::StatusOr<std::vector<Surfel>> all = ReadAllSurfels(*t->db_);
  if (!all.ok()) return all.status();
  t->surfels_ = std::move(*all);
  return t;
}

TempDatabase::~TempDatabase() {
  db_.reset();
  if (!dir_.empty()) {
    std::error_code ec;
    std::filesystem::remove_all(dir_, ec);
  }
}

}  // namespace pbgi::testing
