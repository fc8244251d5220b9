// The tree checker behind pbgi::VerifyTree (include/pbgi/build.h): the octree's invariants,
// checked over any page source (store/page_io.h). Internal.
#ifndef PBGI_TREE_VERIFY_H_
#define PBGI_TREE_VERIFY_H_

#include <string>

#include "absl/status/status.h"
#include "pbgi/store.h"
#include "store/page_io.h"

namespace pbgi::internal {

// OK when `meta` describes a pbgi database as a build writes it: points and nodes, page counts
// that fit them, finite bounds that are not empty, the root inside the node pages, SH order 2.
// Else DataLoss naming `name` and what is wrong. PageStore::Open refuses only what no store can
// hold (store/meta_codec.h): a bare store of pages need not be a database, but a record crafted
// with a valid checksum (no points, NaN bounds) must not be shaded as zeros, so the query
// layer's open and VerifyTree check this too.
absl::Status CheckDatabaseMeta(const StoreMeta& meta, const std::string& name);

// Checks the tree that `pages` holds against `meta` (its counts, depth and root). Reads every
// page once; the error names the first violation.
absl::Status VerifyTreePages(const StoreMeta& meta, const PageSource& pages);

}  // namespace pbgi::internal

#endif  // PBGI_TREE_VERIFY_H_
