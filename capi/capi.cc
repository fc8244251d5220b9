// The C API (include/pbgi/pbgi.h) over the C++ one: handles own C++ objects, statuses become
// pbgi_status codes with the message kept per thread and per handle, and no exception leaves a
// call (docs/design.md, "Bindings").
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <exception>
#include <limits>
#include <memory>
#include <mutex>
#include <new>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "pbgi/build.h"
#include "pbgi/pbgi.h"
#include "pbgi/ply.h"
#include "pbgi/query.h"
#include "pbgi/shade.h"
#include "pbgi/status.h"
#include "pbgi/store.h"

#define PBGI_CAPI_STRINGIFY_(x) #x
#define PBGI_CAPI_STRINGIFY(x) PBGI_CAPI_STRINGIFY_(x)

struct pbgi_cancel {
  std::atomic<bool> raised{false};
};

struct pbgi_database {
  std::unique_ptr<pbgi::Database> db;
  mutable std::mutex error_mu;
  absl::Status last_error;
};

struct pbgi_reader {
  std::unique_ptr<pbgi::Reader> reader;
  pbgi::Gathered gathered;
  std::vector<pbgi_cluster> clusters;
  std::vector<pbgi_surfel> surfels;
  std::string last_error;
};

namespace pbgi {
namespace {

static_assert(static_cast<int>(absl::StatusCode::kUnauthenticated) == PBGI_UNAUTHENTICATED);
static_assert(static_cast<int>(absl::StatusCode::kDataLoss) == PBGI_DATA_LOSS);
static_assert(static_cast<int>(absl::StatusCode::kInvalidArgument) == PBGI_INVALID_ARGUMENT);
static_assert(std::atomic<bool>::is_always_lock_free, "pbgi_cancel_raise must be signal-safe");

// The calling thread's last failed call.
thread_local std::string t_error_message;
thread_local pbgi_status t_error_code = PBGI_OK;

pbgi_status Record(const absl::Status& s) {
  if (s.ok()) return PBGI_OK;
  t_error_code = static_cast<pbgi_status>(s.code());
  t_error_message.assign(s.message().data(), s.message().size());
  return t_error_code;
}

pbgi_status Record(pbgi_database* db, const absl::Status& s) {
  if (s.ok()) return PBGI_OK;
  if (db != nullptr) {
    std::lock_guard<std::mutex> lock(db->error_mu);
    db->last_error = s;
  }
  return Record(s);
}

pbgi_status Record(pbgi_reader* r, const absl::Status& s) {
  if (s.ok()) return PBGI_OK;
  if (r != nullptr) r->last_error.assign(s.message().data(), s.message().size());
  return Record(s);
}

// Runs `fn` (returning absl::Status) so that no exception escapes into C.
template <typename Fn>
absl::Status Guard(const char* call, Fn&& fn) {
  try {
    return fn();
  } catch (const std::bad_alloc&) {
    return absl::ResourceExhaustedError(absl::StrFormat("%s: out of memory", call));
  } catch (const std::exception& e) {
    return absl::InternalError(absl::StrFormat("%s: %s", call, e.what()));
  } catch (...) {
    return absl::InternalError(absl::StrFormat("%s: unknown exception", call));
  }
}

absl::Status NullArgument(const char* call, const char* arg) {
  return absl::InvalidArgumentError(absl::StrFormat("%s: %s is NULL", call, arg));
}

glm::vec3 Vec3(const float v[3]) { return glm::vec3(v[0], v[1], v[2]); }
void Store3(const glm::vec3& v, float out[3]) { out[0] = v.x, out[1] = v.y, out[2] = v.z; }

Surfel FromC(const pbgi_surfel& c) {
  Surfel s;
  s.position = Vec3(c.position);
  s.normal = Vec3(c.normal);
  s.radius = c.radius;
  s.radiance = Vec3(c.radiance);
  return s;
}

pbgi_surfel ToC(const Surfel& s) {
  pbgi_surfel c;
  Store3(s.position, c.position);
  Store3(s.normal, c.normal);
  c.radius = s.radius;
  Store3(s.radiance, c.radiance);
  return c;
}

// One place that copies a Cluster's named fields into the C struct: a field added to Cluster
// (pbgi/surfel.h) that C callers need gets one line here and one in pbgi_cluster.
pbgi_cluster ToC(const Cluster& c) {
  pbgi_cluster o;
  Store3(c.bounds.lo, o.bounds_lo);
  Store3(c.bounds.hi, o.bounds_hi);
  o.area = c.area;
  std::copy(c.sh_area.begin(), c.sh_area.end(), o.sh_area);
  for (int k = 0; k < 3; ++k) std::copy(c.sh_power[k].begin(), c.sh_power[k].end(), o.sh_power[k]);
  o.depth = c.depth;
  o.first_point = c.first_point;
  o.point_count = c.point_count;
  return o;
}

// The caller's callbacks as a SurfelSource, converting batches through a buffer of C surfels.
class CallbackSource final : public SurfelSource {
 public:
  explicit CallbackSource(const pbgi_surfel_source& src) : src_(src) {}
  absl::StatusOr<size_t> Next(absl::Span<Surfel> out) override {
    buffer_.resize(out.size());
    const int64_t n = src_.next(src_.user, buffer_.data(), buffer_.size());
    if (n < 0) {
      return absl::AbortedError(
          absl::StrFormat("surfel source: next() returned %d after %d surfels", n, read_));
    }
    if (static_cast<uint64_t>(n) > out.size()) {
      return absl::AbortedError(
          absl::StrFormat("surfel source: next() returned %d for a capacity of %d", n, out.size()));
    }
    for (int64_t i = 0; i < n; ++i) out[i] = FromC(buffer_[i]);
    read_ += static_cast<uint64_t>(n);
    return static_cast<size_t>(n);
  }
  absl::Status Rewind() override {
    const int rc = src_.rewind(src_.user);
    if (rc != 0) {
      return absl::AbortedError(absl::StrFormat("surfel source: rewind() returned %d", rc));
    }
    read_ = 0;
    return absl::OkStatus();
  }
  Bounds KnownBounds() const override {
    Bounds b;
    if (src_.has_bounds) {
      b.lo = Vec3(src_.bounds_lo);
      b.hi = Vec3(src_.bounds_hi);
    }
    return b;
  }
  int64_t KnownCount() const override { return src_.count; }
  bool HasRadiance() const override { return src_.has_radiance != 0; }

