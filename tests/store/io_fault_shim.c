/* An LD_PRELOAD shim that fails the k-th write, fsync or rename of a process, for the I/O
 * fault test (tests/store/io_fault_test.sh). Configured by environment variables:
 *   PBGI_FAULT_OPS    which calls count: any of "write" (write, pwrite, pwrite64, writev,
 *                     pwritev, pwritev64), "fsync" (fsync, fdatasync), "rename" (rename,
 *                     renameat, renameat2), comma-separated;
 *   PBGI_FAULT_PATH   only calls on files under this directory count (the descriptor's path
 *                     from /proc/self/fd; a rename's old or new path);
 *   PBGI_FAULT_AT     the call that fails, counting from 1 (0 or unset: none, only count);
 *   PBGI_FAULT_ERRNO  EIO (default) or ENOSPC;
 *   PBGI_FAULT_STICKY 1: every counted call from the k-th on fails (a full disk), else only
 *                     the k-th (a transient error);
 *   PBGI_FAULT_SHORT  1: a failing write first writes half of its bytes and returns that many
 *                     (a short write), as a disk that fills up mid-write does;
 *   PBGI_FAULT_COUNT_FILE  at exit, the number of counted calls is written there.
 * Only for tests: not thread-safe beyond an atomic counter, Linux only. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/types.h>
#include <sys/uio.h>
#include <unistd.h>

enum { kWrite = 1, kFsync = 2, kRename = 4 };

static int g_ops = -1;
static const char* g_path;
static size_t g_path_len;
static long g_at;
static int g_errno = EIO;
static int g_sticky, g_short;
static long g_count;

static void Init(void) {
  if (g_ops >= 0) return;
  const char* ops = getenv("PBGI_FAULT_OPS");
  int mask = 0;
  if (ops != NULL) {
    if (strstr(ops, "write")) mask |= kWrite;
    if (strstr(ops, "fsync")) mask |= kFsync;
    if (strstr(ops, "rename")) mask |= kRename;
  }
  g_path = getenv("PBGI_FAULT_PATH");
  g_path_len = g_path ? strlen(g_path) : 0;
  const char* at = getenv("PBGI_FAULT_AT");
  g_at = at ? atol(at) : 0;
  const char* e = getenv("PBGI_FAULT_ERRNO");
  if (e != NULL && strcmp(e, "ENOSPC") == 0) g_errno = ENOSPC;
  const char* st = getenv("PBGI_FAULT_STICKY");
  g_sticky = st != NULL && st[0] == '1';
  const char* sh = getenv("PBGI_FAULT_SHORT");
  g_short = sh != NULL && sh[0] == '1';
  g_ops = mask;
}

static int Under(const char* path) {
  return path != NULL && (g_path_len == 0 || strncmp(path, g_path, g_path_len) == 0);
}

static int FdUnder(int fd) {
  char link[64], target[4096];
  snprintf(link, sizeof(link), "/proc/self/fd/%d", fd);
  const ssize_t n = readlink(link, target, sizeof(target) - 1);
  if (n <= 0) return 0;
  target[n] = '\0';
  return Under(target);
}

/* Whether this counted call fails. */
static int Hit(int op, int counted) {
  Init();
  if (!(g_ops & op) || !counted) return 0;
  const long k = __atomic_add_fetch(&g_count, 1, __ATOMIC_RELAXED);
  return g_at > 0 && (k == g_at || (g_sticky && k > g_at));
}

__attribute__((destructor)) static void Report(void) {
  const char* f = getenv("PBGI_FAULT_COUNT_FILE");
  if (f == NULL) return;
  FILE* out = fopen(f, "w");
  if (out == NULL) return;
  fprintf(out, "%ld\n", g_count);
  fclose(out);
}

#define REAL(name, type) \
  static type real = NULL; \
  if (real == NULL) real = (type)dlsym(RTLD_NEXT, name)

typedef ssize_t (*WriteFn)(int, const void*, size_t);
typedef ssize_t (*PwriteFn)(int, const void*, size_t, off_t);
typedef ssize_t (*WritevFn)(int, const struct iovec*, int);
typedef ssize_t (*PwritevFn)(int, const struct iovec*, int, off_t);
typedef int (*FsyncFn)(int);
typedef int (*RenameFn)(const char*, const char*);
typedef int (*RenameatFn)(int, const char*, int, const char*);
typedef int (*Renameat2Fn)(int, const char*, int, const char*, unsigned);

ssize_t write(int fd, const void* buf, size_t n) {
  REAL("write", WriteFn);
  if (Hit(kWrite, FdUnder(fd))) {
    if (g_short && n > 1) return real(fd, buf, n / 2);
    errno = g_errno;
    return -1;
  }
  return real(fd, buf, n);
}

static ssize_t Pwrite(PwriteFn real, int fd, const void* buf, size_t n, off_t off) {
  if (Hit(kWrite, FdUnder(fd))) {
    if (g_short && n > 1) return real(fd, buf, n / 2, off);
    errno = g_errno;
    return -1;
  }
  return real(fd, buf, n, off);
}
ssize_t pwrite(int fd, const void* buf, size_t n, off_t off) {
  REAL("pwrite", PwriteFn);
  return Pwrite(real, fd, buf, n, off);
}
ssize_t pwrite64(int fd, const void* buf, size_t n, off_t off) {
  REAL("pwrite64", PwriteFn);
  return Pwrite(real, fd, buf, n, off);
}

ssize_t writev(int fd, const struct iovec* iov, int cnt) {
  REAL("writev", WritevFn);
  if (Hit(kWrite, FdUnder(fd))) {
    if (g_short && cnt > 1) return real(fd, iov, cnt / 2);
    errno = g_errno;
    return -1;
  }
  return real(fd, iov, cnt);
}

static ssize_t Pwritev(PwritevFn real, int fd, const struct iovec* iov, int cnt, off_t off) {
  if (Hit(kWrite, FdUnder(fd))) {
    if (g_short && cnt > 1) return real(fd, iov, cnt / 2, off);
    errno = g_errno;
    return -1;
  }
  return real(fd, iov, cnt, off);
}
ssize_t pwritev(int fd, const struct iovec* iov, int cnt, off_t off) {
  REAL("pwritev", PwritevFn);
  return Pwritev(real, fd, iov, cnt, off);
}
ssize_t pwritev64(int fd, const struct iovec* iov, int cnt, off_t off) {
  REAL("pwritev64", PwritevFn);
  return Pwritev(real, fd, iov, cnt, off);
}

int fsync(int fd) {
  REAL("fsync", FsyncFn);
  if (Hit(kFsync, FdUnder(fd))) {
    errno = g_errno;
    return -1;
  }
  return real(fd);
}
int fdatasync(int fd) {
  REAL("fdatasync", FsyncFn);
  if (Hit(kFsync, FdUnder(fd))) {
    errno = g_errno;
    return -1;
  }
  return real(fd);
}

int rename(const char* from, const char* to) {
  REAL("rename", RenameFn);
  if (Hit(kRename, Under(from) || Under(to))) {
    errno = g_errno;
    return -1;
  }
  return real(from, to);
}
int renameat(int a, const char* from, int b, const char* to) {
  REAL("renameat", RenameatFn);
  if (Hit(kRename, Under(from) || Under(to))) {
    errno = g_errno;
    return -1;
  }
  return real(a, from, b, to);
}
int renameat2(int a, const char* from, int b, const char* to, unsigned flags) {
  REAL("renameat2", Renameat2Fn);
  if (Hit(kRename, Under(from) || Under(to))) {
    errno = g_errno;
    return -1;
  }
  return real(a, from, b, to, flags);
}
