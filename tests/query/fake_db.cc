#include "tests/query/fake_db.h"

#include <algorithm>
#include <array>
#include <cstdlib>
#include <cstring>
#include <numeric>

#include "pbgi/sh.h"
#include "tree/format.h"
#include "tree/morton.h"

namespace pbgi::internal {
namespace {

constexpr int kBits = 10;  // enough for test sizes; deeper cells share a leaf

uint64_t Key(const glm::vec3& p, const glm::vec3& lo, float size) {
  uint64_t key = 0;
  uint32_t q[3];
  for (int a = 0; a < 3; ++a) {
    float t = (p[a] - lo[a]) / size * float(1 << kBits);
    q[a] = static_cast<uint32_t>(std::clamp(t, 0.0f, float((1 << kBits) - 1)));
  }
  for (int b = kBits - 1; b >= 0; --b) {
    key = key << 3 | ((q[0] >> b) & 1) << 2 | ((q[1] >> b) & 1) << 1 | ((q[2] >> b) & 1);
  }
  return key;
}

struct TNode {
  Bounds bounds;
  double area = 0;
  std::array<double, 9> sh{};
  std::array<std::array<double, 9>, 3> power{};
  uint64_t first = 0, count = 0;
  uint32_t depth = 0;
  std::vector<int> children;
  NodeRef ref = kNoNodeRef;
};

struct Builder {
  const std::vector<Surfel>& s;
  const std::vector<uint64_t>& keys;
  uint32_t leaf_size;
  std::vector<TNode> nodes;

