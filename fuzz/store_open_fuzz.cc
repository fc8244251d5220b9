// Opening a store file (PageStore::Open, with the check of LMDB's own pages that runs before
// LMDB sees it) on any bytes, then what `pbgi verify` and a reader do: every page read. Errors,
// never a crash: a file that passes the check is one LMDB can read without faulting.
#include <sys/stat.h>
#include <unistd.h>

#include <cstdlib>
#include <string>

#include "fuzz/fuzz_util.h"
#include "pbgi/store.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  // One scratch store directory for the whole run, removed at exit.
  static const struct Scratch {
    std::string dir;
    Scratch() {
      const char* base = std::getenv("TMPDIR");
      dir = std::string(base != nullptr ? base : "/tmp") + "/pbgi-store-fuzz-XXXXXX";
      if (mkdtemp(dir.data()) == nullptr) std::abort();
    }
    ~Scratch() {
      unlink((dir + "/data.mdb").c_str());
      rmdir(dir.c_str());
    }
  } scratch;
  const std::string& dir = scratch.dir;
  const std::string file = dir + "/data.mdb";
  {
    FILE* f = std::fopen(file.c_str(), "wb");
    if (f == nullptr) std::abort();
    if (size > 0 && std::fwrite(data, 1, size, f) != size) std::abort();
    std::fclose(f);
  }
  pbgi::StoreOptions options;
  options.copy_pages = size % 2 == 1;  // both read paths
  auto store = pbgi::PageStore::Open(dir, options);
  if (!store.ok()) return 0;
  auto report = pbgi::CheckAllPages(**store);
  auto txn = (*store)->BeginRead();
  if (!txn.ok()) return 0;
  const pbgi::StoreMeta& m = (*store)->meta();
  for (pbgi::Section s : {pbgi::Section::kNodes, pbgi::Section::kPoints}) {
    const uint64_t pages = s == pbgi::Section::kNodes ? m.node_pages : m.point_pages;
    for (uint64_t i = 0; i < pages && i < 4096; ++i) {
      auto page = txn->Get(s, i);
      if (page.ok()) {
        uint32_t sum = 0;
        for (uint8_t b : page->payload) sum += b;
        (void)sum;
      }
    }
  }
  return 0;
}
