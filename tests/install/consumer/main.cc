// Writes a small store through the installed library, reads it back and checks every byte.
#include <cstdio>
#include <string>
#include <vector>

#include "pbgi/store.h"

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: pbgi_consumer STORE_DIR\n");
    return 2;
  }
  const std::string path = argv[1];
  pbgi::StoreOptions options;
  options.page_size = pbgi::EfficientPageSize(1);
  auto writer = pbgi::PageWriter::Create(path, options);
  if (!writer.ok()) {
    std::fprintf(stderr, "consumer: %s\n", writer.status().ToString().c_str());
    return 1;
  }
  const uint64_t kPages = 20;
  for (uint64_t i = 0; i < kPages; ++i) {
    std::vector<uint8_t> payload(100 + i, static_cast<uint8_t>(i));
    auto s = (*writer)->Append(pbgi::Section::kPoints, i, pbgi::PageKind::kPoint, 1, payload);
    if (!s.ok()) {
      std::fprintf(stderr, "consumer: %s\n", s.ToString().c_str());
      return 1;
    }
  }
  pbgi::StoreMeta meta;
  meta.point_count = kPages;
  meta.stats["consumer"] = "yes";
  if (auto s = (*writer)->Finish(meta); !s.ok()) {
    std::fprintf(stderr, "consumer: %s\n", s.ToString().c_str());
    return 1;
  }
  auto store = pbgi::PageStore::Open(path);
  if (!store.ok()) {
    std::fprintf(stderr, "consumer: %s\n", store.status().ToString().c_str());
    return 1;
  }
  auto txn = (*store)->BeginRead();
  if (!txn.ok()) return 1;
  for (uint64_t i = 0; i < kPages; ++i) {
    auto view = txn->Get(pbgi::Section::kPoints, i);
    if (!view.ok() || view->payload.size() != 100 + i) {
      std::fprintf(stderr, "consumer: page %llu is wrong\n", static_cast<unsigned long long>(i));
      return 1;
    }
    for (uint8_t b : view->payload) {
      if (b != static_cast<uint8_t>(i)) return 1;
    }
  }
  auto report = pbgi::CheckAllPages(**store);
  if (!report.ok() || !report->ok() || report->points.pages != kPages) {
    std::fprintf(stderr, "consumer: check failed\n");
    return 1;
  }
  std::printf("consumer: ok (%llu pages, %llu bytes on disk)\n",
              static_cast<unsigned long long>(kPages),
              static_cast<unsigned long long>((*store)->FileBytes()));
  return 0;
}
