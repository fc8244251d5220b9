// What a page costs to decode when it enters the cache (tree/decoded_page.h): format version 3's
// compact records (tree/format.h) against the plain float records of version 2, decoded by a
// copy of version 2's loop, in one run; "v3z" adds zstd's decompression of the payload, as
// ReadTxn::Get does for a compressed page (store/page_store.cc). Full pages of the default size
// (65520 bytes), records from a random scene. Counters: us_per_page and ns_per_record.
//   query_decode_bench [benchmark flags]   e.g. --benchmark_repetitions=5
//                                              --benchmark_report_aggregates_only=true
#include <cmath>
#include <cstring>
#include <random>
#include <vector>

#include "benchmark/benchmark.h"
#include "pbgi/query.h"
#include "tree/cut.h"
#include "tree/decoded_page.h"
#include "tree/format.h"
#include "tree/morton.h"
#include "zstd.h"

namespace pbgi::internal {
namespace {

// Version 2's records (plain floats) and decode loop, as they were before format version 3.
struct V2Point {
  float position[3];
  float normal[3];
  float radius;
  float radiance[3];
};
static_assert(sizeof(V2Point) == 40);
constexpr uint32_t kV2NodeCommon = 104, kV2NodeRadiance = 216;
constexpr uint32_t kV2PointOcclusion = 28, kV2PointRadiance = 40;

void DecodeV2(const uint8_t* data, Section section, uint32_t count, Channels c, DecodedPage* page) {
  page->count = count;
  if (section == Section::kNodes) {
    const uint32_t rec = HasRadiance(c) ? kV2NodeRadiance : kV2NodeCommon;
    page->nodes.reset(new NodeHot[count]);
    page->areas.reset(new float[count]);
    if (HasRadiance(c)) page->power.reset(new std::array<Sh9, 3>[count]);
    for (uint32_t i = 0; i < count; ++i) {
      NodeRecordRadiance r{};
      std::memcpy(&r, data + size_t{i} * rec, rec);
      const NodeRecordCommon& n0 = r.common;
      if (!std::isfinite(n0.lo[0]) || n0.lo[0] > n0.hi[0] || n0.area < 0) std::abort();
      NodeHot& n = page->nodes[i];
      n.lo = {n0.lo[0], n0.lo[1], n0.lo[2]};
      n.hi = {n0.hi[0], n0.hi[1], n0.hi[2]};
      n.abs_max = AbsMax(n.lo, n.hi);
      page->areas[i] = n0.area;
      n.area_bound = ProjectedAreaBound(n0.sh_area);
      n.reach = NodeReach(n0.area);
      n.centre = 0.5f * (n.lo + n.hi);
      const NearSphere near = NodeNearSphere(n.lo, n.hi, n.reach);
      n.near_centre = near.centre;
      n.near_radius2 = near.radius2;
      std::memcpy(n.sh_area.data(), n0.sh_area, sizeof(n.sh_area));
      n.depth = static_cast<uint8_t>(n0.depth);
      n.child_count = static_cast<uint8_t>(n0.child_count);
      n.flat = NodeIsFlat(n.sh_area.data(), n.lo, n.hi) ? 1 : 0;  // as DecodePage
      n.children = n0.children;
      n.first_point = n0.first_point;
      n.point_count = n0.point_count;
      if (page->power) {
        for (int k = 0; k < 3; ++k) {
          std::memcpy(page->power[i][k].data(), r.sh_power[k], sizeof(r.sh_power[k]));
        }
      }
    }
  } else {
    const uint32_t rec = HasRadiance(c) ? kV2PointRadiance : kV2PointOcclusion;
    page->points.reset(new Surfel[count]);
    for (uint32_t i = 0; i < count; ++i) {
      V2Point r{};
      std::memcpy(&r, data + size_t{i} * rec, rec);
      Surfel& s = page->points[i];
      s.position = {r.position[0], r.position[1], r.position[2]};
      s.normal = {r.normal[0], r.normal[1], r.normal[2]};
      s.radius = std::fabs(r.radius);
      s.two_sided = std::signbit(r.radius);
      s.radiance =
          HasRadiance(c) ? glm::vec3(r.radiance[0], r.radiance[1], r.radiance[2]) : glm::vec3(0.0f);
    }
  }
}

struct Page {
  StoreMeta meta;
  PageHeader header{};
  std::vector<uint8_t> payload;
};

// A full page of `section` in format `version` (2 or 3), records of a random scene.
Page MakePage(Section section, Channels c, int version) {
  Page p;
  p.meta.channels = c;
  p.meta.page_size = kDefaultPageSize;
  p.meta.point_count = uint64_t{1} << 32;
  Bounds b;
  b.Extend(glm::vec3(0.0f));
  b.Extend(glm::vec3(100.0f));
  const PositionGrid grid = GridOfCube(MortonCube(b));
  for (int a = 0; a < 3; ++a) p.meta.grid_origin[a] = grid.origin[a];
  p.meta.grid_step = grid.step;
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  const uint32_t v3_rec = section == Section::kNodes ? NodeRecordSize(c) : PointRecordSize(c);
  const uint32_t v2_rec = section == Section::kNodes
                              ? (HasRadiance(c) ? kV2NodeRadiance : kV2NodeCommon)
                              : (HasRadiance(c) ? kV2PointRadiance : kV2PointOcclusion);
  const uint32_t rec = version == 2 ? v2_rec : v3_rec;
  const uint32_t count = (kDefaultPageSize - sizeof(PageHeader)) / rec;
  p.payload.resize(size_t{count} * rec);
  for (uint32_t i = 0; i < count; ++i) {
    uint8_t* dst = p.payload.data() + size_t{i} * rec;
    if (section == Section::kNodes) {
      NodeRecordRadiance r{};
      NodeRecordCommon& n = r.common;
      for (int k = 0; k < 3; ++k) {
        n.lo[k] = 100 * u(rng);
        n.hi[k] = n.lo[k] + u(rng);
      }
      const bool leaf = u(rng) < 0.77f;
      n.flags = leaf ? kNodeFlagLeaf : 0;
      n.child_count = leaf ? 0 : 1 + static_cast<uint32_t>(rng() % 8);
      n.children = leaf ? kNoNodeRef : MakeNodeRef(5, rng() % 100);
      n.first_point = rng() % 1000000;
      n.point_count = 1 + rng() % 16;
      n.depth = 1 + rng() % 12;
      n.area = u(rng);
      for (int k = 0; k < 9; ++k) n.sh_area[k] = (k == 0 ? 1.0f : u(rng) - 0.5f) * n.area;
      for (int ch = 0; ch < 3; ++ch) {
        for (int k = 0; k < 9; ++k) r.sh_power[ch][k] = n.sh_area[k] * u(rng);
      }
      if (version == 2) {
        std::memcpy(dst, &r, rec);
      } else {
        EncodeNodeRecord(r, c, grid, dst);
      }
    } else {
      const float pos[3] = {100 * u(rng), 100 * u(rng), 100 * u(rng)};
      const glm::vec3 nv = glm::normalize(glm::vec3(u(rng) - 0.5f, u(rng) - 0.5f, u(rng)));
      const float nrm[3] = {nv.x, nv.y, nv.z};
      const float radius = 0.01f + 0.1f * u(rng);
      const float rad[3] = {u(rng), u(rng), u(rng)};
      if (version == 2) {
        V2Point r{
            {pos[0], pos[1], pos[2]}, {nrm[0], nrm[1], nrm[2]}, radius, {rad[0], rad[1], rad[2]}};
        std::memcpy(dst, &r, rec);
      } else {
        EncodePointRecord(pos, nrm, radius, rad, c, grid, dst);
      }
    }
  }
  p.header.kind =
      static_cast<uint16_t>(section == Section::kNodes ? PageKind::kNode : PageKind::kPoint);
  p.header.format = static_cast<uint16_t>(version);
  p.header.record_count = count;
  p.header.payload_bytes = static_cast<uint32_t>(p.payload.size());
  p.header.page_no = 0;
  if (section == Section::kPoints) p.meta.point_count = count;
  return p;
}

// version 4 stands for 3 with zstd (level 1, as PageWriter) over the payload.
void BM_Decode(benchmark::State& state, Section section, Channels c, int version) {
  const Page p = MakePage(section, c, version == 4 ? 3 : version);
  PageView view;
  view.header = &p.header;
  view.payload = absl::MakeConstSpan(p.payload);
  std::vector<uint8_t> frame(ZSTD_compressBound(p.payload.size()));
  frame.resize(ZSTD_compress(frame.data(), frame.size(), p.payload.data(), p.payload.size(), 1));
  std::vector<uint8_t> whole(p.payload.size());
  ZSTD_DCtx* dctx = ZSTD_createDCtx();
  for (auto _ : state) {
    DecodedPage page;
    if (version == 4) {
      const size_t n =
          ZSTD_decompressDCtx(dctx, whole.data(), whole.size(), frame.data(), frame.size());
      if (n != whole.size()) {
        state.SkipWithError("zstd");
        break;
      }
      PageView v = view;
      v.payload = absl::MakeConstSpan(whole);
      absl::Status s = DecodePage(v, section, 0, p.meta, "bench", &page);
      if (!s.ok()) {
        state.SkipWithError(std::string(s.message()).c_str());
        break;
      }
    } else if (version == 3) {
      absl::Status s = DecodePage(view, section, 0, p.meta, "bench", &page);
      if (!s.ok()) {
        state.SkipWithError(std::string(s.message()).c_str());
        return;
      }
    } else {
      DecodeV2(p.payload.data(), section, p.header.record_count, c, &page);
    }
    benchmark::DoNotOptimize(page.count);
    benchmark::ClobberMemory();
  }
  const double pages = static_cast<double>(state.iterations());
  state.counters["us_per_page"] =
      benchmark::Counter(pages * 1e-6, benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
  state.counters["ns_per_record"] =
      benchmark::Counter(pages * p.header.record_count * 1e-9,
                         benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
  state.counters["records"] = p.header.record_count;
  state.counters["stored_bytes"] = version == 4 ? frame.size() : p.payload.size();
  ZSTD_freeDCtx(dctx);
}

void Register() {
  for (int version : {2, 3, 4}) {
    for (Channels c : {Channels::kOcclusion, Channels::kRadiance}) {
      for (Section s : {Section::kNodes, Section::kPoints}) {
        const std::string name =
            std::string("Decode/") + (version == 4 ? "v3z" : "v" + std::to_string(version)) + "/" +
            (c == Channels::kRadiance ? "radiance" : "occlusion") + "/" + SectionName(s);
        benchmark::RegisterBenchmark(name.c_str(), [s, c, version](benchmark::State& st) {
          BM_Decode(st, s, c, version);
        })->Unit(benchmark::kMicrosecond);
      }
    }
  }
}

}  // namespace
}  // namespace pbgi::internal

int main(int argc, char** argv) {
  pbgi::internal::Register();
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
