// Database::Open over LMDB, in its own file: code that opens only in-memory sources does not
// link the store.
#include "pbgi/query.h"
#include "query/page_source.h"

namespace pbgi {

absl::StatusOr<std::unique_ptr<Database>> Database::Open(const std::string& path,
                                                         const DatabaseOptions& options) {
  absl::StatusOr<std::unique_ptr<internal::PageSource>> source =
      internal::OpenLmdbPageSource(path, options.verify_checksums, options.copy_pages);
  if (!source.ok()) return source.status();
  return OpenSource(std::move(*source), options);
}

}  // namespace pbgi
