// An in-memory database for query tests that need no builder: a small octree built in memory
// from a vector of surfels and written as node and point pages (tree/format.h) into a
// MemPageStore. Sibling groups are packed into node pages in depth-first order.
#ifndef PBGI_TESTS_QUERY_FAKE_DB_H_
#define PBGI_TESTS_QUERY_FAKE_DB_H_

#include <cstdint>
#include <memory>
#include <vector>

#include "pbgi/surfel.h"
#include "store/mem_page_store.h"

namespace pbgi::internal {

struct FakeDbOptions {
  uint32_t leaf_size = 8;
  uint32_t page_size = 4096 - 16;
  Channels channels = Channels::kRadiance;
};

struct FakeDb {
  std::unique_ptr<MemPageStore> source;
  std::vector<Surfel> surfels;  // in database (Morton) order: index = global point index
};

FakeDb BuildFakeDb(const std::vector<Surfel>& input, const FakeDbOptions& options);

}  // namespace pbgi::internal

#endif  // PBGI_TESTS_QUERY_FAKE_DB_H_
