// Writes the seed corpus of the fuzz targets into fuzz/corpus/ (run by hand after a format
// change: `cmake --build out/dev --target pbgi_fuzz_corpus && out/dev/fuzz/pbgi_make_corpus
// fuzz/corpus`).
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "pbgi/build.h"
#include "pbgi/ply.h"
#include "pbgi/store.h"
#include "pbgi/testing.h"
#include "store/meta_codec.h"
#include "tree/format.h"

namespace {

void Write(const std::filesystem::path& file, const std::string& bytes) {
  std::filesystem::create_directories(file.parent_path());
  std::ofstream out(file, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

std::string Read(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), {});
}

}  // namespace

int main(int argc, char** argv) {
  using namespace pbgi;
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s CORPUS_DIR\n", argv[0]);
    return 2;
  }
  const std::filesystem::path root = argv[1];
  const std::filesystem::path scratch = std::filesystem::temp_directory_path() / "pbgi-corpus";
  std::filesystem::remove_all(scratch);
  std::filesystem::create_directories(scratch);
  const std::vector<Surfel> surfels = testing::RandomSceneSurfels(40, 3);

  // PLY: what PlyWriter writes (binary, ASCII, with and without colour) and hand-made variants.
  for (bool ascii : {false, true}) {
    for (bool colour : {false, true}) {
      const std::string f = (scratch / "p.ply").string();
      auto w = PlyWriter::Create(f, {ascii, colour});
      (void)(*w)->Write(absl::MakeConstSpan(surfels).subspan(0, 12));
      (void)(*w)->Close();
      Write(root / "fuzz_ply" /
                absl::StrCat(ascii ? "ascii" : "binary", colour ? "_rgb" : "", ".ply"),
            Read(f));
    }
  }
  // Two-sided surfels with sheet tags and back radiance (PlyWriterOptions::two_sided).
  {
    std::vector<Surfel> thin(surfels.begin(), surfels.begin() + 12);
    for (size_t i = 0; i < thin.size(); i += 2) {
      thin[i].two_sided = true;
      thin[i].sheet = static_cast<uint8_t>(1 + i);
      thin[i].back_radiance = 0.5f * thin[i].radiance;
    }
    for (bool ascii : {false, true}) {
      const std::string f = (scratch / "t.ply").string();
      PlyWriterOptions wo;
      wo.ascii = ascii;
      wo.two_sided = true;
      auto w = PlyWriter::Create(f, wo);
      (void)(*w)->Write(thin);
      (void)(*w)->Close();
      Write(root / "fuzz_ply" / absl::StrCat(ascii ? "ascii" : "binary", "_two_sided.ply"),
            Read(f));
    }
  }
  Write(root / "fuzz_ply" / "uchar_colour_faces.ply",
        "ply\nformat ascii 1.0\ncomment hand-made\nelement vertex 2\nproperty double x\n"
        "property double y\nproperty double z\nproperty float nx\nproperty float ny\n"
        "property float nz\nproperty float radius\nproperty uchar red\nproperty uchar green\n"
        "property uchar blue\nproperty int extra\nelement face 1\n"
        "property list uchar int vertex_indices\nend_header\n"
        "0 0 0 0 0 1 0.1 255 0 12 7\n1 0 0 0 1 0 0.2 0 0 0 -3\n3 0 1 1\n");
  Write(root / "fuzz_ply" / "binary_shorts.ply",
        std::string("ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty short x\n"
                    "property short y\nproperty short z\nproperty char nx\nproperty char ny\n"
                    "property char nz\nproperty ushort radius\nend_header\n") +
            std::string("\x01\x00\x02\x00\x03\x00\x00\x00\x01\x05\x00", 11));

  // Meta records: a database's, an incomplete one, one with many statistics.
  StoreMeta m;
  m.point_count = 1000;
  m.node_count = 150;
  m.node_pages = 1;
  m.point_pages = 1;
  m.bounds.lo = {-1, -2, -3};
  m.bounds.hi = {4, 5, 6};
  m.max_depth = 7;
  Write(root / "fuzz_meta_codec" / "database.bin", internal::EncodeMeta(m, true));
  Write(root / "fuzz_meta_codec" / "incomplete.bin", internal::EncodeMeta(StoreMeta{}, false));
  for (int i = 0; i < 12; ++i) m.stats[absl::StrCat("stat", i)] = absl::StrCat(i * 1.5);
  m.layout = "postorder";
  Write(root / "fuzz_meta_codec" / "stats.bin", internal::EncodeMeta(m, true));

  // Stores: tiny databases (inline pages, overflow pages, compressed pages) and a bare page
  // store.
  for (uint32_t page_size : {1024u, 4080u, 16368u}) {
    const std::string db = (scratch / absl::StrCat("db", page_size)).string();
    // The largest page size's store holds back radiances (Channels::kRadianceBothSides): a
    // third of its surfels two-sided, their backs dimmer than their fronts.
    std::vector<Surfel> input = surfels;
    if (page_size > 8192) {
      for (size_t i = 0; i < input.size(); i += 3) {
        input[i].two_sided = true;
        input[i].back_radiance = 0.25f * input[i].radiance;
      }
    }
    VectorSurfelSource src(input);
    BuildOptions o;
    o.page_size = page_size;
    o.channels = page_size < 1760 ? Channels::kOcclusion : Channels::kRadiance;
    o.leaf_size = 4;
    o.tmp_dir = scratch.string();
    auto st = BuildDatabase(src, db, o);
    if (!st.ok()) {
      std::fprintf(stderr, "%s\n", std::string(st.status().message()).c_str());
      return 1;
    }
    Write(root / "fuzz_store_open" / absl::StrCat("database_", page_size, ".mdb"),
          Read(db + "/data.mdb"));

    // The gather target: its node page 0 and point page 0 behind a receiver.
    auto store = PageStore::Open(db);
    auto txn = (*store)->BeginRead();
    auto nodes = txn->Get(Section::kNodes, (*store)->meta().root >> 16);
    const std::string node_payload(reinterpret_cast<const char*>(nodes->payload.data()),
                                   nodes->payload.size());
    const uint32_t node_records = nodes->header->record_count;
    auto points = txn->Get(Section::kPoints, 0);
    const std::string point_payload(reinterpret_cast<const char*>(points->payload.data()),
                                    points->payload.size());
    std::string in;
    const Channels ch = (*store)->meta().channels;
    const uint8_t flags = (HasRadiance(ch) ? 1 : 0) |
                          static_cast<uint8_t>(((*store)->meta().root & 7) << 1) | (3 << 4) |
                          (ch == Channels::kRadianceBothSides ? 0x80 : 0);
    in.push_back(static_cast<char>(flags));
    const float rec[6] = {0.5f, 0.5f, 0.5f, 0.0f, 0.0f, 1.0f};
    in.append(reinterpret_cast<const char*>(rec), sizeof(rec));
    const uint16_t nr = static_cast<uint16_t>(node_records);
    const uint16_t nb = static_cast<uint16_t>(node_payload.size());
    in.append(reinterpret_cast<const char*>(&nr), 2);
    in.append(reinterpret_cast<const char*>(&nb), 2);
    in += node_payload + point_payload;
    Write(root / "fuzz_page_gather" / absl::StrCat("root_page_", page_size, ".bin"), in);
  }
  {
    const std::string bare = (scratch / "bare").string();
    StoreOptions so;
    so.page_size = 64;
    so.sync = false;
    auto w = PageWriter::Create(bare, so);
    for (uint64_t i = 0; i < 3; ++i) {
      const std::vector<uint8_t> payload(16, static_cast<uint8_t>(i));
      (void)(*w)->Append(Section::kNodes, i, PageKind::kNode, 1, payload);
      (void)(*w)->Append(Section::kPoints, i, PageKind::kPoint, 2, payload);
    }
    StoreMeta bm;
    bm.point_count = 6;
    bm.node_count = 3;
    (void)(*w)->Finish(bm);
    w->reset();
    Write(root / "fuzz_store_open" / "bare_64.mdb", Read(bare + "/data.mdb"));
  }
  std::filesystem::remove_all(scratch);
  return 0;
}
