#include "query/front_cache.h"

#include <algorithm>
#include <utility>

namespace pbgi::internal {

FrontCache::FrontCache(uint64_t budget_bytes, uint32_t max_entries)
    : budget_(budget_bytes), slots_(std::max<uint32_t>(2, max_entries)) {
  free_.reserve(slots_.size());
  for (uint32_t i = static_cast<uint32_t>(slots_.size()); i-- > 0;) free_.push_back(i);
  // Twice the entries: erase+insert cycles then rehash in place and never allocate.
  index_.reserve(slots_.size() * 2);
}

void FrontCache::Unlink(uint32_t i) {
  Slot& s = slots_[i];
  if (s.prev != kNil)
    slots_[s.prev].next = s.next;
  else
    head_ = s.next;
  if (s.next != kNil)
    slots_[s.next].prev = s.prev;
  else
    tail_ = s.prev;
  s.prev = s.next = kNil;
}

void FrontCache::LinkFront(uint32_t i) {
  Slot& s = slots_[i];
  s.prev = kNil;
  s.next = head_;
  if (head_ != kNil) slots_[head_].prev = i;
  head_ = i;
  if (tail_ == kNil) tail_ = i;
}

void FrontCache::EvictOne() {
  const uint32_t i = tail_;
  Unlink(i);
  Slot& s = slots_[i];
  index_.erase(s.key);
  used_ -= s.handle.charge();
  s.handle.Release();
  s.page = nullptr;
  free_.push_back(i);
  --size_;
  ++evictions_;
}

const DecodedPage* FrontCache::Insert(uint64_t key, PageCache::Handle handle) {
  const uint64_t charge = handle.charge();
  while (size_ > 0 && (free_.empty() || (size_ >= 2 && used_ + charge > budget_))) EvictOne();
  const uint32_t i = free_.back();
  free_.pop_back();
  Slot& s = slots_[i];
  s.key = key;
  s.page = &static_cast<const CachedPage*>(handle.value())->page;
  s.handle = std::move(handle);
  used_ += charge;
  ++size_;
  index_.emplace(key, i);
  LinkFront(i);
  return s.page;
}

void FrontCache::Clear() {
  while (size_ > 0) EvictOne();
}

}  // namespace pbgi::internal
