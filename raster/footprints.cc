// The elements' footprints on the micro-buffer: polygons that tile (see raster/polygon.h and
// docs/design.md, "Raster").
//
// - A flat cluster (|sum A_i n_i| > kFlatness A) is the part of its mean plane inside its
//   footprint box.
// - A cluster that is not flat is the faces of its footprint box that face the receiver: they
//   tile the box's silhouette, and two boxes that share a face draw it once (it faces only one
//   side).
// - The surfels that the gather returns are grouped by leaf and normal; a group of co-planar
//   surfels is the part of its plane inside its footprint box, like a flat cluster.
// The footprint box is the element's box of surfel centres grown to its octree cell where the
// surface reaches the cell's side (within a surfel spacing), else by half a spacing (where the
// surface ends): cells of a cut tile space, so the footprints of one surface tile the view.
// Coverage inside a footprint is the element's projected area over the footprint's, at most 1,
// and exactly 1 when the surface fills its cell.
#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>

#include "absl/container/inlined_vector.h"
#include "base/math.h"
#include "glm/geometric.hpp"
#include "glm/vec2.hpp"
#include "pbgi/sh.h"
#include "raster/polygon.h"
#include "raster/rasterizer.h"

namespace pbgi::internal {
namespace {

// A flat footprint whose polygon holds at most this many surfels' areas fills its cell whenever
// it reaches the cell's sides (see FlatFootprint).
constexpr double kSmallCell = 9.0;
// A group's core (SheetCore; two-sided groups, and one-sided ones from kOneSidedCoreMinCount
// members): the hull of its centres grown by kCoreGrow spacings is drawn opaque when the group's
// centre lies within kCoreNear spacings of the receiver, fading to nothing at kCoreFar
// (docs/design.md, "A piece's core").
constexpr float kCoreGrow = 0.5f;
constexpr float kCoreNear = 3.0f;
constexpr float kCoreFar = 6.0f;
// kCoreNear and kCoreFar hold at this raster resolution and scale with it: a piece's hedge is
// seen where the piece spans more than about a pixel, as far away as the pixels are fine.
constexpr float kCoreRes = 12.0f;
// A centre is carried to a side where the sheet goes on only from within this many spacings of
// it in the plane (FootprintBox snaps a side within 1.5 spacings of the centres along its axis).
constexpr float kCoreCarry = 1.5f;
// The rest of the footprint of such a group whose sheet goes on past its cell keeps at least this
// share of its opacity: where the core holds about the surfels' area or more, their count is
// sampling noise, and the core is a guess of the sheet's outline too (a neighbouring cell's core
// need not reach the side they share). One whose sheet ends in its cell (a whole leaf) keeps
// what is left of the area: its core is about the leaf, and the rest lies past it.
constexpr float kCoreRingKeep = 0.5f;
// A one-sided group (a wall, the ground) near the receiver that holds less than its footprint has
// a core too, its centres' hull grown by kCoreGrow (not carried: SheetCell's sides are a two-sided
// sheet's), the rest holding what is left: the ground's cell at a trunk's foot, empty under the
// trunk, was drawn at 0.795 over the ground a receiver on the trunk 0.7 spacings above it saw,
// where rays see it whole. From this many members: a pair's rectangle, a guess of where a wall
// ends a spacing (1.4 m in the city at 4 M surfels) wide, reached half a metre past a wall's
// open end over sky that rays see.
constexpr int kOneSidedCoreMinCount = 3;
// A group's centres whose hull grown by kCoreGrow (its Minkowski sum with the disk) spans more
// than this many times their surfels' area have a gap between them that the sampling would have
// filled had there been surface: samples of separate parts (2CylinderEngine: three of a plate's
// surfels 2.7 spacings apart, their hull over sky that rays see), or a surface's holes. Such a
// group has no core. Jittered samples of one sheet span about their area (a lone surfel 0.79, a
// lattice's piece 0.8 to 1.3, a pair two spacings apart 1.4).
constexpr double kCoreMaxSpan = 1.5;
// A flat cluster that fills a cell more than this many surfels' areas wide is a piece of one
// sheet (a mesh's thin panel), not of foliage, whose leaves are not much wider than a cell of
// their own size (FlatFootprint's `sheet`; docs/design.md, "Porous layers").
constexpr double kSheetCell = 4.0 * kSmallCell;
// An axis k lies in a plane with unit normal n when |n_k| < kInPlaneAxis: a footprint box snaps
// to its cell only along such axes, and along the others it spans the cell (FootprintBox).
constexpr float kInPlaneAxis = 0.9f;
// Along an axis nearly along its plane's normal a flat footprint's box is its cell, padded by
// this many spacings past the centres (FootprintBox).
constexpr float kPlanePad = 0.05f;
// A cell side beyond this is no side (SheetCell moves the sides a sheet does not go on across
// to the largest float).
constexpr float kNoSide = 1e37f;
// A co-planar group's surfels lie within this many spacings of its first surfel's plane.
// Grouped by their normals alone, the surfels of two faces meeting at a crease of 15-20 degrees
// made one mean plane that passed just above a receiver near the crease: drawn from behind over
// its hemisphere when two-sided, culled with the other face's share when one-sided (bug:
// crease_group_over_receiver; FootprintTest.ACreaseIsTwoPlanes: the first row past a 20 degree
// crease lies 0.17 spacings off). A smooth surface's sag within a group stays below it
// (FootprintTest.ClosedSphereOfSurfelsOccludesNearlyFully leaks at 0.1).
constexpr float kGroupThickness = 0.15f;
// CrossLeafConvexPair: the largest |cos| between two faces that end at each other's planes.
constexpr float kCrossLeafCos = 0.1f;
// RadiancePieces: the members' radiance differs when one is this far from the mean.
constexpr float kPieceContrast = 0.1f;
// Two groups meet at a convex edge when each one's centroid lies behind the other's plane by
// more than this many of its spacings (ConvexEdges).
constexpr float kConvexDepth = 0.05f;
// A surface whose last row of centres comes within this many spacings of the receiver's
// tangent plane stands on the receiver's surface (ContactCell).
constexpr float kContactReach = 1.0f;
// How far (spacings) ContactCell moves a box's side to reach the receiver's tangent plane at
// most, and how close to that side it keeps the footprint's centres, within FootprintBox's
// snapping distance of 1.5 spacings.
constexpr float kContactGrowth = 4.0f;
constexpr float kContactSnap = 1.4f;
// Along a contact, a footprint snaps to its cell's side when its centres end within this many
// spacings of it.
constexpr float kContactAlong = 2.5f;

// A cluster is porous (foliage, grass: pieces facing every way with gaps between them) when
// |sum A_i n_i| < kPorousCoherence * sum A_i; two-sided content always is, its sides cancelling
// in the sum (the pieces of one two-sided card still add up: they face the same way and join
// one layer). Its layer composites as an independent one's: see Rasterizer::Layer() and
// Close().
constexpr float kPorousCoherence = 0.5f;

// The opacity over its box's silhouette of a porous cluster whose projected area is `tau` times
// the silhouette's. Its two-sided share (leaves: pieces scattered at random depths, overlapping
// each other at random) covers 1 - exp(-tau) of it, as a layer of independent pieces does
// (Beer-Lambert); adding them and clamping at 1 counted every overlap twice, and the forest's
// crowns at the default cut made the ground under them +0.018 too dark, falling to +0.006 only
// at a finer cut (bug: porous_cluster_overlaps_added). The one-sided share (a trunk in its cell,
// closed: its front faces do not overlap each other) keeps min(1, tau). The two-sided share
// is the band-0 area (both sides of a two-sided surfel) less the area: docs/design.md,
// "Porous layers".
float PorousOpacity(const Cluster& c, float tau) {
  float two_sided = 0.0f;
  if (c.area > 0.0f) {
    two_sided = std::clamp(sh::AreaAndNormalSum(c.sh_area.data()).area / c.area - 1.0f, 0.0f, 1.0f);
  }
  return two_sided * (1.0f - std::exp(-tau)) + (1.0f - two_sided) * std::min(1.0f, tau);
}

// The cluster's PreparedSplat::flags: porous, or (hitsides both) seen from behind, its
// area-weighted normal pointing away from the receiver at `origin`.
uint8_t ClusterFlags(const Cluster& c, const glm::vec3& origin, HitSides sides) {
  const sh::FirstMoments m = sh::AreaAndNormalSum(c.sh_area.data());
  const float porous = kPorousCoherence * m.area;
  if (glm::dot(m.normal_sum, m.normal_sum) < porous * porous) return kSplatPorous;
  const glm::vec3 centre = 0.5f * (c.bounds.lo + c.bounds.hi);
  return sides == HitSides::kBoth && glm::dot(m.normal_sum, centre - origin) > 0.0f ? kSplatBack
                                                                                    : 0;
}

// Whether a solid (not porous) cluster is faces of its box: its normals lie along the world
// axes, one way per axis (sum A_i n_i n_i^T is diagonal with |N_k| on the diagonal), on at least
// two axes (one is a flat cluster), and each face fills the box's side across its axis to
// kBoxFaceFill. A room's edge or corner cell, a building's edge, a wall and the street it
// stands on. Such content closes its box seen from any side the faces face: a ray that enters
// the box and leaves it through a side no face covers goes on into the neighbouring cell of
// the same edge, or was already inside the solid. Drawn translucent, its opacity (the content's
// solid angle over the box's) spread evenly over the silhouette, it left the pixels where the
// content lies short and closed rooms leaked 0.5 % (bug: box_face_clusters_leak; docs/design.md,
// "Box-face clusters"). Only for a receiver at `origin` in front of every face put at the box's
// back along its normal (a room's inside, a street beside a wall): one behind a face plane
// may see the content from behind, where its projected area is 0 (a closed room seen from
// outside).
constexpr float kBoxFaceTolerance = 0.02f;
constexpr float kBoxFaceFill = 0.9f;
bool BoxFaces(const Cluster& c, const Bounds& box, const glm::vec3& origin) {
  if (!(c.area > 0.0f)) return false;
  const sh::FirstMoments f = sh::AreaAndNormalSum(c.sh_area.data());
  const std::array<float, 6> m = sh::SecondMoment(c.sh_area.data());
  const float tol = kBoxFaceTolerance * f.area;
  if (std::fabs(m[3]) > tol || std::fabs(m[4]) > tol || std::fabs(m[5]) > tol) return false;
  const glm::vec3 ext = box.hi - box.lo;
  float off = 0.0f;
  int faces = 0;
  for (int k = 0; k < 3; ++k) {
    const float a = std::fabs(f.normal_sum[k]);
    off += std::fabs(a - m[k]);
    if (a <= tol) continue;
    ++faces;
    if (a < kBoxFaceFill * ext[(k + 1) % 3] * ext[(k + 2) % 3]) return false;
    if (f.normal_sum[k] > 0.0f ? !(origin[k] > box.lo[k]) : !(origin[k] < box.hi[k])) {
      return false;
    }
  }
  return faces >= 2 && off <= tol;
}

// Whether `cell` is a usable octree cell for content with box `b` (the gather sets it; a
// caller-built cluster may not). Three lanes of four, the same comparisons as one axis at a time.
bool CellHolds(const Bounds& cell, const Bounds& b) {
  V4 clo, chi, blo, bhi;
  LoadBounds(cell, &clo, &chi);
  LoadBounds(b, &blo, &bhi);
  // Bounds::Empty() of either.
  if (Movemask4((clo > chi) | (blo > bhi)) != 0) return false;
  const V4 e = chi - clo;
  const float tol = 1e-4f * std::max(1e-30f, std::sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]));
  return Movemask4((blo >= clo - tol) & (bhi <= chi + tol)) == 0xf;
}

// A solid cluster that is two or three faces of a box's edge or corner inside its cell: a
// building's corner, the top of its wall, a roof's corner, the street beside a wall. Its
// normals lie along two or three world axes, one way each (sum A_i n_i n_i^T is diagonal with
// the |N_a| on it). Drawn as its box's silhouette at an even opacity, such content spread its
// projected area over the air in front of its faces where the edge lies inside the cell, and a
// building's corner came out half transparent from the street (0.56 of the pixels where rays
// find the wall; the city's error rose at finer cuts: docs/eval.md, "Session 17"). Where the
// faces are:
// - Convex, when the receiver lies behind one face wherever in the centres' box its plane
//   is, and not behind another (a building's wall and roof seen from the street; a concave
//   edge, a wall on the street, would put the receiver under the street): each face lies at
//   the side of the centres' box that its normal points to, and reaches from the other faces'
//   planes across the footprint box `box`, away from their normals.
// - Two faces otherwise (hitsides front or not): each spans the box along the third axis k
//   and reaches from the edge to the side of the cell that its surface goes on through: the
//   side at which the centres come nearest to the cell (the edge lies inside the cell, at any
//   distance from the other side). Each face's plane is the end of the centres' box that the
//   other face leaves. Where the faces' areas say otherwise (the a face reaches |N_a| / ext_k
//   across the other's axis: more than the box holds), it is not such an edge; where both
//   faces fill their sides (a room's corner, a box's edge), BoxFaces and the box's silhouette
//   draw it.
// Writes the faces that the receiver at `origin` sees from the front (up to three) into
// `out`, relative to it, and returns their count; -1 when the content's normals are not along
// two or three world axes, one way each, and kAlongAxes when they are but the content is not
// such an edge, or a face would be drawn larger than its content (TurnedFaces then has nothing
// to add).
constexpr float kEdgeFaceFill = 0.9f;
constexpr int kAlongAxes = -2;
int EdgeFaces(const Cluster& c, const Bounds* footprint_box, float spacing, const glm::vec3& origin,
              HitSides sides, Polygon out[3]) {
  // With hitsides back the faces' fronts do not occlude: the box's silhouette, as before.
  if (!(c.area > 0.0f) || sides == HitSides::kBack) return -1;
  // The first moments first: most clusters face one axis or none.
  const sh::FirstMoments f = sh::AreaAndNormalSum(c.sh_area.data());
  const float tol = kBoxFaceTolerance * f.area;
  bool face[3];
  int faces = 0;
  for (int a = 0; a < 3; ++a) {
    face[a] = std::fabs(f.normal_sum[a]) > tol;
    faces += face[a] ? 1 : 0;
  }
  if (faces < 2) return -1;
  const std::array<float, 6> m = sh::SecondMoment(c.sh_area.data());
  if (std::fabs(m[3]) > tol || std::fabs(m[4]) > tol || std::fabs(m[5]) > tol) return -1;
  float off = 0.0f;
  for (int a = 0; a < 3; ++a) off += std::fabs(std::fabs(f.normal_sum[a]) - m[a]);
  if (off > tol) return -1;
  if (!CellHolds(c.cell, c.bounds)) return kAlongAxes;
  const Bounds box = footprint_box != nullptr
                         ? *footprint_box
                         : FootprintBox(c.bounds, c.cell, spacing, glm::vec3(0.0f), nullptr);
  const glm::vec3 ext = box.hi - box.lo;
  if (!(ext.x > 0.0f) || !(ext.y > 0.0f) || !(ext.z > 0.0f)) return kAlongAxes;
  float sign[3], edge[3] = {0.0f, 0.0f, 0.0f};
  bool to_hi[3] = {false, false, false};
  int behind = 0;
  for (int a = 0; a < 3; ++a) {
    sign[a] = f.normal_sum[a] > 0.0f ? 1.0f : -1.0f;
    // Behind the face wherever in the centres' box its plane is.
    if (face[a] && (sign[a] > 0.0f ? origin[a] < c.bounds.lo[a] : origin[a] > c.bounds.hi[a])) {
      ++behind;
    }
  }
  if (sides == HitSides::kFront && behind > 0 && behind < faces) {
    for (int a = 0; a < 3; ++a) {
      if (!face[a]) continue;
      edge[a] = sign[a] > 0.0f ? c.bounds.hi[a] : c.bounds.lo[a];
      to_hi[a] = sign[a] < 0.0f;
    }
  } else {
    if (faces != 2) return kAlongAxes;
    const int k = !face[0] ? 0 : (!face[1] ? 1 : 2);
    const int i = (k + 1) % 3, j = (k + 2) % 3;
    // How far each face reaches across the other's axis.
    float len[3] = {0.0f, 0.0f, 0.0f};
    len[j] = std::fabs(f.normal_sum[i]) / ext[k];
    len[i] = std::fabs(f.normal_sum[j]) / ext[k];
    if (len[i] > (2.0f - kEdgeFaceFill) * ext[i] || len[j] > (2.0f - kEdgeFaceFill) * ext[j]) {
      return kAlongAxes;
    }
    if (len[i] >= kEdgeFaceFill * ext[i] && len[j] >= kEdgeFaceFill * ext[j]) return kAlongAxes;
    // The a face's plane is at the end of the centres' box that the other face leaves: its
    // centres all lie in it.
    for (int a : {i, j}) {
      to_hi[a] = c.cell.hi[a] - c.bounds.hi[a] < c.bounds.lo[a] - c.cell.lo[a];
      edge[a] = to_hi[a] ? c.bounds.lo[a] : c.bounds.hi[a];
    }
  }
  int n = 0;
  for (int a = 0; a < 3; ++a) {
    if (!face[a]) continue;
    if (!(sign[a] * (origin[a] - edge[a]) > 0.0f)) {
      // Seen from behind: nothing with front; with back or both, the box's silhouette.
      if (sides != HitSides::kFront) return kAlongAxes;
      continue;
    }
    // The face's extent along the other two axes: from another face's plane away from its
    // normal, or across the box.
    const int b = (a + 1) % 3, d = (a + 2) % 3;
    float lo[3], hi[3];
    for (int e : {b, d}) {
      lo[e] = face[e] && to_hi[e] ? edge[e] : box.lo[e];
      hi[e] = face[e] && !to_hi[e] ? edge[e] : box.hi[e];
    }
    if (!(hi[b] > lo[b]) || !(hi[d] > lo[d])) continue;
    // A face drawn larger than its content (a wall that ends inside the box) would be drawn
    // opaque over what it does not cover.
    if ((hi[b] - lo[b]) * (hi[d] - lo[d]) * kEdgeFaceFill > std::fabs(f.normal_sum[a])) {
      return kAlongAxes;
    }
    Polygon& p = out[n++];
    p.n = 4;
    const float bs[4] = {lo[b], hi[b], hi[b], lo[b]};
    const float ds[4] = {lo[d], lo[d], hi[d], hi[d]};
    for (int v = 0; v < 4; ++v) {
      glm::vec3 x;
      x[a] = edge[a];
      x[b] = bs[v];
      x[d] = ds[v];
      p.v[v] = x - origin;
    }
  }
  return n;
}