 private:
  pbgi_surfel_source src_;
  std::vector<pbgi_surfel> buffer_;
  uint64_t read_ = 0;
};

absl::StatusOr<BuildOptions> ToBuildOptions(const pbgi_build_options* c) {
  pbgi_build_options d;
  if (c == nullptr) {
    pbgi_build_options_init(&d);
    c = &d;
  }
  BuildOptions o;
  o.memory_bytes = c->memory_bytes;
  o.leaf_size = c->leaf_size;
  o.page_size = c->page_size;
  switch (c->channels) {
    case PBGI_CHANNELS_OCCLUSION:
      o.channels = Channels::kOcclusion;
      break;
    case PBGI_CHANNELS_RADIANCE:
      o.channels = Channels::kRadiance;
      break;
    default:
      return absl::InvalidArgumentError(
          absl::StrFormat("pbgi_build: channels %d is not a pbgi_channels", int(c->channels)));
  }
  switch (c->layout) {
    case PBGI_LAYOUT_COHERENT:
      o.layout = Layout::kCoherent;
      break;
    case PBGI_LAYOUT_POSTORDER:
      o.layout = Layout::kPostOrder;
      break;
    case PBGI_LAYOUT_BREADTH_FIRST:
      o.layout = Layout::kBreadthFirst;
      break;
    case PBGI_LAYOUT_SHUFFLED:
      o.layout = Layout::kShuffled;
      break;
    default:
      return absl::InvalidArgumentError(
          absl::StrFormat("pbgi_build: layout %d is not a pbgi_layout", int(c->layout)));
  }
  if (c->threads < 0) {
    return absl::InvalidArgumentError(absl::StrFormat("pbgi_build: threads %d < 0", c->threads));
  }
  o.threads = c->threads;
  if (c->tmp_dir != nullptr) o.tmp_dir = c->tmp_dir;
  o.skip_invalid = c->skip_invalid != 0;
  o.shuffle_seed = c->shuffle_seed;
  if (c->progress != nullptr) {
    pbgi_build_progress_fn fn = c->progress;
    void* user = c->progress_user;
    o.progress = [fn, user](const BuildProgress& p) {
      fn(user, p.pass, p.points_done, p.points_total);
    };
  }
  if (c->cancel != nullptr) o.cancel = &c->cancel->raised;
  return o;
}

void ToC(const BuildStats& s, pbgi_build_stats* out) {
  out->points = s.points;
  out->skipped = s.skipped;
  out->nodes = s.nodes;
  out->leaves = s.leaves;
  out->node_pages = s.node_pages;
  out->point_pages = s.point_pages;
  out->max_depth = s.max_depth;
  out->bytes_on_disk = s.bytes_on_disk;
  out->peak_rss_bytes = s.peak_rss_bytes;
  out->seconds = s.seconds_total;
}

Cut ToCut(const pbgi_cut* c) {
  Cut cut;
  if (c != nullptr) {
    cut.max_solid_angle = c->max_solid_angle;
    cut.max_distance = c->max_distance;
    cut.cosine_weighted = c->cosine_weighted != 0;
  }
  return cut;
}

absl::StatusOr<ShadeOptions> ToShadeOptions(const pbgi_shade_options* c) {
  pbgi_shade_options d;
  if (c == nullptr) {
    pbgi_shade_options_init(&d);
    c = &d;
  }
  ShadeOptions o;
  o.cut = ToCut(&c->cut);
  RasterOptions& r = o.raster;
  r.resolution = c->resolution;
  r.bias = c->bias;
  r.clamp = c->clamp != 0;
  r.max_distance = c->raster_max_distance;
  switch (c->hitsides) {
    case PBGI_HITSIDES_FRONT:
      r.hitsides = HitSides::kFront;
      break;
    case PBGI_HITSIDES_BACK:
      r.hitsides = HitSides::kBack;
      break;
    case PBGI_HITSIDES_BOTH:
      r.hitsides = HitSides::kBoth;
      break;
    default:
      return absl::InvalidArgumentError(
          absl::StrFormat("pbgi_shade: hitsides %d is not a pbgi_hitsides", int(c->hitsides)));
  }
  r.near_field_factor = c->near_field_factor;
  r.near_field_samples = c->near_field_samples;
  r.compute_radiance = c->compute_radiance != 0;
  switch (c->lobe) {
    case PBGI_LOBE_NONE:
      r.lobe = GlossyLobe::kNone;
      break;
    case PBGI_LOBE_PHONG:
      r.lobe = GlossyLobe::kPhong;
      break;
    case PBGI_LOBE_GGX:
      r.lobe = GlossyLobe::kGgx;
      break;
    default:
      return absl::InvalidArgumentError(
          absl::StrFormat("pbgi_shade: lobe %d is not a pbgi_lobe", int(c->lobe)));
  }
  r.phong_exponent = c->phong_exponent;
  r.ggx_roughness = c->ggx_roughness;
  if (c->threads < 0) {
    return absl::InvalidArgumentError(absl::StrFormat("pbgi_shade: threads %d < 0", c->threads));
  }
  o.threads = c->threads;
  o.z_order = c->z_order != 0;
  if (c->progress != nullptr) {
    pbgi_shade_progress_fn fn = c->progress;
    void* user = c->progress_user;
    o.progress = [fn, user](const ShadeProgress& p) { fn(user, p.done, p.total); };
  }
  o.progress_interval_seconds = c->progress_interval_seconds;
  if (c->cancel != nullptr) o.cancel = &c->cancel->raised;
  o.radiance_contrast = c->radiance_contrast;
  return o;
}

absl::Status Verify(const std::string& path) {
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PageStore> store, PageStore::Open(path));
  PBGI_ASSIGN_OR_RETURN(StoreCheckReport report, CheckAllPages(*store));
  if (!report.ok()) return report.first_error;
  return VerifyTree(*store);
}

}  // namespace
}  // namespace pbgi

