// PageCache: the shared, sharded LRU of decoded pages (docs/design.md, "Query").
//
// The shape of LevelDB's util/cache.cc -- per shard a table, a list of pinned entries and a list
// of evictable ones in LRU order, capacity in bytes of charge -- with what RocksDB added later:
// shards padded to a cache line, a 64-bit mix of the key before taking the shard bits (so that
// neighbouring page numbers spread over shards), single-flight loading, and mutex annotations.
//
// Thread safety: a PageCache is safe to share between threads. A Handle belongs to one thread.
//
// Contracts:
// - A looked-up entry is pinned until its Handle is destroyed (or Release()d): a pinned entry is
//   never evicted, and its value never moves.
// - Usage counts pinned entries too. The cache evicts unpinned entries, least recently used
//   first, until usage <= capacity; if pinned entries alone exceed the capacity it stays over
//   until they are released. Callers keep their pins within the budget (query.h explains how).
// - Lookup() calls its loader at most once for concurrent misses of one key: the other callers
//   wait for the result. A failed load is returned to everyone who waited for it and is never
//   cached: the next Lookup() tries again.
// - REQUIRES: every Handle is destroyed before the cache.
#ifndef PBGI_QUERY_PAGE_CACHE_H_
#define PBGI_QUERY_PAGE_CACHE_H_

#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/container/flat_hash_map.h"
#include "absl/functional/function_ref.h"
#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace pbgi::internal {

// What the cache holds. Values are immutable once inserted.
class CacheValue {
 public:
  virtual ~CacheValue() = default;
};

// Finalizer of MurmurHash3 (a 64-bit mix): every key bit affects the top (shard) bits.
inline uint64_t MixKey(uint64_t k) {
  k ^= k >> 33;
  k *= 0xff51afd7ed558ccdull;
  k ^= k >> 33;
  k *= 0xc4ceb9fe1a85ec53ull;
  k ^= k >> 33;
  return k;
}

class PageCache {
 private:
  struct Entry;

 public:
  struct Counters {
    uint64_t hits = 0;          // found loaded
    uint64_t waits = 0;         // found loading by another thread, and waited for it
    uint64_t misses = 0;        // not found: this caller loaded it
    uint64_t loads = 0;         // successful loads (pages read)
    uint64_t load_charge = 0;   // charge of the successful loads
    uint64_t failed_loads = 0;  // loads that returned an error (never cached)
    uint64_t evictions = 0;
    uint64_t releases = 0;  // handles released (unpins)
    // Every call that took a shard's lock on behalf of a caller: lookups and unpins.
    uint64_t calls() const { return hits + waits + misses + releases; }
  };

  // A loaded value and what it costs in bytes.
  struct Loaded {
    std::unique_ptr<CacheValue> value;
    uint64_t charge = 0;
  };
  using Loader = absl::FunctionRef<absl::StatusOr<Loaded>()>;

  // How a Lookup() was served.
  enum class Outcome { kHit, kWaited, kLoaded };

  // A pin on one entry. Move-only; unpins when destroyed.
  class Handle {
   public:
    Handle() = default;
    Handle(Handle&& o) noexcept : cache_(o.cache_), e_(o.e_) { o.cache_ = nullptr, o.e_ = nullptr; }
    Handle& operator=(Handle&& o) noexcept;
    Handle(const Handle&) = delete;
    Handle& operator=(const Handle&) = delete;
    ~Handle() { Release(); }

    void Release();
    explicit operator bool() const { return e_ != nullptr; }
    const CacheValue* value() const;
    uint64_t charge() const;
    uint64_t key() const;

   private:
    friend class PageCache;
    Handle(PageCache* cache, Entry* e) : cache_(cache), e_(e) {}
    PageCache* cache_ = nullptr;
    Entry* e_ = nullptr;
  };

  // `capacity_bytes` is split evenly over 2^shard_bits shards.
  PageCache(uint64_t capacity_bytes, int shard_bits);
  ~PageCache();
  PageCache(const PageCache&) = delete;
  PageCache& operator=(const PageCache&) = delete;

  // Returns a pinned handle to the entry for `key`, calling `load` to fill it on a miss.
  absl::StatusOr<Handle> Lookup(uint64_t key, Loader load, Outcome* outcome = nullptr);

  uint64_t capacity() const { return capacity_; }
  int shard_bits() const { return shard_bits_; }
  uint64_t usage() const;         // charge of all entries
  uint64_t pinned_usage() const;  // charge of pinned entries
  size_t entries() const;
  Counters counters() const;
  // Evicts every unpinned entry.
  void Prune();

  // Shard bits for a cache of `capacity_bytes` holding pages of about `page_charge` bytes: up to
  // 16 shards, but at least 8 pages per shard so a small cache still behaves as one LRU.
  static int DefaultShardBits(uint64_t capacity_bytes, uint64_t page_charge);

 private:
  struct Entry {
    uint64_t key = 0;
    std::unique_ptr<CacheValue> value;
    uint64_t charge = 0;
    uint32_t refs = 0;  // one for the cache while in_cache, one per Handle or waiter
    bool in_cache = false;
    bool loading = false;
    absl::Status status;  // of a failed load
    Entry* prev = nullptr;
    Entry* next = nullptr;
  };

  // std::mutex rather than absl::Mutex: the distribution's Abseil is not built with TSan
  // annotations, so ThreadSanitizer could not see absl::Mutex synchronize; pthread mutexes and
  // condition variables it intercepts.
  struct alignas(64) Shard {
    Shard();
    mutable std::mutex mu;
    std::condition_variable loaded;  // signalled when an entry's load finishes
    uint64_t capacity = 0;
    uint64_t usage ABSL_GUARDED_BY(mu) = 0;
    uint64_t pinned ABSL_GUARDED_BY(mu) = 0;
    Entry lru ABSL_GUARDED_BY(mu);     // in_cache, refs == 1: evictable, oldest first
    Entry in_use ABSL_GUARDED_BY(mu);  // in_cache, refs >= 2, loaded: pinned
    absl::flat_hash_map<uint64_t, Entry*> table ABSL_GUARDED_BY(mu);
    Counters counters ABSL_GUARDED_BY(mu);
  };

  Shard& ShardFor(uint64_t key) {
    return shards_[shard_bits_ == 0 ? 0 : MixKey(key) >> (64 - shard_bits_)];
  }
  static void ListRemove(Entry* e);
  static void ListAppend(Entry* list, Entry* e);
  void Ref(Shard& s, Entry* e) ABSL_EXCLUSIVE_LOCKS_REQUIRED(s.mu);
  void Unref(Shard& s, Entry* e) ABSL_EXCLUSIVE_LOCKS_REQUIRED(s.mu);
  void EvictWhileOver(Shard& s) ABSL_EXCLUSIVE_LOCKS_REQUIRED(s.mu);
  void ReleaseEntry(Entry* e);

  uint64_t capacity_;
  int shard_bits_;
  std::unique_ptr<Shard[]> shards_;
};

}  // namespace pbgi::internal

#endif  // PBGI_QUERY_PAGE_CACHE_H_