// Turned edges drawn as their faces (docs/design.md, "Turned edges drawn as their faces"): a
// solid cluster whose content is two or three faces of a box turned about one world axis k
// (cornell's blocks, a mesh's box-like parts standing on a floor): up to two sides, their
// normals across k and at right angles to each other, and a cap along k, one way each.
// kTurnedMargin: the edge lies this many spacings farther (on average over the pair's normal)
// from the cell's sides at its end than the faces' other ends do, or which end is the edge is not
// known. kTurnedFit: a face's polygon holds its content's area to this share (and a surfel's
// area), or the model does not hold.
constexpr float kTurnedMargin = 1.0f;
constexpr float kTurnedFit = 0.15f;
// A side whose area is less than this many surfels' is left out of the model when a cap and
// another side remain (TurnedFaceModel).
constexpr float kTurnedSliver = 1.5f;

// The faces of a turned edge: planes {dot(normal[f], x) = offset[f]} (x relative to the
// footprint box's centre), each face its plane inside the box on the solid's side of the other
// planes (behind them where the edge is convex, in front where it is concave). The sides come
// first, the cap (if any) last.
struct TurnedModel {
  int count = 0, sides = 0, k = 2;  // k: the turn axis
  bool cap = false, convex = true;
  glm::vec3 normal[3];
  glm::vec2 across[2];  // the sides' normals in the plane across k: axes k + 1, k + 2
  float area[3];
  float offset[3];
  glm::vec3 centre{0.0f};        // the footprint box's centre
  glm::vec3 lo{0.0f}, hi{0.0f};  // the footprint box, relative to its centre
  Polygon poly[3];               // the faces' polygons (TurnedFacePolygon), relative to it
};

// The chord of the line {p : dot(e, p) = d}, p = d e + t u (u the unit normal's perpendicular),
// across the rectangle [lo, hi]: t in [*t0, *t1] (empty when *t0 > *t1; piecewise linear and
// continuous in d either way).
void Chord(const glm::vec2& e, const glm::vec2& u, float d, const glm::vec2& lo,
           const glm::vec2& hi, float* t0, float* t1) {
  float a = -std::numeric_limits<float>::infinity(), b = -a;
  for (int k = 0; k < 2; ++k) {
    if (u[k] == 0.0f) continue;
    float x = (lo[k] - d * e[k]) / u[k], y = (hi[k] - d * e[k]) / u[k];
    if (x > y) std::swap(x, y);
    a = std::max(a, x);
    b = std::min(b, y);
  }
  *t0 = a;
  *t1 = b;
}

// Clips the convex polygon q[0, n) of the plane to the side of the line {p : dot(e, p) = d}
// that `keep` says (dot(e, p) <= d for +1, >= d for -1), into out (n + 1 vertices at most),
// one pass of Sutherland-Hodgman; returns the count.
int ClipToLine(const glm::vec2* q, int n, const glm::vec2& e, float d, float keep, glm::vec2* out) {
  int m = 0;
  for (int v = 0; v < n; ++v) {
    const glm::vec2 a = q[v], b = q[(v + 1) % n];
    const float fa = keep * (d - glm::dot(e, a)), fb = keep * (d - glm::dot(e, b));
    if (fa >= 0.0f) out[m++] = a;
    if ((fa >= 0.0f) != (fb >= 0.0f)) out[m++] = a + (fa / (fa - fb)) * (b - a);
  }
  return m;
}

// The area of the polygon q[0, n) of the plane (the shoelace sum).
float PlaneArea(const glm::vec2* q, int n) {
  float twice = 0.0f;
  for (int v = 0; v < n; ++v) {
    const glm::vec2 a = q[v], b = q[(v + 1) % n];
    twice += a.x * b.y - a.y * b.x;
  }
  return 0.5f * std::fabs(twice);
}

// The cap's section in the plane across k: the box's rectangle [lo, hi] on the solid's side of
// the first `sides` sides' lines, into q (at most 6 vertices); returns the count.
int CapSection(const TurnedModel& t, int sides, const glm::vec2& lo, const glm::vec2& hi,
               glm::vec2 q[6]) {
  glm::vec2 r[6] = {lo, {hi.x, lo.y}, hi, {lo.x, hi.y}};
  int n = 4;
  const float keep = t.convex ? 1.0f : -1.0f;
  for (int g = 0; g < sides && n >= 3; ++g) {
    n = ClipToLine(r, n, t.across[g], t.offset[g], keep, q);
    std::copy(q, q + n, r);
  }
  std::copy(r, r + n, q);
  return n;
}

// Face f's polygon (relative to the box's centre) into p, and its area. A side is a rectangle:
// its chord of the box's rectangle across k, ended by the other side's line, times the box's
// extent along k, ended by the cap's plane; the cap is its section (CapSection) at its level.
float TurnedFacePolygon(const TurnedModel& t, int f, Polygon* p) {
  const int k = t.k, i = (k + 1) % 3, j = (k + 2) % 3;
  const glm::vec2 lo(t.lo[i], t.lo[j]), hi(t.hi[i], t.hi[j]);
  // The solid's side of a plane: dot(n, x) <= offset (convex) or >= (concave).
  const float keep = t.convex ? 1.0f : -1.0f;
  auto lift = [&](const glm::vec2& q, float z) {
    glm::vec3 x;
    x[i] = q.x, x[j] = q.y, x[k] = z;
    return x;
  };
  p->n = 0;
  if (f < t.sides) {
    const glm::vec2 e = t.across[f], u(-e.y, e.x);
    float t0, t1;
    Chord(e, u, t.offset[f], lo, hi, &t0, &t1);
    if (t.sides == 2) {
      // On the chord dot(e_g, p) = s t, s = +-1 (the sides are at right angles).
      const int g = 1 - f;
      const float s = glm::dot(t.across[g], u) > 0.0f ? 1.0f : -1.0f;
      if (keep * s > 0.0f) {
        t1 = std::min(t1, s * t.offset[g]);
      } else {
        t0 = std::max(t0, s * t.offset[g]);
      }
    }
    float z0 = t.lo[k], z1 = t.hi[k];
    if (t.cap) {
      const float nk = t.normal[t.count - 1][k], at = nk * t.offset[t.count - 1];
      if (keep * nk > 0.0f) {
        z1 = std::min(z1, at);
      } else {
        z0 = std::max(z0, at);
      }
    }
    if (!(t1 > t0) || !(z1 > z0)) return 0.0f;
    const glm::vec2 base = t.offset[f] * e;
    p->n = 4;
    p->v[0] = lift(base + t0 * u, z0);
    p->v[1] = lift(base + t1 * u, z0);
    p->v[2] = lift(base + t1 * u, z1);
    p->v[3] = lift(base + t0 * u, z1);
    return (t1 - t0) * (z1 - z0);
  }
  glm::vec2 q[6];
  const int n = CapSection(t, t.sides, lo, hi, q);
  if (n < 3) return 0.0f;
  const float at = t.normal[f][k] * t.offset[f];
  p->n = n;
  for (int v = 0; v < n; ++v) p->v[v] = lift(q[v], at);
  return PlaneArea(q, n);
}

// A root of phi in [a, b] (to |phi| <= ftol): the first sign change of 8 samples, refined by
// the Illinois rule (phi is piecewise linear or quadratic with a few kinks). Where phi keeps its
// sign (the areas, sampled, ask a little more than the box holds), the first sample nearest to 0;
// the caller checks the faces' areas.
template <typename Phi>
void TurnedRoot(const Phi& phi, float a, float b, float ftol, float* root) {
  constexpr int kSamples = 8;
  float x0 = a, f0 = phi(a);
  *root = a;
  float nearest = std::fabs(f0);
  for (int s = 1; s <= kSamples; ++s) {
    const float x1 = a + (b - a) * static_cast<float>(s) / kSamples, f1 = phi(x1);
    if (f0 == 0.0f) {
      *root = x0;
      return;
    }
    if ((f0 < 0.0f) != (f1 < 0.0f)) {
      float lo = x0, flo = f0, hi = x1, fhi = f1;
      int side = 0;
      for (int it = 0; it < 24; ++it) {
        const float x = (lo * fhi - hi * flo) / (fhi - flo);
        if (!(x > std::min(lo, hi) && x < std::max(lo, hi))) break;
        const float fx = phi(x);
        if (std::fabs(fx) <= ftol || std::fabs(hi - lo) < 1e-4f * std::fabs(b - a)) {
          lo = hi = x;
          break;
        }
        if ((fx < 0.0f) == (flo < 0.0f)) {
          lo = x, flo = fx;
          if (side == -1) fhi *= 0.5f;
          side = -1;
        } else {
          hi = x, fhi = fx;
          if (side == 1) flo *= 0.5f;
          side = 1;
        }
      }
      *root = 0.5f * (lo + hi);
      return;
    }
    if (std::fabs(f1) < nearest - 1e-4f * std::fabs(b - a)) nearest = std::fabs(f1), *root = x1;
    x0 = x1, f0 = f1;
  }
}

// The turned faces of cluster c (flat or not) in its footprint box (`footprint_box`, or
// FootprintBox's when null, computed only once the moments qualify), when its moments say
// they are the faces of a box turned about one world axis and the faces' areas place them in
// the box (the caller's docs/design.md rule); false otherwise. Content along the world axes is
// left to BoxFaces and EdgeFaces.
bool TurnedFaceModel(const Cluster& c, const Bounds* footprint_box, float spacing, TurnedModel* t) {
  const sh::FirstMoments f = sh::AreaAndNormalSum(c.sh_area.data());
  const float tol = kBoxFaceTolerance * f.area;
  // One face (or nearly): a plane, drawn as such.
  if (glm::dot(f.normal_sum, f.normal_sum) > (1.0f - 2.0f * kBoxFaceTolerance) * f.area * f.area) {
    return false;
  }
  const std::array<float, 6> m = sh::SecondMoment(c.sh_area.data());
  auto mm = [&](int a, int b) {
    if (a == b) return m[a];
    const int s = a + b;
    return s == 1 ? m[3] : (s == 3 ? m[4] : m[5]);
  };
  float off = 0.0f;
  for (int a = 0; a < 3; ++a) off += std::fabs(std::fabs(f.normal_sum[a]) - m[a]);
  if (off <= tol && std::fabs(m[3]) <= tol && std::fabs(m[4]) <= tol && std::fabs(m[5]) <= tol) {
    return false;  // along the world axes
  }
  // The turn axis k: an eigenvector of M with the cap's area, one way, as its eigenvalue. In
  // the plane across it, two faces at right angles with areas A1, A2 and unit normals e1, e2
  // have A1 + A2 = M_ii + M_jj and A1^2 + A2^2 = |N_ij|^2, which gives the areas; N_ij = A1 e1 +
  // A2 e2 then gives the normals up to a mirror, and M's in-plane part picks the one that it
  // holds (within the tolerance, or the content is not such faces).
  int k = -1;
  float best = tol;
  glm::vec2 e1(0.0f), e2(0.0f);
  float a1 = 0.0f, a2 = 0.0f;
  for (int kk = 0; kk < 3; ++kk) {
    const int i = (kk + 1) % 3, j = (kk + 2) % 3;
    if (std::fabs(mm(i, kk)) > tol || std::fabs(mm(j, kk)) > tol) continue;
    if (std::fabs(std::fabs(f.normal_sum[kk]) - m[kk]) > tol) continue;
    const float tr = m[i] + m[j];
    const glm::vec2 n(f.normal_sum[i], f.normal_sum[j]);
    const float nl = glm::length(n);
    if (!(tr > tol) || !(nl > tol)) continue;
    const float disc = 2.0f * nl * nl - tr * tr;
    if (disc < -2.0f * tol * tr) continue;  // normals that cancel: not one way each
    const float big = 0.5f * (tr + std::sqrt(std::max(0.0f, disc))), small = tr - big;
    const glm::vec2 nh = n / nl, p(-nh.y, nh.x);
    const float ca = std::min(1.0f, big / nl), sa = std::sqrt(std::max(0.0f, 1.0f - ca * ca));
    for (float sign : {1.0f, -1.0f}) {
      const glm::vec2 u = ca * nh + sign * sa * p;
      // The second side's normal: u's perpendicular on the side of what N leaves.
      glm::vec2 v(-u.y, u.x);
      if (glm::dot(v, n - big * u) < 0.0f) v = -v;
      const float bii = big * u.x * u.x + small * v.x * v.x;
      const float bjj = big * u.y * u.y + small * v.y * v.y;
      const float bij = big * u.x * u.y + small * v.x * v.y;
      const float r = std::fabs((bii - bjj) - (m[i] - m[j])) + 2.0f * std::fabs(bij - mm(i, j));
      if (r <= best) {
        best = r, k = kk, e1 = u, e2 = v, a1 = big, a2 = small > tol ? small : 0.0f;
      }
    }
  }
  if (k < 0) return false;
  const int i = (k + 1) % 3, j = (k + 2) % 3;
  const float cap = std::fabs(f.normal_sum[k]) > tol ? std::fabs(f.normal_sum[k]) : 0.0f;
  // A side of a surfel's area or so is a sliver across the cell's side whose sampled area
  // (a whole surfel where the sliver holds a part of one) would move the edge: left out.
  if (a2 > 0.0f && a2 < kTurnedSliver * spacing * spacing && cap > 0.0f) a2 = 0.0f;
  const int sides = a2 > 0.0f ? 2 : 1;
  if (sides + (cap > 0.0f ? 1 : 0) < 2) return false;
  if (!CellHolds(c.cell, c.bounds)) return false;
  const Bounds box = footprint_box != nullptr
                         ? *footprint_box
                         : FootprintBox(c.bounds, c.cell, spacing, glm::vec3(0.0f), nullptr);
  const glm::vec3 o = 0.5f * (box.lo + box.hi);
  t->centre = o;
  t->lo = box.lo - o;
  t->hi = box.hi - o;
  if (!(t->hi.x > 0.0f) || !(t->hi.y > 0.0f) || !(t->hi.z > 0.0f)) return false;
  t->count = 0;
  t->k = k;
  t->sides = sides;
  t->cap = cap > 0.0f;
  t->across[0] = e1;
  t->across[1] = e2;
  auto add = [&](const glm::vec3& n, float area) {
    t->normal[t->count] = n;
    t->area[t->count] = area;
    t->offset[t->count] = 0.0f;
    ++t->count;
  };
  glm::vec3 n1(0.0f), n2(0.0f), nk(0.0f);
  n1[i] = e1.x, n1[j] = e1.y;
  add(n1, a1);
  if (sides == 2) {
    n2[i] = e2.x, n2[j] = e2.y;
    add(n2, a2);
  }
  if (cap > 0.0f) {
    nk[k] = f.normal_sum[k] > 0.0f ? 1.0f : -1.0f;
    add(nk, cap);
  }
  // Convex or concave, every pair alike: a pair's edge lies at the end of the content along
  // w = n_f + n_g (convex) or -w (concave), and the faces go on through the cell's sides at the
  // other end, where the centres come nearest to them.
  int convex = 0, concave = 0;
  for (int a = 0; a < t->count; ++a) {
    for (int b = a + 1; b < t->count; ++b) {
      const glm::vec3 w = t->normal[a] + t->normal[b];
      float plus = 0.0f, minus = 0.0f, weight = 0.0f;
      for (int x = 0; x < 3; ++x) {
        const float gap_hi = c.cell.hi[x] - c.bounds.hi[x], gap_lo = c.bounds.lo[x] - c.cell.lo[x];
        plus += std::fabs(w[x]) * (w[x] > 0.0f ? gap_hi : gap_lo);
        minus += std::fabs(w[x]) * (w[x] > 0.0f ? gap_lo : gap_hi);
        weight += std::fabs(w[x]);
      }
      const float margin = kTurnedMargin * spacing * weight;
      if (plus > minus + margin) {
        ++convex;
      } else if (minus > plus + margin) {
        ++concave;
      } else {
        return false;
      }
    }
  }
  if (convex > 0 && concave > 0) return false;
  t->convex = convex > 0;
  // The cap's plane: the end of the centres' box that its normal points to (convex: a block's
  // top) or the other (concave: the floor a block stands on); its centres all lie in it.
  float height = t->hi[k] - t->lo[k];
  if (cap > 0.0f) {
    const bool up = nk[k] > 0.0f;
    const float at = (up == t->convex ? c.bounds.hi[k] : c.bounds.lo[k]) - o[k];
    t->offset[t->count - 1] = nk[k] * at;
    // The sides lie behind the cap (convex) or in front of it.
    height = (up == t->convex) ? at - t->lo[k] : t->hi[k] - at;
    if (!(height > 0.0f)) return false;
  }
  // The sides' offsets. The sides span the box along k up to the cap, so in the plane across k
  // each is a chord of the box's rectangle [lo, hi] as long as its area over the height.
  const glm::vec2 lo(t->lo[i], t->lo[j]), hi(t->hi[i], t->hi[j]);
  float d_lo = 0.0f, d_hi = 0.0f;
  for (int x = 0; x < 4; ++x) {
    const glm::vec2 corner((x & 1) ? hi.x : lo.x, (x & 2) ? hi.y : lo.y);
    const float d = glm::dot(e1, corner);
    d_lo = x == 0 ? d : std::min(d_lo, d);
    d_hi = x == 0 ? d : std::max(d_hi, d);
  }
  if (sides == 2) {
    // Side 1's chord runs along e2 (t = dot(e2, p)) and ends at side 2's plane, t <= d2
    // (convex) or t >= d2, and side 2's along e1, ending at side 1's: each length fixes the
    // other side's offset, and d1 is the root of phi.
    const float l1 = a1 / height, l2 = a2 / height;
    const bool cv = t->convex;
    auto d2_of = [&](float d1) {
      float t0, t1;
      Chord(e1, e2, d1, lo, hi, &t0, &t1);
      return cv ? t0 + l1 : t1 - l1;
    };
    auto phi = [&](float d1) {
      float s0, s1;
      Chord(e2, e1, d2_of(d1), lo, hi, &s0, &s1);
      return (cv ? s0 + l2 : s1 - l2) - d1;
    };
    float d1;
    TurnedRoot(phi, d_lo, d_hi, 1e-3f * spacing, &d1);
    t->offset[0] = d1;
    t->offset[1] = d2_of(d1);
  } else {
    // One side and the cap: the side's offset from the cap's area (monotonic in it), the
    // part of the box's rectangle behind the side's line (convex) or in front of it.
    const float cap_area = t->area[t->count - 1];
    auto phi = [&](float d1) {
      t->offset[0] = d1;
      glm::vec2 q[6];
      return PlaneArea(q, CapSection(*t, 1, lo, hi, q)) - cap_area;
    };
    float d1;
    TurnedRoot(phi, d_lo, d_hi, 1e-3f * cap_area, &d1);
    t->offset[0] = d1;
  }
  // Every face's polygon must hold its content's area, and together they must reach the
  // centres' box.
  Bounds drawn;
  for (int a = 0; a < t->count; ++a) {
    Polygon& p = t->poly[a];
    const float area = TurnedFacePolygon(*t, a, &p);
    if (p.n < 3) return false;
    if (std::fabs(area - t->area[a]) > kTurnedFit * t->area[a] + spacing * spacing) return false;
    for (int v = 0; v < p.n; ++v) drawn.Extend(p.v[v] + o);
  }
  for (int x = 0; x < 3; ++x) {
    if (drawn.lo[x] > c.bounds.lo[x] + 0.5f * spacing ||
        drawn.hi[x] < c.bounds.hi[x] - 0.5f * spacing) {
      return false;
    }
  }
  return true;
}

