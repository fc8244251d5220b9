// Builds a small database through the installed core, gathers from it and shades a batch of
// receivers, and checks what it gets: the store reads back, every surfel in front of a receiver
// is represented, and a receiver inside a closed box is occluded all round while one outside
// is not.
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include "pbgi/build.h"
#include "pbgi/query.h"
#include "pbgi/shade.h"
#include "pbgi/store.h"

namespace {

int Fail(const char* what, const std::string& why) {
  std::fprintf(stderr, "consumer: %s: %s\n", what, why.c_str());
  return 1;
}

// A closed cube [-1, 1]^3 of inward-facing surfels, `n` per face edge.
std::vector<pbgi::Surfel> Box(int n) {
  std::vector<pbgi::Surfel> out;
  const float step = 2.0f / static_cast<float>(n);
  const float radius = step * 0.75f;  // disks overlap: no gaps
  for (int axis = 0; axis < 3; ++axis) {
    for (float side : {-1.0f, 1.0f}) {
      for (int i = 0; i < n; ++i) {
        for (int j = 0; j < n; ++j) {
          pbgi::Surfel s;
          s.position[axis] = side;
          s.position[(axis + 1) % 3] = -1.0f + step * (static_cast<float>(i) + 0.5f);
          s.position[(axis + 2) % 3] = -1.0f + step * (static_cast<float>(j) + 0.5f);
          s.normal = glm::vec3(0.0f);
          s.normal[axis] = -side;
          s.radius = radius;
          s.radiance = glm::vec3(0.5f);
          out.push_back(s);
        }
      }
    }
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: pbgi_consumer WORK_DIR\n");
    return 2;
  }
  const std::string db_path = std::string(argv[1]) + "/box.pbgi";
  const std::vector<pbgi::Surfel> box = Box(40);
  pbgi::VectorSurfelSource source(box);
  pbgi::BuildOptions build;
  build.memory_bytes = 64 << 20;
  build.tmp_dir = argv[1];
  auto stats = pbgi::BuildDatabase(source, db_path, build);
  if (!stats.ok()) return Fail("build", stats.status().ToString());
  if (stats->points != box.size()) return Fail("build", "wrong point count");

  auto store = pbgi::PageStore::Open(db_path);
  if (!store.ok()) return Fail("open store", store.status().ToString());
  if (auto s = pbgi::VerifyTree(**store); !s.ok()) return Fail("verify", s.ToString());
  auto report = pbgi::CheckAllPages(**store);
  if (!report.ok() || !report->ok()) return Fail("check", "pages are inconsistent");

  auto db = pbgi::Database::Open(db_path);
  if (!db.ok()) return Fail("open database", db.status().ToString());
  auto reader = (*db)->NewReader();
  if (!reader.ok()) return Fail("reader", reader.status().ToString());
  // From the centre, every surfel in front of the tangent plane is in the cut, alone or inside a
  // cluster (whose point range may also hold surfels behind the plane).
  pbgi::Gathered g;
  const pbgi::Receiver centre{glm::vec3(0.0f), glm::vec3(0.0f, 0.0f, 1.0f)};
  if (auto s = (*reader)->Gather(centre, pbgi::Cut{}, &g); !s.ok()) {
    return Fail("gather", s.ToString());
  }
  uint64_t represented = g.surfels.size();
  for (const pbgi::Cluster& c : g.clusters) represented += c.point_count;
  uint64_t in_front = 0;
  for (const pbgi::Surfel& s : box) in_front += pbgi::SurfelWhollyBehind(s, centre) ? 0 : 1;
  if (represented < in_front || represented > box.size() || g.clusters.empty()) {
    return Fail("gather", "the cut does not cover the surfels in front");
  }

  // Inside the box every direction above the receiver is covered; outside, looking away, none.
  std::vector<pbgi::ShadeReceiver> receivers;
  for (int i = 0; i < 16; ++i) {
    const float t = -0.5f + static_cast<float>(i) / 16.0f;
    receivers.push_back({glm::vec3(t, 0.1f, -0.2f), glm::vec3(0, 0, 1), glm::vec3(0, 0, 1)});
  }
  receivers.push_back({glm::vec3(0, 0, 3), glm::vec3(0, 0, 1), glm::vec3(0, 0, 1)});
  std::vector<pbgi::ShadeResult> out(receivers.size());
  pbgi::ShadeOptions options;
  options.threads = 2;
  pbgi::ShadeStats shade;
  if (auto s = pbgi::ShadeBatch(**db, receivers, options, absl::MakeSpan(out), &shade); !s.ok()) {
    return Fail("shade", s.ToString());
  }
  for (size_t i = 0; i + 1 < out.size(); ++i) {
    if (!(std::abs(out[i].occlusion - 1.0f) < 0.02f)) {
      return Fail("shade", "a receiver inside the box is not occluded");
    }
  }
  if (!(out.back().occlusion < 0.01f)) return Fail("shade", "the receiver outside is occluded");
  std::printf("consumer: ok (%llu surfels, %llu nodes; shaded %llu receivers, occlusion %.4f)\n",
              static_cast<unsigned long long>(stats->points),
              static_cast<unsigned long long>(stats->nodes),
              static_cast<unsigned long long>(shade.receivers), out.front().occlusion);
  return 0;
}
