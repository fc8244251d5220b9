/* pbgi.h: the C API of Coherent PBGI (module capi/, docs/design.md, "Bindings").
 *
 * For renderers and tools that embed the library through C: build a database from a callback
 * that hands out batches of surfels, open it, gather the octree cut for one receiver, and shade
 * a batch of receivers on several threads. It is a thin layer over the C++ API (pbgi/build.h,
 * pbgi/query.h, pbgi/shade.h), whose documentation holds the details of what each call computes.
 *
 *   pbgi_database* db;
 *   if (pbgi_database_open("scene.pbgi", NULL, &db) != PBGI_OK) {
 *     fprintf(stderr, "%s\n", pbgi_last_error());
 *     return 1;
 *   }
 *   pbgi_shade_options o;
 *   pbgi_shade_options_init(&o);
 *   o.threads = 8;
 *   pbgi_status s = pbgi_shade(db, receivers, n, &o, results, NULL);
 *   pbgi_database_close(db);
 *
 * CONVENTIONS
 *
 * Names: every symbol starts with pbgi_ (types, functions) or PBGI_ (constants).
 *
 * Errors: every call that can fail returns a pbgi_status; PBGI_OK (0) is success, and the other
 * values are the codes of absl::StatusCode (the library's own), with the same numbers. A call
 * that fails records a message that says what and where (the store, the page, the surfel or
 * receiver index, the option and its value):
 *  - for the calling thread, in pbgi_last_error() / pbgi_last_error_code() (thread-local, like
 *    errno: set by every failing call, left alone by calls that succeed, cleared by
 *    pbgi_clear_error());
 *  - and, for a call made on a handle, in that handle: pbgi_database_error() (copied out under a
 *    lock, as a database is shared between threads) and pbgi_reader_error().
 * No C++ exception ever crosses this API: an allocation failure is PBGI_RESOURCE_EXHAUSTED, any
 * other exception PBGI_INTERNAL.
 *
 * Options: every options struct has an _init() function that fills in the defaults; call it
 * first and then set the fields you need. Later versions add fields only at the end of a struct,
 * and PBGI_C_API_VERSION grows when they do.
 *
 * Lifetimes: a handle is made by one _open() or _create() call and released by exactly one
 * _close() or _destroy() call. Memory that the library hands out (the arrays of a
 * pbgi_gathered) belongs to the handle that produced it, valid until the next call on it.
 * Strings passed in are copied when the call needs them later.
 *
 * Thread safety, per object:
 *  - pbgi_database: safe to share; any number of threads may call pbgi_shade(),
 *    pbgi_reader_create() and pbgi_database_info() on it at once. pbgi_database_close() must
 *    not run concurrently with any other call on it, and every reader made from it must be
 *    destroyed first.
 *  - pbgi_reader: one thread at a time (make one per thread).
 *  - pbgi_cancel: pbgi_cancel_raise() may be called from any thread and from a signal handler.
 *  - pbgi_build(): independent builds may run at once (to different paths).
 *  - Callbacks (surfel source, progress) run on a thread of the library's: the surfel source
 *    from one thread at a time, a progress callback from one thread at a time.
 */
#ifndef PBGI_PBGI_H_
#define PBGI_PBGI_H_

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Grows when a struct gains fields or a call is added. */
#define PBGI_C_API_VERSION 1

/* ---- errors ------------------------------------------------------------------------------- */

/* The codes of absl::StatusCode, with the same values. */
typedef enum pbgi_status {
  PBGI_OK = 0,
  PBGI_CANCELLED = 1, /* a pbgi_cancel was raised */
  PBGI_UNKNOWN = 2,
  PBGI_INVALID_ARGUMENT = 3, /* bad option, NaN, zero normal, NULL pointer, ... */
  PBGI_DEADLINE_EXCEEDED = 4,
  PBGI_NOT_FOUND = 5, /* no database at the path, missing page */
  PBGI_ALREADY_EXISTS = 6,
  PBGI_PERMISSION_DENIED = 7,
  PBGI_RESOURCE_EXHAUSTED = 8,  /* out of memory, disk full, map too large */
  PBGI_FAILED_PRECONDITION = 9, /* e.g. radiance asked of an occlusion-only database */
  PBGI_ABORTED = 10,            /* a surfel source callback reported an error */
  PBGI_OUT_OF_RANGE = 11,
  PBGI_UNIMPLEMENTED = 12,
  PBGI_INTERNAL = 13,
  PBGI_UNAVAILABLE = 14, /* a file that cannot be created or written */
  PBGI_DATA_LOSS = 15,   /* a damaged store: checksum, truncation, tree invariants */
  PBGI_UNAUTHENTICATED = 16
} pbgi_status;