// The faces of a turned edge (TurnedFaceModel) that the receiver at `origin` sees from the
// front, relative to it, into `out` (up to three): their count, or -1 when the content is not
// such an edge or (hitsides both, or a concave edge) the receiver lies behind a face's plane,
// where the box's silhouette serves as before.
int TurnedFaces(const Cluster& c, const Bounds* footprint_box, float spacing,
                const glm::vec3& origin, HitSides sides, Polygon out[3]) {
  if (!(c.area > 0.0f) || sides == HitSides::kBack) return -1;
  TurnedModel t;
  if (!TurnedFaceModel(c, footprint_box, spacing, &t)) return -1;
  const glm::vec3 r = origin - t.centre;
  int n = 0;
  for (int a = 0; a < t.count; ++a) {
    if (!(glm::dot(t.normal[a], r) > t.offset[a])) {
      if (sides != HitSides::kFront || !t.convex) return -1;
      continue;
    }
    Polygon& p = out[n++];
    p = t.poly[a];
    for (int v = 0; v < p.n; ++v) p.v[v] -= r;
  }
  return n;
}

// The spacing of a cluster's surfels, by which its footprint box grows (FootprintBox).
float ClusterSpacing(const Cluster& c) {
  return std::sqrt(std::max(0.0f, c.area) /
                   static_cast<float>(std::max<uint64_t>(1, c.point_count)));
}

// A co-planar group of one cell's surfels (Rasterizer::PrepareSurfelGroups): its surfels are
// order[end - count, end).
struct SurfelGroup {
  size_t end = 0;
  int count = 0;
  bool two_sided = false;
  glm::vec3 n0{0.0f};  // the first surfel's unit normal
  double area = 0.0;
  glm::dvec3 nsum{0.0}, csum{0.0}, lsum{0.0};
  glm::dvec3 back_lsum{0.0};  // a two-sided group's back radiance times area
  Bounds centres;
  // The least height of a centre above the receiver's tangent plane (its box's lowest corner
  // lies lower where the plane is not along an axis).
  float hmin = std::numeric_limits<float>::infinity();
  // From the sums once the group is complete (Finish()), for ContactCell's every pair:
  // whether the group has an area and a normal, its unit normal, centroid and spacing.
  bool solid = false;
  glm::vec3 normal{0.0f}, centroid{0.0f};
  float spacing = 0.0f;
  bool on_axis = false;  // the normal lies within about 8 degrees of a world axis

  void Finish() {
    const double l = glm::length(nsum);
    solid = l > 0.0 && area > 0.0;
    if (!solid) return;
    normal = glm::vec3(nsum / l);
    on_axis = std::max({std::fabs(normal.x), std::fabs(normal.y), std::fabs(normal.z)}) > 0.99f;
    centroid = glm::vec3(csum / area);
    spacing = static_cast<float>(std::sqrt(area / count));
  }
};

// Where a group's surface meets another's in the same cell (a wall standing on a roof or the
// street, the two faces of a box's edge), the first ends at the second's plane, not half a
// spacing past its last row of centres: the cell that a's footprint box snaps to (FootprintBox)
// is ended there. Without it the footprint stopped up to half a spacing short of the contact,
// where a receiver beside the contact looked through the gap to the sky (the thin lines of
// too little occlusion along the city's contacts: docs/eval.md, "Session 10"). b's plane must
// cross one of a's in-plane axes squarely (|n| > 0.99 along it), b's centres must come within
// 1.5 of its spacings of a's plane and a's within 1.5 of a's spacings of b's, on one side of
// it, and their boxes so grown must overlap.
Bounds ContactCell(const Bounds& cell, const SurfelGroup& a, absl::Span<const SurfelGroup> groups,
                   const glm::vec3& origin, const glm::vec3& nr, float crease_tol, bool* contact,
                   Bounds* reach = nullptr, bool* on_receiver = nullptr) {
  Bounds out = cell;
  *contact = false;
  if (reach) *reach = a.centres;
  if (on_receiver) *on_receiver = false;
  if (a.two_sided || !a.solid) return out;
  const glm::vec3 na = a.normal, ca = a.centroid;
  const float sa = a.spacing;
  const bool has_cell = CellHolds(cell, a.centres);
  if (!has_cell) {
    // No cell (a caller-built set, a lone surfel's): the box's own, unbounded.
    const float inf = std::numeric_limits<float>::infinity();
    out.lo = glm::vec3(-inf);
    out.hi = glm::vec3(inf);
  }
  // The receiver's own surface: a surface standing on it (a wall on the roof or the street
  // that the receiver lies on) whose last row of centres is within a spacing of its tangent
  // plane reaches that plane; the hemisphere's clip (AddPolygon) then ends it there exactly.
  // Along each in-plane axis that rises with the plane's normal, the box's side facing the
  // plane moves until all of it lies behind the plane: where the plane is not along an axis (a
  // block turned on the floor) the side's far end decides, and the footprint's centres (`reach`)
  // move with it so that the box snaps to it. Before, only the side's nearest corner did, and
  // only when it lay in front of the plane: a receiver on a turned block's face a few
  // hundredths of a spacing above the floor looked through the gap under the floor (0.02-0.30
  // for rays' 0.50: FootprintTest.ATurnedWallStandingOnTheFloorReachesIt; docs/eval.md,
  // "Session 16").
  int raised = 0;  // the axes moved to the receiver's plane, bit k
  // Only a surface that the receiver sees from the front stands on its plane: with hitsides
  // both, the receiver's own curved surface seen from behind (a leg's tip) grew into its view
  // (spider.obj both: 0.37 for rays' 0.0002). A receiver on the crease lies behind by up to
  // the crease tolerance (Rasterizer::CreaseShift).
  if (std::fabs(glm::dot(na, nr)) < 0.9f && glm::dot(na, origin - ca) > -crease_tol) {
    const float h = a.hmin;
    if (h > -0.25f * sa && h < kContactReach * sa) {
      for (int k = 0; k < 3; ++k) {
        if (std::fabs(na[k]) > kInPlaneAxis || std::fabs(nr[k]) < 0.5f) continue;
        // The box's side facing the plane, across the cell (the centres' box without one: the
        // surface goes on along the contact to the cell's sides, below), as a box flat along
        // k: its highest point decides how far the side moves.
        Bounds side = has_cell ? cell : a.centres;
        side.lo[k] = side.hi[k] = nr[k] > 0.0f ? a.centres.lo[k] : a.centres.hi[k];
        float side_low, face;
        BoxDotRange(side, nr, origin, &side_low, &face);
        const float ext = std::max(0.0f, face) / std::fabs(nr[k]) + 0.25f * sa;
        if (!(ext < kContactGrowth * sa)) continue;
        // Past the cell's side too, when the plane lies beyond all of that side (a sliver of
        // the surface in the next cell, maybe without a surfel of its own); where the plane
        // enters the cell through that side, the next cell's surface reaches it there.
        bool past = true;
        if (has_cell) {
          Bounds cell_side = cell;
          cell_side.lo[k] = cell_side.hi[k] = nr[k] > 0.0f ? cell.lo[k] : cell.hi[k];
          float near, far;
          BoxDotRange(cell_side, nr, origin, &near, &far);
          past = near > 0.0f;
        }
        if (nr[k] > 0.0f) {
          out.lo[k] = a.centres.lo[k] - ext;
          if (!past) out.lo[k] = std::max(out.lo[k], cell.lo[k]);
          if (reach) reach->lo[k] = std::min(reach->lo[k], out.lo[k] + kContactSnap * sa);
        } else {
          out.hi[k] = a.centres.hi[k] + ext;
          if (!past) out.hi[k] = std::min(out.hi[k], cell.hi[k]);
          if (reach) reach->hi[k] = std::max(reach->hi[k], out.hi[k] - kContactSnap * sa);
        }
        *contact = true;
        raised |= 1 << k;
      }
    }
  }
  if (!has_cell) return *contact ? out : cell;
  for (const SurfelGroup& b : groups) {
    if (&b == &a || b.two_sided || !b.solid) continue;
    const glm::vec3 nb = b.normal, cb = b.centroid;
    const float sb = b.spacing;
    int k = 0;
    for (int j = 1; j < 3; ++j) {
      if (std::fabs(nb[j]) > std::fabs(nb[k])) k = j;
    }
    if (std::fabs(nb[k]) < 0.99f || std::fabs(na[k]) > kInPlaneAxis) continue;
    if (!GrownBoxesOverlap(a.centres, 1.5f * sa, b.centres, 1.5f * sb)) continue;
    // Along the edge where they meet, b spans a (within a spacing): a wall beside the street
    // around a building's corner does not end the street in front of the building. Each side
    // by half of its own spacing: b's surface reaches that far past its last centre, and a
    // lone surfel of b (a tower's face, sparsely sampled) spans a only so (bug:
    // lone_face_does_not_end_its_corner: the other face went on past the tower's corner to its
    // cell's side, over a roof receiver 0.11 in front of its plane, 0.48 for rays' 0.27).
    int m = 0;
    for (int j = 1; j < 3; ++j) {
      if (std::fabs(na[j]) > std::fabs(na[m])) m = j;
    }
    if (m == k) continue;
    const int e = 3 - m - k;
    // b's centres against a's plane.
    float lo, hi;
    BoxDotRange(b.centres, na, ca, &lo, &hi);
    // Unless they meet at a convex edge (each one's centres behind the other's plane): a roof
    // ends at its wall's plane however few of the wall's surfels its cell holds. With a lone
    // surfel of the wall under the roof's edge the roof went on to its cell's side, past the
    // wall, and a receiver above the street saw the sunlit roof where the shaded wall is (bug:
    // roof_overhangs_its_wall; city irradiance +0.13 of 1.74). A street around a building's
    // corner meets the other wall at a concave edge (the wall stands in front of the street's
    // plane), so it still goes on.
    bool convex = false;
    if (hi < 0.0f) {
      float alo, ahi;
      BoxDotRange(a.centres, nb, cb, &alo, &ahi);
      convex = ahi < 0.0f;
    }
    if (!convex && (b.centres.lo[e] - 0.5f * sb > a.centres.lo[e] + 0.5f * sa ||
                    b.centres.hi[e] + 0.5f * sb < a.centres.hi[e] - 0.5f * sa)) {
      continue;
    }
    if (lo > 1.5f * sb || hi < -1.5f * sb) continue;
    // b's plane along axis k, at a's centroid.
    float c = cb[k];
    for (int j = 0; j < 3; ++j) {
      if (j != k) c -= nb[j] * (ca[j] - cb[j]) / nb[k];
    }
    if (a.centres.lo[k] >= c - 0.05f * sa && a.centres.lo[k] - c < 1.5f * sa && c > out.lo[k]) {
      out.lo[k] = std::min(c, a.centres.lo[k]);
      *contact = true;
    } else if (a.centres.hi[k] <= c + 0.05f * sa && c - a.centres.hi[k] < 1.5f * sa &&
               c < out.hi[k]) {
      out.hi[k] = std::max(c, a.centres.hi[k]);
      *contact = true;
    }
  }
  // Along the contact (the in-plane axes not moved to the receiver's plane) the surface goes on
  // to its cell's sides, or to where another group's plane ends it (above): a turned block
  // cuts the floor's cells along it in slivers that hold a surfel or two, and their footprints
  // left holes between them right at the receiver's foot.
  // A side farther than kContactAlong spacings from the centres is where the surface ends (a
  // trunk's narrow face in a wide cell of ground), not a gap between samples. A contact along
  // an axis cuts no slivers (the cells' sides run along it), and there a side is left where it
  // was: snapped past a building's corner, a wall reached over a street receiver beside it
  // (city: 0.89 for rays' 0.85).
  const glm::vec3 line = glm::cross(na, nr);
  const float line2 = glm::dot(line, line);
  const bool oblique =
      line2 > 0.0f && std::max({line.x * line.x, line.y * line.y, line.z * line.z}) < 0.98f * line2;
  // Such a footprint's opacity counts only its part in front of the receiver (the caller).
  if (on_receiver) *on_receiver = raised && oblique;
  // Nor where another surface of the cell goes on past it (a trunk's next face, turned
  // another way): the receiver's own surface aside, whose plane is the contact's other side.
  if (raised && reach && oblique) {
    for (int k = 0; k < 3; ++k) {
      if (std::fabs(na[k]) > kInPlaneAxis || (raised >> k) & 1) continue;
      bool lo_free = a.centres.lo[k] - out.lo[k] < kContactAlong * sa;
      bool hi_free = out.hi[k] - a.centres.hi[k] < kContactAlong * sa;
      for (const SurfelGroup& b : groups) {
        if (&b == &a || b.two_sided || !b.solid || !(std::fabs(glm::dot(b.normal, nr)) < 0.9f)) {
          continue;
        }
        lo_free = lo_free && !(b.centres.lo[k] < a.centres.lo[k] - 0.5f * sa);
        hi_free = hi_free && !(b.centres.hi[k] > a.centres.hi[k] + 0.5f * sa);
      }
      if (lo_free) reach->lo[k] = std::min(reach->lo[k], out.lo[k] + kContactSnap * sa);
      if (hi_free) reach->hi[k] = std::max(reach->hi[k], out.hi[k] - kContactSnap * sa);
    }
  }
  return out;
}

// A cell's convex edges: bit j of edges[i] when one-sided groups i and j are not parallel and
// each one's centroid lies behind the other's plane (the first 32 groups). Returns whether the
// groups are the faces of one convex solid: at least three, and every pair that is not parallel
// meets at a convex edge (a trunk, a column, a box's corner). Two faces both along world axes
// are left out: ContactCell's boxes already end them at each other's planes.
bool ConvexEdges(absl::Span<const SurfelGroup> groups, uint32_t* edges) {
  const size_t n = std::min<size_t>(groups.size(), 32);
  int faces = 0;
  bool all = true;
  for (size_t i = 0; i < n; ++i) edges[i] = 0;
  for (size_t i = 0; i < n; ++i) {
    const SurfelGroup& a = groups[i];
    if (a.two_sided || !a.solid) continue;
    ++faces;
    for (size_t j = i + 1; j < n; ++j) {
      const SurfelGroup& b = groups[j];
      if (b.two_sided || !b.solid || !(glm::dot(a.normal, b.normal) < 0.9f)) continue;
      if (a.on_axis && b.on_axis) continue;
      const glm::vec3 ab = b.centroid - a.centroid;
      if (glm::dot(b.normal, ab) > kConvexDepth * a.spacing &&
          glm::dot(a.normal, ab) < -kConvexDepth * b.spacing) {
        edges[i] |= 1u << j;
        edges[j] |= 1u << i;
      } else {
        all = false;
      }
    }
  }
  return faces >= 3 && all;
}

