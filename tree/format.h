// The record formats inside node and point pages: the contract between build/ (which writes
// them) and query/ (which reads them). Internal: not part of the public API.
//
// Point pages: a PageHeader, then `record_count` point records, fixed size, in Morton order.
// Global point index i lives in page i / PointsPerPage(), slot i % PointsPerPage(); every point
// page but the last is full. So a node's points, a contiguous range of global indices, can be
// found without any per-page table.
//
// Node pages: a PageHeader, then `record_count` node records, fixed size. Siblings (the children
// of one node) are always stored contiguously in one page, so an interior node refers to its
// children with one NodeRef and a count. In the coherent layout a page holds a treelet: a group
// of siblings and as many levels of their descendants as fit, in depth-first order.
#ifndef PBGI_TREE_FORMAT_H_
#define PBGI_TREE_FORMAT_H_

#include <cmath>
#include <cstdint>
#include <cstring>

#include "pbgi/store.h"
#include "pbgi/surfel.h"

namespace pbgi::internal {

// Where a node lives: page number (high 48 bits) and slot in the page (low 16 bits).
using NodeRef = uint64_t;
inline constexpr NodeRef MakeNodeRef(uint64_t page_no, uint32_t slot) {
  return (page_no << 16) | slot;
}
inline constexpr uint64_t RefPage(NodeRef r) { return r >> 16; }
inline constexpr uint32_t RefSlot(NodeRef r) { return static_cast<uint32_t>(r & 0xffff); }
inline constexpr NodeRef kNoNodeRef = ~uint64_t{0};

inline constexpr uint32_t kNodeFlagLeaf = 1u;

// A node record, as stored. The radiance part is present only in radiance databases.
struct NodeRecordCommon {
  float lo[3];
  float hi[3];
  uint32_t flags;        // kNodeFlagLeaf
  uint32_t child_count;  // interior: number of children (1..8), stored contiguously; leaf: 0
  uint64_t children;     // interior: NodeRef of the first child; leaf: kNoNodeRef
  uint64_t first_point;  // the subtree's points are [first_point, first_point + point_count)
  uint64_t point_count;
  float area;        // total surfel area
  uint32_t depth;    // root = 0
  float sh_area[9];  // projected area SH
  uint32_t pad;
};
static_assert(sizeof(NodeRecordCommon) == 104);

struct NodeRecordRadiance {
  NodeRecordCommon common;
  float sh_power[3][9];  // power SH per colour
  uint32_t pad;
};
static_assert(sizeof(NodeRecordRadiance) == 216);

inline uint32_t NodeRecordSize(Channels c) {
  return HasRadiance(c) ? sizeof(NodeRecordRadiance) : sizeof(NodeRecordCommon);
}

// Point records. The radius's sign bit says the surfel is two-sided (Surfel::two_sided): a
// stored radius is always > 0 otherwise (the builder refuses the rest), so the flag costs no
// byte, and stores of format version 1, which predate it, read as all one-sided.
inline float EncodeRadius(float radius, bool two_sided) {
  return two_sided ? -std::fabs(radius) : std::fabs(radius);
}
inline bool RadiusTwoSided(float stored) { return std::signbit(stored); }

struct PointRecordOcclusion {
  float position[3];
  float normal[3];
  float radius;
};
static_assert(sizeof(PointRecordOcclusion) == 28);

struct PointRecordRadiance {
  float position[3];
  float normal[3];
  float radius;
  float radiance[3];
};
static_assert(sizeof(PointRecordRadiance) == 40);

inline uint32_t PointRecordSize(Channels c) {
  return HasRadiance(c) ? sizeof(PointRecordRadiance) : sizeof(PointRecordOcclusion);
}

inline uint32_t NodesPerPage(uint32_t page_size, Channels c) {
  return (page_size - sizeof(PageHeader)) / NodeRecordSize(c);
}
inline uint32_t PointsPerPage(uint32_t page_size, Channels c) {
  return (page_size - sizeof(PageHeader)) / PointRecordSize(c);
}

// Decodes point record `slot` of a point page payload.
inline Surfel DecodePoint(const uint8_t* payload, uint32_t slot, Channels c) {
  Surfel s;
  if (HasRadiance(c)) {
    PointRecordRadiance r;
    std::memcpy(&r, payload + size_t{slot} * sizeof(r), sizeof(r));
    s.position = {r.position[0], r.position[1], r.position[2]};
    s.normal = {r.normal[0], r.normal[1], r.normal[2]};
    s.radius = std::fabs(r.radius);
    s.two_sided = RadiusTwoSided(r.radius);
    s.radiance = {r.radiance[0], r.radiance[1], r.radiance[2]};
  } else {
    PointRecordOcclusion r;
    std::memcpy(&r, payload + size_t{slot} * sizeof(r), sizeof(r));
    s.position = {r.position[0], r.position[1], r.position[2]};
    s.normal = {r.normal[0], r.normal[1], r.normal[2]};
    s.radius = std::fabs(r.radius);
    s.two_sided = RadiusTwoSided(r.radius);
    s.radiance = glm::vec3(0.0f);
  }
  return s;
}

}  // namespace pbgi::internal

#endif  // PBGI_TREE_FORMAT_H_