/* "OK", "INVALID_ARGUMENT", ...; "UNKNOWN" for a value outside the enum. Static storage. */
const char* pbgi_status_name(pbgi_status status);

/* The message of the calling thread's last failed call, "" if none since the thread started or
 * since pbgi_clear_error(). Lifetime: valid until the calling thread's next failing call or
 * pbgi_clear_error(). Threads: each thread sees its own. */
const char* pbgi_last_error(void);
/* The code of that call, PBGI_OK if none. */
pbgi_status pbgi_last_error_code(void);
void pbgi_clear_error(void);

/* The library's version, "MAJOR.MINOR.PATCH". Static storage. */
const char* pbgi_version(void);

/* ---- cancellation ------------------------------------------------------------------------- */

/* A flag that stops a build or a shading batch at its next batch or block of receivers, which
 * then returns PBGI_CANCELLED (a build also removes its temporary files and the incomplete
 * store). One flag may serve several calls at once. */
typedef struct pbgi_cancel pbgi_cancel;

/* NULL when out of memory. */
pbgi_cancel* pbgi_cancel_create(void);
/* Any thread, and async-signal-safe (a lock-free atomic store): a SIGINT handler may call it. */
void pbgi_cancel_raise(pbgi_cancel* cancel);
/* Lowers the flag for reuse. Not while a call that uses it is running. */
void pbgi_cancel_reset(pbgi_cancel* cancel);
int pbgi_cancel_raised(const pbgi_cancel* cancel);
/* REQUIRES: no call that uses it is running. NULL is ignored. */
void pbgi_cancel_destroy(pbgi_cancel* cancel);

/* ---- surfels and building ----------------------------------------------------------------- */

/* A disk: position, unit normal, radius > 0, and the diffusely reflected radiance baked into it
 * (zero when the database stores occlusion only). */
typedef struct pbgi_surfel {
  float position[3];
  float normal[3];
  float radius;
  float radiance[3];
} pbgi_surfel;

/* Fills out[0 .. capacity) with the next surfels of the stream and returns how many it wrote:
 * 0 at the end of the stream, a negative value on an error of the caller's (the build then
 * fails with PBGI_ABORTED, naming the value and how many surfels had been read). */
typedef int64_t (*pbgi_next_surfels_fn)(void* user, pbgi_surfel* out, size_t capacity);
/* Restarts the stream at its first surfel: the builder reads the stream twice when it does not
 * know the bounds. Returns 0 on success, nonzero on an error (PBGI_ABORTED). */
typedef int (*pbgi_rewind_fn)(void* user);

/* A stream of surfels from the caller, pulled in batches: the builder never holds it whole, so
 * the source may be larger than memory. Called from one thread at a time (not necessarily the
 * thread that called pbgi_build()). */
typedef struct pbgi_surfel_source {
  pbgi_next_surfels_fn next; /* required */
  pbgi_rewind_fn rewind;     /* required */
  void* user;                /* passed to both */
  int64_t count;             /* number of surfels when known (progress), else -1 */
  int has_radiance;          /* nonzero when the surfels carry radiance */
  /* Nonzero when bounds_lo/hi hold the bounds of all positions: saves the bounds pass. */
  int has_bounds;
  float bounds_lo[3];
  float bounds_hi[3];
} pbgi_surfel_source;

typedef enum pbgi_channels {
  PBGI_CHANNELS_OCCLUSION = 0, /* geometry only: ambient occlusion */
  PBGI_CHANNELS_RADIANCE = 1   /* plus RGB radiance per surfel and power SH per node */
} pbgi_channels;

/* Order of node records in pages; only COHERENT is meant for production (pbgi/build.h). */
typedef enum pbgi_layout {
  PBGI_LAYOUT_COHERENT = 0,
  PBGI_LAYOUT_POSTORDER = 1,
  PBGI_LAYOUT_BREADTH_FIRST = 2,
  PBGI_LAYOUT_SHUFFLED = 3
} pbgi_layout;

/* `pass` is "bounds", "sort" or "merge+octree" (static storage); total is -1 when unknown.
 * Called at most every few hundred thousand surfels. */