// Where two one-sided groups of a cell meet at a convex edge, a's footprint ends at b's plane
// (docs/design.md, "Faces of a convex solid in one cell"). Without it each face's plane ran on
// across the cell past the edge, in front of the solid: the faces of a forest's trunk, each its
// cell's section by its plane, closed pixels over the ground beside it where rays pass the trunk
// (bug: convex_faces_run_past_their_edge). In a cell whose groups are the faces of one convex
// solid (ConvexEdges) each face ends at every other's plane. Otherwise b must meet a within the
// cell (each group's centres within 1.5 spacings of the other's plane, their boxes so grown
// overlapping) and span a along their edge (within half a spacing each side), as in
// ContactCell: a roof goes on past the top of a notch's wall beside it. `edges`: bit j for
// groups[j] (ConvexEdges); `p` is relative to `from`. Returns whether it was clipped.
bool ClipAtConvexEdges(const SurfelGroup& a, uint32_t edges, absl::Span<const SurfelGroup> groups,
                       bool convex_solid, const glm::vec3& from, Polygon* p) {
  bool clipped = false;
  for (; edges != 0; edges &= edges - 1) {
    const SurfelGroup& b = groups[std::countr_zero(edges)];
    const glm::vec3 na = a.normal, nb = b.normal;
    const float sa = a.spacing, sb = b.spacing;
    if (!convex_solid) {
      float lo, hi;
      BoxDotRange(b.centres, na, a.centroid, &lo, &hi);
      if (lo > 1.5f * sb || hi < -1.5f * sb) continue;
      BoxDotRange(a.centres, nb, b.centroid, &lo, &hi);
      if (lo > 1.5f * sa || hi < -1.5f * sa) continue;
      if (!GrownBoxesOverlap(a.centres, 1.5f * sa, b.centres, 1.5f * sb)) continue;
      const glm::vec3 edge = glm::cross(na, nb);
      const float el = glm::length(edge);
      if (!(el > 0.0f)) continue;
      float alo, ahi, blo, bhi;
      BoxDotRange(a.centres, edge / el, glm::vec3(0.0f), &alo, &ahi);
      BoxDotRange(b.centres, edge / el, glm::vec3(0.0f), &blo, &bhi);
      if (blo - 0.5f * sb > alo + 0.5f * sa || bhi + 0.5f * sb < ahi - 0.5f * sa) continue;
    }
    // Keep dot(nb, x - cb) <= 0, x = from + v, to within a hundredth of a spacing: a polygon
    // that already ends at the plane (ContactCell, a box's side on it) is left as it is.
    ClipHalfSpace(-nb, glm::dot(nb, from - b.centroid) - 0.01f * sb, p);
    clipped = true;
    if (p->n < 3) break;
  }
  return clipped;
}

// Two two-sided groups whose normals are within this cosine (about 25 degrees, a co-planar
// group's) are one sheet going on, not a junction.
constexpr float kJunctionCos = 0.906f;

// The side of two-sided group b's plane that all of a's centres lie on (to within a quarter of
// b's spacing), reaching within 1.5 of b's spacings of it: *sign +1 where dot(nb, x - cb) >= 0,
// -1 where <= 0. False when a's centres lie on both sides or farther.
bool SheetSide(const SurfelGroup& a, const SurfelGroup& b, float* sign) {
  const float sb = b.spacing;
  float lo, hi;
  BoxDotRange(a.centres, b.normal, b.centroid, &lo, &hi);
  if (lo >= -0.25f * sb && lo <= 1.5f * sb) {
    *sign = 1.0f;
  } else if (hi <= 0.25f * sb && hi >= -1.5f * sb) {
    *sign = -1.0f;
  } else {
    return false;
  }
  return true;
}

// Whether two-sided group a meets two-sided group b at a junction (an L, a T, a ridge, a fold):
// their planes differ by more than a co-planar group's 25 degrees, a lies on one side of b's
// plane (SheetSide, *sign), and b's centres reach a's plane (within 1.5 of a's spacings).
// Sheets of different known tags (two leaves of a crown) meet nothing.
bool MeetsAtSheetJunction(const SurfelGroup& a, const SurfelGroup& b, const Gathered& g,
                          const uint32_t* order, float* sign) {
  if (&b == &a || !b.two_sided || !b.solid) return false;
  const uint8_t ta = g.surfels[order[a.end - a.count]].sheet;
  const uint8_t tb = g.surfels[order[b.end - b.count]].sheet;
  if (ta != 0 && tb != 0 && ta != tb) return false;
  if (std::fabs(glm::dot(a.normal, b.normal)) > kJunctionCos) return false;
  if (!SheetSide(a, b, sign)) return false;
  float lo, hi;
  BoxDotRange(b.centres, a.normal, a.centroid, &lo, &hi);
  return !(lo > 1.5f * a.spacing || hi < -1.5f * a.spacing);
}

// A two-sided group's footprint ends at the plane of another two-sided group of its cell that
// it meets at a junction (MeetsAtSheetJunction), on its own centres' side. Past that plane the
// section holds no part of its sheet. Returns whether it met one (its polygon then ends at
// that plane, cut here or not).
bool ClipAtSheetJunctions(const SurfelGroup& a, absl::Span<const SurfelGroup> groups,
                          const Gathered& g, const uint32_t* order, const glm::vec3& from,
                          Polygon* p) {
  bool met = false;
  for (const SurfelGroup& b : groups) {
    float sign;
    if (!MeetsAtSheetJunction(a, b, g, order, &sign)) continue;
    // Keep sign * dot(nb, x - cb) >= 0, x = from + v.
    ClipHalfSpace(sign * b.normal, sign * glm::dot(b.normal, b.centroid - from), p);
    met = true;
    if (p->n < 3) break;
  }
  return met;
}

// A one-sided group's footprint ends at the plane of a one-sided group of another leaf that it
// meets at a convex edge: both lie along world axes (as the cells' sides do) at right angles
// (within about 6 degrees), each one's centres lie behind the other's plane and within 1.5 of
// its spacings of it, and their boxes so grown overlap. A wall whose last row of centres lies
// just under its roof, the roof's surfels in the next leaf, snapped to its cell's side and stood
// up to a spacing above the roof, in front of what lies beyond (bug: wall_overhangs_its_roof;
// city irradiance -0.07 of 0.36 on a receiver a little above such a roof). Not for turned
// faces: a sparse trunk's facets (a few surfels each) ended at the planes of facets across the
// trunk too, and lost occlusion (FootprintTest.ATrunksFacesEndAtTheirEdges 18 % short, the
// forest +1.2 % MAE). Pairs within a cell are ContactCell's and ClipAtConvexEdges'.
// Whether a and b (of different leaves) meet so: the test above, symmetric in a and b.
bool CrossLeafConvexPair(const SurfelGroup& a, const SurfelGroup& b) {
  if (std::fabs(glm::dot(a.normal, b.normal)) > kCrossLeafCos) return false;
  if (!GrownBoxesOverlap(a.centres, 1.5f * a.spacing, b.centres, 1.5f * b.spacing)) return false;
  float lo, hi;
  BoxDotRange(b.centres, a.normal, a.centroid, &lo, &hi);
  if (!(hi < 0.0f && hi > -1.5f * b.spacing)) return false;
  BoxDotRange(a.centres, b.normal, b.centroid, &lo, &hi);
  return hi < 0.0f && hi > -1.5f * a.spacing;
}

// A leaf cell and its groups [g0, g1) among every cell's (PrepareSurfelGroups).
struct CellRun {
  Bounds cell;
  size_t g0, g1;
};

// Whether two-sided group a, in `cell`, ends at the plane of two-sided group b of a touching
// cell: they meet at a junction (MeetsAtSheetJunction, their centres' boxes grown by 1.5
// spacings overlapping) and b's plane leaves a's cell on a's side (to within a hundredth of b's
// spacing), so that ending a there takes off only what reaches past the cell. The caller asks
// only for groups that may reach past it.
bool CrossLeafSheetPair(const SurfelGroup& a, const Bounds& cell, const SurfelGroup& b,
                        const Gathered& g, const uint32_t* order) {
  // Most pairs are one sheet going on across its cells: the cheapest test first.
  if (std::fabs(glm::dot(a.normal, b.normal)) > kJunctionCos) return false;
  if (!GrownBoxesOverlap(a.centres, 1.5f * a.spacing, b.centres, 1.5f * b.spacing)) return false;
  float sign;
  if (!MeetsAtSheetJunction(a, b, g, order, &sign)) return false;
  float lo, hi;
  BoxDotRange(cell, sign * b.normal, b.centroid, &lo, &hi);
  return lo >= -0.01f * b.spacing;
}

// Every pair (a, b) of `all`'s groups in two different cells that touch (octree cells share a
// face, an edge or a corner) that meet so: one-sided faces at a convex edge (CrossLeafConvexPair),
// both ways; with `sheets`, two-sided sheets at a junction past a's cell (CrossLeafSheetPair),
// each way on its own. `sheets` needs leaf cells (the gather's, which do not overlap). The cells
// are swept along x: a receiver near a sparse database gathers hundreds of groups, and testing
// every pair of groups cost 3 M instructions per receiver (city 50 k surfels).
void CrossLeafPairs(absl::Span<const SurfelGroup> all, absl::Span<const CellRun> runs,
                    const Gathered& g, const uint32_t* order, bool sheets,
                    std::vector<std::pair<uint32_t, uint32_t>>* pairs) {
  static thread_local std::vector<uint32_t> order_x;
  pairs->clear();
  auto convex = [](const SurfelGroup& a) { return !a.two_sided && a.solid && a.on_axis; };
  auto sheet = [&](const SurfelGroup& a) { return sheets && a.two_sided && a.solid; };
  // A group whose centres all lie more than 1.5 spacings inside its cell's sides along its
  // plane ends inside the cell (FlatFootprint grows at most a spacing past them, a pair's
  // rhombus 1.5 across): it ends at no other cell's sheet. By group, for the sheets.
  static thread_local std::vector<uint8_t> reaches_out;
  reaches_out.assign(all.size(), 0);
  order_x.clear();
  for (uint32_t r = 0; r < runs.size(); ++r) {
    bool any = false;
    for (size_t i = runs[r].g0; i < runs[r].g1; ++i) {
      const SurfelGroup& a = all[i];
      if (sheet(a)) {
        const Bounds& cell = runs[r].cell;
        for (int k = 0; k < 3 && !reaches_out[i]; ++k) {
          if (!(std::fabs(a.normal[k]) < kInPlaneAxis)) continue;
          reaches_out[i] = a.centres.lo[k] - cell.lo[k] < 1.5f * a.spacing ||
                           cell.hi[k] - a.centres.hi[k] < 1.5f * a.spacing;
        }
      }
      any = any || convex(a) || sheet(a);
    }
    if (any) order_x.push_back(r);
  }
  if (order_x.size() < 2) return;
  std::sort(order_x.begin(), order_x.end(), [&](uint32_t x, uint32_t y) {
    return runs[x].cell.lo.x < runs[y].cell.lo.x ||
           (runs[x].cell.lo.x == runs[y].cell.lo.x && x < y);
  });
  for (size_t i = 0; i < order_x.size(); ++i) {
    const CellRun& ri = runs[order_x[i]];
    const Bounds& ci = ri.cell;
    for (size_t j = i + 1; j < order_x.size() && runs[order_x[j]].cell.lo.x <= ci.hi.x; ++j) {
      const CellRun& rj = runs[order_x[j]];
      const Bounds& cj = rj.cell;
      if (cj.lo.y > ci.hi.y || ci.lo.y > cj.hi.y || cj.lo.z > ci.hi.z || ci.lo.z > cj.hi.z) {
        continue;
      }
      for (size_t a = ri.g0; a < ri.g1; ++a) {
        const bool ca = convex(all[a]), sa = sheet(all[a]);
        if (!ca && !sa) continue;
        for (size_t b = rj.g0; b < rj.g1; ++b) {
          const uint32_t a32 = static_cast<uint32_t>(a), b32 = static_cast<uint32_t>(b);
          if (ca) {
            if (!convex(all[b]) || !CrossLeafConvexPair(all[a], all[b])) continue;
            pairs->push_back({a32, b32});
            pairs->push_back({b32, a32});
          } else if (sheet(all[b])) {
            if (reaches_out[a] && CrossLeafSheetPair(all[a], ci, all[b], g, order)) {
              pairs->push_back({a32, b32});
            }
            if (reaches_out[b] && CrossLeafSheetPair(all[b], cj, all[a], g, order)) {
              pairs->push_back({b32, a32});
            }
          }
        }
      }
    }
  }
}

// Clips a's footprint (group `ai` of `all`) at the planes of its partners, partners[first[ai],
// first[ai + 1]) (CrossLeafPairs): a one-sided face keeps what lies behind a partner's plane,
// a two-sided sheet its own side of it.
bool CrossLeafClip(uint32_t ai, absl::Span<const SurfelGroup> all, absl::Span<const uint32_t> first,
                   absl::Span<const uint32_t> partners, const glm::vec3& from, Polygon* p) {
  bool clipped = false;
  const SurfelGroup& a = all[ai];
  for (uint32_t k = first[ai]; k < first[ai + 1] && p->n >= 3; ++k) {
    const SurfelGroup& b = all[partners[k]];
    if (a.two_sided) {
      // Keep a's side of b's plane (CrossLeafSheetPair), to within the hundredth of b's spacing
      // that the pair allowed b's plane inside a's cell.
      float sign;
      if (!SheetSide(a, b, &sign)) continue;
      ClipHalfSpace(sign * b.normal,
                    sign * glm::dot(b.normal, b.centroid - from) - 0.01f * b.spacing, p);
    } else {
      ClipHalfSpace(-b.normal, glm::dot(b.normal, from - b.centroid) - 0.01f * b.spacing, p);
    }
    clipped = true;
  }
  return clipped;
}

// The runs of one leaf's surfels in a gather (the gather emits a leaf's surfels together) and a
// uniform grid over their leaf cells, so that SheetCell looks only at the runs whose cells lie
// near a group's: it looked at every run for every two-sided group, and a receiver of
// 2CylinderEngine that gathers thousands of leaves spent half its time there.
class LeafRunIndex {
 public:
  void Build(const Gathered& g, absl::Span<const uint32_t> runs) {
    runs_ = runs;
    n_ = g.surfels.size();
    const size_t count = runs.size();
    boxes_.resize(count);
    Bounds all;
    for (size_t r = 0; r < count; ++r) {
      boxes_[r] = g.leaf_cells[g.surfel_leaf[runs[r]]];
      all.Extend(boxes_[r]);
    }
    // About two runs per grid cell, at most 32 cells per axis.
    dim_ = std::clamp(static_cast<int>(std::cbrt(static_cast<double>(count) / 2.0)), 1, 32);
    lo_ = all.lo;
    const glm::vec3 extent = glm::max(all.hi - all.lo, glm::vec3(1e-30f));
    inv_ = static_cast<float>(dim_) / extent;
    first_.assign(size_t(dim_) * dim_ * dim_ + 1, 0);
    big_.clear();
    // Two passes: count, then fill (CSR). A run whose cell spans more than 64 grid cells is
    // always a candidate.
    for (int pass = 0; pass < 2; ++pass) {
      if (pass == 1) {
        for (size_t c = 1; c < first_.size(); ++c) first_[c] += first_[c - 1];
        items_.resize(first_.back());
        at_.assign(first_.begin(), first_.end() - 1);
      }
      for (size_t r = 0; r < count; ++r) {
        int a[3], b[3];
        Range(boxes_[r], a, b);
        if ((b[0] - a[0] + 1) * (b[1] - a[1] + 1) * (b[2] - a[2] + 1) > 64) {
          if (pass == 0) big_.push_back(static_cast<uint32_t>(r));
          continue;
        }
        for (int z = a[2]; z <= b[2]; ++z) {
          for (int y = a[1]; y <= b[1]; ++y) {
            for (int x = a[0]; x <= b[0]; ++x) {
              const size_t c = (size_t(z) * dim_ + y) * dim_ + x;
              if (pass == 0) {
                ++first_[c + 1];
              } else {
                items_[at_[c]++] = static_cast<uint32_t>(r);
              }
            }
          }
        }
      }
    }
    stamp_.assign(count, 0);
    epoch_ = 0;
  }
  // Calls f(first, end, cell) once for every run whose leaf cell may meet `query`: its surfels
  // [first, end) of the gather and its leaf's cell.
  template <typename F>
  void ForNear(const Bounds& query, F&& f) {
    if (++epoch_ == 0) {
      std::fill(stamp_.begin(), stamp_.end(), 0);
      epoch_ = 1;
    }
    auto visit = [&](uint32_t r) {
      if (stamp_[r] == epoch_) return true;
      stamp_[r] = epoch_;
      return f(runs_[r], r + 1 < runs_.size() ? runs_[r + 1] : n_, boxes_[r]);
    };
    for (uint32_t r : big_) {
      if (!visit(r)) return;
    }
    int a[3], b[3];
    Range(query, a, b);
    for (int z = a[2]; z <= b[2]; ++z) {
      for (int y = a[1]; y <= b[1]; ++y) {
        for (int x = a[0]; x <= b[0]; ++x) {
          const size_t c = (size_t(z) * dim_ + y) * dim_ + x;
          for (uint32_t k = first_[c]; k < first_[c + 1]; ++k) {
            if (!visit(items_[k])) return;
          }
        }
      }
    }
  }

 private:
  // The grid cells [a, b] per axis that box `x` meets, clamped to the grid.
  void Range(const Bounds& x, int a[3], int b[3]) const {
    for (int k = 0; k < 3; ++k) {
      const float u = (x.lo[k] - lo_[k]) * inv_[k], v = (x.hi[k] - lo_[k]) * inv_[k];
      a[k] = std::clamp(static_cast<int>(std::floor(std::max(u, -1.0f))), 0, dim_ - 1);
      b[k] = std::clamp(static_cast<int>(std::floor(std::min(v, float(dim_)))), 0, dim_ - 1);
    }
  }

  absl::Span<const uint32_t> runs_;
  size_t n_ = 0;
  std::vector<Bounds> boxes_;
  glm::vec3 lo_{0.0f}, inv_{1.0f};
  int dim_ = 1;
  std::vector<uint32_t> first_, at_, items_, big_, stamp_;
  uint32_t epoch_ = 0;
};

