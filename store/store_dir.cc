// What lives in a store directory besides the store: FindStoreLeftovers and
// CheckOutsideStores (pbgi/store.h).
#include <sys/stat.h>

#include <filesystem>
#include <optional>
#include <string>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "pbgi/store.h"
#include "store/store_internal.h"
#include "store/write_lock.h"

namespace pbgi {

StoreLeftovers FindStoreLeftovers(const std::string& path) {
  StoreLeftovers out;
  const std::string tmp = absl::StrCat(path, "/", internal::kBuildingFile);
  for (const std::string& f : {tmp, tmp + internal::kLockSuffix}) {
    struct stat st;
    if (stat(f.c_str(), &st) == 0 && S_ISREG(st.st_mode)) {
      out.files.push_back(f);
      out.bytes += static_cast<uint64_t>(st.st_size);
    }
  }
  if (std::optional<std::string> pid = internal::WriterLockHolder(path)) out.active_writer = *pid;
  return out;
}

namespace {

// What marks a store directory: its file, a build's file, or a build's lock.
bool IsStoreDirectory(const std::filesystem::path& dir) {
  std::error_code ec;
  for (const char* f : {internal::kDataFile, internal::kBuildingFile, internal::kWriterLockFile}) {
    if (std::filesystem::exists(dir / f, ec)) return true;
  }
  return false;
}

}  // namespace

absl::Status CheckOutsideStores(const std::string& output) {
  std::error_code ec;
  // Through symbolic links: a link into a store directory is inside it.
  std::filesystem::path p = std::filesystem::weakly_canonical(std::filesystem::absolute(output, ec), ec);
  if (ec) p = std::filesystem::absolute(output, ec);
  const std::filesystem::path dir = p.parent_path();
  for (const std::filesystem::path& d : {p, dir}) {
    if (!std::filesystem::is_directory(d, ec) || !IsStoreDirectory(d)) continue;
    return absl::FailedPreconditionError(absl::StrFormat(
        "refusing to write %s: %s is a database directory (it holds %s or a build's files), and "
        "anything written there could destroy the database; write somewhere else",
        output, d.string(), internal::kDataFile));
  }
  return absl::OkStatus();
}

}  // namespace pbgi
