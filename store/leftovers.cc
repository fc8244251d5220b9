// FindStoreLeftovers (pbgi/store.h).
#include <sys/stat.h>

#include <optional>
#include <string>

#include "absl/strings/str_cat.h"
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

}  // namespace pbgi