// A two-sided co-planar group's footprint snaps to the sides of its leaf cell across which its
// sheet goes on, and ends where its surfels end elsewhere (docs/design.md, "Two-sided sheets
// across their cells"). A side goes on when two-sided surfels of other leaves lie beyond it
// (within kSheetReach spacings) as the next samples of the sheet of the group's surfels, along
// all of the group's extent beside that side (to within a spacing at either end): a surfel b
// is the next sample of the group's surfel a when it lies within kSheetNext spacings of a,
// faces a's way and lies in a's tangent plane, each to within the 25 degrees that a co-planar
// group allows (a faceted sheet's next facet goes on too). A sheet that goes on along a part of
// the side only (a rim, a hole or a slot at the side) keeps the leaf's rule there. Returns the
// cell with every other side moved out of reach, or an empty box when no side goes on.
// *along_traces: the same judged along each side's trace on the plane instead of the world axes
// (for `surrounded`, PrepareSurfelGroups). `members`: the group's surfels' indices in g.surfels;
// `runs`: the gather's runs of one leaf's surfels.
constexpr float kSheetReach = 1.5f;
constexpr float kSheetNext = 2.5f;
constexpr float kSheetCos = 0.9f;     // the co-planar group's normal test
constexpr float kSheetSlope = 0.43f;  // sin 25.5 degrees
// A group of fewer surfels keeps the leaf's rule: a piece of a leaf sampled by two surfels
// (the forest's at 2 M surfels, about two per leaf) says too little of where its leaf ends.
constexpr int kSheetMinCount = 3;
Bounds SheetCell(const Bounds& cell, uint32_t leaf, const SurfelGroup& gr, const Gathered& g,
                 const uint32_t* members, LeafRunIndex& runs, Bounds* along_traces) {
  *along_traces = Bounds{};
  const float sp = gr.spacing, reach = kSheetReach * sp;
  bool in_plane[3], near[6], any = false;  // near[2 k] (near[2 k + 1]): the low (high) side of k
  for (int k = 0; k < 3; ++k) {
    in_plane[k] = std::fabs(gr.normal[k]) < kInPlaneAxis;
    near[2 * k] = in_plane[k] && gr.centres.lo[k] - cell.lo[k] < reach;
    near[2 * k + 1] = in_plane[k] && cell.hi[k] - gr.centres.hi[k] < reach;
    any = any || near[2 * k] || near[2 * k + 1];
  }
  if (!any) return Bounds{};
  // The next samples found beyond each side, by their box; a side goes on once they reach
  // within a spacing of both ends of the group's extent along the side's other in-plane axes.
  Bounds seen[6];
  auto goes_on = [&](int q) {
    if (seen[q].Empty()) return false;
    for (int k = 0; k < 3; ++k) {
      if (k == q / 2 || !in_plane[k]) continue;
      if (seen[q].lo[k] > gr.centres.lo[k] + sp || seen[q].hi[k] < gr.centres.hi[k] - sp) {
        return false;
      }
    }
    return true;
  };
  // The same along each side's trace on the plane (the direction in the plane along the side),
  // for *along_traces: the world axes count an axis near a turned plane's normal (|n_k| just
  // under kInPlaneAxis) as along the side, and beyond a side the next samples, a thin slab of
  // the plane, span little of it where the group spans the plane's rise across the cell. The
  // group's extent there is its members' within reach of the side (its row along the side, not
  // the section's widest), and the next samples must reach within kSheetReach spacings of its
  // ends (a stratified row's jitter on both sides of the side; docs/design.md, "Two-sided sheets
  // across their cells").
  glm::vec3 trace[6];
  float group_lo[6], group_hi[6], seen_lo[6], seen_hi[6];
  for (int q = 0; q < 6; ++q) {
    seen_lo[q] = group_lo[q] = std::numeric_limits<float>::max();
    seen_hi[q] = group_hi[q] = -std::numeric_limits<float>::max();
    if (!near[q]) continue;
    glm::vec3 axis(0.0f);
    axis[q / 2] = 1.0f;
    trace[q] = glm::normalize(glm::cross(gr.normal, axis));
    for (int m = 0; m < gr.count; ++m) {
      const glm::vec3& x = g.surfels[members[m]].position;
      const int k = q / 2;
      if (q % 2 == 0 ? !(x[k] - cell.lo[k] < reach) : !(cell.hi[k] - x[k] < reach)) continue;
      const float t = glm::dot(trace[q], x);
      group_lo[q] = std::min(group_lo[q], t);
      group_hi[q] = std::max(group_hi[q], t);
    }
  }
  auto goes_on_along_trace = [&](int q) {
    return seen_lo[q] <= group_lo[q] + reach && seen_hi[q] >= group_hi[q] - reach;
  };
  int open = 0;  // the near sides not known to go on yet by both measures: bit q
  for (int q = 0; q < 6; ++q) open |= near[q] ? 1 << q : 0;
  // The open sides that x lies beyond, within reach: bit 2 k (2 k + 1) for k's low (high) side.
  auto beyond = [&](const glm::vec3& x) {
    int sides = 0;
    for (int k = 0; k < 3; ++k) {
      if (x[k] < cell.lo[k] && x[k] >= cell.lo[k] - reach) sides |= 1 << (2 * k);
      if (x[k] > cell.hi[k] && x[k] <= cell.hi[k] + reach) sides |= 1 << (2 * k + 1);
    }
    return sides & open;
  };
  const float next2 = kSheetNext * kSheetNext * sp * sp, cos2 = kSheetCos * kSheetCos;
  Bounds near_cell;
  near_cell.lo = cell.lo - reach;
  near_cell.hi = cell.hi + reach;
  // The result does not depend on the order the runs come in: a side's box of next samples only
  // grows, and a side that goes on stays on.
  runs.ForNear(near_cell, [&](size_t j, size_t end, const Bounds& c) {
    const uint32_t l = g.surfel_leaf[j];
    bool touches = l != leaf;
    for (int k = 0; k < 3 && touches; ++k) {
      touches = c.lo[k] <= cell.hi[k] + reach && c.hi[k] >= cell.lo[k] - reach;
    }
    for (; touches && j < end && open != 0; ++j) {
      const Surfel& b = g.surfels[j];
      const int sides = b.two_sided ? beyond(b.position) : 0;
      if (sides == 0) continue;
      const float nb2 = glm::dot(b.normal, b.normal);
      for (int m = 0; m < gr.count; ++m) {
        const Surfel& a = g.surfels[members[m]];
        // Another sheet (both tags known and different: another leaf) is not this one's next
        // sample, however it lies.
        if (a.sheet != 0 && b.sheet != 0 && a.sheet != b.sheet) continue;
        const glm::vec3 d = b.position - a.position;
        const float dd = glm::dot(d, d);
        if (dd > next2) continue;
        const float na2 = glm::dot(a.normal, a.normal), ab = glm::dot(a.normal, b.normal);
        if (ab * ab < cos2 * na2 * nb2) continue;
        const float off = kSheetSlope * std::sqrt(dd) + kGroupThickness * sp;
        const float ad = glm::dot(a.normal, d);
        if (ad * ad > off * off * na2) continue;
        for (int q = 0; q < 6; ++q) {
          if (!(sides & (1 << q))) continue;
          seen[q].Extend(b.position);
          const float t = glm::dot(trace[q], b.position);
          seen_lo[q] = std::min(seen_lo[q], t);
          seen_hi[q] = std::max(seen_hi[q], t);
          if (goes_on(q) && goes_on_along_trace(q)) open &= ~(1 << q);
        }
        break;
      }
    }
    return open != 0;
  });
  constexpr float kFar = std::numeric_limits<float>::max();
  auto sides = [&](auto&& on_side) {
    Bounds out = cell;
    bool snaps = false;
    for (int q = 0; q < 6; ++q) {
      const bool on = near[q] && on_side(q);
      snaps = snaps || on;
      if (!on) (q % 2 == 0 ? out.lo : out.hi)[q / 2] = q % 2 == 0 ? -kFar : kFar;
    }
    return snaps ? out : Bounds{};
  };
  *along_traces = sides(goes_on_along_trace);
  return sides(goes_on);
}

// The trace of world axis k's direction `sign` on the plane of unit `normal`, as a unit vector
// in *t; false where the axis lies within about 17 degrees of the normal (no direction in the
// plane to speak of).
bool AxisTrace(int k, float sign, const glm::vec3& normal, glm::vec3* t) {
  glm::vec3 e(0.0f);
  e[k] = sign;
  e -= glm::dot(e, normal) * normal;
  const float l = glm::length(e);
  if (!(l > 0.3f)) return false;
  *t = e / l;
  return true;
}

// In how many directions within its plane (unit `normal`) a sheet goes on past its cell: the
// sides SheetCell kept (the others it moved out of reach), their outward axes projected on the
// plane, those within 45 degrees of each other counted once (a tilted sheet that goes on past
// a corner crosses two sides there, one edge of the sheet).
int GoingOnDirections(const Bounds& sheet_cell, const glm::vec3& normal) {
  glm::vec3 seen[6];
  int count = 0;
  for (int q = 0; q < 6; ++q) {
    const int k = q / 2;
    const bool kept = q % 2 == 0 ? sheet_cell.lo[k] > -kNoSide : sheet_cell.hi[k] < kNoSide;
    glm::vec3 e;
    // A side across the plane's normal is no edge of it.
    if (!kept || !AxisTrace(k, q % 2 == 0 ? -1.0f : 1.0f, normal, &e)) continue;
    bool same = false;
    for (int i = 0; i < count && !same; ++i) same = glm::dot(seen[i], e) > 0.7071f;
    if (!same) seen[count++] = e;
  }
  return count;
}

}  // namespace

namespace {
// FootprintBox with CellHolds(cell, centres) given.
Bounds FootprintBoxIn(const Bounds& centres, const Bounds& cell, bool has_cell, float spacing,
                      const glm::vec3& plane_normal, bool* full, int* snapped,
                      const Bounds* reach) {
  // The three axes in lanes (the fourth repeats the third), each lane the scalar expressions.
  V4 clo, chi, slo, shi, rlo, rhi;
  LoadBounds(cell, &clo, &chi);
  LoadBounds(centres, &slo, &shi);
  if (reach != nullptr) {
    LoadBounds(*reach, &rlo, &rhi);
  } else {
    rlo = clo;
    rhi = chi;
  }
  const V4 n = {plane_normal.x, plane_normal.y, plane_normal.z, plane_normal.z};
  // |n| by clearing the sign bit.
  const V4i abs_bits = {0x7fffffff, 0x7fffffff, 0x7fffffff, 0x7fffffff};
  const V4i in_plane = (V4)((V4i)n & abs_bits) < kInPlaneAxis;
  // A cell less than two spacings across cannot tell a surface's edge from sampling noise
  // (bug: sparse_full_cell_leak): its sides always snap.
  const V4i small = chi - clo < 2.0f * spacing;
  const V4i usable = has_cell ? in_plane : V4i{0, 0, 0, 0};
  const V4i snap_lo = usable & (small | (slo - rlo < 1.5f * spacing));
  const V4i snap_hi = usable & (small | (rhi - shi < 1.5f * spacing));
  V4 lo = snap_lo ? clo : slo - 0.5f * spacing;
  V4 hi = snap_hi ? chi : shi + 0.5f * spacing;
  if (has_cell) {
    // Along an axis nearly along the normal, the cell: a plane turned from that axis runs
    // across it as far as the other axes let it, and ends at the cell's sides, where the
    // neighbouring cell's footprint takes over; it ran on past them into that footprint
    // (docs/design.md, "Footprints of a turned plane"). Padded by a twentieth of a spacing
    // past the centres, so that a plane on the cell's side stays inside the box.
    // A side moved out of reach (SheetCell) is not a side: half a spacing past the centres.
    const V4i across = ~in_plane;
    lo = across ? (clo > -kNoSide ? Min4(clo, slo - kPlanePad * spacing) : lo) : lo;
    hi = across ? (chi < kNoSide ? Max4(chi, shi + kPlanePad * spacing) : hi) : hi;
  }
  Bounds b;
  b.lo = glm::vec3(lo[0], lo[1], lo[2]);
  b.hi = glm::vec3(hi[0], hi[1], hi[2]);
  if (full) {
    // An axis along which the plane extends must reach both sides of the cell for the plane to
    // fill it (an axis nearly along the normal does not matter).
    *full = has_cell && (Movemask4(in_plane & ~(snap_lo & snap_hi)) & 7) == 0;
  }
  if (snapped) {
    // Bit 2 k: the low side along axis k snapped, bit 2 k + 1: the high side.
    const int l = Movemask4(snap_lo), h = Movemask4(snap_hi);
    *snapped = (l & 1) | ((l & 2) << 1) | ((l & 4) << 2) | ((h & 1) << 1) | ((h & 2) << 2) |
               ((h & 4) << 3);
  }
  return b;
}
}  // namespace

Bounds FootprintBox(const Bounds& centres, const Bounds& cell, float spacing,
                    const glm::vec3& plane_normal, bool* full, int* snapped, const Bounds* reach) {
  return FootprintBoxIn(centres, cell, CellHolds(cell, centres), spacing, plane_normal, full,
                        snapped, reach);
}

bool PlaneReach(const glm::vec3& normal, float offset, const Bounds& cell, float spacing,
                const glm::vec3& origin, Bounds* reach) {
  // A plane along the axes reaches the cell's sides across them: the cell serves. So it does
  // for a cell with sides moved out of reach (SheetCell): those never snap.
  const glm::vec3 a = glm::abs(normal);
  if (std::max({a.x, a.y, a.z}) >= 1.0f - 1e-6f * (a.x + a.y + a.z)) return false;
  for (int k = 0; k < 3; ++k) {
    if (!(cell.lo[k] > -kNoSide) || !(cell.hi[k] < kNoSide)) return false;
  }
  // FootprintBox's box along the axes nearly along the normal, relative to the origin.
  glm::vec3 lo = cell.lo - origin, hi = cell.hi - origin;
  for (int k = 0; k < 3; ++k) {
    if (a[k] < kInPlaneAxis) continue;
    lo[k] -= kPlanePad * spacing;
    hi[k] += kPlanePad * spacing;
  }
  // The plane's polygon in the box has its corners on the box's edges: where the plane meets
  // each of the twelve, the bounds of those points.
  Bounds r;
  for (int k = 0; k < 3; ++k) {
    if (!(a[k] > 0.0f)) continue;  // edges along k lie parallel to the plane
    const int i = (k + 1) % 3, j = (k + 2) % 3;
    for (float u : {lo[i], hi[i]}) {
      for (float v : {lo[j], hi[j]}) {
        const float t = (offset - normal[i] * u - normal[j] * v) / normal[k];
        if (!(t >= lo[k] && t <= hi[k])) continue;
        glm::vec3 q;
        q[k] = t;
        q[i] = u;
        q[j] = v;
        r.Extend(q + origin);
      }
    }
  }
  if (r.Empty()) return false;
  *reach = r;
  return true;
}

Bounds FlatBox(const Bounds& centres, const Bounds& cell, float spacing, const glm::vec3& normal,
               float offset, const glm::vec3& origin, bool* full, int* snapped) {
  const bool has_cell = CellHolds(cell, centres);
  const Bounds box =
      FootprintBoxIn(centres, cell, has_cell, spacing, normal, full, snapped, nullptr);
  // Where every in-plane side snapped to the cell's, it snaps to the plane's reach as well
  // (the reach lies inside the cell): only the others ask for it.
  Bounds reach;
  if (*full || !has_cell || !PlaneReach(normal, offset, cell, spacing, origin, &reach)) {
    return box;
  }
  return FootprintBoxIn(centres, cell, has_cell, spacing, normal, full, snapped, &reach);
}

float FlatFootprint(const Bounds& centres, const Bounds& cell, float spacing,
                    const glm::vec3& normal, float offset, const glm::vec3& origin, double area,
                    bool backs, Polygon* p, bool* sheet) {
  if (sheet != nullptr) *sheet = false;
  bool full = false;
  int snapped = 0;
  Bounds box = FlatBox(centres, cell, spacing, normal, offset, origin, &full, &snapped);
  PlaneBoxPolygon(normal, offset, box.lo - origin, box.hi - origin, p);
  double poly = p->n >= 3 ? PolygonArea(*p) : 0.0;
  if (!(poly > 0.0) || !(area > 0.0)) {
    p->n = 0;
    return 0.0f;
  }
  // A surface that reaches every side of its cell fills it, unless it clearly lacks the area
  // (a corner cut off): the sum of surfel areas is a noisy estimate of the surface's area, and
  // a coverage clamped at 1 would lose the noise's excess. In a cell at most kSmallCell
  // surfels' areas wide the count says nothing ("full" already needs the surface within 1.5
  // spacings of every side, which an edge through the middle is not): a cell that holds two
  // surfels where three were expected would get a coverage of 2/3, which leaks wherever the
  // cell is seen, the more the finer the raster (bug: sparse_full_cell_leak).
  const double m = poly / std::max(1e-30, double(spacing) * spacing);
  const double lacks = m <= kSmallCell ? 0.0 : 0.7;
  const bool fills = full && !backs && area >= lacks * poly;
  // (A cell wider than kSheetCell is wider than kSmallCell: `fills` asks for 70 % of its area.)
  if (sheet != nullptr) *sheet = fills && m > kSheetCell;
  if (fills) return 1.0f;
  const bool has_cell = CellHolds(cell, centres);
  for (int iter = 0; iter < 2 && area > poly * 1.0001; ++iter) {
    // Grow the free in-plane axes by the missing factor, shared among them.
    int free_axes = 0;
    for (int k = 0; k < 3; ++k) {
      const int sides = (snapped >> (2 * k)) & 3;
      if (std::fabs(normal[k]) < kInPlaneAxis && sides != 3) ++free_axes;
    }
    if (free_axes == 0) break;
    const double f = std::pow(area / poly, 1.0 / free_axes);
    for (int k = 0; k < 3; ++k) {
      const int sides = (snapped >> (2 * k)) & 3;
      if (!(std::fabs(normal[k]) < kInPlaneAxis) || sides == 3) continue;
      const float grow = static_cast<float>((f - 1.0) * (box.hi[k] - box.lo[k]));
      const bool lo_free = !(sides & 1), hi_free = !(sides & 2);
      const float share = lo_free && hi_free ? 0.5f * grow : grow;
      if (lo_free) box.lo[k] -= share;
      if (hi_free) box.hi[k] += share;
      if (has_cell) {
        box.lo[k] = std::max(box.lo[k], cell.lo[k]);
        box.hi[k] = std::min(box.hi[k], cell.hi[k]);
      }
      // No farther than a surfel's disk reaches past the outermost centres: a plane that cuts
      // its box obliquely (the mean plane of a curved patch) is not grown across the cell.
      box.lo[k] = std::max(box.lo[k], centres.lo[k] - spacing);
      box.hi[k] = std::min(box.hi[k], centres.hi[k] + spacing);
    }
    Polygon q;
    PlaneBoxPolygon(normal, offset, box.lo - origin, box.hi - origin, &q);
    const double qa = q.n >= 3 ? PolygonArea(q) : 0.0;
    if (!(qa > poly)) break;
    *p = q;
    poly = qa;
  }
  return std::min(1.0f, static_cast<float>(area / poly));
}