typedef void (*pbgi_build_progress_fn)(void* user, const char* pass, uint64_t done, int64_t total);

/* The options of `pbgi build` (pbgi::BuildOptions). */
typedef struct pbgi_build_options {
  uint64_t memory_bytes;  /* budget of the sort, merge and write batch; default 1 GiB */
  uint32_t leaf_size;     /* maximum points per leaf; default 16 */
  uint32_t page_size;     /* bytes per page; default 32752 (k * 4096 - 16 is efficient) */
  pbgi_channels channels; /* default PBGI_CHANNELS_RADIANCE */
  pbgi_layout layout;     /* default PBGI_LAYOUT_COHERENT */
  int threads;            /* 0 or 1: one thread; >= 2: pipelined passes (pbgi/build.h) */
  const char* tmp_dir;    /* sort runs; NULL: the database's parent directory */
  int skip_invalid;       /* nonzero: drop NaN/Inf, zero normals, radius <= 0 and count them */
  uint64_t shuffle_seed;  /* PBGI_LAYOUT_SHUFFLED only */
  pbgi_build_progress_fn progress; /* NULL: none */
  void* progress_user;
  pbgi_cancel* cancel; /* NULL: none */
} pbgi_build_options;

void pbgi_build_options_init(pbgi_build_options* options);

/* What a build did (a subset of pbgi::BuildStats). */
typedef struct pbgi_build_stats {
  uint64_t points;  /* surfels stored */
  uint64_t skipped; /* invalid surfels dropped (skip_invalid) */
  uint64_t nodes;
  uint64_t leaves;
  uint64_t node_pages;
  uint64_t point_pages;
  uint32_t max_depth;
  uint64_t bytes_on_disk;
  uint64_t peak_rss_bytes; /* of the process, after the build */
  double seconds;          /* wall time of the build */
} pbgi_build_stats;

/* Builds a database at `path` (a directory, created or replaced only when the build succeeds:
 * readers of a previous database there are undisturbed) from every surfel of `source`.
 * `options` NULL: the defaults; `stats` may be NULL. Errors: PBGI_INVALID_ARGUMENT for an
 * invalid surfel (naming its index in the stream, unless skip_invalid) or option, or an empty
 * stream; PBGI_ABORTED when a callback failed; PBGI_CANCELLED; PBGI_RESOURCE_EXHAUSTED.
 * Blocks until the build is done; the callbacks run during the call only, from one thread at a
 * time. Threads: any thread; builds to different paths may run at once. Lifetime: `source`,
 * `options` and the strings they point to need to live only for the call. */
pbgi_status pbgi_build(const pbgi_surfel_source* source, const char* path,
                       const pbgi_build_options* options, pbgi_build_stats* stats);

/* The same from a PLY point file (pbgi/ply.h: x y z nx ny nz radius [r g b]), streamed.
 * PBGI_NOT_FOUND or PBGI_UNAVAILABLE for a file that cannot be read, PBGI_INVALID_ARGUMENT or
 * PBGI_DATA_LOSS (naming the record) for a malformed one. Threads: as pbgi_build(). */
pbgi_status pbgi_build_ply(const char* ply_path, const char* path,
                           const pbgi_build_options* options, pbgi_build_stats* stats);

/* Reads every page of the database at `path` (checksums, kinds, numbers, counts) and checks the
 * tree's invariants (pbgi::VerifyTree). PBGI_DATA_LOSS names the first problem found.
 * Threads: any thread, also while the database is open elsewhere (it is read-only). */
pbgi_status pbgi_verify(const char* path);

/* ---- databases ---------------------------------------------------------------------------- */

typedef struct pbgi_database pbgi_database;

typedef struct pbgi_database_options {
  uint64_t cache_bytes;        /* decoded pages, both cache levels together; default 256 MiB */
  uint64_t reader_cache_bytes; /* each reader's own LRU; 0: an automatic share (pbgi/query.h) */
  int verify_checksums;        /* default 1 */
  int copy_pages;              /* default 1: the map never becomes resident memory */
} pbgi_database_options;

void pbgi_database_options_init(pbgi_database_options* options);

/* Opens the finished database at `path` read-only. `options` NULL: the defaults. On success *db
 * is a new handle; on failure it is set to NULL: PBGI_NOT_FOUND for no database, PBGI_DATA_LOSS
 * for a garbage, truncated or incomplete one, PBGI_FAILED_PRECONDITION for another format
 * version. Threads: any thread; a database may be opened by several handles and processes at
 * once. Lifetime: until pbgi_database_close(); `path` and `options` only for the call. */
