// Error handling helpers. The library returns absl::Status / absl::StatusOr<T> and never throws
// or exits across its boundary; only tools/ turns an error into an exit code.
#ifndef PBGI_STATUS_H_
#define PBGI_STATUS_H_

#include "absl/status/status.h"
#include "absl/status/statusor.h"

#define PBGI_STATUS_CONCAT_INNER_(a, b) a##b
#define PBGI_STATUS_CONCAT_(a, b) PBGI_STATUS_CONCAT_INNER_(a, b)

// Returns from the enclosing function when `expr` (an absl::Status) is not OK.
#define PBGI_RETURN_IF_ERROR(expr)               \
  do {                                           \
    ::absl::Status _pbgi_status = (expr);        \
    if (!_pbgi_status.ok()) return _pbgi_status; \
  } while (0)

// PBGI_ASSIGN_OR_RETURN(auto x, MakeX()): declares x from an absl::StatusOr, or returns its error.
#define PBGI_ASSIGN_OR_RETURN(lhs, expr) \
  PBGI_ASSIGN_OR_RETURN_IMPL_(PBGI_STATUS_CONCAT_(_pbgi_statusor_, __LINE__), lhs, expr)
#define PBGI_ASSIGN_OR_RETURN_IMPL_(tmp, lhs, expr) \
  auto tmp = (expr);                                \
  if (!tmp.ok()) return std::move(tmp).status();    \
  lhs = std::move(tmp).value()

#endif  // PBGI_STATUS_H_
