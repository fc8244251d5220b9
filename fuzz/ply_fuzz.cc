// The PLY reader (pbgi/ply.h) on any bytes: errors, never crashes; a file it reads whole gives
// the header's count of surfels, the same ones again after Rewind().
#include <cstring>
#include <vector>

#include "fuzz/fuzz_util.h"
#include "pbgi/ply.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static pbgi::fuzz::MemFile file;
  auto src = pbgi::OpenPly(file.Set(data, size));
  if (!src.ok()) return 0;
  std::vector<pbgi::Surfel> buf(61), first;
  for (int pass = 0; pass < 2; ++pass) {
    uint64_t count = 0;
    bool ok = true;
    for (;;) {
      auto n = (*src)->Next(absl::MakeSpan(buf));
      if (!n.ok()) {
        ok = false;
        break;
      }
      if (*n == 0) break;
      if (pass == 0 && first.empty()) first.assign(buf.begin(), buf.begin() + *n);
      if (pass == 1 && count == 0 && !first.empty()) {
        pbgi::fuzz::Require(*n == first.size() &&
                            std::memcmp(buf.data(), first.data(), *n * sizeof(pbgi::Surfel)) == 0);
      }
      count += *n;
    }
    if (ok) pbgi::fuzz::Require(count == static_cast<uint64_t>((*src)->KnownCount()));
    if (!(*src)->Rewind().ok()) break;
  }
  return 0;
}
