// The one place where LMDB's integer return codes (and the errno values it passes through)
// become absl::Status values (docs/design.md, "Errors").
#ifndef PBGI_STORE_LMDB_STATUS_H_
#define PBGI_STORE_LMDB_STATUS_H_

#include <string>

#include "absl/status/status.h"
#include "absl/strings/string_view.h"

namespace pbgi::internal {

// Translates `rc` (MDB_SUCCESS is OK) into a Status whose message starts with `context` (say which
// store file and which operation), then says what went wrong in words and LMDB's own text.
//   MDB_MAP_FULL, ENOSPC, EDQUOT, EFBIG, ENOMEM, MDB_READERS_FULL, MDB_TXN_FULL ->
//   ResourceExhausted ENOENT, MDB_NOTFOUND                                -> NotFound EACCES,
//   EPERM, EROFS                                -> PermissionDenied MDB_CORRUPTED,
//   MDB_PAGE_NOTFOUND, MDB_INVALID, EIO  -> DataLoss MDB_VERSION_MISMATCH, MDB_INCOMPATIBLE ->
//   FailedPrecondition MDB_KEYEXIST                                        -> AlreadyExists
//   anything else                                       -> Internal
absl::Status LmdbStatus(int rc, absl::string_view context);

// The same, for a write to the LMDB file `file`. LMDB reports a short write as EIO, and a full
// disk usually shows up as one (the last write is partial before the next fails with ENOSPC), so
// EIO is examined further: little space left on the file's file system -> ResourceExhausted
// "disk full"; the file at the process's file size limit (RLIMIT_FSIZE) -> ResourceExhausted.
absl::Status LmdbWriteStatus(int rc, absl::string_view context, const std::string& file);

}  // namespace pbgi::internal

#endif  // PBGI_STORE_LMDB_STATUS_H_