using pbgi::Guard;
using pbgi::NullArgument;
using pbgi::Record;

extern "C" {

const char* pbgi_status_name(pbgi_status status) {
  switch (status) {
    case PBGI_OK:
      return "OK";
    case PBGI_CANCELLED:
      return "CANCELLED";
    case PBGI_UNKNOWN:
      return "UNKNOWN";
    case PBGI_INVALID_ARGUMENT:
      return "INVALID_ARGUMENT";
    case PBGI_DEADLINE_EXCEEDED:
      return "DEADLINE_EXCEEDED";
    case PBGI_NOT_FOUND:
      return "NOT_FOUND";
    case PBGI_ALREADY_EXISTS:
      return "ALREADY_EXISTS";
    case PBGI_PERMISSION_DENIED:
      return "PERMISSION_DENIED";
    case PBGI_RESOURCE_EXHAUSTED:
      return "RESOURCE_EXHAUSTED";
    case PBGI_FAILED_PRECONDITION:
      return "FAILED_PRECONDITION";
    case PBGI_ABORTED:
      return "ABORTED";
    case PBGI_OUT_OF_RANGE:
      return "OUT_OF_RANGE";
    case PBGI_UNIMPLEMENTED:
      return "UNIMPLEMENTED";
    case PBGI_INTERNAL:
      return "INTERNAL";
    case PBGI_UNAVAILABLE:
      return "UNAVAILABLE";
    case PBGI_DATA_LOSS:
      return "DATA_LOSS";
    case PBGI_UNAUTHENTICATED:
      return "UNAUTHENTICATED";
  }
  return "UNKNOWN";
}

const char* pbgi_last_error(void) { return pbgi::t_error_message.c_str(); }
pbgi_status pbgi_last_error_code(void) { return pbgi::t_error_code; }
void pbgi_clear_error(void) {
  pbgi::t_error_code = PBGI_OK;
  pbgi::t_error_message.clear();
}

const char* pbgi_version(void) { return PBGI_CAPI_STRINGIFY(PBGI_VERSION_STRING); }

pbgi_cancel* pbgi_cancel_create(void) { return new (std::nothrow) pbgi_cancel; }
void pbgi_cancel_raise(pbgi_cancel* c) {
  if (c != nullptr) c->raised.store(true);
}
void pbgi_cancel_reset(pbgi_cancel* c) {
  if (c != nullptr) c->raised.store(false);
}
int pbgi_cancel_raised(const pbgi_cancel* c) { return c != nullptr && c->raised.load() ? 1 : 0; }
void pbgi_cancel_destroy(pbgi_cancel* c) { delete c; }

void pbgi_build_options_init(pbgi_build_options* c) {
  if (c == nullptr) return;
  const pbgi::BuildOptions d;
  std::memset(c, 0, sizeof(*c));
  c->memory_bytes = d.memory_bytes;
  c->leaf_size = d.leaf_size;
  c->page_size = d.page_size;
  c->channels = PBGI_CHANNELS_RADIANCE;
  c->layout = PBGI_LAYOUT_COHERENT;
  c->threads = d.threads;
  c->tmp_dir = nullptr;
  c->skip_invalid = d.skip_invalid ? 1 : 0;
  c->shuffle_seed = d.shuffle_seed;
}

pbgi_status pbgi_build(const pbgi_surfel_source* source, const char* path,
                       const pbgi_build_options* options, pbgi_build_stats* stats) {
  return Record(Guard("pbgi_build", [&]() -> absl::Status {
    if (source == nullptr) return NullArgument("pbgi_build", "source");
    if (source->next == nullptr) return NullArgument("pbgi_build", "source->next");
    if (source->rewind == nullptr) return NullArgument("pbgi_build", "source->rewind");
    if (path == nullptr) return NullArgument("pbgi_build", "path");
    PBGI_ASSIGN_OR_RETURN(pbgi::BuildOptions o, pbgi::ToBuildOptions(options));
    pbgi::CallbackSource src(*source);
    PBGI_ASSIGN_OR_RETURN(pbgi::BuildStats s, pbgi::BuildDatabase(src, path, o));
    if (stats != nullptr) pbgi::ToC(s, stats);
    return absl::OkStatus();
  }));
}

pbgi_status pbgi_build_ply(const char* ply_path, const char* path,
                           const pbgi_build_options* options, pbgi_build_stats* stats) {
  return Record(Guard("pbgi_build_ply", [&]() -> absl::Status {
    if (ply_path == nullptr) return NullArgument("pbgi_build_ply", "ply_path");
    if (path == nullptr) return NullArgument("pbgi_build_ply", "path");
    PBGI_ASSIGN_OR_RETURN(pbgi::BuildOptions o, pbgi::ToBuildOptions(options));
    PBGI_ASSIGN_OR_RETURN(std::unique_ptr<pbgi::SurfelSource> src, pbgi::OpenPly(ply_path));
    PBGI_ASSIGN_OR_RETURN(pbgi::BuildStats s, pbgi::BuildDatabase(*src, path, o));
    if (stats != nullptr) pbgi::ToC(s, stats);
    return absl::OkStatus();
  }));
}

pbgi_status pbgi_verify(const char* path) {
  return Record(Guard("pbgi_verify", [&]() -> absl::Status {
    if (path == nullptr) return NullArgument("pbgi_verify", "path");
    return pbgi::Verify(path);
  }));
}

void pbgi_database_options_init(pbgi_database_options* c) {
  if (c == nullptr) return;
  const pbgi::DatabaseOptions d;
  std::memset(c, 0, sizeof(*c));
  c->cache_bytes = d.cache_bytes;
  c->reader_cache_bytes = d.reader_cache_bytes;
  c->verify_checksums = d.verify_checksums ? 1 : 0;
  c->copy_pages = d.copy_pages ? 1 : 0;
}

pbgi_status pbgi_database_open(const char* path, const pbgi_database_options* options,
                               pbgi_database** db) {
  if (db != nullptr) *db = nullptr;
  return Record(Guard("pbgi_database_open", [&]() -> absl::Status {
    if (path == nullptr) return NullArgument("pbgi_database_open", "path");
    if (db == nullptr) return NullArgument("pbgi_database_open", "db");
    pbgi::DatabaseOptions o;
    if (options != nullptr) {
      o.cache_bytes = options->cache_bytes;
      o.reader_cache_bytes = options->reader_cache_bytes;
      o.verify_checksums = options->verify_checksums != 0;
      o.copy_pages = options->copy_pages != 0;
    }
    PBGI_ASSIGN_OR_RETURN(std::unique_ptr<pbgi::Database> d, pbgi::Database::Open(path, o));
    auto handle = std::make_unique<pbgi_database>();
    handle->db = std::move(d);
    *db = handle.release();
    return absl::OkStatus();
  }));
}

void pbgi_database_close(pbgi_database* db) { delete db; }

pbgi_status pbgi_database_info(const pbgi_database* db, pbgi_info* info) {
  return Record(Guard("pbgi_database_info", [&]() -> absl::Status {
    if (db == nullptr) return NullArgument("pbgi_database_info", "db");
    if (info == nullptr) return NullArgument("pbgi_database_info", "info");
    const pbgi::StoreMeta& m = db->db->meta();
    std::memset(info, 0, sizeof(*info));
    info->format_version = m.version;
    info->page_size = m.page_size;
    info->channels =
        pbgi::HasRadiance(m.channels) ? PBGI_CHANNELS_RADIANCE : PBGI_CHANNELS_OCCLUSION;
    info->leaf_size = m.leaf_size;
    pbgi::Store3(m.bounds.lo, info->bounds_lo);
    pbgi::Store3(m.bounds.hi, info->bounds_hi);
    info->point_count = m.point_count;
    info->node_count = m.node_count;
    info->node_pages = m.node_pages;
    info->point_pages = m.point_pages;
    info->max_depth = m.max_depth;
    info->file_bytes = db->db->FileBytes();
    std::snprintf(info->layout, sizeof(info->layout), "%s", m.layout.c_str());
    return absl::OkStatus();
  }));
}

pbgi_status pbgi_database_error(const pbgi_database* db, char* buf, size_t size) {
  if (db == nullptr) {
    if (buf != nullptr && size > 0) buf[0] = '\0';
    return PBGI_OK;
  }
  std::lock_guard<std::mutex> lock(db->error_mu);
  if (buf != nullptr && size > 0) {
    const absl::string_view m = db->last_error.message();
    const size_t n = std::min(size - 1, m.size());
    std::memcpy(buf, m.data(), n);
    buf[n] = '\0';
  }
  return static_cast<pbgi_status>(db->last_error.code());
}

void pbgi_cut_init(pbgi_cut* c) {
  if (c == nullptr) return;
  const pbgi::Cut d;
  c->max_solid_angle = d.max_solid_angle;
  c->max_distance = d.max_distance;
  c->cosine_weighted = d.cosine_weighted ? 1 : 0;
}

pbgi_status pbgi_reader_create(pbgi_database* db, pbgi_reader** reader) {
  if (reader != nullptr) *reader = nullptr;
  return Record(db, Guard("pbgi_reader_create", [&]() -> absl::Status {
                  if (db == nullptr) return NullArgument("pbgi_reader_create", "db");
                  if (reader == nullptr) return NullArgument("pbgi_reader_create", "reader");
                  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<pbgi::Reader> r, db->db->NewReader());
                  auto handle = std::make_unique<pbgi_reader>();
                  handle->reader = std::move(r);
                  *reader = handle.release();
                  return absl::OkStatus();
                }));
}

