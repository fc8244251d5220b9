// The page decoder (tree/decoded_page.h) and the gather that trusts what it decoded, on any
// bytes: one node page and one point page made of the input, a receiver from it, a gather from
// a root slot in it. Errors (DataLoss naming the page, InvalidArgument for the receiver), never
// a crash, an endless walk or a read outside a page.
//   input: [flags u8][receiver: 6 x f32][node records u16][node payload bytes u16][payloads...];
//   flags: bit 0 radiance, bits 1-3 the root slot, bits 4-6 the depth, bit 7 back radiance.
#include <algorithm>
#include <cstring>
#include <memory>
#include <vector>

#include "fuzz/fuzz_util.h"
#include "pbgi/query.h"
#include "query/database_internal.h"
#include "store/mem_page_store.h"
#include "tree/decoded_page.h"
#include "tree/format.h"

namespace {

template <typename T>
T Take(const uint8_t*& p, const uint8_t* end) {
  T v{};
  const size_t n = std::min<size_t>(sizeof(T), static_cast<size_t>(end - p));
  std::memcpy(&v, p, n);
  p += n;
  return v;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace pbgi;
  using namespace pbgi::internal;
  const uint8_t* p = data;
  const uint8_t* end = data + size;
  const uint8_t flags = Take<uint8_t>(p, end);
  Receiver r;
  for (int i = 0; i < 3; ++i) r.position[i] = Take<float>(p, end);
  for (int i = 0; i < 3; ++i) r.normal[i] = Take<float>(p, end);
  const uint16_t node_records = Take<uint16_t>(p, end);
  const size_t node_bytes = std::min<size_t>(Take<uint16_t>(p, end), static_cast<size_t>(end - p));
  const std::vector<uint8_t> node_payload(p, p + node_bytes);
  const std::vector<uint8_t> point_payload(p + node_bytes, end);

  StoreMeta m;
  m.channels = !(flags & 1)     ? Channels::kOcclusion
               : (flags & 0x80) ? Channels::kRadianceBothSides
                                : Channels::kRadiance;
  const size_t biggest =
      std::max({node_payload.size(), point_payload.size(), size_t{NodeRecordSize(m.channels)} + 8});
  m.page_size = static_cast<uint32_t>((sizeof(PageHeader) + biggest + 7) / 8 * 8);
  const uint32_t per_page = PointsPerPage(m.page_size, m.channels);
  const uint32_t points = std::min<uint32_t>(
      per_page, static_cast<uint32_t>(point_payload.size() / PointRecordSize(m.channels)));
  m.point_count = std::max<uint32_t>(points, 1);
  m.point_pages = 1;
  m.node_count = std::max<uint16_t>(node_records, 1);
  m.node_pages = 1;
  m.root = MakeNodeRef(0, (flags >> 1) & 7);
  m.max_depth = (flags >> 4) & 7;
  m.bounds.lo = glm::vec3(0.0f);
  m.bounds.hi = glm::vec3(1.0f);
  m.grid_step = 1.0f / (1 << kGridBits);  // the grid of the unit box (format version 3)

  // The decoder alone, on both kinds of pages.
  for (Section s : {Section::kNodes, Section::kPoints}) {
    const std::vector<uint8_t>& payload = s == Section::kNodes ? node_payload : point_payload;
    PageHeader h{};
    h.kind = static_cast<uint16_t>(s == Section::kNodes ? PageKind::kNode : PageKind::kPoint);
    h.record_count = s == Section::kNodes ? node_records : points;
    h.payload_bytes = static_cast<uint32_t>(payload.size());
    PageView v;
    v.header = &h;
    v.payload = absl::MakeConstSpan(payload);
    DecodedPage page;
    if (DecodePage(v, s, 0, m, "fuzz", &page).ok()) {
      pbgi::fuzz::Require(page.count == h.record_count);
      (void)page.ArrayBytes();
    }
  }

  // A gather over them.
  auto src = std::make_unique<MemPageStore>(m, "fuzz");
  if (!src->Append(Section::kNodes, 0, PageKind::kNode, node_records, node_payload).ok() ||
      !src->Append(Section::kPoints, 0, PageKind::kPoint, points, point_payload).ok()) {
    return 0;
  }
  DatabaseOptions o;
  o.cache_bytes = 1 << 20;
  auto db = OpenDatabase(std::move(src), o);
  if (!db.ok()) return 0;
  auto reader = (*db)->NewReader();
  if (!reader.ok()) return 0;
  Cut cut;
  cut.cosine_weighted = (flags & 0x80) != 0;
  Gathered g;
  QueryStats stats;
  if ((*reader)->Gather(r, cut, &g, &stats).ok()) {
    // What a gather returns lies inside the database.
    for (const Cluster& c : g.clusters) {
      pbgi::fuzz::Require(c.point_count <= m.point_count &&
                          c.first_point <= m.point_count - c.point_count);
    }
    for (uint64_t id : g.surfel_ids) pbgi::fuzz::Require(id < m.point_count);
  }
  std::vector<Surfel> read;
  (void)(*reader)->ReadPoints(0, m.point_count, &read);
  return 0;
}
