#include "query/page_cache.h"

#include <string>
#include <utility>

namespace pbgi::internal {
namespace {

// A copy of `s` that shares no reference-counted payload with it. Each waiter of a failed load
// gets its own: the distribution's Abseil counts references inside a library that
// ThreadSanitizer cannot see, so a payload shared across threads would look like a race.
absl::Status Unshared(const absl::Status& s) {
  return absl::Status(s.code(), std::string(s.message()));
}

}  // namespace

PageCache::Handle& PageCache::Handle::operator=(Handle&& o) noexcept {
  if (this != &o) {
    Release();
    cache_ = o.cache_;
    e_ = o.e_;
    o.cache_ = nullptr;
    o.e_ = nullptr;
  }
  return *this;
}

void PageCache::Handle::Release() {
  if (e_ != nullptr) {
    cache_->ReleaseEntry(e_);
    e_ = nullptr;
    cache_ = nullptr;
  }
}

// An entry's value, charge and key do not change while it is pinned, so reading them needs no
// lock.
const CacheValue* PageCache::Handle::value() const { return e_->value.get(); }
uint64_t PageCache::Handle::charge() const { return e_->charge; }
uint64_t PageCache::Handle::key() const { return e_->key; }

PageCache::Shard::Shard() {
  std::lock_guard<std::mutex> l(mu);
  lru.next = lru.prev = &lru;
  in_use.next = in_use.prev = &in_use;
}

PageCache::PageCache(uint64_t capacity_bytes, int shard_bits)
    : capacity_(capacity_bytes),
      shard_bits_(shard_bits < 0 ? 0 : (shard_bits > 10 ? 10 : shard_bits)),
      shards_(new Shard[size_t{1} << shard_bits_]) {
  const uint64_t n = uint64_t{1} << shard_bits_;
  const uint64_t per_shard = (capacity_bytes + n - 1) / n;
  for (uint64_t i = 0; i < n; ++i) shards_[i].capacity = per_shard;
}

PageCache::~PageCache() {
  const size_t n = size_t{1} << shard_bits_;
  for (size_t i = 0; i < n; ++i) {
    Shard& s = shards_[i];
    std::lock_guard<std::mutex> l(s.mu);
    // REQUIRES: no handles, so every entry is on the lru list with refs == 1.
    while (s.lru.next != &s.lru) {
      Entry* e = s.lru.next;
      ListRemove(e);
      e->in_cache = false;
      Unref(s, e);
    }
    s.table.clear();
  }
}

int PageCache::DefaultShardBits(uint64_t capacity_bytes, uint64_t page_charge) {
  if (page_charge == 0) page_charge = 1;
  int bits = 0;
  while (bits < 4 && capacity_bytes / page_charge >= (uint64_t{8} << (bits + 1))) ++bits;
  return bits;
}

void PageCache::ListRemove(Entry* e) {
  e->next->prev = e->prev;
  e->prev->next = e->next;
  e->next = e->prev = nullptr;
}

void PageCache::ListAppend(Entry* list, Entry* e) {
  e->next = list;
  e->prev = list->prev;
  e->prev->next = e;
  e->next->prev = e;
}

void PageCache::Ref(Shard& s, Entry* e) {
  if (e->refs == 1 && e->in_cache && !e->loading) {
    ListRemove(e);
    ListAppend(&s.in_use, e);
    s.pinned += e->charge;
  }
  ++e->refs;
}

void PageCache::Unref(Shard& s, Entry* e) {
  --e->refs;
  if (e->refs == 0) {
    delete e;
  } else if (e->in_cache && e->refs == 1 && !e->loading) {
    ListRemove(e);
    ListAppend(&s.lru, e);
    s.pinned -= e->charge;
  }
}

void PageCache::EvictWhileOver(Shard& s) {
  while (s.usage > s.capacity && s.lru.next != &s.lru) {
    Entry* old = s.lru.next;
    ListRemove(old);
    s.table.erase(old->key);
    old->in_cache = false;
    s.usage -= old->charge;
    ++s.counters.evictions;
    Unref(s, old);
  }
}

void PageCache::ReleaseEntry(Entry* e) {
  Shard& s = ShardFor(e->key);
  std::lock_guard<std::mutex> l(s.mu);
  ++s.counters.releases;
  Unref(s, e);
  EvictWhileOver(s);
}

absl::StatusOr<PageCache::Handle> PageCache::Lookup(uint64_t key, Loader load, Outcome* outcome) {
  Shard& s = ShardFor(key);
  std::unique_lock<std::mutex> lock(s.mu);
  if (auto it = s.table.find(key); it != s.table.end()) {
    Entry* e = it->second;
    if (!e->loading) {
      Ref(s, e);
      ++s.counters.hits;
      lock.unlock();
      if (outcome != nullptr) *outcome = Outcome::kHit;
      return Handle(this, e);
    }
    // Single flight: another thread is reading this page; wait for its result. Our reference
    // keeps the entry alive even if the load fails and it leaves the table.
    ++e->refs;
    ++s.counters.waits;
    s.loaded.wait(lock, [e]() { return !e->loading; });
    if (!e->status.ok()) {
      absl::Status status = Unshared(e->status);
      Unref(s, e);
      return status;
    }
    lock.unlock();
    if (outcome != nullptr) *outcome = Outcome::kWaited;
    return Handle(this, e);
  }

  auto* e = new Entry;
  e->key = key;
  e->refs = 2;  // the cache's and the caller's
  e->in_cache = true;
  e->loading = true;
  s.table.emplace(key, e);
  ++s.counters.misses;
  lock.unlock();

  absl::StatusOr<Loaded> loaded = load();

  lock.lock();
  e->loading = false;
  s.loaded.notify_all();  // waiters re-check once this thread releases the lock
  if (!loaded.ok() || loaded->value == nullptr) {
    // Never cache a failed load: waiters get the error, the next Lookup() loads again.
    e->status =
        loaded.ok() ? absl::InternalError("page loader returned no value") : loaded.status();
    ++s.counters.failed_loads;
    s.table.erase(key);
    e->in_cache = false;
    absl::Status status = Unshared(e->status);
    Unref(s, e);  // the cache's reference
    Unref(s, e);  // the caller's
    return status;
  }
  e->value = std::move(loaded->value);
  e->charge = loaded->charge;
  s.usage += e->charge;
  s.pinned += e->charge;
  ListAppend(&s.in_use, e);
  ++s.counters.loads;
  s.counters.load_charge += e->charge;
  EvictWhileOver(s);
  lock.unlock();
  if (outcome != nullptr) *outcome = Outcome::kLoaded;
  return Handle(this, e);
}

uint64_t PageCache::usage() const {
  uint64_t total = 0;
  for (size_t i = 0; i < (size_t{1} << shard_bits_); ++i) {
    std::lock_guard<std::mutex> l(shards_[i].mu);
    total += shards_[i].usage;
  }
  return total;
}

uint64_t PageCache::pinned_usage() const {
  uint64_t total = 0;
  for (size_t i = 0; i < (size_t{1} << shard_bits_); ++i) {
    std::lock_guard<std::mutex> l(shards_[i].mu);
    total += shards_[i].pinned;
  }
  return total;
}

size_t PageCache::entries() const {
  size_t total = 0;
  for (size_t i = 0; i < (size_t{1} << shard_bits_); ++i) {
    std::lock_guard<std::mutex> l(shards_[i].mu);
    total += shards_[i].table.size();
  }
  return total;
}

PageCache::Counters PageCache::counters() const {
  Counters c;
  for (size_t i = 0; i < (size_t{1} << shard_bits_); ++i) {
    std::lock_guard<std::mutex> l(shards_[i].mu);
    const Counters& x = shards_[i].counters;
    c.hits += x.hits;
    c.waits += x.waits;
    c.misses += x.misses;
    c.loads += x.loads;
    c.load_charge += x.load_charge;
    c.failed_loads += x.failed_loads;
    c.evictions += x.evictions;
    c.releases += x.releases;
  }
  return c;
}

void PageCache::Prune() {
  for (size_t i = 0; i < (size_t{1} << shard_bits_); ++i) {
    Shard& s = shards_[i];
    std::lock_guard<std::mutex> l(s.mu);
    while (s.lru.next != &s.lru) {
      Entry* old = s.lru.next;
      ListRemove(old);
      s.table.erase(old->key);
      old->in_cache = false;
      s.usage -= old->charge;
      ++s.counters.evictions;
      Unref(s, old);
    }
  }
}

}  // namespace pbgi::internal
