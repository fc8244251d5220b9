#include "store/lmdb_status.h"

#include <lmdb.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/statvfs.h>

#include <cerrno>
#include <string>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace pbgi::internal {

absl::Status LmdbStatus(int rc, absl::string_view context) {
  if (rc == MDB_SUCCESS) return absl::OkStatus();
  const std::string lmdb_text = mdb_strerror(rc);
  auto msg = [&](absl::string_view what) {
    return absl::StrCat(context, ": ", what, " (LMDB: ", lmdb_text, ")");
  };
  switch (rc) {
    case MDB_MAP_FULL:
      return absl::ResourceExhaustedError(
          msg("map full: the store needs more than the current map size"));
    case ENOSPC:
      return absl::ResourceExhaustedError(msg("disk full: no space left on the device"));
    case EDQUOT:
      return absl::ResourceExhaustedError(msg("disk quota exceeded"));
    case EFBIG:
      return absl::ResourceExhaustedError(msg("file too large (file size limit reached)"));
    case ENOMEM:
      return absl::ResourceExhaustedError(msg("out of memory or address space for the map"));
    case MDB_READERS_FULL:
      return absl::ResourceExhaustedError(msg("too many concurrent readers"));
    case MDB_TXN_FULL:
      return absl::ResourceExhaustedError(msg("write transaction has too many dirty pages"));
    case MDB_DBS_FULL:
      return absl::ResourceExhaustedError(msg("too many named sections"));
    case ENOENT:
      return absl::NotFoundError(msg("no such file or directory"));
    case MDB_NOTFOUND:
      return absl::NotFoundError(msg("not found"));
    case EACCES:
    case EPERM:
      return absl::PermissionDeniedError(msg("permission denied"));
    case EROFS:
      return absl::PermissionDeniedError(msg("read-only file system"));
    case MDB_CORRUPTED:
    case MDB_PAGE_NOTFOUND:
      return absl::DataLossError(msg("the LMDB file is corrupted"));
    case MDB_INVALID:
      return absl::DataLossError(
          msg("not an LMDB file, or its header is damaged (garbage or truncated data.mdb)"));
    case EIO:
      return absl::DataLossError(msg("I/O error (short write or read: disk full or failing?)"));
    case MDB_VERSION_MISMATCH:
      return absl::FailedPreconditionError(
          msg("the file was written by an incompatible LMDB version"));
    case MDB_INCOMPATIBLE:
      return absl::FailedPreconditionError(
          msg("the file's layout does not match what was asked of it (not a pbgi store?)"));
    case MDB_KEYEXIST:
      return absl::AlreadyExistsError(msg("key exists or is out of append order"));
    case EINVAL:
      return absl::InvalidArgumentError(msg("invalid argument"));
    default:
      return absl::InternalError(msg(absl::StrCat("unexpected LMDB error ", rc)));
  }
}

absl::Status LmdbWriteStatus(int rc, absl::string_view context, const std::string& file) {
  if (rc == EIO) {
    struct statvfs fs;
    if (statvfs(file.c_str(), &fs) == 0) {
      const uint64_t free_bytes = static_cast<uint64_t>(fs.f_bavail) * fs.f_frsize;
      if (free_bytes < (uint64_t{16} << 20)) {
        return absl::ResourceExhaustedError(absl::StrFormat(
            "%s: disk full: a write to %s was cut short and only %d bytes are free on its file "
            "system",
            context, file, free_bytes));
      }
    }
    struct rlimit lim;
    struct stat st;
    if (getrlimit(RLIMIT_FSIZE, &lim) == 0 && lim.rlim_cur != RLIM_INFINITY &&
        stat(file.c_str(), &st) == 0 &&
        static_cast<uint64_t>(st.st_size) + 4096 > static_cast<uint64_t>(lim.rlim_cur)) {
      return absl::ResourceExhaustedError(absl::StrFormat(
          "%s: file too large: %s reached the process's file size limit (RLIMIT_FSIZE, %d "
          "bytes)",
          context, file, static_cast<uint64_t>(lim.rlim_cur)));
    }
  }
  return LmdbStatus(rc, context);
}

}  // namespace pbgi::internal
