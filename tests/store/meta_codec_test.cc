#include "store/meta_codec.h"

#include <cstring>
#include <string>

#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace pbgi::internal {
namespace {

using ::testing::HasSubstr;

StoreMeta SampleMeta() {
  StoreMeta m;
  m.page_size = EfficientPageSize(4);
  m.channels = Channels::kOcclusion;
  m.sh_order = 2;
  m.leaf_size = 8;
  m.bounds.lo = {-1.5f, 2.0f, -3.25f};
  m.bounds.hi = {4.0f, 5.5f, 6.75f};
  m.point_count = 123456789012ull;
  m.node_count = 98765;
  m.node_pages = 17;
  m.point_pages = 4242;
  m.root = 0x0000123400050006ull;
  m.max_depth = 21;
  m.layout = "breadth-first";
  m.stats["build_seconds"] = "12.5";
  m.stats["peak_rss_bytes"] = "123456";
  m.stats[""] = "empty key";
  return m;
}

TEST(MetaCodecTest, RoundTripPreservesEveryField) {
  const StoreMeta m = SampleMeta();
  for (bool complete : {false, true}) {
    const std::string bytes = EncodeMeta(m, complete);
    absl::StatusOr<DecodedMeta> d = DecodeMeta(bytes, "test");
    ASSERT_TRUE(d.ok()) << d.status();
    EXPECT_EQ(d->complete, complete);
    const StoreMeta& r = d->meta;
    EXPECT_EQ(r.magic, kStoreMagic);
    EXPECT_EQ(r.version, kStoreFormatVersion);
    EXPECT_EQ(r.page_size, m.page_size);
    EXPECT_EQ(r.channels, m.channels);
    EXPECT_EQ(r.sh_order, m.sh_order);
    EXPECT_EQ(r.leaf_size, m.leaf_size);
    EXPECT_EQ(r.bounds.lo, m.bounds.lo);
    EXPECT_EQ(r.bounds.hi, m.bounds.hi);
    EXPECT_EQ(r.point_count, m.point_count);
    EXPECT_EQ(r.node_count, m.node_count);
    EXPECT_EQ(r.node_pages, m.node_pages);
    EXPECT_EQ(r.point_pages, m.point_pages);
    EXPECT_EQ(r.root, m.root);
    EXPECT_EQ(r.max_depth, m.max_depth);
    EXPECT_EQ(r.layout, m.layout);
    EXPECT_EQ(r.stats, m.stats);
  }
}

TEST(MetaCodecTest, FutureVersionIsRefusedWithBothNumbers) {
  std::string bytes = EncodeMeta(SampleMeta(), true);
  const uint32_t future = kStoreFormatVersion + 6;
  std::memcpy(&bytes[8], &future, 4);
  // Even a future record whose body this version cannot parse gets the version message.
  bytes.resize(30);
  absl::StatusOr<DecodedMeta> d = DecodeMeta(bytes, "store X");
  ASSERT_FALSE(d.ok());
  EXPECT_EQ(d.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(d.status().message(), HasSubstr("version " + std::to_string(future)));
  EXPECT_THAT(d.status().message(), HasSubstr("up to " + std::to_string(kStoreFormatVersion)));
  EXPECT_THAT(d.status().message(), HasSubstr("store X"));
}

// Versions 1 and 2 stored plain float records, version 3 compact ones without sheet tags,
// version 4 nodes without a radiance contrast; this library (tree/format.h) does not read them:
// the message names the version and the versions it reads, and says to rebuild.
TEST(MetaCodecTest, OldVersionsAreRefusedWithBothNumbersAndRebuild) {
  for (uint32_t old : {1u, 2u, 3u, 4u}) {
    std::string bytes = EncodeMeta(SampleMeta(), true);
    std::memcpy(&bytes[8], &old, 4);
    absl::StatusOr<DecodedMeta> d = DecodeMeta(bytes, "store Y");
    ASSERT_FALSE(d.ok()) << old;
    EXPECT_EQ(d.status().code(), absl::StatusCode::kFailedPrecondition);
    EXPECT_THAT(d.status().message(), HasSubstr("version " + std::to_string(old)));
    EXPECT_THAT(d.status().message(),
                HasSubstr("versions " + std::to_string(kOldestReadableStoreFormatVersion) + " to " +
                          std::to_string(kStoreFormatVersion)));
    EXPECT_THAT(d.status().message(), HasSubstr("rebuild"));
    EXPECT_THAT(d.status().message(), HasSubstr("store Y"));
  }
}

// A version-5 store is a version-6 store without the back radiance: read as it is. Its meta
// cannot name kRadianceBothSides, which version 6 added.
TEST(MetaCodecTest, VersionFiveIsReadAndCannotHoldBothSides) {
  StoreMeta m = SampleMeta();
  m.version = 5;
  m.channels = Channels::kRadiance;
  absl::StatusOr<DecodedMeta> d = DecodeMeta(EncodeMeta(m, true), "store V");
  ASSERT_TRUE(d.ok()) << d.status();
  EXPECT_EQ(d->meta.version, 5u);
  EXPECT_EQ(d->meta.channels, Channels::kRadiance);
  m.channels = Channels::kRadianceBothSides;
  d = DecodeMeta(EncodeMeta(m, true), "store V");
  ASSERT_FALSE(d.ok());
  EXPECT_THAT(d.status().message(), HasSubstr("unknown channels 2"));
  m.version = 6;
  d = DecodeMeta(EncodeMeta(m, true), "store V");
  ASSERT_TRUE(d.ok()) << d.status();
  EXPECT_EQ(d->meta.channels, Channels::kRadianceBothSides);
}

TEST(MetaCodecTest, GridRoundTrips) {
  StoreMeta m = SampleMeta();
  m.grid_origin = glm::vec3(-1.5f, 2.25f, 1e6f);
  m.grid_step = 3.0e-4f;
  absl::StatusOr<DecodedMeta> d = DecodeMeta(EncodeMeta(m, true), "s");
  ASSERT_TRUE(d.ok()) << d.status();
  EXPECT_EQ(d->meta.grid_origin, m.grid_origin);
  EXPECT_EQ(d->meta.grid_step, m.grid_step);
}

TEST(MetaCodecTest, WrongMagicIsRefused) {
  std::string bytes = EncodeMeta(SampleMeta(), true);
  bytes[0] ^= 0x20;
  absl::StatusOr<DecodedMeta> d = DecodeMeta(bytes, "s");
  ASSERT_FALSE(d.ok());
  EXPECT_EQ(d.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(d.status().message(), HasSubstr("magic"));
}

TEST(MetaCodecTest, EveryTruncationIsDataLoss) {
  const std::string bytes = EncodeMeta(SampleMeta(), true);
  for (size_t n = 0; n < bytes.size(); ++n) {
    absl::StatusOr<DecodedMeta> d = DecodeMeta(absl::string_view(bytes).substr(0, n), "s");
    ASSERT_FALSE(d.ok()) << n;
    EXPECT_EQ(d.status().code(), absl::StatusCode::kDataLoss) << n << ": " << d.status();
  }
}

TEST(MetaCodecTest, FlippedBodyByteIsDataLoss) {
  const std::string good = EncodeMeta(SampleMeta(), true);
  for (size_t i = kMetaHeaderBytes; i < good.size(); ++i) {
    std::string bytes = good;
    bytes[i] ^= 0x01;
    absl::StatusOr<DecodedMeta> d = DecodeMeta(bytes, "s");
    ASSERT_FALSE(d.ok()) << i;
    EXPECT_THAT(d.status().message(), HasSubstr("checksum")) << i;
  }
}

}  // namespace
}  // namespace pbgi::internal
