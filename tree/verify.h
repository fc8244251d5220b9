// The tree checker behind pbgi::VerifyTree (include/pbgi/build.h): the octree's invariants,
// checked over any page source (store/page_io.h). Internal.
#ifndef PBGI_TREE_VERIFY_H_
#define PBGI_TREE_VERIFY_H_

#include "absl/status/status.h"
#include "pbgi/store.h"
#include "store/page_io.h"

namespace pbgi::internal {

// Checks the tree that `pages` holds against `meta` (its counts, depth and root). Reads every
// page once; the error names the first violation.
absl::Status VerifyTreePages(const StoreMeta& meta, const PageSource& pages);

}  // namespace pbgi::internal

#endif  // PBGI_TREE_VERIFY_H_