// The rhombus's long diagonal lies along the pair, three times the centres' distance; its short
// one across, as long as the pair's area asks. Centres that coincide are FlatFootprint's.
float PairFootprint(const glm::vec3& c1, const glm::vec3& c2, const glm::vec3& normal, float offset,
                    const glm::vec3& origin, float spacing, double area, Polygon* p) {
  auto onto = [&](const glm::vec3& c) {
    const glm::vec3 r = c - origin;
    return r - (glm::dot(normal, r) - offset) * normal;
  };
  const glm::vec3 q1 = onto(c1), q2 = onto(c2);
  glm::vec3 a = q2 - q1;
  const float d = glm::length(a);
  if (!(d > 1e-3f * spacing) || !(area > 0.0) || !std::isfinite(d)) return -1.0f;
  a /= d;
  const glm::vec3 b = glm::cross(normal, a);
  // The sampler puts a quad's two surfels at its triangles' centroids, a third of its diagonal
  // apart along the other diagonal: three times that is the quad's extent along the pair, and
  // twice its area over that its extent across, the rhombus's diagonals.
  const float len = std::clamp(3.0f * d, spacing, d + 2.0f * spacing);
  const float wid =
      std::clamp(2.0f * static_cast<float>(area) / len, 0.5f * spacing, 3.0f * spacing);
  const glm::vec3 mid = 0.5f * (q1 + q2), ha = 0.5f * len * a, hb = 0.5f * wid * b;
  p->n = 4;
  p->v[0] = mid - ha;
  p->v[1] = mid + hb;
  p->v[2] = mid + ha;
  p->v[3] = mid - hb;
  return std::min(1.0f, static_cast<float>(2.0 * area / (double(len) * wid)));
}

// A two-sided group's footprint in its own plane ({x : normal . x = offset} relative to
// `origin`): the rectangle of its members' centres along their principal axes there, grown by
// half a spacing, and further while it holds less than their area (at most a spacing past the
// outermost centres), as FlatFootprint grows a box. Returns its coverage, or -1 when it has no
// extent.
float InPlaneFootprint(const Surfel* surfels, const uint32_t* members, int count,
                       const glm::vec3& normal, float offset, const glm::vec3& origin,
                       float spacing, double area, Polygon* p) {
  if (count < 1 || !(area > 0.0)) return -1.0f;
  auto onto = [&](int i) {
    const glm::vec3 r = surfels[members[i]].position - origin;
    return r - (glm::dot(normal, r) - offset) * normal;
  };
  glm::vec3 u0, v0;
  OrthonormalBasis(normal, &u0, &v0);
  glm::vec3 mid(0.0f);
  for (int i = 0; i < count; ++i) mid += onto(i);
  mid /= static_cast<float>(count);
  double cxx = 0, cyy = 0, cxy = 0;
  for (int i = 0; i < count; ++i) {
    const glm::vec3 d = onto(i) - mid;
    const double x = glm::dot(d, u0), y = glm::dot(d, v0);
    cxx += x * x, cyy += y * y, cxy += x * y;
  }
  // The axes: the centres' principal directions (a tilted leaf's pieces); where they have
  // none to speak of (eigenvalues within kIsotropic of each other: a square grid of samples),
  // of those and the world axes' traces on the plane the one whose rectangle of centres is the
  // smallest (a sheet sampled along the world axes).
  constexpr double kIsotropic = 1.5;
  glm::vec3 dirs[4];
  int nd = 0;
  const float th = 0.5f * static_cast<float>(std::atan2(2.0 * cxy, cxx - cyy));
  dirs[nd++] = std::cos(th) * u0 + std::sin(th) * v0;
  const double half_tr = 0.5 * (cxx + cyy);
  const double disc = std::sqrt(0.25 * (cxx - cyy) * (cxx - cyy) + cxy * cxy);
  const bool isotropic = half_tr + disc <= kIsotropic * (half_tr - disc);
  for (int k = 0; k < 3 && isotropic; ++k) {
    if (AxisTrace(k, 1.0f, normal, &dirs[nd])) ++nd;
  }
  glm::vec3 a = dirs[0], b = glm::cross(normal, a);
  float alo = 0.0f, ahi = 0.0f, blo = 0.0f, bhi = 0.0f, best = std::numeric_limits<float>::max();
  for (int c = 0; c < nd; ++c) {
    const glm::vec3 ca = dirs[c], cb = glm::cross(normal, ca);
    float x0 = std::numeric_limits<float>::max(), x1 = -x0, y0 = x0, y1 = -x0;
    for (int i = 0; i < count; ++i) {
      const glm::vec3 d = onto(i) - mid;
      const float x = glm::dot(d, ca), y = glm::dot(d, cb);
      x0 = std::min(x0, x), x1 = std::max(x1, x), y0 = std::min(y0, y), y1 = std::max(y1, y);
    }
    const float area_c = (x1 - x0 + spacing) * (y1 - y0 + spacing);
    if (area_c < best) best = area_c, a = ca, b = cb, alo = x0, ahi = x1, blo = y0, bhi = y1;
  }
  const float h = 0.5f * spacing;
  float l = ahi - alo + 2.0f * h, w = bhi - blo + 2.0f * h;
  if (!(l > 0.0f) || !(w > 0.0f) || !std::isfinite(l * w)) return -1.0f;
  float ga = h, gb = h;
  if (area > double(l) * w) {
    const float f = std::sqrt(static_cast<float>(area / (double(l) * w)));
    ga = std::min(spacing, h + 0.5f * (f - 1.0f) * l);
    gb = std::min(spacing, h + 0.5f * (f - 1.0f) * w);
    l = ahi - alo + 2.0f * ga, w = bhi - blo + 2.0f * gb;
  }
  p->n = 4;
  p->v[0] = mid + (alo - ga) * a + (blo - gb) * b;
  p->v[1] = mid + (ahi + ga) * a + (blo - gb) * b;
  p->v[2] = mid + (ahi + ga) * a + (bhi + gb) * b;
  p->v[3] = mid + (alo - ga) * a + (bhi + gb) * b;
  return std::min(1.0f, static_cast<float>(area / (double(l) * w)));
}

// The convex hull of pts[0, n) (sorted in place), counter-clockwise, into hull (room for 2 n
// points): its vertex count, below 3 when the points lie on a line (Andrew's monotone chain).
int ConvexHull2(glm::vec2* pts, int n, glm::vec2* hull) {
  std::sort(pts, pts + n, [](const glm::vec2& x, const glm::vec2& y) {
    return x.x < y.x || (x.x == y.x && x.y < y.y);
  });
  auto turn = [](const glm::vec2& o, const glm::vec2& u, const glm::vec2& v) {
    return (u.x - o.x) * (v.y - o.y) - (u.y - o.y) * (v.x - o.x);
  };
  int k = 0;
  for (int i = 0; i < n; ++i) {
    while (k >= 2 && turn(hull[k - 2], hull[k - 1], pts[i]) <= 0.0f) --k;
    hull[k++] = pts[i];
  }
  for (int i = n - 2, lower = k + 1; i >= 0; --i) {
    while (k >= lower && turn(hull[k - 2], hull[k - 1], pts[i]) <= 0.0f) --k;
    hull[k++] = pts[i];
  }
  return k - 1;
}

// The part of a group's footprint `clip` that is surely its surface: the convex hull of
// its members' centres projected on its plane ({x : normal . x = offset} relative to `origin`),
// and of the same centres carried in the plane to each side of `goes_on` that is a side (where
// SheetCell found the sheet going on past the cell) from within `carry` of it, each edge moved out
// by `grow` (a mitred offset), inside `clip` (in the same plane). Each centre stands for a piece of
// its sheet about a spacing wide, so the sheet holds its centres' hull and goes on about half a
// spacing past it; centres on one line (a pair, a lone surfel) hold the rectangle `grow` past
// their segment on every side. A corner too sharp to mitre (the mitre would reach over 3.2 times
// `grow`) is bevelled when `bevel`, else the group has no core. Returns the core's area, 0 when
// it has none (more than kMaxMembers centres, centres spread over more than kCoreMaxSpan times
// their surfels' `area`, a sharp corner not bevelled, a hull of more than kMaxPolygonVertices).
double SheetCore(const Surfel* surfels, const uint32_t* members, int count, const glm::vec3& normal,
                 float offset, const glm::vec3& origin, float grow, double area, bool bevel,
                 const Bounds& goes_on, float carry, const Polygon& clip, Polygon* core) {
  constexpr int kMaxMembers = 64;
  constexpr int kMaxPoints = 7 * kMaxMembers;  // each centre, and carried to up to six sides
  if (count < 1 || count > kMaxMembers || clip.n < 3) return 0.0;
  glm::vec3 a, unused;
  OrthonormalBasis(normal, &a, &unused);
  const glm::vec3 b = glm::cross(normal, a);  // (a, b) turns around the normal
  glm::vec3 on[kMaxPoints];
  glm::vec3 mid(0.0f);
  for (int i = 0; i < count; ++i) {
    const glm::vec3 r = surfels[members[i]].position - origin;
    on[i] = r - (glm::dot(normal, r) - offset) * normal;
    mid += on[i];
  }
  mid /= static_cast<float>(count);
  glm::vec2 pts[kMaxPoints];
  glm::vec2 hull[2 * kMaxPoints];
  auto plane = [&](const glm::vec3& x) {
    return glm::vec2(glm::dot(x - mid, a), glm::dot(x - mid, b));
  };
  // The centres' own hull, and their spread (before they are carried): the hull's Minkowski sum
  // with the disk of radius `grow`, its area plus its perimeter times `grow` plus the disk's.
  for (int i = 0; i < count; ++i) pts[i] = plane(on[i]);
  int n = ConvexHull2(pts, count, hull);  // counter-clockwise in (a, b)
  if (count >= 2) {
    const int m = std::max(1, n);
    double hull_area = 0.0, perimeter = 0.0;
    for (int i = 0; i < m; ++i) {
      const glm::vec2 u = hull[i], v = hull[(i + 1) % m];
      hull_area += 0.5 * (double(u.x) * v.y - double(v.x) * u.y);
      perimeter += glm::length(v - u);
    }
    const double spread = std::fabs(hull_area) + perimeter * grow + sh::kPi * double(grow) * grow;
    if (!(spread <= kCoreMaxSpan * area)) return 0.0;
  }
  // Where the sheet goes on past a side of its cell, it spans the cell up to that side: each
  // centre moved in the plane, straight towards the side, to it.
  int total = count;
  for (int k = 0; k < 3 && !goes_on.Empty(); ++k) {
    const float across = 1.0f - normal[k] * normal[k];
    if (!(std::fabs(normal[k]) < kInPlaneAxis)) continue;
    glm::vec3 u(0.0f);
    u[k] = 1.0f;
    u -= normal[k] * normal;
    const float u_length = std::sqrt(across);
    for (const float side : {goes_on.lo[k], goes_on.hi[k]}) {
      if (!(std::fabs(side) < kNoSide)) continue;
      const float rel = side - origin[k];
      for (int i = 0; i < count; ++i) {
        const float t = (rel - on[i][k]) / across;
        if (std::fabs(t) * u_length <= carry) on[total++] = on[i] + t * u;
      }
    }
  }
  if (total > count) {  // the hull of the centres and their carried copies
    for (int i = 0; i < total; ++i) pts[i] = plane(on[i]);
    n = ConvexHull2(pts, total, hull);
  }
  if (n < 3) {
    // The centres lie on a line (or are one point): the hull is that segment, and its offset the
    // rectangle `grow` past it on every side.
    const glm::vec2 p0 = pts[0], p1 = pts[total - 1];
    const float len = glm::length(p1 - p0);
    const glm::vec2 e = len > 0.0f ? (p1 - p0) / len : glm::vec2(1.0f, 0.0f);
    const glm::vec2 q(-e.y, e.x);
    const glm::vec2 v[4] = {p0 - grow * (e + q), p1 + grow * (e - q), p1 + grow * (e + q),
                            p0 - grow * (e - q)};
    core->n = 4;
    for (int i = 0; i < 4; ++i) core->v[i] = mid + v[i].x * a + v[i].y * b;
  } else {
    int out = 0;
    auto put = [&](const glm::vec2& v) {
      if (out == kMaxPolygonVertices) return false;
      core->v[out++] = mid + v.x * a + v.y * b;
      return true;
    };
    for (int i = 0; i < n; ++i) {
      const glm::vec2 e0 = hull[i] - hull[(i + n - 1) % n], e1 = hull[(i + 1) % n] - hull[i];
      const float l0 = glm::length(e0), l1 = glm::length(e1);
      if (!(l0 > 0.0f) || !(l1 > 0.0f)) return 0.0;
      const glm::vec2 n0(e0.y / l0, -e0.x / l0), n1(e1.y / l1, -e1.x / l1);  // outward
      const glm::vec2 m = n0 + n1;
      // 1 + the cosine of the turn: below 0.2 the mitre would reach over 3.2 times `grow`.
      const float dm = glm::dot(m, n0);
      if (dm > 0.2f) {
        if (!put(hull[i] + (grow / dm) * m)) return 0.0;
      } else if (!bevel || !put(hull[i] + grow * n0) || !put(hull[i] + grow * n1)) {
        return 0.0;
      }
    }
    core->n = out;
  }
  glm::vec3 cc(0.0f);
  for (int j = 0; j < clip.n; ++j) cc += clip.v[j];
  cc /= static_cast<float>(clip.n);
  for (int i = 0; i < clip.n && core->n >= 3; ++i) {
    glm::vec3 m = glm::cross(normal, clip.v[(i + 1) % clip.n] - clip.v[i]);
    if (glm::dot(m, cc - clip.v[i]) < 0.0f) m = -m;  // towards the inside
    ClipHalfSpace(m, glm::dot(m, clip.v[i]), core);
  }
  return core->n >= 3 ? PolygonArea(*core) : 0.0;
}

void Rasterizer::AddPolygon(const Polygon& world_rel, PreparedSplat* s) {
  auto& polys = mb_.polygons_;
  if (poly_count_ == polys.size()) polys.emplace_back();
  Polygon& p = polys[poly_count_];
  p.n = world_rel.n;
  bool below = false;
  for (int i = 0; i < p.n; ++i) {
    const V4 v = ToLocal4(world_rel.v[i]);
    p.v[i] = glm::vec3(v[0], v[1], v[2]);
    below |= v[2] < 0.0f;
  }
  // Only the hemisphere above the receiver counts.
  if (below) ClipHalfSpace(glm::vec3(0.0f, 0.0f, 1.0f), &p);
  if (p.n < 3) return;
  ++poly_count_;
  ++s->poly_count;
}

bool Rasterizer::BoxClosed(const glm::vec3& lo, const glm::vec3& hi, float depth) const {
  // The corners in the receiver's frame, from the centre and the three half sides (conservative
  // to within the margins below, not to the bit), all strictly on the pyramid of the centre's
  // face: then so is all of the box, and every polygon in it lies on that face alone
  // (RasterizePolygonTo's one_face).
  const glm::vec3 c = ToLocal(0.5f * (lo + hi) - origin_);
  const glm::vec3 h = 0.5f * (hi - lo);
  const glm::vec3 hx = h.x * world_x_, hy = h.y * world_y_, hz = h.z * world_z_;
  const glm::vec3 ac(std::fabs(c.x), std::fabs(c.y), std::fabs(c.z));
  const int k = ac.x >= ac.y ? (ac.x >= ac.z ? 0 : 2) : (ac.y >= ac.z ? 1 : 2);
  const int k1 = k == 0 ? 1 : 0, k2 = k == 2 ? 1 : 2;
  const float sign = c[k] < 0.0f ? -1.0f : 1.0f;
  // The eight corners as two sets of four lanes, corners 4 q .. 4 q + 3 (the same sums, in the
  // same order, as one corner at a time: corner i takes +h along world axis j where bit j of i
  // is set). Four lanes, not eight: the baseline build lowered eight-lane comparisons lane by
  // lane, and they cost half of the test.
  const V4 sx = {-1, 1, -1, 1}, sy = {-1, -1, 1, 1};
  // |x| by clearing the sign bit.
  const V4i abs_bits = {0x7fffffff, 0x7fffffff, 0x7fffffff, 0x7fffffff};
  V4 w[2], x1[2], x2[2];
  V4i in = {-1, -1, -1, -1};
  for (int q = 0; q < 2; ++q) {
    const float sz = q == 0 ? -1.0f : 1.0f;
    V4 x[3];
    for (int j = 0; j < 3; ++j) x[j] = c[j] + sx * hx[j] + sy * hy[j] + sz * hz[j];
    w[q] = sign * x[k], x1[q] = x[k1], x2[q] = x[k2];
    // A margin of 1e-3 of w keeps clear of the pyramid's sides.
    const V4 ax1 = (V4)((V4i)x1[q] & abs_bits), ax2 = (V4)((V4i)x2[q] & abs_bits);
    in &= (w[q] > 0.0f) & (ax1 < 0.999f * w[q]) & (ax2 < 0.999f * w[q]);
  }
  if (Movemask4(in) != 0xf) return false;
  const V4 inv0 = 1.0f / w[0], inv1 = 1.0f / w[1];
  const V4 a0 = x1[0] * inv0, a1 = x1[1] * inv1, b0 = x2[0] * inv0, b1 = x2[1] * inv1;
  // The same values as one corner at a time (no NaN passed the test above; a zero's sign does
  // not survive pixel()'s t + 1).
  const float amin = Least8(a0, a1), amax = Greatest8(a0, a1);
  const float bmin = Least8(b0, b1), bmax = Greatest8(b0, b1);
  // The polygon's pixel rectangle (RasterizePolygonTo) lies in the corners' one; 1e-2 pixel
  // more keeps clear of rounding (here and in the clipped vertices).
  const float half = 0.5f * static_cast<float>(res_);
  auto pixel = [&](float t, float margin) {
    return std::clamp(static_cast<int>((t + 1.0f) * half + margin), 0, res_ - 1);
  };
  const int face = 2 * k + (sign < 0.0f ? 1 : 0);
  return RectClosed(static_cast<uint32_t>(face * res_ * res_), pixel(amin, -1e-2f),
                    pixel(amax, 1e-2f), pixel(bmin, -1e-2f), pixel(bmax, 1e-2f), depth);
}

