// The meta record codec (store/meta_codec.h) on any bytes: DataLoss or a record that encodes
// and decodes back to itself; CheckDatabaseMeta on whatever decodes.
#include <cstring>
#include <string>

#include "absl/strings/string_view.h"
#include "fuzz/fuzz_util.h"
#include "pbgi/store.h"
#include "store/meta_codec.h"
#include "tree/verify.h"

namespace {

bool Same(const pbgi::StoreMeta& a, const pbgi::StoreMeta& b) {
  auto bits = [](const pbgi::Bounds& x, const pbgi::Bounds& y) {
    return std::memcmp(&x, &y, sizeof(x)) == 0;
  };
  return a.version == b.version && a.page_size == b.page_size && a.channels == b.channels &&
         a.sh_order == b.sh_order && a.leaf_size == b.leaf_size && bits(a.bounds, b.bounds) &&
         a.point_count == b.point_count && a.node_count == b.node_count &&
         a.node_pages == b.node_pages && a.point_pages == b.point_pages && a.root == b.root &&
         a.max_depth == b.max_depth && a.layout == b.layout && a.stats == b.stats;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const absl::string_view bytes(reinterpret_cast<const char*>(data), size);
  auto d = pbgi::internal::DecodeMeta(bytes, "fuzz");
  if (!d.ok()) return 0;
  (void)pbgi::internal::CheckDatabaseMeta(d->meta, "fuzz");
  const std::string again = pbgi::internal::EncodeMeta(d->meta, d->complete);
  auto e = pbgi::internal::DecodeMeta(again, "fuzz");
  pbgi::fuzz::Require(e.ok() && e->complete == d->complete && Same(e->meta, d->meta));
  return 0;
}
