// The lobe-aware cut (Cut::lobe, tree/cut.h LobeCut): its weight against closed forms, and its
// gathers against brute force through the test harness (pbgi/testing.h) over random receivers
// and lobes: every surfel in front exactly once, every cluster below the lobe-weighted
// criterion, a finer lobe cut refining a coarser one.
#include <cmath>
#include <random>
#include <vector>

#include "gtest/gtest.h"
#include "pbgi/build.h"
#include "pbgi/query.h"
#include "pbgi/testing.h"
#include "tree/cut.h"

namespace pbgi {
namespace {

using testing::TempDatabase;

// Lobes with the smallest weight of the cosine-weighted cut (the default, 1, clamps every
// weight below 1 to 1).
CutLobe Phong(float e, glm::vec3 d = {0, 0, 1}, float min_weight = kMinCutCosine) {
  return CutLobe{CutLobeKind::kPhong, d, e, 0.2f, min_weight};
}
CutLobe Ggx(float alpha, glm::vec3 d = {0, 0, 1}, float min_weight = kMinCutCosine) {
  return CutLobe{CutLobeKind::kGgx, d, 32.0f, alpha, min_weight};
}

// pi times the lobe normalized over its hemisphere: (e + 1) / 2 x^e for Phong, the cosine
// itself for e = 1 (the plain cut's weight at the normal).
TEST(LobeCut, WeightIsPiTimesTheNormalizedLobe) {
  EXPECT_FLOAT_EQ(LobeWeight(Phong(32), 1.0f), 16.5f);
  EXPECT_NEAR(LobeWeight(Phong(32), 0.98f), 16.5f * std::pow(0.98f, 32.0f), 1e-4f);
  for (float x : {0.05f, 0.3f, 0.7f, 1.0f}) EXPECT_FLOAT_EQ(LobeWeight(Phong(1), x), x);
  // Outside the lobe: the smallest weight, never 0 (a node there is coarse, not dropped).
  EXPECT_EQ(LobeWeight(Phong(32), 0.5f), kMinCutCosine);
  EXPECT_EQ(LobeWeight(Phong(32), -0.5f), kMinCutCosine);
  EXPECT_EQ(LobeWeight(Ggx(0.3f), -0.1f), kMinCutCosine);
  // The default smallest weight, 1: never coarser than the plain cut.
  CutLobe by_default;
  by_default.kind = CutLobeKind::kPhong;
  EXPECT_EQ(LobeWeight(by_default, 0.5f), 1.0f);
  EXPECT_EQ(LobeWeight(by_default, 1.0f), 16.5f);
  by_default.kind = CutLobeKind::kGgx;
  by_default.ggx_roughness = 1.0f;  // uniform: the weight 1/2 is clamped to 1
  EXPECT_EQ(LobeWeight(by_default, 1.0f), 1.0f);
  // GGX alpha = 1 is the uniform lobe: 1 / 2 everywhere on the hemisphere.
  for (float x : {0.01f, 0.5f, 1.0f}) EXPECT_NEAR(LobeWeight(Ggx(1.0f), x), 0.5f, 1e-6f);
  // Over the hemisphere, the weight (before its clamp) integrates to pi for every lobe.
  for (const CutLobe& lobe : {Phong(8), Phong(32), Phong(200), Ggx(0.1f), Ggx(0.3f), Ggx(0.7f)}) {
    const internal::LobeCut l = internal::MakeLobeCut(lobe);
    double integral = 0;
    const int steps = 200000;
    for (int i = 0; i < steps; ++i) {
      integral += internal::LobeCutRaw(l, (i + 0.5f) / steps);
    }
    integral *= 2.0 * M_PI / steps;
    EXPECT_NEAR(integral, M_PI, 2e-3)
        << int(lobe.kind) << " " << lobe.phong_exponent << " " << lobe.ggx_roughness;
    // Non-decreasing toward the axis, and its largest value at the axis.
    float last = 0;
    for (int i = 0; i <= 1000; ++i) {
      const float w = internal::LobeCutWeight(l, i / 1000.0f);
      EXPECT_GE(w, last);
      last = w;
    }
    EXPECT_EQ(last, l.max_weight);
  }
  // GGX 0.3 at the axis: 1 / alpha^4 / (2 I), I = 1 / (2 alpha^2) + atanh(m) / (2 m).
  const double a2 = 0.09, m = std::sqrt(1 - a2);
  const double want = 1.0 / (a2 * a2) / (1.0 / a2 + std::atanh(m) / m);
  EXPECT_NEAR(LobeWeight(Ggx(0.3f), 1.0f), want, 1e-3 * want);
}

// The weight of a node is the lobe's largest value over its near sphere: a sphere that the
// axis passes through has the axis's weight, wherever its centre lies.
TEST(LobeCut, NodeWeightBoundsTheLobeOverTheNearSphere) {
  const internal::LobeCut l = internal::MakeLobeCut(Phong(32, {0, 0, 2}));
  const glm::vec3 p(0.0f);
  // Centre 0.3 rad off the axis at distance 1, radius 0.31: the axis is inside.
  const glm::vec3 c(std::sin(0.3f), 0.0f, std::cos(0.3f));
  EXPECT_EQ(internal::NodeLobeWeight(l, c, 0.31f * 0.31f, p), l.max_weight);
  // Radius 0.1 (half angle asin(0.1)): the closest direction is 0.3 - asin(0.1) off the axis.
  const float w = internal::NodeLobeWeight(l, c, 0.01f, p);
  EXPECT_NEAR(w, 16.5f * std::pow(std::cos(0.3f - std::asin(0.1f)), 32.0f), 1e-3f);
  EXPECT_GT(w, 16.5f * std::pow(std::cos(0.3f), 32.0f));  // more than at its centre
  // The receiver inside the sphere: the axis's weight.
  EXPECT_EQ(internal::NodeLobeWeight(l, c, 4.0f, p), l.max_weight);
  // Behind the lobe's hemisphere: the smallest weight.
  EXPECT_EQ(internal::NodeLobeWeight(l, -c, 0.01f, p), kMinCutCosine);
}

TEST(LobeCut, GatherRefusesABadLobe) {
  auto t = TempDatabase::Create(testing::RandomSceneSurfels(500, 3));
  ASSERT_TRUE(t.ok()) << t.status();
  auto reader = (*t)->db().NewReader();
  ASSERT_TRUE(reader.ok()) << reader.status();
  Gathered g;
  const Receiver r{{0.5f, 0.5f, -0.5f}, {0, 0, 1}};
  for (const CutLobe& bad : {Phong(32, {0, 0, 0}), Phong(-1), Ggx(0.0f), Ggx(1.5f),
                             Phong(32, {NAN, 0, 1}), Phong(32, {0, 0, 1}, 0.0f)}) {
    Cut cut;
    cut.lobe = bad;
    const absl::Status s = (*reader)->Gather(r, cut, &g);
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
    EXPECT_FALSE(ValidateCutLobe(bad).ok());
  }
}

// Random receivers and lobes (a random axis above the receiver's horizon or anywhere): the
// lobe cut is valid against brute force, a finer one refines a coarser one, and it is finer
// than the plain cut in the lobe's core and coarser outside it.
TEST(LobeCut, CutIsValidAgainstBruteForceForRandomLobes) {
  for (const auto& [leaf, page] :
       {std::pair{16u, EfficientPageSize(1)}, std::pair{4u, EfficientPageSize(2)}}) {
    BuildOptions b;
    b.leaf_size = leaf;
    b.page_size = page;
    b.memory_bytes = 64 << 20;
    auto t = TempDatabase::Create(testing::RandomSceneSurfels(4000, 57), b);
    ASSERT_TRUE(t.ok()) << t.status();
    const std::vector<Surfel>& surfels = (*t)->surfels();
    auto reader = (*t)->db().NewReader();
    ASSERT_TRUE(reader.ok()) << reader.status();
    std::mt19937_64 rng(11);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    std::vector<Receiver> receivers = testing::RandomReceivers(150, 23);
    for (size_t i = 0; i < 150; ++i) {  // and receivers on the surfaces
      const Surfel& s = surfels[(i * 7919) % surfels.size()];
      receivers.push_back({s.position + 1e-4f * s.normal, s.normal});
    }
    Gathered coarse, fine, plain;
    size_t lobe_clusters = 0, plain_clusters = 0, in_core = 0;
    for (size_t i = 0; i < receivers.size(); ++i) {
      const Receiver& r = receivers[i];
      const glm::vec3 n = glm::normalize(r.normal);
      glm::vec3 d;
      do {
        d = glm::vec3(u(rng), u(rng), u(rng)) * 2.0f - 1.0f;
      } while (glm::dot(d, d) > 1.0f || glm::dot(d, d) < 1e-3f);
      if (i % 3 != 0 && glm::dot(d, n) < 0.0f) d -= 2.0f * glm::dot(d, n) * n;  // above
      const float e = std::pow(2.0f, 10.0f * u(rng));                           // Phong 1 .. 1024
      const float alpha = 0.02f + 0.98f * u(rng);
      Cut coarse_cut;
      coarse_cut.max_solid_angle = 0.1f;
      const float min_weight = i % 3 == 1 ? 1.0f : kMinCutCosine;
      coarse_cut.lobe = i % 2 ? Phong(e, d, min_weight) : Ggx(alpha, d, min_weight);
      if (i % 5 == 0) coarse_cut.curved_scale = 0.5f;
      if (i % 7 == 0) coarse_cut.max_distance = 0.8f;
      if (i % 4 == 0) coarse_cut.cosine_weighted = true;  // ignored with a lobe
      Cut fine_cut = coarse_cut;
      fine_cut.max_solid_angle = 0.01f;
      absl::Status s;
      ASSERT_TRUE((s = (*reader)->Gather(r, coarse_cut, &coarse)).ok()) << s;
      ASSERT_TRUE((s = testing::CheckValidCut(coarse, surfels, r, coarse_cut)).ok()) << s;
      ASSERT_TRUE((s = (*reader)->Gather(r, fine_cut, &fine)).ok()) << s;
      ASSERT_TRUE((s = testing::CheckValidCut(fine, surfels, r, fine_cut)).ok()) << s;
      ASSERT_TRUE(
          (s = testing::CheckFinerCutNotSmaller(coarse, fine, surfels, r, coarse_cut, fine_cut))
              .ok())
          << s;
      // The same cut without the lobe is not what the lobe cut checks against, and vice versa:
      // a lobe cut's clusters near the axis are below max_solid_angle / max_weight.
      Cut plain_cut = fine_cut;
      plain_cut.lobe = CutLobe{};
      plain_cut.cosine_weighted = false;
      ASSERT_TRUE((s = (*reader)->Gather(r, plain_cut, &plain)).ok()) << s;
      const internal::LobeCut l = internal::MakeLobeCut(fine_cut.lobe);
      for (const Cluster& c : fine.clusters) {
        const internal::NearSphere ns =
            internal::NodeNearSphere(c.bounds.lo, c.bounds.hi, internal::NodeReach(c.area));
        if (internal::NodeLobeCosine(ns.centre, ns.radius2, r.position, l.axis) >= 1.0f) {
          ++in_core;
          EXPECT_LT(ClusterSolidAngle(c, r) * l.max_weight,
                    internal::NodeCut(fine_cut, c.sh_area.data(), c.bounds.lo, c.bounds.hi)
                        .max_solid_angle);
        }
      }
      lobe_clusters += fine.clusters.size();
      plain_clusters += plain.clusters.size();
    }
    EXPECT_GT(lobe_clusters, 300u);
    EXPECT_GT(plain_clusters, 300u);
    EXPECT_GT(in_core, 20u);
  }
}

// A Phong 1 lobe on the receiver's normal weighs a node by the cosine: its lobe cut is the
// cosine-weighted cut, element for element (the same geometry, pow(x, 1) = x and a scale of 1,
// and the cosine cut's plain test is implied by its weighted one).
TEST(LobeCut, PhongOneOnTheNormalIsTheCosineCut) {
  auto t = TempDatabase::Create(testing::RandomSceneSurfels(4000, 5));
  ASSERT_TRUE(t.ok()) << t.status();
  auto reader = (*t)->db().NewReader();
  ASSERT_TRUE(reader.ok()) << reader.status();
  Gathered a, b;
  size_t clusters = 0;
  for (const Receiver& r : testing::RandomReceivers(200, 8)) {
    Cut cosine;
    cosine.cosine_weighted = true;
    Cut lobe;
    lobe.lobe = Phong(1.0f, r.normal);
    ASSERT_TRUE((*reader)->Gather(r, cosine, &a).ok());
    ASSERT_TRUE((*reader)->Gather(r, lobe, &b).ok());
    ASSERT_TRUE(testing::CheckValidCut(b, (*t)->surfels(), r, lobe).ok());
    ASSERT_EQ(a.clusters.size(), b.clusters.size());
    for (size_t k = 0; k < a.clusters.size(); ++k) {
      EXPECT_EQ(a.clusters[k].first_point, b.clusters[k].first_point);
      EXPECT_EQ(a.clusters[k].point_count, b.clusters[k].point_count);
    }
    EXPECT_EQ(a.surfel_ids, b.surfel_ids);
    clusters += a.clusters.size();
  }
  EXPECT_GT(clusters, 200u);
}

}  // namespace
}  // namespace pbgi