void pbgi_reader_destroy(pbgi_reader* reader) { delete reader; }

pbgi_status pbgi_gather(pbgi_reader* reader, const float position[3], const float normal[3],
                        const pbgi_cut* cut, pbgi_gathered* out) {
  if (out != nullptr) *out = pbgi_gathered{};
  return Record(reader, Guard("pbgi_gather", [&]() -> absl::Status {
                  if (reader == nullptr) return NullArgument("pbgi_gather", "reader");
                  if (position == nullptr) return NullArgument("pbgi_gather", "position");
                  if (normal == nullptr) return NullArgument("pbgi_gather", "normal");
                  if (out == nullptr) return NullArgument("pbgi_gather", "out");
                  reader->clusters.clear();
                  reader->surfels.clear();
                  const pbgi::Receiver r{pbgi::Vec3(position), pbgi::Vec3(normal)};
                  absl::Status s = reader->reader->Gather(r, pbgi::ToCut(cut), &reader->gathered);
                  if (!s.ok()) {
                    reader->gathered.Clear();
                    return s;
                  }
                  const pbgi::Gathered& g = reader->gathered;
                  reader->clusters.reserve(g.clusters.size());
                  for (const pbgi::Cluster& c : g.clusters)
                    reader->clusters.push_back(pbgi::ToC(c));
                  reader->surfels.reserve(g.surfels.size());
                  for (const pbgi::Surfel& s : g.surfels) reader->surfels.push_back(pbgi::ToC(s));
                  out->clusters = reader->clusters.data();
                  out->cluster_count = reader->clusters.size();
                  out->surfels = reader->surfels.data();
                  out->surfel_ids = g.surfel_ids.data();
                  out->surfel_count = reader->surfels.size();
                  return absl::OkStatus();
                }));
}