bool Rasterizer::ClusterHidden(const Cluster& c, const PreparedSplat& s) const {
  // The caller checked the cone splat's pixels (BilinearConeClosed), for where the footprint
  // falls back to it.
  const float spacing = ClusterSpacing(c);
  if (s.flat) {
    const float cosw = std::fabs(glm::dot(s.normal, s.dir));
    if (!(cosw > 0.0f)) return false;  // the cone splat, done
    // FlatFootprint's box: FootprintBox's, grown on its free sides by at most a spacing past
    // the centres (and PlaneBoxPolygon's pad, 5e-5 of its largest side, at most), snapped
    // where the plane leaves the cell (PlaneReach) as there.
    const glm::vec3 mean_world = s.normal.x * t_ + s.normal.y * b_ + s.normal.z * n_;
    bool full = false;
    int snapped = 0;
    Bounds box = FlatBox(c.bounds, c.cell, spacing, mean_world, s.plane, origin_, &full, &snapped);
    for (int k = 0; k < 3; ++k) {
      if (!(snapped & (1 << (2 * k)))) box.lo[k] = std::min(box.lo[k], c.bounds.lo[k] - spacing);
      if (!(snapped & (2 << (2 * k)))) box.hi[k] = std::max(box.hi[k], c.bounds.hi[k] + spacing);
    }
    const glm::vec3 e = box.hi - box.lo;
    const float pad = 1e-4f * std::max({e.x, e.y, e.z});
    return BoxClosed(box.lo - pad, box.hi + pad, s.depth);
  }
  // BoxSilhouette's vertices are the corners of FootprintBox's box, or the cone splat when the
  // receiver is inside it (the corners then span more than one face).
  const Bounds box = FootprintBox(c.bounds, c.cell, spacing, glm::vec3(0.0f), nullptr);
  return BoxClosed(box.lo, box.hi, s.depth);
}

// At most this share of a cluster's area seen (its projected area towards the receiver) is the
// moments' own residual from behind (docs/design.md, "Radiance of axis-aligned content": up to
// 0.06 of a face seen from behind, 0.094 edge-on); more is content that faces the receiver.
constexpr float kBackResidual = 0.1f;
// Whether a flat one-sided cluster shows the receiver (at `origin`) the backs of its surfels:
// the receiver lies behind its mean plane (through the box centre, s.plane), beyond the box's
// thickness along the normal, on the side that `sides` does not draw, and its projected area
// towards the receiver (`seen`) is no more than the moments' residual. What it shows there is
// only what turns towards the receiver, as much as that area says; its plane does not fill its
// cell (docs/design.md, "One-sided sheets seen from behind").
namespace {
bool ShowsBacks(const Cluster& c, const PreparedSplat& s, float seen, const glm::vec3& origin,
                HitSides sides) {
  if (sides == HitSides::kBoth || !(-s.plane > s.thick) || !(seen < kBackResidual * c.area)) {
    return false;
  }
  const glm::vec3 ns = sh::AreaAndNormalSum(c.sh_area.data()).normal_sum;
  const float towards = glm::dot(ns, 0.5f * (c.bounds.lo + c.bounds.hi) - origin);
  return sides == HitSides::kFront ? towards > 0.0f : towards < 0.0f;
}
}  // namespace

bool Rasterizer::BuildClusterFootprint(const Cluster& c, PreparedSplat& s) {
  {
    const float spacing = ClusterSpacing(c);
    const uint32_t first = poly_count_;
    s.poly_count = 0;
    s.poly_first = first;
    s.flags = ClusterFlags(c, origin_, o_.hitsides);  // the cone splat's too, when it keeps it
    // Seen from behind (hitsides both) with its box centre behind the receiver's tangent
    // plane: the receiver's own surface turning away past a convex crease, which only the
    // footprint (its box grown to the cell's sides) brings above that plane. Drawn, a sparse
    // cluster 0.2 away covered 0.26 of spider.obj's receiver where rays meet nothing (bug:
    // own_surface_clusters_seen_from_behind). A surface seen from behind that stands in front
    // of the receiver has its centre in front and still occludes.
    if ((s.flags & kSplatBack) &&
        glm::dot(n_, 0.5f * (c.bounds.lo + c.bounds.hi) - origin_) < 0.0f) {
      return false;
    }
    // A solid cluster that is a box's edge or corner inside its cell: its faces, opaque.
    auto edge_faces = [&](const Bounds* footprint_box) {
      if (s.flags & kSplatPorous) return false;
      Polygon faces[3];
      int count = EdgeFaces(c, footprint_box, spacing, origin_, o_.hitsides, faces);
      if (count == -1) count = TurnedFaces(c, footprint_box, spacing, origin_, o_.hitsides, faces);
      if (count < 0) return false;
      for (int f = 0; f < count; ++f) AddPolygon(faces[f], &s);
      s.alpha = 1.0f;
      s.near = 2;
      return true;
    };
    if (s.flat && edge_faces(nullptr)) return true;
    if (s.flat) {
      // The mean plane (through the box centre, s.plane in the receiver's frame), cut by the box.
      const float cosw = std::fabs(glm::dot(s.normal, s.dir));
      if (!(cosw > 0.0f)) return true;  // keeps the cone splat
      // The projected area toward the receiver, as the cut and the splat measured it.
      const float seen = s.omega * s.depth * s.depth;
      const glm::vec3 mean_world = s.normal.x * t_ + s.normal.y * b_ + s.normal.z * n_;
      Polygon p;
      bool sheet = false;
      const float alpha =
          FlatFootprint(c.bounds, c.cell, spacing, mean_world, s.plane, origin_, seen / cosw,
                        ShowsBacks(c, s, seen, origin_, o_.hitsides), &p, &sheet);
      if (p.n < 3) return true;  // keeps the cone splat
      // Two-sided content that fills a wide cell is a piece of a sheet, not of foliage: it
      // composes as a solid surface's pieces do (docs/design.md, "Porous layers").
      if (sheet) s.flags &= ~kSplatPorous;
      s.alpha = alpha;
      AddPolygon(p, &s);
    } else {
      // The box's faces that face the receiver (at the origin), drawn as one polygon: their
      // silhouette (BoxSilhouette). The faces tile it, so a pixel's coverage is the same sum,
      // for one polygon's cost instead of up to three.
      const Bounds box = FootprintBox(c.bounds, c.cell, spacing, glm::vec3(0.0f), nullptr);
      const glm::vec3 lo = box.lo - origin_, hi = box.hi - origin_;
      const glm::vec3 ext = hi - lo;
      bool inside = true;
      for (int k = 0; k < 3; ++k) inside &= lo[k] <= 0.0f && hi[k] >= 0.0f;
      if (inside) return true;  // keeps the cone splat
      // Opacity: the cluster's solid angle over the faces' (exact: the silhouette's), so that a
      // receiver close to the box, whose near faces subtend far more than the content behind
      // them, is not over-occluded by a parallel projection's ratio.
      int drawn = 0;  // bit k: the face across axis k faces the receiver and has an area
      for (int k = 0; k < 3; ++k) {
        const bool seen = lo[k] > 0.0f || hi[k] < 0.0f;
        // A face of zero extent subtends nothing and draws nothing.
        if (seen && ext[(k + 1) % 3] > 0.0f && ext[(k + 2) % 3] > 0.0f) drawn |= 1 << k;
      }
      if (edge_faces(&box)) return true;
      Polygon q;
      BoxSilhouette(lo, hi, drawn, &q);
      const float faces = q.n >= 3 ? ConeSolidAngle(q) : 0.0f;
      if (!(faces > 0.0f)) return true;  // keeps the cone splat
      AddPolygon(q, &s);
      const float tau = s.omega / faces;
      s.alpha = (s.flags & kSplatPorous)    ? PorousOpacity(c, tau)
                : BoxFaces(c, box, origin_) ? 1.0f
                                            : std::min(1.0f, tau);
    }
    s.near = 2;
  }
  return true;
}

// How many pieces a group's footprint is drawn in: one per member (its Voronoi cell in the
// footprint, with its own radiance) when some member's radiance differs from the group's mean
// by more than kPieceContrast of the mean's largest channel, else one. Drawn at its mean, a
// leaf of the street whose cell crosses a wall's shadow painted the shadowed strip along the
// wall with the sunlit part's light, and a receiver low on the wall saw it fill half its view
// (city, +0.2 of 0.56 irradiance; bug: a_groups_mean_radiance_smears_shadows).
namespace {
int RadiancePieces(const Gathered& g, const uint32_t* members, int count, const glm::vec3& mean,
                   bool back) {
  if (count < 2) return 1;
  const float limit = kPieceContrast * std::max({mean.x, mean.y, mean.z});
  for (int i = 0; i < count; ++i) {
    const Surfel& m = g.surfels[members[i]];
    const glm::vec3 d = glm::abs((back ? m.back_radiance : m.radiance) - mean);
    if (std::max({d.x, d.y, d.z}) > limit) return count;
  }
  return 1;
}
}  // namespace

