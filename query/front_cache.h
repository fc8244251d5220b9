// FrontCache: a Reader's own LRU, the first cache level. It holds pins (PageCache::Handle) into
// the shared cache, not copies, so a page is in memory once whoever uses it; its hits take no
// lock. Fixed capacity, allocated when the Reader is made: no allocation after that.
//
// Not thread-safe: one per Reader.
#ifndef PBGI_QUERY_FRONT_CACHE_H_
#define PBGI_QUERY_FRONT_CACHE_H_

#include <cstdint>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "query/page_cache.h"
#include "tree/decoded_page.h"

namespace pbgi::internal {

// A decoded page as both cache levels hold it; charged its own size and its arrays'.
struct CachedPage final : public CacheValue {
  DecodedPage page;
  uint64_t Charge() const { return sizeof(CachedPage) + page.ArrayBytes(); }
};

class FrontCache {
 public:
  // Holds pages while their charge stays within `budget_bytes` (but always at least two) and
  // at most `max_entries`.
  FrontCache(uint64_t budget_bytes, uint32_t max_entries);
  FrontCache(const FrontCache&) = delete;
  FrontCache& operator=(const FrontCache&) = delete;

  // The page for `key`, made most recently used; nullptr if absent.
  const DecodedPage* Find(uint64_t key) {
    auto it = index_.find(key);
    if (it == index_.end()) return nullptr;
    const uint32_t i = it->second;
    Unlink(i);
    LinkFront(i);
    return slots_[i].page;
  }

  // Adds a pinned page (key absent), evicting least recently used pages to make room. Pointers
  // returned earlier stay valid until evictions() changes.
  const DecodedPage* Insert(uint64_t key, PageCache::Handle handle);

  uint64_t evictions() const { return evictions_; }
  uint64_t used_bytes() const { return used_; }
  uint32_t size() const { return size_; }
  uint64_t budget_bytes() const { return budget_; }
  // A new budget, applied from the next Insert() on.
  void set_budget_bytes(uint64_t bytes) { budget_ = bytes; }
  // Unpins everything.
  void Clear();

 private:
  static constexpr uint32_t kNil = ~uint32_t{0};
  struct Slot {
    uint64_t key = 0;
    PageCache::Handle handle;
    const DecodedPage* page = nullptr;
    uint32_t prev = kNil, next = kNil;
  };
  void Unlink(uint32_t i);
  void LinkFront(uint32_t i);
  void EvictOne();

  uint64_t budget_;
  uint64_t used_ = 0;
  uint32_t size_ = 0;
  uint64_t evictions_ = 0;
  std::vector<Slot> slots_;
  std::vector<uint32_t> free_;
  uint32_t head_ = kNil;  // most recently used
  uint32_t tail_ = kNil;  // least recently used
  absl::flat_hash_map<uint64_t, uint32_t> index_;
};

}  // namespace pbgi::internal

#endif  // PBGI_QUERY_FRONT_CACHE_H_
