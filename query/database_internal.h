// Opening a Database over any page source (store/page_io.h): the LMDB store in production
// (Database::Open), the in-memory store in tests (store/mem_page_store.h). Internal: the page
// seam is not part of the public API.
#ifndef PBGI_QUERY_DATABASE_INTERNAL_H_
#define PBGI_QUERY_DATABASE_INTERNAL_H_

#include <memory>

#include "absl/status/statusor.h"
#include "pbgi/query.h"
#include "store/page_io.h"

namespace pbgi::internal {

absl::StatusOr<std::unique_ptr<Database>> OpenDatabase(std::unique_ptr<PageSource> source,
                                                       const DatabaseOptions& options = {});

}  // namespace pbgi::internal

#endif  // PBGI_QUERY_DATABASE_INTERNAL_H_