void Rasterizer::PrepareSurfelGroups(const Gathered& g, ShadeResult* out) {
  const size_t n = g.surfels.size();
  if (n == 0) return;
  const bool leaves = g.surfel_leaf.size() == n && !g.leaf_cells.empty();
  // Order: by leaf (the gather emits a leaf's surfels together), or by a cell of a grid of
  // about seven mean radii (four spacings) aligned to the surfels' own bounds, so that the
  // grouping moves, scales and turns with the scene.
  auto& order = mb_.groups_;
  auto& keys = mb_.group_keys_;
  order.resize(n);
  for (size_t i = 0; i < n; ++i) order[i] = static_cast<uint32_t>(i);
  // The grid: cells of about four surfel spacings, a power of two times a base of four mean
  // spacings so that denser and sparser surfaces each get their own, nested and aligned at
  // the surfels' low corner less half a mean spacing.
  glm::vec3 grid_lo(0.0f);
  float base = 1.0f;
  constexpr int kLevels = 8;  // levels -8..7 around the base
  auto level_of = [&](const Surfel& sf) {
    const float spacing = 1.7724539f * std::fabs(sf.radius);  // sqrt(pi) r: area-preserving
    const float l = std::round(std::log2(std::max(1e-30f, 4.0f * spacing / base)));
    return static_cast<int>(std::isfinite(l) ? std::clamp(l, -float(kLevels), kLevels - 1.0f)
                                             : 0.0f);
  };
  if (!leaves) {
    Bounds all;
    double area = 0.0;
    for (const Surfel& sf : g.surfels) {
      all.Extend(sf.position);
      area += std::isfinite(sf.radius) ? double(sf.radius) * sf.radius * 3.14159265358979 : 0.0;
    }
    const float spacing = static_cast<float>(std::sqrt(area / double(n)));
    base = std::max(4.0f * spacing, 1e-6f * glm::length(all.hi - all.lo));
    if (!(base > 0.0f) || !std::isfinite(base)) base = 1.0f;
    grid_lo = all.lo - 0.5f * spacing;
    keys.resize(n);
    for (size_t i = 0; i < n; ++i) {
      const int level = level_of(g.surfels[i]);
      const float size = std::ldexp(base, level);
      const glm::vec3 q = glm::floor((g.surfels[i].position - grid_lo) / size);
      uint64_t k = static_cast<uint64_t>(level + kLevels);
      for (int c = 0; c < 3; ++c) {
        const float v = std::isfinite(q[c]) ? std::clamp(q[c], 0.0f, 524287.0f) : 0.0f;
        k = (k << 19) | static_cast<uint64_t>(v);
      }
      keys[i] = k;
    }
    std::sort(order.begin(), order.end(),
              [&](uint32_t a, uint32_t b) { return keys[a] < keys[b]; });
  }
  auto cell_of = [&](uint32_t i) {
    if (leaves) return g.leaf_cells[g.surfel_leaf[i]];
    const uint64_t k = keys[i];
    const float size = std::ldexp(base, static_cast<int>(k >> 57) - kLevels);
    const glm::vec3 q(float((k >> 38) & 0x7ffff), float((k >> 19) & 0x7ffff), float(k & 0x7ffff));
    Bounds cell;
    cell.lo = grid_lo + q * size;
    cell.hi = grid_lo + (q + 1.0f) * size;
    return cell;
  };
  auto same_cell = [&](uint32_t a, uint32_t b) {
    return leaves ? g.surfel_leaf[a] == g.surfel_leaf[b] : keys[a] == keys[b];
  };
  // The runs of one leaf's surfels (the gather emits a leaf's surfels together), for
  // SheetCell's look at the neighbouring leaves: found when a two-sided group first asks, not
  // for every receiver (most see no two-sided surfels).
  auto& runs = mb_.leaf_runs_;
  runs.clear();
  static thread_local LeafRunIndex run_index;
  auto leaf_runs = [&]() -> LeafRunIndex& {
    if (runs.empty()) {
      for (size_t i = 0; i < n; ++i) {
        if (i == 0 || g.surfel_leaf[i] != g.surfel_leaf[i - 1]) {
          runs.push_back(static_cast<uint32_t>(i));
        }
      }
      run_index.Build(g, runs);
    }
    return run_index;
  };
  // Every cell's groups are found first, then drawn: a group's footprint stops at the plane of
  // another that it meets, in its cell or a neighbouring one (CrossLeafClip).
  static thread_local std::vector<SurfelGroup> all;
  static thread_local std::vector<CellRun> cell_runs;
  all.clear();
  cell_runs.clear();
  size_t run0 = 0;
  while (run0 < n) {
    size_t run1 = run0 + 1;
    while (run1 < n && same_cell(order[run0], order[run1])) ++run1;
    const Bounds cell = cell_of(order[run0]);
    // Greedy groups of surfels within ~25 degrees of the group's first normal; a used surfel
    // is marked by moving it to the front of the run's unused part. The cell's groups are found
    // first, then drawn: a group's footprint stops at the plane of another that it meets.
    const size_t g0 = all.size();
    size_t next = run0;
    while (next < run1) {
      const Surfel& first = g.surfels[order[next]];
      const float nn0 = glm::length(first.normal);
      if (!(nn0 > 0.0f) || !(first.radius > 0.0f)) {
        ++out->culled;
        ++next;
        continue;
      }
      const glm::vec3 n0 = first.normal / nn0;
      const float sp0 = 1.7724539f * first.radius;  // sqrt(pi) r: its spacing
      double area = 0;
      glm::dvec3 nsum(0.0), csum(0.0), lsum(0.0), back_lsum(0.0);
      Bounds centres;
      float hmin = std::numeric_limits<float>::infinity();
      int count = 0;
      size_t end = next;
      for (size_t j = next; j < run1; ++j) {
        const Surfel& sf = g.surfels[order[j]];
        const float nn = glm::length(sf.normal);
        if (!(nn > 0.0f) || !(sf.radius > 0.0f)) continue;
        const glm::vec3 nj = sf.normal / nn;
        if (glm::dot(nj, n0) < 0.9f || sf.two_sided != first.two_sided) continue;
        if (std::fabs(glm::dot(n0, sf.position - first.position)) > kGroupThickness * sp0) continue;
        std::swap(order[j], order[end++]);
        const double a = sf.Area();
        area += a;
        nsum += a * glm::dvec3(nj);
        csum += a * glm::dvec3(sf.position);
        lsum += a * glm::dvec3(sf.radiance);
        back_lsum += a * glm::dvec3(sf.back_radiance);
        centres.Extend(sf.position);
        hmin = std::min(hmin, glm::dot(n_, sf.position - origin_));
        ++count;
      }
      next = end;
      SurfelGroup gr;
      gr.n0 = n0;
      gr.end = end;
      gr.count = count;
      gr.two_sided = first.two_sided;
      gr.area = area;
      gr.nsum = nsum;
      gr.csum = csum;
      gr.lsum = lsum;
      gr.back_lsum = back_lsum;
      gr.centres = centres;
      gr.hmin = hmin;
      gr.Finish();
      all.push_back(gr);
    }
    cell_runs.push_back({cell, g0, all.size()});
    run0 = run1;
  }
  static thread_local std::vector<std::pair<uint32_t, uint32_t>> cross_pairs;
  CrossLeafPairs(all, cell_runs, g, order.data(), leaves, &cross_pairs);
  // Each group's partners, in the order found (a counting sort by group).
  static thread_local std::vector<uint32_t> partner_first, partners;
  partner_first.assign(all.size() + 1, 0);
  for (const auto& [a, b] : cross_pairs) ++partner_first[a + 1];
  for (size_t i = 0; i < all.size(); ++i) partner_first[i + 1] += partner_first[i];
  partners.resize(cross_pairs.size());
  {
    static thread_local std::vector<uint32_t> at;
    at.assign(partner_first.begin(), partner_first.end() - 1);
    for (const auto& [a, b] : cross_pairs) partners[at[a]++] = b;
  }
  for (const CellRun& run : cell_runs) {
    const Bounds& cell = run.cell;
    const absl::Span<const SurfelGroup> groups(all.data() + run.g0, run.g1 - run.g0);
    uint32_t edges[32];
    const bool convex_solid = ConvexEdges(groups, edges);
    for (const SurfelGroup& gr : groups) {
      const size_t end = gr.end;
      const int count = gr.count;
      const double area = gr.area;
      const Bounds& centres = gr.centres;
      const Surfel& first = g.surfels[order[end - count]];
      const glm::vec3 n0 = gr.n0;
      // ContactCell's answer, when the lone surfel's test below already asked it.
      bool contact = false, have_contact_cell = false, on_receiver = false;
      Bounds contact_cell, reach;
      if (count == 1) {
        // A lone surfel is its own disk (exact near the receiver), unless it fills a leaf cell
        // a few spacings wide: then it is the cell's piece of its surface like a group, or the
        // gaps around its disk would leak (bug: sparse_full_cell_leak). Seen from the front,
        // its sides snap where the plane leaves the cell, as a group's do (FlatBox): with the
        // cell's own sides, a turned plane's surfel in a wedge's cell stayed its disk (bug:
        // lone_surfel_fill_ignores_the_planes_reach; docs/design.md, "Footprints of a turned
        // plane"). Seen from behind (hitsides both) it keeps the cell's sides: there a lone
        // surfel is mostly a curved surface turning away, which its plane across the cell
        // overstates (Wuson.ply, CesiumMilkTruck); so does a two-sided one (a leaf's piece).
        const Surfel& lone = g.surfels[order[end - 1]];
        bool fills = false;
        if (leaves) {
          const float sp = std::sqrt(static_cast<float>(area));
          Bounds c;
          c.Extend(lone.position);
          const float offset = glm::dot(n0, lone.position - origin_);
          int snapped = 0;
          const Bounds box = !lone.two_sided && offset < 0.0f
                                 ? FlatBox(c, cell, sp, n0, offset, origin_, &fills, &snapped)
                                 : FootprintBox(c, cell, sp, n0, &fills);
          const glm::vec3 e = box.hi - box.lo;
          const float face = std::max({e.x * e.y, e.y * e.z, e.x * e.z});
          fills = fills && face <= kSmallCell * sp * sp;
        }
        if (!fills) {
          contact_cell = ContactCell(cell, gr, groups, origin_, n_, crease_tol_, &contact, &reach,
                                     &on_receiver);
          have_contact_cell = true;
          if (!contact) {
            PrepareSurfel(lone, out);
            continue;
          }
        }
      }
      if (!gr.solid) continue;
      const glm::vec3 normal = gr.normal;
      const glm::vec3 centroid = gr.centroid;
      glm::vec3 rel = centroid - origin_;
      float side = -glm::dot(normal, rel);  // > 0: the receiver is in front
      glm::vec3 from = origin_;             // the receiver, as this group sees it (CreaseShift)
      if (const float shift = CreaseShift(first.two_sided, normal, side); shift != 0.0f) {
        rel -= shift * normal;
        from += shift * normal;
        side += shift;
      }
      const HitSides sides = first.two_sided ? HitSides::kBoth : o_.hitsides;
      const bool visible = (sides == HitSides::kFront && side > 0.0f) ||
                           (sides == HitSides::kBack && side < 0.0f) ||
                           (sides == HitSides::kBoth && side != 0.0f);
      const float d = glm::length(rel);
      if (!visible || !std::isfinite(d) || d > o_.max_distance) {
        out->culled += count;
        continue;
      }
      const float spacing = gr.spacing;
      // Drawn, the receiver's own surface seen from behind covered up to half the hemisphere
      // (+0.03 of the +0.055 excess on Wuson.ply; bug: own_surface_seen_from_behind).
      float thickness = 0.0f;
      uint8_t sheet = first.sheet;  // the members' common tag, 0 when they differ
      if (first.two_sided) {
        for (size_t j = end - count; j < end; ++j) {
          const Surfel& m = g.surfels[order[j]];
          thickness = std::max(thickness, std::fabs(glm::dot(normal, m.position - centroid)));
          if (m.sheet != sheet) sheet = 0;
        }
      }
      if (OwnSurfaceFromBehind(first.two_sided, sheet, normal, rel, spacing) ||
          (first.two_sided && !OtherSheet(sheet) &&
           InsideOwnSheet(normal, rel, thickness, spacing))) {
        out->culled += count;
        continue;
      }
      const glm::vec3 facing = side > 0.0f ? normal : -normal;
      // A piece of a leaf ends where its surfels end, not at its cell's sides: snapped to them,
      // the leaves' groups tiled their cells and over-occluded the forest (+23%, seen once the
      // cells were the octree's, bug: cells_off_the_key_cube). A sheet that goes on past a side
      // snaps to it (SheetCell): ended half a spacing past its outermost centres, its cells'
      // footprints left gaps along every side, and a receiver in a wedge under a thin part of
      // a mesh looked through them (bug: two_sided_sheet_gaps_between_cells).
      if (!first.two_sided && !have_contact_cell) {
        contact_cell =
            ContactCell(cell, gr, groups, origin_, n_, crease_tol_, &contact, &reach, &on_receiver);
      }
      // A two-sided group's sheet goes on past its cell where SheetCell finds its next samples
      // beyond a side; a pair (fewer than kSheetMinCount) still keeps the leaf's rule there,
      // unless it is alone in its cell and its sheet goes on in three or more directions: then
      // it is a piece of one surface that the sampling left two surfels in (`one_sheet`, the
      // opacity rule below; in two, a pair at a disk's rim over-occluded).
      Bounds along_traces;  // the sides it goes on past, judged along their traces
      const Bounds sheet_cell = first.two_sided && leaves && count >= 2
                                    ? SheetCell(cell, g.surfel_leaf[order[end - 1]], gr, g,
                                                &order[end - count], leaf_runs(), &along_traces)
                                    : Bounds{};
      const bool alone = groups.size() == 1;
      const bool one_sheet =
          alone && !sheet_cell.Empty() &&
          GoingOnDirections(sheet_cell, normal) >= (count >= kSheetMinCount ? 2 : 3);
      const bool surrounded = alone && count >= kSheetMinCount && !along_traces.Empty() &&
                              GoingOnDirections(along_traces, normal) >= 4;
      const Bounds snap_to = !first.two_sided                       ? contact_cell
                             : count >= kSheetMinCount || one_sheet ? sheet_cell
                                                                    : Bounds{};
      Polygon p;
      // A two-sided group whose sheet ends in its cell (a leaf's pieces) is drawn in its own
      // plane's axes: a pair as the rhombus its two centres imply (at 2 M surfels), more as the
      // rectangle of their centres along their principal axes (at 4 M and more). The box of
      // the centres grown to hold their area, cut by a tilted plane, was up to twice the
      // leaf's length along the plane's slope at a lower opacity: a leaf a receiver lay under
      // came out translucent (up to 0.16 short) and one beside it reached over it (bug:
      // a_leafs_pair_drawn_as_its_boxs_section; docs/design.md, "A leaf's pieces"). A pair
      // whose sheet goes on (a sliver of a mesh's thin part that a cell cuts off) keeps the
      // box, which reaches toward the next cell's footprint.
      float alpha = -1.0f;
      if (first.two_sided && leaves && sheet_cell.Empty()) {
        if (count == 2) {
          alpha =
              PairFootprint(g.surfels[order[end - 2]].position, g.surfels[order[end - 1]].position,
                            facing, -std::fabs(side), from, spacing, area, &p);
        } else if (count > 2) {
          alpha = InPlaneFootprint(g.surfels.data(), &order[end - count], count, facing,
                                   -std::fabs(side), from, spacing, area, &p);
        }
      }
      // A polygon that holds a few surfels' areas at most: their count says nothing of how much
      // of it the surface fills (FlatFootprint's small cell).
      auto few_surfels_wide = [&] {
        return p.n >= 3 && PolygonArea(p) <= kSmallCell * double(spacing) * spacing;
      };
      if (alpha < 0.0f) {
        alpha = FlatFootprint(first.two_sided ? centres : reach, snap_to, spacing, facing,
                              -std::fabs(side), from, area, /*backs=*/false, &p);
        // A piece of a sheet that goes on past its cell in two or more directions (a pair:
        // three), alone in the cell, is a part of one surface: in a section a few surfels' areas
        // wide their count says nothing of how much of it the sheet fills (FlatFootprint's small
        // cell). Drawn at its count over its section (three surfels where 4.45 were expected:
        // 0.67; a pair: 0.45), the sheet over a receiver in a wedge under a thin part of a mesh
        // let it see through (Wuson.ply, 0.897 for rays' 0.940; bug:
        // going_on_sheet_pieces_translucent_by_sampling_noise). Where another group shares the
        // cell (a junction, a ridge), the sheet goes on in one direction only, or a pair in two,
        // the section is a poorer outline and the count keeps hedging it (docs/design.md,
        // "Two-sided sheets across their cells").
        if (one_sheet && alpha < 1.0f && few_surfels_wide()) alpha = 1.0f;
        // One whose sheet goes on in four directions, all around it, is opaque however wide:
        // no side of it ends in the cell, and its count under its section's area is the
        // sampling's noise (a sheet over Wuson.ply's receiver in a slot, 15 surfels where 20
        // fit: 0.62 over its section, rays 1.0; bug:
        // surrounded_sheet_pieces_translucent_by_their_count). Judged along the sides' traces
        // (SheetCell's `along_traces`); the footprint keeps the sides judged along the axes.
        if (surrounded && alpha < 1.0f) alpha = 1.0f;
      }
      // Clipped at a convex edge, the polygon loses only what lay past the edge, where the
      // surface is not: its content covers that much more of what is left.
      auto clip_past_edge = [&](auto&& clip) {
        const double before = alpha < 1.0f ? PolygonArea(p) : 0.0;
        if (clip() && before > 0.0 && p.n >= 3) {
          const double after = PolygonArea(p);
          if (after > 0.0) alpha = std::min(1.0f, static_cast<float>(alpha * before / after));
        }
      };
      if (const size_t gi = &gr - groups.data(); gi < 32 && edges[gi] != 0 && p.n >= 3) {
        bool edged = false;
        clip_past_edge([&] {
          return edged = ClipAtConvexEdges(gr, edges[gi], groups, convex_solid, from, &p);
        });
        // Ended at a convex edge, the polygon is a solid's face where it is: a section that
        // holds a few surfels' areas is opaque whatever their count, as a small cell's plane is
        // (FlatFootprint): a face of a trunk whose section held two surfels where its area
        // expected three was drawn at 0.62 (bug: convex_faces_translucent_by_sampling_noise).
        if (edged && alpha < 1.0f && few_surfels_wide()) alpha = 1.0f;
      }
      // A thin-walled part's pieces end where they meet another sheet in their cell. Ending at
      // a junction (cut there or not), a piece is its sheet's where it is, as a convex solid's
      // face is: a section that holds a few surfels' areas is opaque whatever their count. At a
      // fold of a thin part each piece was drawn at its count over its section (six surfels
      // where 6.6 fit: 0.91), and a receiver within a spacing behind one of them saw the sky
      // through both (Wuson.ply: 0.909 for rays' 1; bug:
      // sheet_junction_pieces_translucent_by_sampling_noise).
      if (first.two_sided && groups.size() > 1 && p.n >= 3) {
        bool junction = false;
        clip_past_edge(
            [&] { return junction = ClipAtSheetJunctions(gr, groups, g, order.data(), from, &p); });
        if (junction && alpha < 1.0f && few_surfels_wide()) alpha = 1.0f;
      }
      if (const uint32_t ai = static_cast<uint32_t>(&gr - all.data());
          p.n >= 3 && partner_first[ai] < partner_first[ai + 1]) {
        clip_past_edge([&] { return CrossLeafClip(ai, all, partner_first, partners, from, &p); });
      }
      if (p.n < 3) {
        out->culled += count;
        continue;
      }
      if (on_receiver && alpha < 1.0f) {
        // Grown to the receiver's tangent plane along an oblique contact, the box holds a part
        // behind it where the surface has no surfels; what the receiver sees is the part in
        // front. (Along an axis the box ends at the plane: a wall's cells there keep their
        // opacity, city 0.89 for rays' 0.85 otherwise.)
        Polygon front = p;
        ClipHalfSpace(n_, &front);
        const double fa = front.n >= 3 ? PolygonArea(front) : 0.0;
        // A few surfels' areas say nothing of how much of it the surface fills (FlatFootprint).
        if (fa <= kSmallCell * double(spacing) * spacing) {
          alpha = 1.0f;
        } else if (fa > 0.0) {
          alpha = std::max(alpha, std::min(1.0f, static_cast<float>(area / fa)));
        }
      }
      // A two-sided group seen from behind shows its back radiance.
      const bool back = first.two_sided && side < 0.0f;
      const glm::vec3 rad = glm::vec3((back ? gr.back_lsum : gr.lsum) / area);
      // A translucent piece of a sheet near the receiver: its core (SheetCore) is the sheet
      // wherever it is, opaque, and the rest of the footprint holds what is left of its
      // surfels' area (at least kCoreRingKeep of its opacity where the sheet goes on). Drawn at its
      // count over its section, a leaf a receiver lay 0.6 spacings under was 0.69 where rays see it
      // whole (the forest's worst receiver at 8 M surfels, 0.917 for rays' 0.996; bug:
      // near_sheet_pieces_translucent_inside_their_centres). A pair or a lone surfel is a piece
      // too (a leaf cut by the cells leaves them): drawn at its count over its section, it was a
      // hedge a receiver 1.7 spacings away saw at 0.69 where rays see the leaf whole. The core
      // shrinks about its centre from kCoreNear to kCoreFar spacings away (at res 12; farther
      // at finer rasters, whose pixels see a hedge from farther), to nothing, so that the
      // occlusion stays continuous in the receiver's position and a piece farther away is drawn
      // as before (the far field's pieces drawn as cores and rings over-occluded the forest's
      // canopy: 0.00645 -> 0.00989 at the finer setting). A two-sided group's sharp hull corner
      // is bevelled (a narrow leaf's thin triangle of centres); a one-sided group's is refused,
      // its core not carried to where the panel goes on, so that a sliver of core would take
      // the ring's opacity from the rest of the panel (docs/design.md, "A piece's core").
      Polygon core;
      double core_area = 0.0;
      const float core_scale = static_cast<float>(res_) / kCoreRes;
      if ((first.two_sided || count >= kOneSidedCoreMinCount) && alpha < 1.0f && p.n >= 3 &&
          d < kCoreFar * core_scale * spacing) {
        const double section = PolygonArea(p), held = double(alpha) * section;
        core_area = SheetCore(g.surfels.data(), &order[end - count], count, facing,
                              -std::fabs(side), from, kCoreGrow * spacing, area, first.two_sided,
                              first.two_sided ? snap_to : Bounds{}, kCoreCarry * spacing, p, &core);
        const float ds = d / (core_scale * spacing);
        const float w = std::clamp((kCoreFar - ds) / (kCoreFar - kCoreNear), 0.0f, 1.0f);
        if (core_area > 0.0 && w < 1.0f) {
          glm::vec3 c(0.0f);
          for (int i = 0; i < core.n; ++i) c += core.v[i];
          c /= static_cast<float>(core.n);
          for (int i = 0; i < core.n; ++i) core.v[i] = c + w * (core.v[i] - c);
          core_area *= double(w) * w;
        }
        if (core_area > 0.0 && core_area < section) {
          alpha =
              std::max((first.two_sided && !snap_to.Empty() ? kCoreRingKeep : 0.0f) * alpha,
                       static_cast<float>(std::max(0.0, held - core_area) / (section - core_area)));
        } else {
          core_area = 0.0;
        }
      }
      // One piece per member where the members' radiance differs (RadiancePieces), else one.
      const int pieces = radiance_ ? RadiancePieces(g, &order[end - count], count, rad, back) : 1;
      bool drawn = false;
      for (int piece = 0; piece < pieces; ++piece) {
        // The member's share of the footprint (and of its core): the points nearer its centre
        // than any other member's (a Voronoi cell, by the bisecting planes); the whole of it
        // when there is one piece.
        auto share = [&](const Polygon& whole, Polygon* scratch) -> const Polygon& {
          if (pieces == 1) return whole;
          *scratch = whole;
          const glm::vec3 ci = g.surfels[order[end - count + piece]].position - from;
          for (int j = 0; j < count && scratch->n >= 3; ++j) {
            if (j == piece) continue;
            const glm::vec3 cj = g.surfels[order[end - count + j]].position - from;
            const glm::vec3 dm = ci - cj;
            if (!(glm::dot(dm, dm) > 0.0f)) continue;
            ClipHalfSpace(dm, glm::dot(dm, 0.5f * (ci + cj)), scratch);
          }
          return *scratch;
        };
        Polygon q_scratch;
        const Polygon& q = share(p, &q_scratch);
        if (q.n < 3) continue;
        glm::vec3 piece_rad = rad;
        if (pieces > 1) {
          const Surfel& m = g.surfels[order[end - count + piece]];
          piece_rad = back ? m.back_radiance : m.radiance;
        }
        for (int part = core_area > 0.0 ? 0 : 1; part < 2; ++part) {
          if (part == 1 && !(alpha > 0.0f)) continue;
          Polygon core_scratch;
          const Polygon& drawn_poly = part == 0 ? share(core, &core_scratch) : q;
          if (drawn_poly.n < 3) continue;
          PreparedSplat& s = mb_.splats_[count_];
          s.depth = d;
          s.extent = 0.5f * glm::length(centres.hi - centres.lo) + spacing;
          if (radiance_) {
            Store4(s.rgb1, V4{1.0f, piece_rad.x, piece_rad.y, piece_rad.z});
          } else {
            Store4(s.rgb1, V4{1.0f, 0.0f, 0.0f, 0.0f});
          }
          s.normal = ToLocal(facing);
          s.plane = -std::fabs(side);
          s.thick = 0.0f;
          s.flat = 1;
          s.dir = d > 0.0f ? ToLocal(rel) / d : glm::vec3(0.0f, 0.0f, 1.0f);
          s.omega = 0.0f;
          s.near = 2;
          s.alpha = part == 0 ? 1.0f : alpha;
          s.flags = SurfelFlags(first.two_sided, side);
          s.poly_first = poly_count_;
          s.poly_count = 0;
          AddPolygon(drawn_poly, &s);
          if (s.poly_count == 0) continue;
          ++count_;
          drawn = true;
        }
      }
      if (!drawn) {
        out->culled += count;
        continue;
      }
      out->surfels_drawn += count;
    }
  }
}

}  // namespace pbgi::internal
