// BuildDatabase and VerifyTree over the LMDB store.
#include <chrono>
#include <filesystem>
#include <string>
#include <system_error>

#include "absl/strings/str_format.h"
#include "build/builder.h"
#include "pbgi/build.h"
#include "pbgi/status.h"
#include "pbgi/store.h"

namespace pbgi {
namespace {

class WriterSink final : public internal::PageSink {
 public:
  explicit WriterSink(PageWriter* w) : w_(w) {}
  uint32_t page_size() const override { return w_->page_size(); }
  absl::Status Append(Section section, uint64_t page_no, PageKind kind, uint32_t record_count,
                      absl::Span<const uint8_t> payload) override {
    return w_->Append(section, page_no, kind, record_count, payload);
  }

 private:
  PageWriter* w_;
};

class TxnGetter final : public internal::PageGetter {
 public:
  explicit TxnGetter(ReadTxn* txn) : txn_(txn) {}
  absl::StatusOr<internal::PageRead> Get(Section section, uint64_t page_no) override {
    PBGI_ASSIGN_OR_RETURN(PageView v, txn_->Get(section, page_no));
    internal::PageRead r;
    r.payload = v.payload;
    r.record_count = v.header->record_count;
    r.kind = v.header->kind;
    return r;
  }

 private:
  ReadTxn* txn_;
};

uint64_t DirectoryBytes(const std::string& path) {
  std::error_code ec;
  uint64_t total = 0;
  for (const auto& e : std::filesystem::directory_iterator(path, ec)) {
    if (e.is_regular_file(ec)) total += e.file_size(ec);
  }
  return total;
}

}  // namespace

absl::StatusOr<BuildStats> BuildDatabase(SurfelSource& source, const std::string& db_path,
                                         const BuildOptions& options) {
  std::string tmp_dir = options.tmp_dir;
  if (tmp_dir.empty()) {
    std::filesystem::path parent = std::filesystem::absolute(db_path).parent_path();
    tmp_dir = parent.empty() ? std::string(".") : parent.string();
  }
  std::error_code ec;
  if (!std::filesystem::is_directory(tmp_dir, ec)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("temporary directory '%s' does not exist", tmp_dir));
  }
  StoreOptions so;
  so.page_size = options.page_size;
  so.batch_bytes = internal::PlanMemory(options, source.KnownCount()).batch_bytes;
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PageWriter> writer, PageWriter::Create(db_path, so));
  WriterSink sink(writer.get());
  StoreMeta meta;
  PBGI_ASSIGN_OR_RETURN(BuildStats stats,
                        internal::BuildToSink(source, sink, options, tmp_dir, &meta));
  auto t = std::chrono::steady_clock::now();
  PBGI_RETURN_IF_ERROR(writer->Finish(meta));
  writer.reset();
  stats.seconds_finish =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
  stats.seconds_total += stats.seconds_finish;
  stats.bytes_on_disk = DirectoryBytes(db_path);
  stats.peak_rss_bytes = internal::PeakRss();
  return stats;
}

absl::Status VerifyTree(const PageStore& store) {
  PBGI_ASSIGN_OR_RETURN(ReadTxn txn, store.BeginRead());
  TxnGetter getter(&txn);
  absl::Status s = internal::VerifyTreePages(store.meta(), getter);
  if (!s.ok()) {
    return absl::Status(s.code(), absl::StrFormat("%s: %s", store.path(), s.message()));
  }
  return absl::OkStatus();
}

}  // namespace pbgi
