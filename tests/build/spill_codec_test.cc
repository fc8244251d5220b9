// Compact sort runs (build/spill_codec.h): a block round-trips quantized records exactly, the
// external sort over compact runs gives the stable order of the quantized input in several
// merge passes and with threads, its runs are far smaller than raw ones, and damaged blocks
// are DataLoss naming the run. Packed input (SpillCodec::Pack) gives the same blocks and the
// same sorted output, and a point page writer told that its input is quantized writes the same
// pages and hands back the same records.
#include "build/spill_codec.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <random>
#include <vector>

#include "build/external_sort.h"
#include "build/node_packer.h"
#include "build/octree_builder.h"
#include "gtest/gtest.h"
#include "store/mem_page_store.h"
#include "tests/build/test_clouds.h"
#include "tree/morton.h"

namespace pbgi::internal {
namespace {

// Records as the builder makes them (normalized normals, two-sided in the radius's sign),
// keyed on a grid's cube; `shuffle`: keys in random order (deltas wrap).
std::vector<SortRecord> Records(size_t n, uint64_t seed, const Bounds& b, bool two_sided_some) {
  const std::vector<Surfel> cloud = testing_build::SurfaceCloud(n, seed);
  const MortonQuantizer quant(b);
  std::vector<SortRecord> out;
  for (size_t i = 0; i < cloud.size(); ++i) {
    Surfel s = cloud[i];
    s.two_sided = two_sided_some && i % 3 == 0;
    s.sheet = s.two_sided ? static_cast<uint8_t>(i % 256) : 0;
    if (i % 5 == 0) s.radiance = -s.radiance;  // negative radiance keeps its sign
    out.push_back(MakeSortRecord(quant.Key(s.position), s));
  }
  return out;
}

// What a compact run hands back: the record as its point record decodes.
SortRecord Quantized(const SortRecord& r, const SpillCodec& c) {
  uint8_t rec[kPointRecordBothSidesBytes];  // the largest record
  EncodePointRecord(r.position, r.normal, r.radius, r.radiance, c.channels, c.grid, rec);
  return MakeSortRecord(r.key, DecodePointRecord(rec, c.channels, c.grid));
}

Bounds CloudBounds() { return Bounds{glm::vec3(-3.5f, -3.5f, -1.0f), glm::vec3(3.5f, 3.5f, 2.5f)}; }

SpillCodec Codec(Channels c) { return SpillCodec{c, GridOfCube(MortonCube(CloudBounds()))}; }

// Drains the sorter's output and checks that it is `want`, record for record.
void ExpectOutput(ExternalSorter& s, const std::vector<SortRecord>& want) {
  std::vector<SortRecord> got;
  for (;;) {
    auto block = s.NextBlock();
    ASSERT_TRUE(block.ok()) << block.status();
    if (block->empty()) break;
    got.insert(got.end(), block->begin(), block->end());
  }
  ASSERT_EQ(got.size(), want.size());
  for (size_t i = 0; i < got.size(); ++i) {
    ASSERT_EQ(0, std::memcmp(&got[i], &want[i], sizeof(SortRecord))) << i;
  }
}

TEST(SpillCodecTest, BlockRoundTripsQuantizedRecordsExactly) {
  for (Channels ch : {Channels::kOcclusion, Channels::kRadiance}) {
    const SpillCodec codec = Codec(ch);
    std::vector<SortRecord> in = Records(3000, 7, CloudBounds(), true);
    std::shuffle(in.begin(), in.end(), std::mt19937_64(1));  // unsorted keys: deltas wrap
    SpillBlockWriter w(codec);
    SpillBlockReader r(codec);
    std::vector<uint8_t> bytes;
    for (size_t i = 0; i < in.size(); i += kSpillBlockRecords) {
      const size_t n = std::min<size_t>(kSpillBlockRecords, in.size() - i);
      ASSERT_TRUE(w.Append(absl::MakeConstSpan(in).subspan(i, n), &bytes).ok());
    }
    size_t at = 0, done = 0;
    std::vector<SortRecord> out(kSpillBlockRecords);
    while (at < bytes.size()) {
      uint32_t frame = 0, n = 0;
      ASSERT_TRUE(SpillBlockReader::ParseHeader(bytes.data() + at, codec, "t", &frame, &n).ok());
      ASSERT_TRUE(
          r.Decode(absl::MakeConstSpan(bytes).subspan(at + 8, frame), n, out.data(), "t").ok());
      for (uint32_t i = 0; i < n; ++i) {
        const SortRecord want = Quantized(in[done + i], codec);
        ASSERT_EQ(0, std::memcmp(&out[i], &want, sizeof(SortRecord))) << done + i;
        // Quantizing again changes nothing: the builder's pages are the same either way.
        const SortRecord again = Quantized(out[i], codec);
        ASSERT_EQ(0, std::memcmp(&again, &want, sizeof(SortRecord))) << done + i;
        EXPECT_EQ(RadiusTwoSided(out[i].radius), RadiusTwoSided(in[done + i].radius));
      }
      done += n;
      at += 8 + frame;
    }
    EXPECT_EQ(done, in.size());
    EXPECT_EQ(at, bytes.size());
  }
}

TEST(SpillCodecTest, DamagedBlocksAreDataLoss) {
  const SpillCodec codec = Codec(Channels::kRadiance);
  std::vector<SortRecord> in = Records(500, 8, CloudBounds(), false);
  SpillBlockWriter w(codec);
  std::vector<uint8_t> bytes;
  ASSERT_TRUE(w.Append(in, &bytes).ok());
  uint32_t frame = 0, n = 0;
  ASSERT_TRUE(SpillBlockReader::ParseHeader(bytes.data(), codec, "run-x", &frame, &n).ok());
  EXPECT_EQ(n, 500u);
  EXPECT_EQ(frame + 8, bytes.size());
  std::vector<SortRecord> out(kSpillBlockRecords);
  SpillBlockReader r(codec);
  // A wrong record count: the frame decompresses to another size.
  absl::Status s = r.Decode(absl::MakeConstSpan(bytes).subspan(8), 499, out.data(), "run-x");
  EXPECT_TRUE(absl::IsDataLoss(s)) << s;
  EXPECT_NE(s.message().find("run-x"), std::string::npos) << s;
  // A frame cut short.
  s = r.Decode(absl::MakeConstSpan(bytes).subspan(8, frame - 10), 500, out.data(), "run-x");
  EXPECT_TRUE(absl::IsDataLoss(s)) << s;
  // Headers out of range: no records, too many, a frame larger than any block.
  for (auto [f, k] : {std::pair<uint32_t, uint32_t>{frame, 0},
                      {frame, kSpillBlockRecords + 1},
                      {uint32_t(codec.max_block_bytes()), 10}}) {
    uint8_t h[8];
    std::memcpy(h, &f, 4);
    std::memcpy(h + 4, &k, 4);
    s = SpillBlockReader::ParseHeader(h, codec, "run-x", &frame, &n);
    EXPECT_TRUE(absl::IsDataLoss(s)) << s;
    EXPECT_NE(s.message().find("run-x"), std::string::npos) << s;
  }
}

// Compact runs through the external sort: the stable order of the quantized records, the same
// with merge passes and with threads, and spilled bytes well below 48 per record.
TEST(SpillCodecTest, ExternalSortOverCompactRuns) {
  testing_build::ScratchDir dir("sort_compact");
  const SpillCodec codec = Codec(Channels::kRadiance);
  std::vector<SortRecord> in = Records(40000, 9, CloudBounds(), true);
  for (size_t i = 0; i < in.size(); ++i) in[i].key %= 4093;  // heavy duplication: stability
  std::vector<SortRecord> want(in.size());
  std::transform(in.begin(), in.end(), want.begin(),
                 [&](const SortRecord& r) { return Quantized(r, codec); });
  std::stable_sort(want.begin(), want.end(),
                   [](const SortRecord& a, const SortRecord& b) { return a.key < b.key; });
  struct Case {
    uint64_t run_capacity, merge_bytes;
    int threads;
  };
  for (Case c : {Case{500, 256 << 10, 1}, Case{500, 256 << 10, 2}, Case{4000, 64 << 20, 1},
                 Case{4000, 64 << 20, 2}}) {
    SCOPED_TRACE(::testing::Message() << "run " << c.run_capacity << " threads " << c.threads);
    ExternalSorter::Options o{dir.path().string(), c.run_capacity, c.merge_bytes, c.threads};
    o.compact = codec;
    ExternalSorter s(o);
    for (const auto& r : in) ASSERT_TRUE(s.Add(r).ok());
    ASSERT_TRUE(s.FinishInput().ok());
    EXPECT_EQ(s.runs_spilled(), in.size() / c.run_capacity);
    if (c.merge_bytes < (1 << 20)) {
      EXPECT_GE(s.merge_passes(), 2u);
    }
    // Input runs alone (no merge pass) take well under half of the raw 48 bytes.
    if (s.merge_passes() == 0) {
      EXPECT_LT(s.spill_bytes(), in.size() * 24);
    }
    ASSERT_NO_FATAL_FAILURE(ExpectOutput(s, want));
    EXPECT_TRUE(std::filesystem::is_empty(dir.path()));
  }
}

// A kept compact run that was damaged is DataLoss naming it when the merge reads it.
TEST(SpillCodecTest, DamagedKeptRunIsReported) {
  testing_build::ScratchDir dir("sort_compact_damage");
  const SpillCodec codec = Codec(Channels::kOcclusion);
  std::vector<SortRecord> in = Records(6000, 10, CloudBounds(), false);
  std::vector<KeptRun> kept;
  {
    ExternalSorter::Options o{dir.path().string(), 2000, 1 << 20, 1};
    o.compact = codec;
    ExternalSorter s(o);
    s.SetRunDirectory(dir.path().string(), [&](const std::vector<KeptRun>& runs) {
      kept = runs;
      return absl::OkStatus();
    });
    for (const auto& r : in) ASSERT_TRUE(s.Add(r).ok());
    ASSERT_TRUE(s.FinishInput().ok());
  }
  ASSERT_EQ(kept.size(), 3u);
  for (const KeptRun& k : kept) {
    EXPECT_EQ(k.bytes, std::filesystem::file_size((dir.path() / k.name)));
    EXPECT_LT(k.bytes, k.records * 24);
  }
  {
    // Undamaged: resumes to the same records.
    ExternalSorter::Options o{dir.path().string(), 2000, 1 << 20, 1};
    o.compact = codec;
    ExternalSorter s(o);
    s.SetRunDirectory(dir.path().string(), nullptr);
    ASSERT_TRUE(s.ResumeFrom(kept).ok());
    std::vector<SortRecord> buf(in.size() + 1);
    auto n = s.Next(absl::MakeSpan(buf));
    ASSERT_TRUE(n.ok()) << n.status();
    EXPECT_EQ(*n, in.size());
  }
  // Flip one byte in the middle of the second run.
  const std::string path = (dir.path() / kept[1].name).string();
  {
    std::FILE* f = std::fopen(path.c_str(), "r+b");
    ASSERT_NE(f, nullptr);
    std::fseek(f, static_cast<long>(kept[1].bytes / 2), SEEK_SET);
    const int c = std::fgetc(f);
    std::fseek(f, static_cast<long>(kept[1].bytes / 2), SEEK_SET);
    std::fputc(c ^ 0x5a, f);
    std::fclose(f);
  }
  ExternalSorter::Options o{dir.path().string(), 2000, 1 << 20, 1};
  o.compact = codec;
  ExternalSorter s(o);
  s.SetRunDirectory(dir.path().string(), nullptr);
  absl::Status st = s.ResumeFrom(kept);
  std::vector<SortRecord> buf(1000);
  while (st.ok()) {
    auto n = s.Next(absl::MakeSpan(buf));
    st = n.status();
    if (st.ok() && *n == 0) break;
  }
  ASSERT_FALSE(st.ok());
  EXPECT_TRUE(absl::IsDataLoss(st)) << st;
  EXPECT_NE(st.message().find(kept[1].name), std::string::npos) << st;
  s.KeepRuns();
}

// Packing is the encoding the sort thread did: the same blocks, and Unpack is the quantized record.
TEST(SpillCodecTest, PackedRecordsGiveTheSameBlocks) {
  for (Channels ch : {Channels::kOcclusion, Channels::kRadiance}) {
    const SpillCodec codec = Codec(ch);
    const std::vector<SortRecord> in = Records(2500, 11, CloudBounds(), true);
    std::vector<SortRecord> packed(in.size());
    for (size_t i = 0; i < in.size(); ++i) {
      codec.Pack(in[i], &packed[i]);
      EXPECT_EQ(packed[i].key, in[i].key);
      const SortRecord want = Quantized(in[i], codec);
      const SortRecord got = codec.Unpack(packed[i]);
      ASSERT_EQ(0, std::memcmp(&got, &want, sizeof(SortRecord))) << i;
    }
    SpillBlockWriter plain_writer(codec), packed_writer(codec);
    std::vector<uint8_t> plain_bytes, packed_bytes;
    for (size_t i = 0; i < in.size(); i += kSpillBlockRecords) {
      const size_t n = std::min<size_t>(kSpillBlockRecords, in.size() - i);
      ASSERT_TRUE(plain_writer.Append(absl::MakeConstSpan(in).subspan(i, n), &plain_bytes).ok());
      ASSERT_TRUE(
          packed_writer.Append(absl::MakeConstSpan(packed).subspan(i, n), &packed_bytes, true)
              .ok());
    }
    EXPECT_EQ(plain_bytes, packed_bytes);
  }
}

// A block encoded straight from a run buffer through a permutation (EncodeGathered, the sort
// thread's spill) is the block of the records gathered first: the same bytes, packed or plain,
// for one record, a part block and a full one.
TEST(SpillCodecTest, GatheredBlocksAreTheBlocksOfTheGatheredRecords) {
  for (Channels ch : {Channels::kOcclusion, Channels::kRadiance}) {
    const SpillCodec codec = Codec(ch);
    const std::vector<SortRecord> in = Records(3000, 31, CloudBounds(), true);
    std::vector<SortRecord> packed(in.size());
    for (size_t i = 0; i < in.size(); ++i) codec.Pack(in[i], &packed[i]);
    std::vector<KeyIndex> order(in.size());
    for (size_t i = 0; i < in.size(); ++i) order[i] = KeyIndex{in[i].key, i};
    std::mt19937_64 rng(5);
    std::shuffle(order.begin(), order.end(), rng);
    for (bool is_packed : {false, true}) {
      const std::vector<SortRecord>& base = is_packed ? packed : in;
      for (size_t n : {size_t{1}, size_t{700}, size_t{kSpillBlockRecords}}) {
        std::vector<SortRecord> gathered;
        for (size_t i = 0; i < n; ++i) gathered.push_back(base[order[i].index]);
        SpillBlockWriter a(codec), b(codec);
        std::vector<uint8_t> want;
        ASSERT_TRUE(a.Append(gathered, &want, is_packed).ok());
        std::vector<uint8_t> got(codec.max_block_bytes());
        auto size = b.EncodeGathered(base.data(), absl::MakeConstSpan(order).subspan(0, n),
                                     got.data(), is_packed);
        ASSERT_TRUE(size.ok()) << size.status();
        got.resize(*size);
        EXPECT_EQ(got, want) << n << " packed " << is_packed;
      }
    }
  }
}

// KeyCell is the key's bits 0, 3, 6, ... (x), 1, 4, 7, ... (y) and 2, 5, 8, ... (z), each in
// its 21-bit field, bit by bit, for random keys, single bits and all ones.
TEST(SpillCodecTest, KeyCellDeinterleavesTheKey) {
  auto slow = [](uint64_t key) {
    uint64_t cell = 0;
    for (int b = 0; b < kGridBits; ++b) {
      for (int axis = 0; axis < 3; ++axis) {
        cell |= ((key >> (3 * b + axis)) & 1) << (axis * kGridBits + b);
      }
    }
    return cell;
  };
  std::mt19937_64 rng(63);
  std::vector<uint64_t> keys = {0, ~uint64_t{0}, uint64_t{1} << 63};
  for (int b = 0; b < 64; ++b) keys.push_back(uint64_t{1} << b);
  for (int i = 0; i < 100000; ++i) keys.push_back(rng());
  for (uint64_t k : keys) ASSERT_EQ(KeyCell(k), slow(k)) << std::hex << k;
  const MortonQuantizer quant(CloudBounds());
  const glm::vec3 p(0.25f, -1.5f, 2.0f);
  EXPECT_EQ(KeyCell(quant.Key(p)), slow(quant.Key(p)));
}

// PackBlock is Pack, bit for bit, in place or not: records as the builder makes them (finite,
// normalized normals) and not (unnormalized, zero and signed-zero normals, normals on the folds,
// positions on and off the grid, radii and radiance from denormals to 2^100 with either sign,
// zeros, -0, infinities and NaN in any field), on several grids and on one with a zero step.
TEST(SpillCodecTest, PackBlockIsPack) {
  std::mt19937_64 rng(17);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  auto wild = [&]() -> float {
    switch (rng() % 12) {
      case 0:
        return 0.0f;
      case 1:
        return -0.0f;
      case 2:
        return std::numeric_limits<float>::infinity();
      case 3:
        return std::numeric_limits<float>::quiet_NaN();
      case 4:
        return std::numeric_limits<float>::denorm_min() * float(rng() % 1000);
      default:
        return std::ldexp(u(rng), static_cast<int>(rng() % 200) - 100);
    }
  };
  const Bounds b = CloudBounds();
  std::vector<SortRecord> in = Records(20000, 41, b, true);
  for (size_t i = 0; i < in.size(); ++i) {
    SortRecord& r = in[i];
    if (i % 4 == 1) {  // positions off the grid, unnormalized normals, wide magnitudes
      for (float& p : r.position) p *= 3.0f * u(rng);
      for (float& n : r.normal) n *= std::ldexp(1.0f, static_cast<int>(rng() % 60) - 30);
      r.radius = std::ldexp(u(rng), static_cast<int>(rng() % 80) - 40);
      for (float& l : r.radiance) l = std::ldexp(u(rng), static_cast<int>(rng() % 80) - 40);
    } else if (i % 4 == 2) {  // normals on the folds and axes, signed zeros
      const float a = u(rng);
      const float cases[6][3] = {{a, 1.0f - std::fabs(a), 0.0f},
                                 {a, std::fabs(a) - 1.0f, -0.0f},
                                 {0.0f, -0.0f, -1.0f},
                                 {-0.0f, 0.0f, 1.0f},
                                 {a, 0.0f, -0.5f},
                                 {-0.0f, a, -0.25f}};
      std::memcpy(r.normal, cases[rng() % 6], sizeof r.normal);
    } else if (i % 16 == 3) {  // anything in any field
      float* f = r.position;
      f[rng() % 10] = wild();
      f[rng() % 10] = wild();
    }
  }
  std::vector<PositionGrid> grids = {Codec(Channels::kOcclusion).grid};
  PositionGrid far;
  for (float& o : far.origin) o = 1e5f * u(rng);
  far.step = 1e-3f;
  grids.push_back(far);
  PositionGrid coarse = grids[0];
  coarse.step *= 4096.0f;
  grids.push_back(coarse);
  PositionGrid flat = grids[0];
  flat.step = 0.0f;
  grids.push_back(flat);
  for (Channels ch : {Channels::kOcclusion, Channels::kRadiance}) {
    for (const PositionGrid& g : grids) {
      const SpillCodec codec{ch, g};
      std::vector<SortRecord> want(in.size()), got(in.size());
      for (size_t i = 0; i < in.size(); ++i) codec.Pack(in[i], &want[i]);
      codec.PackBlock(in.data(), in.size(), got.data());
      for (size_t i = 0; i < in.size(); ++i) {
        ASSERT_EQ(0, std::memcmp(&got[i], &want[i], sizeof(SortRecord)))
            << "record " << i << " channels " << static_cast<int>(ch) << " step " << g.step;
      }
      std::vector<SortRecord> in_place = in;
      codec.PackBlock(in_place.data(), in_place.size(), in_place.data());
      ASSERT_EQ(0, std::memcmp(in_place.data(), want.data(), in.size() * sizeof(SortRecord)));
      for (size_t n = 0; n <= 9; ++n) {
        for (size_t at = 0; at < 4; ++at) {
          std::vector<SortRecord> part(in.begin() + at, in.begin() + at + n);
          codec.PackBlock(part.data(), n, part.data());
          for (size_t k = 0; k < n; ++k) {
            ASSERT_EQ(0, std::memcmp(&part[k], &want[at + k], sizeof(SortRecord))) << n << at;
          }
        }
      }
    }
  }
}

// UnpackBlock is Unpack, bit for bit (its SIMD lanes and its scalar tail), for every field
// value a packed record can hold: random bytes (any cell, the two-sided bit, every octahedral
// code including -32768, radius and radiance codes with zero exponents, negative radiance),
// every octahedral code pair on a lattice through the folds (z = 0, x = 0, y = 0), on the
// builder's grid and on grids far from the origin with steps from 2^-30 to 2^20.
TEST(SpillCodecTest, UnpackBlockIsUnpack) {
  std::mt19937_64 rng(20);
  std::vector<PositionGrid> grids = {Codec(Channels::kOcclusion).grid};
  std::uniform_real_distribution<float> origin(-1e6f, 1e6f);
  for (int e = -30; e <= 20; e += 5) {
    PositionGrid g;
    for (float& o : g.origin) o = origin(rng);
    g.step = std::ldexp(1.0f + float(rng() % 1000) / 1000.0f, e);
    grids.push_back(g);
  }
  std::vector<SortRecord> packed;
  for (int i = 0; i < 20000; ++i) {
    SortRecord r;
    std::memset(&r, 0, sizeof r);
    r.key = rng();
    uint64_t words[3] = {rng(), rng(), rng()};
    std::memcpy(SpillCodec::PackedBytes(&r), words, kPointRecordRadianceBytes);
    if (i % 7 == 0) {  // zero exponents: zero radius and radiance
      SpillCodec::PackedBytes(&r)[13] &= 0x03;
      SpillCodec::PackedBytes(&r)[15] &= 0x81;
    }
    packed.push_back(r);
  }
  for (int a = -32768; a <= 32767; a += 257) {
    for (int b : {-32768, -32767, -16384, -1, 0, 1, 16383, 16384, 32767, 32767 - std::abs(a)}) {
      SortRecord r = packed[packed.size() % 20000];
      const int16_t oct[2] = {static_cast<int16_t>(a), static_cast<int16_t>(b)};
      std::memcpy(SpillCodec::PackedBytes(&r) + 8, oct, 4);
      packed.push_back(r);
    }
  }
  for (Channels ch : {Channels::kOcclusion, Channels::kRadiance}) {
    for (const PositionGrid& g : grids) {
      const SpillCodec codec{ch, g};
      std::vector<SortRecord> got(packed.size());
      codec.UnpackBlock(packed.data(), packed.size(), got.data());
      for (size_t i = 0; i < packed.size(); ++i) {
        const SortRecord want = codec.Unpack(packed[i]);
        ASSERT_EQ(0, std::memcmp(&got[i], &want, sizeof(SortRecord)))
            << "record " << i << " channels " << static_cast<int>(ch) << " step " << g.step;
      }
      // Every length up to 9 and every start: the scalar tail and the SIMD body agree.
      for (size_t n = 0; n <= 9; ++n) {
        for (size_t at = 0; at < 4; ++at) {
          std::vector<SortRecord> part(n);
          codec.UnpackBlock(packed.data() + at, n, part.data());
          for (size_t k = 0; k < n; ++k) {
            ASSERT_EQ(0, std::memcmp(&part[k], &got[at + k], sizeof(SortRecord))) << n << " " << at;
          }
        }
      }
    }
  }
}

// The external sort over packed input, spilled (with and without threads) or not: the same
// records in the same order as plain input through compact runs, and quantized either way.
TEST(SpillCodecTest, ExternalSortOverPackedInput) {
  testing_build::ScratchDir dir("sort_packed");
  const SpillCodec codec = Codec(Channels::kRadiance);
  std::vector<SortRecord> in = Records(20000, 13, CloudBounds(), true);
  for (size_t i = 0; i < in.size(); ++i) in[i].key %= 2039;  // duplicates: stability
  std::vector<SortRecord> want(in.size());
  std::transform(in.begin(), in.end(), want.begin(),
                 [&](const SortRecord& r) { return Quantized(r, codec); });
  std::stable_sort(want.begin(), want.end(),
                   [](const SortRecord& a, const SortRecord& b) { return a.key < b.key; });
  for (uint64_t capacity : {uint64_t{3000}, uint64_t{20000}}) {
    for (int threads : {1, 2}) {
      SCOPED_TRACE(::testing::Message() << "run " << capacity << " threads " << threads);
      ExternalSorter::Options o{dir.path().string(), capacity, 64 << 20, threads};
      o.compact = codec;
      o.packed_input = true;
      ExternalSorter s(o);
      for (const auto& r : in) {
        SortRecord p;
        codec.Pack(r, &p);
        ASSERT_TRUE(s.Add(p).ok());
      }
      ASSERT_TRUE(s.FinishInput().ok());
      EXPECT_EQ(s.runs_spilled() > 0, capacity < in.size());
      EXPECT_TRUE(s.output_quantized());
      ASSERT_NO_FATAL_FAILURE(ExpectOutput(s, want));
    }
  }
  // Plain input is quantized only when it went through compact runs.
  ExternalSorter::Options o{dir.path().string(), 100000, 64 << 20, 1};
  o.compact = codec;
  ExternalSorter unspilled(o);
  for (const auto& r : in) ASSERT_TRUE(unspilled.Add(r).ok());
  ASSERT_TRUE(unspilled.FinishInput().ok());
  EXPECT_FALSE(unspilled.output_quantized());
}

// With threads, the caller shares the sort thread's spill when its next run buffer is full
// (ExternalSorter::HelpSpill: the last half of the blocks left become a run of its own): the
// same records in the same stable order, from tmp runs and from named runs, and merged again
// through a merge pass. Whether the caller arrives in time depends on the scheduler, so the
// sort is repeated until it shared a spill (it shares about every one on an idle machine).
TEST(SpillCodecTest, SharedSpillsKeepTheOrder) {
  testing_build::ScratchDir dir("sort_shared");
  const SpillCodec codec = Codec(Channels::kRadiance);
  std::vector<SortRecord> in = Records(250000, 19, CloudBounds(), true);
  for (size_t i = 0; i < in.size(); ++i) in[i].key %= 100003;  // duplicates across the split
  std::vector<SortRecord> packed(in.size()), want(in.size());
  for (size_t i = 0; i < in.size(); ++i) codec.Pack(in[i], &packed[i]);
  std::transform(packed.begin(), packed.end(), want.begin(),
                 [&](const SortRecord& r) { return codec.Unpack(r); });
  std::stable_sort(want.begin(), want.end(),
                   [](const SortRecord& a, const SortRecord& b) { return a.key < b.key; });
  for (bool named : {false, true}) {
    for (uint64_t merge_bytes : {uint64_t{64} << 20, uint64_t{200} << 10}) {
      SCOPED_TRACE(::testing::Message() << "named " << named << " merge " << merge_bytes);
      uint64_t shared = 0;
      for (int attempt = 0; attempt < 20 && shared == 0; ++attempt) {
        const std::filesystem::path runs = dir.path() / "runs";
        std::filesystem::remove_all(runs);
        std::filesystem::create_directories(runs);
        ExternalSorter::Options o{dir.path().string(), 40960, merge_bytes, 2};
        o.compact = codec;
        o.packed_input = true;
        ExternalSorter s(o);
        if (named) s.SetRunDirectory(runs.string(), nullptr);
        for (const auto& p : packed) ASSERT_TRUE(s.Add(p).ok());
        ASSERT_TRUE(s.FinishInput().ok());
        shared = s.spills_shared();
        EXPECT_EQ(s.runs_spilled(), (in.size() + 40959) / 40960 + shared);
        if (merge_bytes < (uint64_t{8} << 20)) {
          EXPECT_GT(s.merge_passes(), 0u);
        }
        ASSERT_NO_FATAL_FAILURE(ExpectOutput(s, want));
      }
      EXPECT_GT(shared, 0u);
    }
  }
}

// Packed output (docs/format.md, "Session 13"): the records in the same stable order as the
// plain sort's, each as SpillCodec::Pack makes it, from packed or plain input, spilled or not,
// through merge passes too, with 1 and 2 threads.
TEST(SpillCodecTest, ExternalSortHandsOutPackedRecords) {
  testing_build::ScratchDir dir("sort_packed_out");
  for (Channels ch : {Channels::kOcclusion, Channels::kRadiance}) {
    const SpillCodec codec = Codec(ch);
    std::vector<SortRecord> in = Records(20000, 19, CloudBounds(), true);
    for (size_t i = 0; i < in.size(); ++i) in[i].key %= 2039;  // duplicates: stability
    std::vector<SortRecord> want(in.size());
    std::transform(in.begin(), in.end(), want.begin(), [&](const SortRecord& r) {
      SortRecord p;
      codec.Pack(r, &p);
      return p;
    });
    std::stable_sort(want.begin(), want.end(),
                     [](const SortRecord& a, const SortRecord& b) { return a.key < b.key; });
    // 256 KiB of merge buffers: a fan-in of 3, so 7 runs take a merge pass.
    for (uint64_t merge_bytes : {uint64_t{64} << 20, uint64_t{256} << 10}) {
      for (uint64_t capacity : {uint64_t{3000}, uint64_t{20000}}) {
        for (int threads : {1, 2}) {
          for (bool packed_input : {false, true}) {
            SCOPED_TRACE(::testing::Message() << "channels " << static_cast<int>(ch) << " merge "
                                              << merge_bytes << " run " << capacity << " threads "
                                              << threads << " packed input " << packed_input);
            ExternalSorter::Options o{dir.path().string(), capacity, merge_bytes, threads};
            o.compact = codec;
            o.packed_input = packed_input;
            o.packed_output = true;
            ExternalSorter s(o);
            for (const auto& r : in) {
              SortRecord p = r;
              if (packed_input) codec.Pack(r, &p);
              ASSERT_TRUE(s.Add(p).ok());
            }
            ASSERT_TRUE(s.FinishInput().ok());
            EXPECT_EQ(s.runs_spilled() > 0, capacity < in.size());
            if (capacity < in.size() && merge_bytes < (1 << 20)) {
              EXPECT_GT(s.merge_passes(), 0u);
            }
            EXPECT_TRUE(s.output_packed());
            ASSERT_NO_FATAL_FAILURE(ExpectOutput(s, want));
          }
        }
      }
    }
  }
}

// A point page writer given packed records copies their bytes: the same pages and the same
// records handed back as when it encodes the plain records.
TEST(SpillCodecTest, PackedInputGivesTheSamePagesAndRecords) {
  for (Channels ch : {Channels::kOcclusion, Channels::kRadiance}) {
    const SpillCodec codec = Codec(ch);
    std::vector<SortRecord> in = Records(5000, 23, CloudBounds(), true);
    for (SortRecord& r : in) {
      if (!HasRadiance(ch)) r.radiance[0] = r.radiance[1] = r.radiance[2] = 0.0f;
    }
    MemPageStore encoding(4096), copying(4096);
    PointPageWriter a(ch, &encoding, codec.grid), b(ch, &copying, codec.grid);
    b.set_input_packed(true);
    for (size_t i = 0; i < in.size(); ++i) {
      SortRecord p, sa, sb;
      codec.Pack(in[i], &p);
      ASSERT_TRUE(a.Add(in[i], &sa).ok());
      ASSERT_TRUE(b.Add(p, &sb).ok());
      ASSERT_EQ(0, std::memcmp(&sa, &sb, sizeof(SortRecord))) << i;
    }
    ASSERT_TRUE(a.Flush().ok());
    ASSERT_TRUE(b.Flush().ok());
    EXPECT_GT(encoding.page_count(Section::kPoints), 1u);
    EXPECT_EQ(encoding.pages(Section::kPoints), copying.pages(Section::kPoints));
  }
}

// The octree pass over packed records given with their decoded form (OctreeBuilder::Add(r,
// stored), stored from SpillCodec::UnpackBlock, as the builder does) writes the same node and
// point pages as the one that decodes each record itself.
TEST(SpillCodecTest, OctreeOverUnpackedBlocksWritesTheSamePages) {
  for (Channels ch : {Channels::kOcclusion, Channels::kRadiance}) {
    const SpillCodec codec = Codec(ch);
    std::vector<SortRecord> in = Records(20000, 29, CloudBounds(), true);
    std::stable_sort(in.begin(), in.end(),
                     [](const SortRecord& a, const SortRecord& b) { return a.key < b.key; });
    std::vector<SortRecord> packed(in.size()), unpacked(in.size());
    for (size_t i = 0; i < in.size(); ++i) codec.Pack(in[i], &packed[i]);
    codec.UnpackBlock(packed.data(), packed.size(), unpacked.data());
    MemPageStore one(4096), block(4096);
    for (bool by_block : {false, true}) {
      MemPageStore* sink = by_block ? &block : &one;
      NodePacker packer(Layout::kCoherent, ch, sink, 0, codec.grid);
      PointPageWriter points(ch, sink, codec.grid);
      points.set_input_quantized(true);
      points.set_input_packed(true);
      OctreeBuilder octree(4, ch, &points, &packer);
      for (size_t i = 0; i < packed.size(); ++i) {
        ASSERT_TRUE((by_block ? octree.Add(packed[i], unpacked[i]) : octree.Add(packed[i])).ok());
      }
      ASSERT_TRUE(octree.Finish().ok());
    }
    EXPECT_GT(one.page_count(Section::kNodes), 1u);
    EXPECT_GT(one.page_count(Section::kPoints), 1u);
    EXPECT_EQ(one.pages(Section::kNodes), block.pages(Section::kNodes));
    EXPECT_EQ(one.pages(Section::kPoints), block.pages(Section::kPoints));
  }
}

// A point page writer told that its input is quantized skips decoding it again: the same pages
// and the same records handed back as when it decodes, for quantized input.
TEST(SpillCodecTest, QuantizedInputSkipsTheDecodeWithTheSameResult) {
  for (Channels ch : {Channels::kOcclusion, Channels::kRadiance}) {
    const SpillCodec codec = Codec(ch);
    std::vector<SortRecord> in = Records(5000, 17, CloudBounds(), true);
    for (SortRecord& r : in) {
      r = Quantized(r, codec);
      if (!HasRadiance(ch)) r.radiance[0] = r.radiance[1] = r.radiance[2] = 0.0f;
    }
    MemPageStore decoding(4096), skipping(4096);
    PointPageWriter a(ch, &decoding, codec.grid), b(ch, &skipping, codec.grid);
    b.set_input_quantized(true);
    for (size_t i = 0; i < in.size(); ++i) {
      SortRecord sa, sb;
      ASSERT_TRUE(a.Add(in[i], &sa).ok());
      ASSERT_TRUE(b.Add(in[i], &sb).ok());
      ASSERT_EQ(0, std::memcmp(&sa, &sb, sizeof(SortRecord))) << i;
    }
    ASSERT_TRUE(a.Flush().ok());
    ASSERT_TRUE(b.Flush().ok());
    EXPECT_GT(decoding.page_count(Section::kPoints), 1u);
    EXPECT_EQ(decoding.pages(Section::kPoints), skipping.pages(Section::kPoints));
  }
}

}  // namespace
}  // namespace pbgi::internal
