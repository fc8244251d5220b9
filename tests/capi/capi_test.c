/* The C API (include/pbgi/pbgi.h) from a C program, compiled as C11: builds a database of a disk
 * from a callback of surfel batches, checks its meta record and the tree, gathers one receiver
 * (every surfel represented once), shades receivers on the disk's axis against the analytic
 * form factor r^2 / (h^2 + r^2) on 1 and 2 threads, and checks the errors (codes, thread-local
 * and per-handle messages) and cancellation.
 * Usage: pbgi_capi_test SCRATCH_DIR. Prints "N passed, M failed" and exits nonzero on failure. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pbgi/pbgi.h"

static int g_passed = 0;
static int g_failed = 0;

#define CHECK(cond, ...)                                                       \
  do {                                                                         \
    if (cond) {                                                                \
      ++g_passed;                                                              \
    } else {                                                                   \
      ++g_failed;                                                              \
      fprintf(stderr, "%s:%d: CHECK(%s) failed: ", __FILE__, __LINE__, #cond); \
      fprintf(stderr, __VA_ARGS__);                                            \
      fprintf(stderr, "\n");                                                   \
    }                                                                          \
  } while (0)

#define DISK_RADIUS 1.0f
#define DISK_HEIGHT 1.0f
#define PITCH 0.01f
static const double kPi = 3.14159265358979323846;

/* A disk of radius DISK_RADIUS at z = DISK_HEIGHT facing down, tiled by surfels on a square
 * grid of PITCH whose areas equal the grid cells', handed out in batches by index. */
typedef struct disk_source {
  int n;       /* grid cells per half side */
  long cursor; /* next grid cell to consider */
  long emitted;
  int batches;
} disk_source;

static int next_cell(disk_source* d, pbgi_surfel* s) {
  const long side = 2L * d->n;
  while (d->cursor < side * side) {
    const long c = d->cursor++;
    const float u = ((float)(c % side) - (float)d->n + 0.5f) * PITCH;
    const float v = ((float)(c / side) - (float)d->n + 0.5f) * PITCH;
    if (u * u + v * v > DISK_RADIUS * DISK_RADIUS) continue;
    s->position[0] = u;
    s->position[1] = v;
    s->position[2] = DISK_HEIGHT;
    s->normal[0] = 0.0f;
    s->normal[1] = 0.0f;
    s->normal[2] = -1.0f;
    s->radius = PITCH / (float)sqrt(kPi);
    s->radiance[0] = 0.5f;
    s->radiance[1] = 0.25f;
    s->radiance[2] = 1.0f;
    return 1;
  }
  return 0;
}

static int64_t disk_next(void* user, pbgi_surfel* out, size_t capacity) {
  disk_source* d = (disk_source*)user;
  size_t k = 0;
  while (k < capacity && next_cell(d, &out[k])) ++k;
  d->emitted += (long)k;
  if (k > 0) ++d->batches;
  return (int64_t)k;
}

static int disk_rewind(void* user) {
  disk_source* d = (disk_source*)user;
  d->cursor = 0;
  d->emitted = 0;
  return 0;
}

static int64_t failing_next(void* user, pbgi_surfel* out, size_t capacity) {
  (void)user, (void)out, (void)capacity;
  return -7;
}

static void on_progress(void* user, uint64_t done, uint64_t total) {
  uint64_t* last = (uint64_t*)user;
  if (done <= total) *last = done;
}

static double form_factor(double r, double h) { return r * r / (h * h + r * r); }