  int Build(uint64_t b, uint64_t e, uint32_t depth) {
    int id = static_cast<int>(nodes.size());
    nodes.emplace_back();
    nodes[id].first = b;
    nodes[id].count = e - b;
    nodes[id].depth = depth;
    if (e - b > leaf_size && depth < static_cast<uint32_t>(kBits)) {
      const int shift = 3 * (kBits - 1 - static_cast<int>(depth));
      uint64_t i = b;
      while (i < e) {
        uint64_t j = i;
        const uint64_t cell = keys[i] >> shift;
        while (j < e && (keys[j] >> shift) == cell) ++j;
        int c = Build(i, j, depth + 1);
        nodes[id].children.push_back(c);
        i = j;
      }
      if (nodes[id].children.size() == 1) {
        // A single child: keep it (a chain), as a real builder may.
      }
    }
    TNode& n = nodes[id];
    if (n.children.empty()) {
      for (uint64_t i = b; i < e; ++i) {
        n.bounds.Extend(s[i].position);
        const double a = s[i].Area();
        n.area += a;
        auto c = sh::ProjectClampedCosine<double>(s[i].normal.x, s[i].normal.y, s[i].normal.z, a);
        for (int k = 0; k < 9; ++k) {
          n.sh[k] += c[k];
          for (int ch = 0; ch < 3; ++ch) n.power[ch][k] += c[k] * s[i].radiance[ch];
        }
      }
    } else {
      for (int c : n.children) {
        const TNode& ch = nodes[c];
        n.bounds.Extend(ch.bounds);
        n.area += ch.area;
        for (int k = 0; k < 9; ++k) {
          n.sh[k] += ch.sh[k];
          for (int x = 0; x < 3; ++x) n.power[x][k] += ch.power[x][k];
        }
      }
    }
    return id;
  }
};

}  // namespace

FakeDb BuildFakeDb(const std::vector<Surfel>& input, const FakeDbOptions& options) {
  FakeDb db;
  Bounds b;
  for (const Surfel& s : input) b.Extend(s.position);
  // The pages hold the surfels quantized (format version 3, tree/format.h): the fake's surfels
  // and aggregates are the decoded ones, and each page stores the code it was decoded from.
  const PositionGrid grid = GridOfCube(MortonCube(b));
  const uint32_t prec = PointRecordSize(options.channels);
  std::vector<std::array<uint8_t, kPointRecordBothSidesBytes>> codes(input.size());
  std::vector<Surfel> quantized(input.size());
  for (size_t i = 0; i < input.size(); ++i) {
    const Surfel& s = input[i];
    EncodeSurfelRecord(s, options.channels, grid, codes[i].data());
    quantized[i] = DecodePointRecord(codes[i].data(), options.channels, grid);
  }
  const glm::vec3 ext = b.Extent();
  const float size = std::max(1e-6f, std::max(ext.x, std::max(ext.y, ext.z))) * 1.001f;
  std::vector<uint64_t> keys(input.size());
  std::vector<uint32_t> order(input.size());
  std::iota(order.begin(), order.end(), 0);
  for (size_t i = 0; i < input.size(); ++i) keys[i] = Key(quantized[i].position, b.lo, size);
  std::stable_sort(order.begin(), order.end(),
                   [&](uint32_t x, uint32_t y) { return keys[x] < keys[y]; });
  std::vector<uint64_t> sorted_keys(input.size());
  for (size_t i = 0; i < input.size(); ++i) {
    db.surfels.push_back(quantized[order[i]]);
    sorted_keys[i] = keys[order[i]];
  }

  Builder bld{db.surfels, sorted_keys, options.leaf_size, {}};
  bld.nodes.reserve(input.size() * 2);
  const int root = bld.Build(0, db.surfels.size(), 0);

  // Place sibling groups in pages, depth first; the root is a group of one.
  const uint32_t per_page = NodesPerPage(options.page_size, options.channels);
  std::vector<std::vector<int>> pages(1);
  auto place = [&](const std::vector<int>& group) {
    if (pages.back().size() + group.size() > per_page) pages.emplace_back();
    for (size_t k = 0; k < group.size(); ++k) {
      bld.nodes[group[k]].ref = MakeNodeRef(pages.size() - 1, pages.back().size());
      pages.back().push_back(group[k]);
    }
  };
  place({root});
  std::vector<int> stack{root};
  uint32_t max_depth = 0;
  while (!stack.empty()) {
    int id = stack.back();
    stack.pop_back();
    max_depth = std::max(max_depth, bld.nodes[id].depth);
    if (!bld.nodes[id].children.empty()) place(bld.nodes[id].children);
    for (auto it = bld.nodes[id].children.rbegin(); it != bld.nodes[id].children.rend(); ++it) {
      stack.push_back(*it);
    }
  }

  StoreMeta meta;
  meta.page_size = options.page_size;
  meta.channels = options.channels;
  meta.leaf_size = options.leaf_size;
  meta.bounds = bld.nodes[root].bounds;  // of the decoded positions, as the builder records it
  meta.point_count = db.surfels.size();
  meta.node_count = bld.nodes.size();
  meta.node_pages = pages.size();
  meta.root = bld.nodes[root].ref;
  meta.max_depth = max_depth;
  meta.layout = "fake";
  for (int a = 0; a < 3; ++a) meta.grid_origin[a] = grid.origin[a];
  meta.grid_step = grid.step;
  const uint32_t ppp = PointsPerPage(options.page_size, options.channels);
  meta.point_pages = (db.surfels.size() + ppp - 1) / ppp;
  db.source = std::make_unique<MemPageStore>(meta, "fake-db");
  db.source->AllowOversizePages();

  const uint32_t nrec = NodeRecordSize(options.channels);
  for (size_t pg = 0; pg < pages.size(); ++pg) {
    std::vector<uint8_t> payload(pages[pg].size() * nrec, 0);
    for (size_t k = 0; k < pages[pg].size(); ++k) {
      const TNode& n = bld.nodes[pages[pg][k]];
      NodeRecordRadiance r{};
      NodeRecordCommon& c = r.common;
      for (int a = 0; a < 3; ++a) c.lo[a] = n.bounds.lo[a], c.hi[a] = n.bounds.hi[a];
      c.flags = n.children.empty() ? kNodeFlagLeaf : 0;
      c.child_count = static_cast<uint32_t>(n.children.size());
      c.children = n.children.empty() ? kNoNodeRef : bld.nodes[n.children[0]].ref;
      c.first_point = n.first;
      c.point_count = n.count;
      c.area = static_cast<float>(n.area);
      c.depth = n.depth;
      for (int i = 0; i < 9; ++i) c.sh_area[i] = static_cast<float>(n.sh[i]);
      for (int ch = 0; ch < 3; ++ch) {
        for (int i = 0; i < 9; ++i) r.sh_power[ch][i] = static_cast<float>(n.power[ch][i]);
      }
      EncodeNodeRecord(r, options.channels, grid, payload.data() + k * nrec);
    }
    const absl::Status s = db.source->Append(Section::kNodes, pg, PageKind::kNode,
                                             static_cast<uint32_t>(pages[pg].size()), payload);
    if (!s.ok()) std::abort();  // pages in order, oversize allowed: cannot fail
  }
  for (uint64_t pg = 0; pg < meta.point_pages; ++pg) {
    const uint64_t first = pg * ppp;
    const uint64_t n = std::min<uint64_t>(ppp, db.surfels.size() - first);
    std::vector<uint8_t> payload(n * prec, 0);
    for (uint64_t k = 0; k < n; ++k) {
      std::memcpy(payload.data() + k * prec, codes[order[first + k]].data(), prec);
    }
    const absl::Status s = db.source->Append(Section::kPoints, pg, PageKind::kPoint,
                                             static_cast<uint32_t>(n), payload);
    if (!s.ok()) std::abort();
  }
  return db;
}

}  // namespace pbgi::internal
