"""The exceptions of the pbgi package: one class per absl::StatusCode, all under pbgi.Error.

The library reports every failure as an absl::Status (a code and a message that says what and
where); the extension raises it as the class of its code, so that callers can catch a kind of
failure (``except pbgi.DataLossError``) or any of them (``except pbgi.Error``) and read
``e.code`` (the number of absl::StatusCode, also the C API's pbgi_status), ``e.code_name``
("DATA_LOSS") and ``e.message``.
"""

CODE_NAMES = {
    1: "CANCELLED",
    2: "UNKNOWN",
    3: "INVALID_ARGUMENT",
    4: "DEADLINE_EXCEEDED",
    5: "NOT_FOUND",
    6: "ALREADY_EXISTS",
    7: "PERMISSION_DENIED",
    8: "RESOURCE_EXHAUSTED",
    9: "FAILED_PRECONDITION",
    10: "ABORTED",
    11: "OUT_OF_RANGE",
    12: "UNIMPLEMENTED",
    13: "INTERNAL",
    14: "UNAVAILABLE",
    15: "DATA_LOSS",
    16: "UNAUTHENTICATED",
}


class Error(Exception):
    """A failure reported by the library: ``code``, ``code_name`` and ``message``."""

    code = 2

    def __init__(self, message, code=None):
        super().__init__(message)
        self.message = message
        if code is not None:
            self.code = code

    @property
    def code_name(self):
        return CODE_NAMES.get(self.code, "UNKNOWN")

    def __str__(self):
        return f"{self.message} [{self.code_name}]"


class CancelledError(Error):
    code = 1


class UnknownError(Error):
    code = 2


class InvalidArgumentError(Error, ValueError):
    """Bad input: shapes, dtypes, NaN, zero normals, options out of range, ..."""

    code = 3


class DeadlineExceededError(Error):
    code = 4


class NotFoundError(Error):
    """No database (or file) at the path."""

    code = 5


class AlreadyExistsError(Error):
    code = 6


class PermissionDeniedError(Error):
    code = 7


class ResourceExhaustedError(Error):
    """Out of memory, disk full, a map that cannot grow."""

    code = 8


class FailedPreconditionError(Error):
    """E.g. radiance asked of an occlusion-only database, another format version."""

    code = 9


class AbortedError(Error):
    code = 10


class OutOfRangeError(Error):
    code = 11


class UnimplementedError(Error):
    code = 12


class InternalError(Error):
    code = 13


class UnavailableError(Error):
    """A file that cannot be created, read or written."""

    code = 14


class DataLossError(Error):
    """A damaged database: checksums, truncation, broken tree invariants."""

    code = 15


class UnauthenticatedError(Error):
    code = 16


_BY_CODE = {
    cls.code: cls
    for cls in (
        CancelledError, UnknownError, InvalidArgumentError, DeadlineExceededError,
        NotFoundError, AlreadyExistsError, PermissionDeniedError, ResourceExhaustedError,
        FailedPreconditionError, AbortedError, OutOfRangeError, UnimplementedError,
        InternalError, UnavailableError, DataLossError, UnauthenticatedError,
    )
}


def error_class(code):
    """The exception class of an absl::StatusCode number (the extension calls this)."""
    return _BY_CODE.get(code, Error)