int main(int argc, char** argv) {
  if (argc != 2) {
    fprintf(stderr, "usage: %s SCRATCH_DIR\n", argv[0]);
    return 2;
  }
  char path[4096], ply[4096];
  snprintf(path, sizeof(path), "%s/disk.pbgi", argv[1]);
  snprintf(ply, sizeof(ply), "%s/missing.ply", argv[1]);

  CHECK(strcmp(pbgi_status_name(PBGI_DATA_LOSS), "DATA_LOSS") == 0, "%s",
        pbgi_status_name(PBGI_DATA_LOSS));
  CHECK(strlen(pbgi_version()) >= 5, "version '%s'", pbgi_version());

  /* Build from the callback, in batches, with a small budget and leaves. */
  disk_source disk = {(int)ceilf(DISK_RADIUS / PITCH), 0, 0, 0};
  pbgi_surfel_source src;
  memset(&src, 0, sizeof(src));
  src.next = disk_next;
  src.rewind = disk_rewind;
  src.user = &disk;
  src.count = -1;
  src.has_radiance = 1;
  pbgi_build_options bo;
  pbgi_build_options_init(&bo);
  bo.memory_bytes = 64u << 20;
  bo.leaf_size = 8;
  bo.page_size = 4096 - 16;
  pbgi_build_stats bs;
  pbgi_status s = pbgi_build(&src, path, &bo, &bs);
  CHECK(s == PBGI_OK, "pbgi_build: %s: %s", pbgi_status_name(s), pbgi_last_error());
  if (s != PBGI_OK) goto done;
  CHECK(bs.points == (uint64_t)disk.emitted && bs.points > 30000, "%llu points, %ld emitted",
        (unsigned long long)bs.points, disk.emitted);
  CHECK(disk.batches > 1, "%d batches", disk.batches);
  CHECK(bs.leaves > bs.points / 8 && bs.nodes > bs.leaves, "%llu nodes %llu leaves",
        (unsigned long long)bs.nodes, (unsigned long long)bs.leaves);
  CHECK(pbgi_verify(path) == PBGI_OK, "pbgi_verify: %s", pbgi_last_error());

  pbgi_database* db = NULL;
  s = pbgi_database_open(path, NULL, &db);
  CHECK(s == PBGI_OK && db != NULL, "open: %s", pbgi_last_error());
  if (db == NULL) goto done;
  pbgi_info info;
  CHECK(pbgi_database_info(db, &info) == PBGI_OK, "info: %s", pbgi_last_error());
  CHECK(info.point_count == bs.points, "%llu points", (unsigned long long)info.point_count);
  CHECK(info.channels == PBGI_CHANNELS_RADIANCE && info.leaf_size == 8 &&
            info.page_size == 4096 - 16 && strcmp(info.layout, "coherent") == 0,
        "channels %d leaf %u page %u layout %s", (int)info.channels, info.leaf_size, info.page_size,
        info.layout);
  CHECK(fabsf(info.bounds_lo[2] - DISK_HEIGHT) < 1e-6f && info.bounds_hi[0] <= DISK_RADIUS,
        "bounds z %g x %g", info.bounds_lo[2], info.bounds_hi[0]);

  /* Gather at the disk's centre below it: every surfel is in front, represented once. */
  pbgi_reader* reader = NULL;
  CHECK(pbgi_reader_create(db, &reader) == PBGI_OK, "reader: %s", pbgi_last_error());
  if (reader != NULL) {
    const float p[3] = {0.0f, 0.0f, 0.0f}, n[3] = {0.0f, 0.0f, 2.0f};
    pbgi_gathered g;
    s = pbgi_gather(reader, p, n, NULL, &g);
    CHECK(s == PBGI_OK, "gather: %s", pbgi_reader_error(reader));
    uint64_t covered = g.surfel_count;
    double area = 0.0;
    for (size_t i = 0; i < g.cluster_count; ++i) {
      covered += g.clusters[i].point_count;
      area += g.clusters[i].area;
      CHECK(g.clusters[i].bounds_lo[2] >= DISK_HEIGHT - 1e-5f, "cluster %zu below", i);
    }
    for (size_t i = 0; i < g.surfel_count; ++i) {
      area += kPi * g.surfels[i].radius * g.surfels[i].radius;
      CHECK(g.surfel_ids[i] < info.point_count, "surfel id %llu",
            (unsigned long long)g.surfel_ids[i]);
    }
    CHECK(covered == info.point_count, "cut covers %llu of %llu points",
          (unsigned long long)covered, (unsigned long long)info.point_count);
    CHECK(g.cluster_count > 0, "no clusters");
    const double want_area = (double)info.point_count * PITCH * PITCH;
    CHECK(fabs(area - want_area) < 1e-3 * want_area, "area %g want %g", area, want_area);

    /* A zero normal: INVALID_ARGUMENT, on the thread and on the reader. */
    const float zero[3] = {0.0f, 0.0f, 0.0f};
    pbgi_clear_error();
    s = pbgi_gather(reader, p, zero, NULL, &g);
    CHECK(s == PBGI_INVALID_ARGUMENT, "zero normal: %s", pbgi_status_name(s));
    CHECK(pbgi_last_error_code() == PBGI_INVALID_ARGUMENT && strlen(pbgi_last_error()) > 0,
          "last error '%s'", pbgi_last_error());
    CHECK(strcmp(pbgi_reader_error(reader), pbgi_last_error()) == 0, "reader error '%s'",
          pbgi_reader_error(reader));
    CHECK(g.cluster_count == 0 && g.surfel_count == 0, "a failed gather returned elements");
    pbgi_reader_destroy(reader);
  }

  /* Shade receivers on the axis at several distances below the disk. */
  enum { kReceivers = 64 };
  pbgi_shade_receiver receivers[kReceivers];
  pbgi_shade_result one[kReceivers], two[kReceivers];
  for (int i = 0; i < kReceivers; ++i) {
    const float z = DISK_HEIGHT - 0.25f - 1.5f * (float)(i % 8) / 7.0f;
    memset(&receivers[i], 0, sizeof(receivers[i]));
    receivers[i].position[2] = z;
    receivers[i].normal[2] = 1.0f;
    receivers[i].reflection[2] = 1.0f;
  }
  pbgi_shade_options so;
  pbgi_shade_options_init(&so);
  so.threads = 1;
  uint64_t last_done = 0;
  so.progress = on_progress;
  so.progress_user = &last_done;
  pbgi_shade_stats st;
  s = pbgi_shade(db, receivers, kReceivers, &so, one, &st);
  CHECK(s == PBGI_OK, "shade: %s", pbgi_last_error());
  CHECK(last_done == kReceivers, "progress ended at %llu", (unsigned long long)last_done);
  CHECK(st.receivers == kReceivers && st.clusters > 0, "stats: %llu receivers %llu clusters",
        (unsigned long long)st.receivers, (unsigned long long)st.clusters);
  double worst = 0.0;
  for (int i = 0; i < kReceivers; ++i) {
    const double h = DISK_HEIGHT - receivers[i].position[2];
    const double want = form_factor(DISK_RADIUS, h);
    const double err = fabs(one[i].occlusion - want) / want;
    if (err > worst) worst = err;
    CHECK(err < 0.03, "receiver %d at h %g: occlusion %g, analytic %g", i, h, one[i].occlusion,
          want);
    /* The disk emits its radiance towards the receiver: irradiance = pi * L * form factor. */
    const double e = kPi * 0.25 * want;
    CHECK(fabs(one[i].irradiance[1] - e) < 0.05 * e, "receiver %d: irradiance %g, want %g", i,
          one[i].irradiance[1], e);
  }
  printf("disk: worst relative occlusion error %.4f over %d receivers\n", worst, kReceivers);

  /* Two threads and Z-order give the same bits. */
  so.threads = 2;
  so.progress = NULL;
  s = pbgi_shade(db, receivers, kReceivers, &so, two, NULL);
  CHECK(s == PBGI_OK, "shade on 2 threads: %s", pbgi_last_error());
  for (int i = 0; i < kReceivers; ++i) {
    CHECK(one[i].occlusion == two[i].occlusion && one[i].irradiance[0] == two[i].irradiance[0],
          "receiver %d: %g on 1 thread, %g on 2", i, one[i].occlusion, two[i].occlusion);
  }

  /* Errors: a bad receiver is named; the message is on the thread and on the database. */
  receivers[5].normal[2] = 0.0f;
  s = pbgi_shade(db, receivers, kReceivers, &so, two, NULL);
  CHECK(s == PBGI_INVALID_ARGUMENT, "zero normal: %s", pbgi_status_name(s));
  CHECK(strstr(pbgi_last_error(), "receiver 5") != NULL, "message '%s'", pbgi_last_error());
  char buf[256];
  CHECK(pbgi_database_error(db, buf, sizeof(buf)) == PBGI_INVALID_ARGUMENT &&
            strcmp(buf, pbgi_last_error()) == 0,
        "database error '%s'", buf);
  receivers[5].normal[2] = 1.0f;
  so.resolution = 2;
  s = pbgi_shade(db, receivers, kReceivers, &so, two, NULL);
  CHECK(s == PBGI_INVALID_ARGUMENT && strstr(pbgi_last_error(), "resolution") != NULL,
        "resolution 2: %s '%s'", pbgi_status_name(s), pbgi_last_error());
  so.resolution = 12;
  CHECK(so.radiance_contrast == 16.0f, "default radiance_contrast %g", so.radiance_contrast);
  so.radiance_contrast = -1.0f;
  s = pbgi_shade(db, receivers, kReceivers, &so, two, NULL);
  CHECK(s == PBGI_INVALID_ARGUMENT && strstr(pbgi_last_error(), "radiance_contrast") != NULL,
        "radiance_contrast -1: %s '%s'", pbgi_status_name(s), pbgi_last_error());
  so.radiance_contrast = 16.0f;

  /* A raised cancel flag stops the batch. */
  pbgi_cancel* cancel = pbgi_cancel_create();
  pbgi_cancel_raise(cancel);
  so.cancel = cancel;
  s = pbgi_shade(db, receivers, kReceivers, &so, two, NULL);
  CHECK(s == PBGI_CANCELLED, "cancelled shade: %s", pbgi_status_name(s));
  pbgi_cancel_reset(cancel);
  CHECK(!pbgi_cancel_raised(cancel), "reset");
  s = pbgi_shade(db, receivers, kReceivers, &so, two, NULL);
  CHECK(s == PBGI_OK, "after reset: %s", pbgi_last_error());
  pbgi_database_close(db);

  /* Build errors: a missing file, a failing callback, a cancelled build (the old store stays). */
  s = pbgi_build_ply(ply, path, NULL, NULL);
  CHECK(s == PBGI_NOT_FOUND || s == PBGI_UNAVAILABLE, "missing ply: %s '%s'", pbgi_status_name(s),
        pbgi_last_error());
  CHECK(strstr(pbgi_last_error(), "missing.ply") != NULL, "message '%s'", pbgi_last_error());
  pbgi_surfel_source bad = src;
  bad.next = failing_next;
  s = pbgi_build(&bad, path, &bo, NULL);
  CHECK(s == PBGI_ABORTED && strstr(pbgi_last_error(), "-7") != NULL, "failing source: %s '%s'",
        pbgi_status_name(s), pbgi_last_error());
  pbgi_build_options co = bo;
  co.cancel = cancel;
  pbgi_cancel_raise(cancel);
  disk_rewind(&disk);
  s = pbgi_build(&src, path, &co, NULL);
  CHECK(s == PBGI_CANCELLED, "cancelled build: %s '%s'", pbgi_status_name(s), pbgi_last_error());
  pbgi_cancel_destroy(cancel);
  CHECK(pbgi_verify(path) == PBGI_OK, "the previous store after failed builds: %s",
        pbgi_last_error());
  s = pbgi_database_open(ply, NULL, &db);
  CHECK(s == PBGI_NOT_FOUND && db == NULL, "open missing: %s", pbgi_status_name(s));

done:
  printf("%d passed, %d failed\n", g_passed, g_failed);
  return g_failed == 0 && g_passed > 0 ? 0 : 1;
}