pbgi_status pbgi_database_open(const char* path, const pbgi_database_options* options,
                               pbgi_database** db);
/* REQUIRES: no other call on it is running and its readers are destroyed. NULL is ignored. */
void pbgi_database_close(pbgi_database* db);

/* What the database's meta record holds. */
typedef struct pbgi_info {
  uint32_t format_version;
  uint32_t page_size;
  pbgi_channels channels;
  uint32_t leaf_size;
  float bounds_lo[3]; /* of all surfel positions */
  float bounds_hi[3];
  uint64_t point_count;
  uint64_t node_count;
  uint64_t node_pages;
  uint64_t point_pages;
  uint32_t max_depth;
  uint64_t file_bytes;
  char layout[32]; /* "coherent", ... (NUL-terminated) */
} pbgi_info;

/* Threads: any thread, concurrently with every call but pbgi_database_close(). */
pbgi_status pbgi_database_info(const pbgi_database* db, pbgi_info* info);

/* Copies the message of the last failed call made on `db` (by any thread) into buf (at most
 * size bytes, NUL-terminated; "" if none) and returns its code, PBGI_OK if none. */
pbgi_status pbgi_database_error(const pbgi_database* db, char* buf, size_t size);

/* ---- gathering the cut for one receiver --------------------------------------------------- */

/* When a node may stand for its surfels (pbgi::Cut). */
typedef struct pbgi_cut {
  float max_solid_angle; /* steradians; default 0.03; 0: every surfel on its own */
  float max_distance;    /* ignore what is farther; default +infinity */
  int cosine_weighted;   /* weigh the solid angle by the cosine to the normal; default 0 */
} pbgi_cut;

void pbgi_cut_init(pbgi_cut* cut);

/* An octree node standing for every surfel below it (pbgi::Cluster). */
typedef struct pbgi_cluster {
  float bounds_lo[3]; /* of the surfel centres below it */
  float bounds_hi[3];
  float area;           /* total surfel area */
  float sh_area[9];     /* projected area, order-2 SH (pbgi/sh.h) */
  float sh_power[3][9]; /* emitted power per colour; zero without radiance */
  uint32_t depth;       /* root = 0 */
  uint64_t first_point; /* its surfels are the global indices [first_point, +point_count) */
  uint64_t point_count;
} pbgi_cluster;

/* What a gather returned. The arrays belong to the reader: valid until its next gather or its
 * destruction. */
typedef struct pbgi_gathered {
  const pbgi_cluster* clusters;
  size_t cluster_count;
  const pbgi_surfel* surfels;
  const uint64_t* surfel_ids; /* global point index of each surfel */
  size_t surfel_count;
} pbgi_gathered;

/* One thread's access to a database: its own cache of pins and one read snapshot. */
typedef struct pbgi_reader pbgi_reader;

/* Threads: any thread, concurrently on one database; the reader then belongs to one thread at
 * a time. Lifetime: until pbgi_reader_destroy(), which must come before the database's close.
 * Make no more readers than threads (each holds an LMDB reader slot, 126 by default). */
pbgi_status pbgi_reader_create(pbgi_database* db, pbgi_reader** reader);
/* NULL is ignored. */
void pbgi_reader_destroy(pbgi_reader* reader);

/* Gathers the cut for the receiver at `position` with `normal` (need not be unit length): every
 * surfel in front of its tangent plane is in `out` once, by itself or by one cluster.
 * `cut` NULL: the defaults. PBGI_INVALID_ARGUMENT for a non-finite position or a zero or
 * non-finite normal; PBGI_DATA_LOSS for a damaged page (out is then empty).
 * Threads: the reader's one thread at a time. Lifetime: out's arrays until the reader's next
 * gather or its destruction (copy what you keep). */
pbgi_status pbgi_gather(pbgi_reader* reader, const float position[3], const float normal[3],
                        const pbgi_cut* cut, pbgi_gathered* out);

/* The message of the reader's last failed call, "" if none. Lifetime: until the reader's next
 * failing call or its destruction. Threads: the reader's thread. */
const char* pbgi_reader_error(const pbgi_reader* reader);

/* ---- shading a batch ---------------------------------------------------------------------- */

typedef struct pbgi_shade_receiver {
  float position[3];
  float normal[3];     /* need not be unit length, must not be zero */
  float reflection[3]; /* centre of the glossy lobe (world space) */
} pbgi_shade_receiver;

