// The happens-before edges of a TBB fork-join region, told to ThreadSanitizer.
//
// Debian's libtbb is not instrumented: TSan sees neither the hand-over of a task to a worker
// thread nor the wait for its end, so what the caller wrote before a parallel loop and read
// after it was reported as a race with the workers (ShadeEngine's per-thread statistics read
// after the loop, the sampler's buffers freed after its pilot reduce). A TsanRegion marks the
// two edges: the caller's writes before the region happen before every task (fork), and every
// task happens before what the caller does after Joined() (join). Tasks get no edge between
// each other, so a race between two tasks is still reported. Outside a TSan build it is empty
// and every call compiles to nothing.
#ifndef PBGI_BASE_TSAN_REGION_H_
#define PBGI_BASE_TSAN_REGION_H_

#if defined(__SANITIZE_THREAD__)
#define PBGI_TSAN_REGION 1
#elif defined(__has_feature)
#if __has_feature(thread_sanitizer)
#define PBGI_TSAN_REGION 1
#endif
#endif

#ifdef PBGI_TSAN_REGION
extern "C" void __tsan_acquire(void* addr);
extern "C" void __tsan_release(void* addr);
#endif

namespace pbgi::internal {

class TsanRegion {
 public:
  // One task's span: from its construction (the fork edge) to its destruction (the join edge),
  // early returns included.
  class Task {
   public:
    explicit Task(const TsanRegion& region) : region_(region) {
#ifdef PBGI_TSAN_REGION
      __tsan_acquire(&region_.fork_);
#endif
    }
    ~Task() {
#ifdef PBGI_TSAN_REGION
      __tsan_release(&region_.join_);
#endif
    }
    Task(const Task&) = delete;
    Task& operator=(const Task&) = delete;

   private:
    [[maybe_unused]] const TsanRegion& region_;  // read only under PBGI_TSAN_REGION
  };

  // Constructed before the region's tasks are handed to TBB (Fork() again before a later
  // hand-over of the same region).
  TsanRegion() { Fork(); }
  TsanRegion(const TsanRegion&) = delete;
  TsanRegion& operator=(const TsanRegion&) = delete;

  void Fork() const {
#ifdef PBGI_TSAN_REGION
    __tsan_release(&fork_);
#endif
  }
  // At the top of each task body: `const TsanRegion::Task task(region);`.
  // After the loop returns (or the task group's wait()): everything the tasks did is visible.
  void Joined() const {
#ifdef PBGI_TSAN_REGION
    __tsan_acquire(&join_);
#endif
  }

 private:
  [[maybe_unused]] mutable char fork_ = 0, join_ = 0;  // read only under PBGI_TSAN_REGION
};

}  // namespace pbgi::internal

#endif  // PBGI_BASE_TSAN_REGION_H_