const char* pbgi_reader_error(const pbgi_reader* reader) {
  return reader == nullptr ? "" : reader->last_error.c_str();
}

void pbgi_shade_options_init(pbgi_shade_options* c) {
  if (c == nullptr) return;
  const pbgi::ShadeOptions d;
  std::memset(c, 0, sizeof(*c));
  pbgi_cut_init(&c->cut);
  c->resolution = d.raster.resolution;
  c->bias = d.raster.bias;
  c->clamp = d.raster.clamp ? 1 : 0;
  c->raster_max_distance = d.raster.max_distance;
  c->hitsides = PBGI_HITSIDES_FRONT;
  c->near_field_factor = d.raster.near_field_factor;
  c->near_field_samples = d.raster.near_field_samples;
  c->compute_radiance = d.raster.compute_radiance ? 1 : 0;
  c->lobe = PBGI_LOBE_NONE;
  c->phong_exponent = d.raster.phong_exponent;
  c->ggx_roughness = d.raster.ggx_roughness;
  c->threads = d.threads;
  c->z_order = d.z_order ? 1 : 0;
  c->progress_interval_seconds = d.progress_interval_seconds;
  c->radiance_contrast = pbgi::kRecommendedRadianceContrast;
}

pbgi_status pbgi_shade(pbgi_database* db, const pbgi_shade_receiver* receivers, size_t count,
                       const pbgi_shade_options* options, pbgi_shade_result* results,
                       pbgi_shade_stats* stats) {
  return Record(
      db, Guard("pbgi_shade", [&]() -> absl::Status {
        if (db == nullptr) return NullArgument("pbgi_shade", "db");
        if (count > 0 && receivers == nullptr) return NullArgument("pbgi_shade", "receivers");
        if (count > 0 && results == nullptr) return NullArgument("pbgi_shade", "results");
        if (count > std::numeric_limits<uint32_t>::max()) {
          return absl::InvalidArgumentError(
              absl::StrFormat("pbgi_shade: %d receivers, at most 2^32 - 1 per batch", count));
        }
        PBGI_ASSIGN_OR_RETURN(pbgi::ShadeOptions o, pbgi::ToShadeOptions(options));
        if (o.raster.compute_radiance && !pbgi::HasRadiance(db->db->meta().channels)) {
          return absl::FailedPreconditionError(absl::StrFormat(
              "pbgi_shade: %s stores occlusion only: set compute_radiance = 0", db->db->path()));
        }
        std::vector<pbgi::ShadeReceiver> in(count);
        for (size_t i = 0; i < count; ++i) {
          in[i].position = pbgi::Vec3(receivers[i].position);
          in[i].normal = pbgi::Vec3(receivers[i].normal);
          in[i].reflection = pbgi::Vec3(receivers[i].reflection);
        }
        std::vector<pbgi::ShadeResult> out(count);
        pbgi::ShadeStats s;
        PBGI_RETURN_IF_ERROR(pbgi::ShadeBatch(*db->db, in, o, absl::MakeSpan(out), &s));
        for (size_t i = 0; i < count; ++i) {
          const pbgi::ShadeResult& r = out[i];
          pbgi_shade_result& c = results[i];
          c.occlusion = r.occlusion;
          pbgi::Store3(r.irradiance, c.irradiance);
          pbgi::Store3(r.glossy, c.glossy);
          c.coverage = r.coverage;
          c.clusters_drawn = r.clusters_drawn;
          c.surfels_drawn = r.surfels_drawn;
          c.near_disks_drawn = r.near_disks_drawn;
          c.culled = r.culled;
        }
        if (stats != nullptr) {
          stats->receivers = s.receivers;
          stats->seconds = s.seconds;
          stats->gather_seconds = s.gather_seconds;
          stats->raster_seconds = s.raster_seconds;
          stats->clusters = s.query.clusters;
          stats->surfels = s.query.surfels;
          stats->nodes_visited = s.query.nodes_visited;
          stats->pages_read = s.cache.shared.pages_read;
        }
        return absl::OkStatus();
      }));
}

}  // extern "C"