typedef struct pbgi_shade_result {
  float occlusion;     /* cosine-weighted, 0..1 */
  float irradiance[3]; /* integral of L cos: a uniform hemisphere of radiance L gives pi L */
  float glossy[3];     /* lobe-weighted mean radiance */
  float coverage;      /* covered fraction of the hemisphere's solid angle */
  uint32_t clusters_drawn;
  uint32_t surfels_drawn;
  uint32_t near_disks_drawn;
  uint32_t culled;
} pbgi_shade_result;

typedef enum pbgi_hitsides {
  PBGI_HITSIDES_FRONT = 0,
  PBGI_HITSIDES_BACK = 1,
  PBGI_HITSIDES_BOTH = 2
} pbgi_hitsides;

typedef enum pbgi_lobe { PBGI_LOBE_NONE = 0, PBGI_LOBE_PHONG = 1, PBGI_LOBE_GGX = 2 } pbgi_lobe;

/* Called from one worker thread at a time, at most every progress_interval_seconds, and once
 * at the end of a batch that succeeds (done == total). */
typedef void (*pbgi_shade_progress_fn)(void* user, uint64_t done, uint64_t total);

/* pbgi::ShadeOptions: the cut, the rasterizer's options (pbgi/raster.h) and the driver's. */
typedef struct pbgi_shade_options {
  pbgi_cut cut;
  int resolution;            /* micro-buffer pixels per face edge, 4..64; default 12 */
  float bias;                /* offset along the normal (world units); default 0 */
  int clamp;                 /* depth-layered compositing and clamping; default 1 */
  float raster_max_distance; /* elements farther are ignored; default +infinity */
  pbgi_hitsides hitsides;    /* default FRONT */
  float near_field_factor;   /* default 4 */
  int near_field_samples;    /* 1..16; default 4 */
  int compute_radiance;      /* irradiance and glossy; 0: occlusion only (faster); default 1 */
  pbgi_lobe lobe;            /* glossy lobe; default NONE (no glossy output) */
  float phong_exponent;      /* default 32 */
  float ggx_roughness;       /* (0, 1]; default 0.2 */
  int threads;               /* 0: all cores */
  int z_order;               /* visit receivers in Z-order (coherence); default 1 */
  pbgi_shade_progress_fn progress; /* NULL: none */
  void* progress_user;
  double progress_interval_seconds; /* default 1 */
  pbgi_cancel* cancel;              /* NULL: none */
  /* Irradiance and glossy: nodes whose parts' radiance strays from their mean are refined by
   * this times their contrast (ShadeOptions::radiance_contrast); default 16, as `pbgi shade`;
   * 0: off. */
  float radiance_contrast;
} pbgi_shade_options;

void pbgi_shade_options_init(pbgi_shade_options* options);

/* What a batch cost (a subset of pbgi::ShadeStats). */
typedef struct pbgi_shade_stats {
  uint64_t receivers;
  double seconds;        /* wall time */
  double gather_seconds; /* thread time, summed over threads */
  double raster_seconds;
  uint64_t clusters; /* gathered, summed over receivers */
  uint64_t surfels;
  uint64_t nodes_visited;
  uint64_t pages_read; /* loaded from the store into the shared cache */
} pbgi_shade_stats;

/* Shades receivers[0 .. count) into results[0 .. count) (results[i] belongs to receivers[i]) on
 * options->threads threads. Each result depends only on its receiver, the database and the
 * options. `options` NULL: the defaults; `stats` may be NULL. Errors: PBGI_INVALID_ARGUMENT
 * naming the receiver (non-finite position, zero or non-finite normal) or the option, before
 * anything is shaded; PBGI_FAILED_PRECONDITION for radiance from an occlusion-only database;
 * PBGI_CANCELLED; PBGI_DATA_LOSS for a damaged page. On error the results are incomplete.
 * Threads: any number of threads may shade from one database at once (each call makes its own
 * readers and threads: mind the cache budget of pbgi_database_options). Lifetime: receivers,
 * results and options need to live only for the call; the callbacks run during it only. */
pbgi_status pbgi_shade(pbgi_database* db, const pbgi_shade_receiver* receivers, size_t count,
                       const pbgi_shade_options* options, pbgi_shade_result* results,
                       pbgi_shade_stats* stats);

#ifdef __cplusplus
}
#endif

#endif /* PBGI_PBGI_H_ */
