// pbgi._pbgi: the Python extension under the `pbgi` package (python/pbgi/__init__.py holds the
// user-facing functions; docs/design.md, "Bindings"). It goes through the public C++ API only.
//
// - Arrays: float32 or float64, any strides, read in place (no copy of a whole input); shapes,
//   dtypes and values are checked here, naming the argument, the expected and actual shape or
//   dtype and the first bad index.
// - Errors: an absl::Status becomes an instance of pbgi.Error's subclass for its code
//   (python/pbgi/_errors.py), carrying the library's message and code.
// - Long calls (build, shade) run with the GIL released on a thread of their own while the
//   calling thread waits; every poll interval the calling thread takes the GIL to check for
//   signals (Ctrl-C raises KeyboardInterrupt, which cancels the call) and to call the progress
//   callback, so Python code only ever runs on the calling thread.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <exception>
#include <functional>
#include <limits>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <type_traits>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "pbgi/build.h"
#include "pbgi/ply.h"
#include "pbgi/query.h"
#include "pbgi/raster.h"
#include "pbgi/shade.h"
#include "pbgi/status.h"
#include "pbgi/store.h"
#include "pybind11/functional.h"
#include "pybind11/numpy.h"
#include "pybind11/pybind11.h"
#include "pybind11/stl.h"

namespace py = pybind11;

namespace pbgi::python {
namespace {

// ---- errors ---------------------------------------------------------------------------------

// Carries a Status out of C++ into the exception translator below.
class StatusError : public std::exception {
 public:
  explicit StatusError(absl::Status s) : status_(std::move(s)), what_(status_.ToString()) {}
  const absl::Status& status() const { return status_; }
  const char* what() const noexcept override { return what_.c_str(); }

 private:
  absl::Status status_;
  std::string what_;
};

void Check(const absl::Status& s) {
  if (!s.ok()) throw StatusError(s);
}

template <typename T>
T Check(absl::StatusOr<T> s) {
  if (!s.ok()) throw StatusError(s.status());
  return std::move(s).value();
}

[[noreturn]] void Invalid(const std::string& message) {
  throw StatusError(absl::InvalidArgumentError(message));
}

// Sets the Python error for `s`: pbgi._errors.error_class(code)(message, code).
void RaiseStatus(const absl::Status& s) {
  py::object errors = py::module_::import("pbgi._errors");
  const int code = static_cast<int>(s.code());
  py::object cls = errors.attr("error_class")(code);
  py::object exc = cls(std::string(s.message()), code);
  PyErr_SetObject(cls.ptr(), exc.ptr());
}

// ---- arrays ---------------------------------------------------------------------------------

std::string ShapeString(const py::array& a) {
  std::vector<std::string> dims;
  for (py::ssize_t i = 0; i < a.ndim(); ++i) dims.push_back(std::to_string(a.shape(i)));
  return "(" + absl::StrJoin(dims, ", ") + (a.ndim() == 1 ? ",)" : ")");
}

std::string DtypeString(const py::array& a) { return py::str(a.dtype()).cast<std::string>(); }

// A read-only view of a float32 or float64 array of shape (n,) or (n, k), any strides. Holds a
// reference to the array, so it stays valid with the GIL released.
class FloatView {
 public:
  FloatView() = default;
  // `obj` must be a numpy array (or convertible to one) of shape (n, cols), or (n,) when cols
  // is 0; n must equal `rows` unless rows < 0. `like` names the argument whose n it must match.
  FloatView(py::handle obj, const char* name, int cols, py::ssize_t rows = -1,
            const char* like = nullptr) {
    if (!py::isinstance<py::array>(obj)) {
      // A list or tuple of numbers: converted to float64 (a numpy array keeps its dtype, and
      // is refused below unless it is float32 or float64).
      array_ = py::array_t<double, py::array::forcecast>::ensure(obj);
      PyErr_Clear();
      if (!array_) {
        Invalid(absl::StrFormat("%s: expected a numpy array, got %s", name,
                                py::str(py::type::of(obj).attr("__name__")).cast<std::string>()));
      }
    } else {
      array_ = py::reinterpret_borrow<py::array>(obj);
    }
    const std::string want_shape =
        cols == 0 ? (rows >= 0 ? absl::StrFormat("(%d,)", rows) : std::string("(n,)"))
                  : (rows >= 0 ? absl::StrFormat("(%d, %d)", rows, cols)
                               : absl::StrFormat("(n, %d)", cols));
    const bool shape_ok =
        cols == 0 ? array_.ndim() == 1 : array_.ndim() == 2 && array_.shape(1) == cols;
    if (!shape_ok || (rows >= 0 && array_.shape(0) != rows)) {
      Invalid(absl::StrFormat("%s: expected shape %s%s, got %s", name, want_shape,
                              like != nullptr && shape_ok ? absl::StrFormat(" like %s", like) : "",
                              ShapeString(array_)));
    }
    const py::dtype dt = array_.dtype();
    if (dt.kind() != 'f' || (dt.itemsize() != 4 && dt.itemsize() != 8) ||
        !dt.attr("isnative").cast<bool>()) {
      Invalid(absl::StrFormat("%s: expected dtype float32 or float64, got %s", name,
                              DtypeString(array_)));
    }
    f64_ = dt.itemsize() == 8;
    data_ = static_cast<const char*>(array_.data());
    n_ = array_.shape(0);
    s0_ = array_.strides(0);
    s1_ = cols == 0 ? 0 : array_.strides(1);
    name_ = name;
  }

  explicit operator bool() const { return data_ != nullptr || n_ == 0; }
  py::ssize_t size() const { return n_; }
  const char* name() const { return name_; }

  float At(py::ssize_t i, py::ssize_t j = 0) const {
    const char* p = data_ + i * s0_ + j * s1_;
    if (f64_) {
      double d;
      std::memcpy(&d, p, sizeof d);
      return static_cast<float>(d);
    }
    float f;
    std::memcpy(&f, p, sizeof f);
    return f;
  }
  glm::vec3 Vec3(py::ssize_t i) const { return glm::vec3(At(i, 0), At(i, 1), At(i, 2)); }

 private:
  py::array array_;
  const char* data_ = nullptr;
  py::ssize_t n_ = 0, s0_ = 0, s1_ = 0;
  bool f64_ = false;
  const char* name_ = "";
};

bool Finite(const glm::vec3& v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}

std::string Format(const glm::vec3& v) { return absl::StrFormat("(%g, %g, %g)", v.x, v.y, v.z); }

// Values are checked after the conversion to float (a float64 beyond float's range is Inf).
void CheckVec3s(const FloatView& v, bool nonzero) {
  for (py::ssize_t i = 0; i < v.size(); ++i) {
    const glm::vec3 x = v.Vec3(i);
    if (!Finite(x)) {
      Invalid(absl::StrFormat("%s[%d] is not finite (as float32): %s", v.name(), i, Format(x)));
    }
    if (nonzero && x == glm::vec3(0.0f)) Invalid(absl::StrFormat("%s[%d] is zero", v.name(), i));
  }
}

void CheckRadii(const FloatView& v) {
  for (py::ssize_t i = 0; i < v.size(); ++i) {
    const float r = v.At(i);
    if (!(std::isfinite(r) && r > 0.0f)) {
      Invalid(absl::StrFormat("%s[%d] = %g: a radius must be finite and > 0", v.name(), i, r));
    }
  }
}

// A new C-contiguous float32 array of shape (n,) or (n, cols).
py::array_t<float> NewFloats(py::ssize_t n, int cols) {
  if (cols == 0) return py::array_t<float>({n});
  return py::array_t<float>({n, static_cast<py::ssize_t>(cols)});
}

// ---- structured arrays of the gathered elements -----------------------------------------------

// numpy dtypes whose fields sit at the C++ structs' own offsets, so a vector of structs becomes
// an array by one copy. Each struct's fields are named here and only here: a field added to
// Cluster or Surfel (pbgi/surfel.h) that Python needs is one more line.
class StructDtype {
 public:
  StructDtype& Field(const char* name, const char* format, size_t offset) {
    names_.append(name);
    formats_.append(format);
    offsets_.append(offset);
    return *this;
  }
  py::dtype Make(size_t itemsize) const {
    py::dict d;
    d["names"] = names_;
    d["formats"] = formats_;
    d["offsets"] = offsets_;
    d["itemsize"] = itemsize;
    return py::dtype::from_args(d);
  }

 private:
  py::list names_, formats_, offsets_;
};

static_assert(sizeof(glm::vec3) == 3 * sizeof(float));
static_assert(std::is_standard_layout_v<Cluster> && std::is_trivially_copyable_v<Cluster>);
static_assert(std::is_standard_layout_v<Surfel> && std::is_trivially_copyable_v<Surfel>);

py::dtype ClusterDtype() {
  return StructDtype()
      .Field("bounds_lo", "(3,)f4", offsetof(Cluster, bounds) + offsetof(Bounds, lo))
      .Field("bounds_hi", "(3,)f4", offsetof(Cluster, bounds) + offsetof(Bounds, hi))
      .Field("area", "f4", offsetof(Cluster, area))
      .Field("sh_area", "(9,)f4", offsetof(Cluster, sh_area))
      .Field("sh_power", "(3,9)f4", offsetof(Cluster, sh_power))
      .Field("depth", "u4", offsetof(Cluster, depth))
      .Field("first_point", "u8", offsetof(Cluster, first_point))
      .Field("point_count", "u8", offsetof(Cluster, point_count))
      .Make(sizeof(Cluster));
}

py::dtype SurfelDtype() {
  return StructDtype()
      .Field("position", "(3,)f4", offsetof(Surfel, position))
      .Field("normal", "(3,)f4", offsetof(Surfel, normal))
      .Field("radius", "f4", offsetof(Surfel, radius))
      .Field("radiance", "(3,)f4", offsetof(Surfel, radiance))
      .Field("two_sided", "?", offsetof(Surfel, two_sided))
      .Field("sheet", "u1", offsetof(Surfel, sheet))
      .Field("back_radiance", "(3,)f4", offsetof(Surfel, back_radiance))
      .Make(sizeof(Surfel));
}

template <typename T>
py::array StructArray(const std::vector<T>& v, const py::dtype& dt) {
  py::array a(dt, std::vector<py::ssize_t>{static_cast<py::ssize_t>(v.size())},
              std::vector<py::ssize_t>{});
  if (!v.empty()) std::memcpy(a.mutable_data(), v.data(), v.size() * sizeof(T));
  return a;
}

// ---- running a long call with the GIL released ------------------------------------------------

// Runs work() on a thread of its own with the GIL released. Every `interval` seconds (and once
// at the end) the calling thread takes the GIL, checks for signals and calls tick(); a Python
// exception from either raises *cancel, waits for work() to stop, and is rethrown. Returns
// work()'s status otherwise.
absl::Status RunReleased(const std::function<absl::Status()>& work, std::atomic<bool>* cancel,
                         const std::function<void()>& tick, double interval) {
  std::mutex mu;
  std::condition_variable cv;
  bool finished = false;
  absl::Status result;
  std::exception_ptr py_error;
  const auto wait = std::chrono::duration<double>(std::max(interval, 0.001));
  {
    py::gil_scoped_release release;
    std::thread worker([&] {
      absl::Status s;
      try {
        s = work();
      } catch (const std::bad_alloc&) {
        s = absl::ResourceExhaustedError("out of memory");
      } catch (const std::exception& e) {
        s = absl::InternalError(e.what());
      }
      std::lock_guard<std::mutex> lock(mu);
      result = std::move(s);
      finished = true;
      cv.notify_all();
    });
    std::unique_lock<std::mutex> lock(mu);
    while (!finished) {
      cv.wait_for(lock, wait);
      if (finished) break;
      lock.unlock();
      {
        py::gil_scoped_acquire acquire;
        if (!py_error) {
          try {
            if (PyErr_CheckSignals() != 0) throw py::error_already_set();
            if (tick) tick();
          } catch (...) {
            py_error = std::current_exception();
            cancel->store(true);
          }
        }
      }
      lock.lock();
    }
    lock.unlock();
    worker.join();
  }
  if (py_error) std::rethrow_exception(py_error);
  return result;
}

// ---- building ---------------------------------------------------------------------------------

// Surfels read in place from the caller's arrays, converted to float per batch.
class ArraySource final : public SurfelSource {
 public:
  ArraySource(FloatView positions, FloatView normals, FloatView radii, FloatView radiance,
              bool has_radiance, FloatView two_sided, bool has_two_sided, FloatView back,
              bool has_back)
      : p_(std::move(positions)),
        n_(std::move(normals)),
        r_(std::move(radii)),
        c_(std::move(radiance)),
        t_(std::move(two_sided)),
        b_(std::move(back)),
        has_radiance_(has_radiance),
        has_two_sided_(has_two_sided),
        has_back_(has_back) {}
  absl::StatusOr<size_t> Next(absl::Span<Surfel> out) override {
    const size_t k = std::min(out.size(), static_cast<size_t>(p_.size()) - pos_);
    for (size_t j = 0; j < k; ++j) {
      const py::ssize_t i = static_cast<py::ssize_t>(pos_ + j);
      Surfel& s = out[j];
      s.position = p_.Vec3(i);
      s.normal = n_.Vec3(i);
      s.radius = r_.At(i);
      s.radiance = has_radiance_ ? c_.Vec3(i) : glm::vec3(0.0f);
      // A two-sided surfel without a back radiance shows its radiance on both sides.
      s.two_sided = has_two_sided_ && t_.At(i) != 0.0f;
      s.back_radiance = !s.two_sided ? glm::vec3(0.0f) : has_back_ ? b_.Vec3(i) : s.radiance;
    }
    pos_ += k;
    return k;
  }
  absl::Status Rewind() override {
    pos_ = 0;
    return absl::OkStatus();
  }
  int64_t KnownCount() const override { return p_.size(); }
  bool HasRadiance() const override { return has_radiance_; }

 private:
  FloatView p_, n_, r_, c_, t_, b_;
  bool has_radiance_, has_two_sided_, has_back_;
  size_t pos_ = 0;
};

struct BuildArgs {
  uint64_t memory_bytes = BuildOptions{}.memory_bytes;
  uint32_t leaf_size = BuildOptions{}.leaf_size;
  uint32_t page_size = kDefaultBuildPageSize;
  std::string channels;  // "", "radiance", "occlusion"
  std::string layout = "coherent";
  int threads = 0;
  std::string tmp_dir;
  bool skip_invalid = false;
  uint64_t shuffle_seed = BuildOptions{}.shuffle_seed;
  py::object progress;  // None or callable(pass, done, total)
  double progress_interval = 0.1;
};

py::dict StatsDict(const BuildStats& s) {
  py::dict d;
  d["points"] = s.points;
  d["skipped"] = s.skipped;
  d["nodes"] = s.nodes;
  d["leaves"] = s.leaves;
  d["node_pages"] = s.node_pages;
  d["point_pages"] = s.point_pages;
  d["max_depth"] = s.max_depth;
  d["max_leaf_points"] = s.max_leaf_points;
  d["bytes_on_disk"] = s.bytes_on_disk;
  d["node_page_fill"] = s.node_page_fill;
  d["seconds_bounds"] = s.seconds_bounds;
  d["seconds_sort"] = s.seconds_sort;
  d["seconds_merge"] = s.seconds_merge;
  d["seconds_finish"] = s.seconds_finish;
  d["seconds_total"] = s.seconds_total;
  d["runs_spilled"] = s.runs_spilled;
  d["spill_bytes"] = s.spill_bytes;
  d["peak_rss_bytes"] = s.peak_rss_bytes;
  d["threads"] = s.threads;
  return d;
}

py::dict Build(const std::string& path, SurfelSource& source, const BuildArgs& a) {
  BuildOptions o;
  o.memory_bytes = a.memory_bytes;
  o.leaf_size = a.leaf_size;
  o.page_size = a.page_size;
  if (a.channels.empty()) {
    o.channels = source.HasRadiance() ? Channels::kRadiance : Channels::kOcclusion;
  } else if (a.channels == "radiance") {
    o.channels = Channels::kRadiance;
  } else if (a.channels == "occlusion") {
    o.channels = Channels::kOcclusion;
  } else {
    Invalid(absl::StrFormat("channels must be 'occlusion' or 'radiance', not '%s'", a.channels));
  }
  o.layout = Check(ParseLayout(a.layout));
  if (a.threads < 0) Invalid(absl::StrFormat("threads must be >= 0, not %d", a.threads));
  o.threads = a.threads;
  o.tmp_dir = a.tmp_dir;
  o.skip_invalid = a.skip_invalid;
  o.shuffle_seed = a.shuffle_seed;
  std::atomic<bool> cancel{false};
  o.cancel = &cancel;
  // The builder reports from its threads into these; the calling thread hands them to Python.
  std::atomic<const char*> pass{nullptr};
  std::atomic<uint64_t> done{0};
  std::atomic<int64_t> total{-1};
  std::atomic<uint64_t> reports{0};
  if (!a.progress.is_none()) {
    o.progress = [&](const BuildProgress& p) {
      done.store(p.points_done);
      total.store(p.points_total);
      pass.store(p.pass);
      reports.fetch_add(1);
    };
  }
  uint64_t shown = 0;
  auto tick = [&] {
    const uint64_t r = reports.load();
    if (a.progress.is_none() || r == shown || pass.load() == nullptr) return;
    shown = r;
    a.progress(std::string(pass.load()), done.load(), total.load());
  };
  BuildStats stats;
  Check(RunReleased(
      [&]() -> absl::Status {
        PBGI_ASSIGN_OR_RETURN(stats, BuildDatabase(source, path, o));
        return absl::OkStatus();
      },
      &cancel, tick, a.progress_interval));
  if (!a.progress.is_none()) a.progress(std::string("done"), stats.points, int64_t(stats.points));
  return StatsDict(stats);
}

BuildArgs ToBuildArgs(uint64_t memory_bytes, uint32_t leaf_size, uint32_t page_size,
                      const std::string& channels, const std::string& layout, int threads,
                      const std::string& tmp_dir, bool skip_invalid, uint64_t shuffle_seed,
                      py::object progress, double progress_interval) {
  BuildArgs a;
  a.memory_bytes = memory_bytes;
  a.leaf_size = leaf_size;
  a.page_size = page_size;
  a.channels = channels;
  a.layout = layout;
  a.threads = threads;
  a.tmp_dir = tmp_dir;
  a.skip_invalid = skip_invalid;
  a.shuffle_seed = shuffle_seed;
  a.progress = std::move(progress);
  a.progress_interval = progress_interval;
  return a;
}

py::dict BuildArrays(const std::string& path, py::handle positions, py::handle normals,
                     py::handle radii, py::handle radiance, py::handle two_sided,
                     py::handle back_radiance, const BuildArgs& a) {
  FloatView p(positions, "positions", 3);
  FloatView n(normals, "normals", 3, p.size(), "positions");
  FloatView r(radii, "radii", 0, p.size(), "positions");
  FloatView c, t, b;
  if (!radiance.is_none()) c = FloatView(radiance, "radiance", 3, p.size(), "positions");
  if (!two_sided.is_none()) t = FloatView(two_sided, "two_sided", 0, p.size(), "positions");
  if (!back_radiance.is_none()) {
    if (two_sided.is_none() || radiance.is_none()) {
      Invalid("back_radiance needs two_sided and radiance (a back is a two-sided surfel's)");
    }
    b = FloatView(back_radiance, "back_radiance", 3, p.size(), "positions");
  }
  if (p.size() == 0) Invalid("positions: no surfels (an empty input is an error)");
  if (!a.skip_invalid) {
    CheckVec3s(p, false);
    CheckVec3s(n, true);
    CheckRadii(r);
    if (!radiance.is_none()) CheckVec3s(c, false);
    if (!back_radiance.is_none()) CheckVec3s(b, false);
  }
  if (a.channels == "radiance" && radiance.is_none()) {
    Invalid("channels='radiance' needs a radiance array (n, 3)");
  }
  ArraySource source(std::move(p), std::move(n), std::move(r), std::move(c), !radiance.is_none(),
                     std::move(t), !two_sided.is_none(), std::move(b), !back_radiance.is_none());
  return Build(path, source, a);
}

py::dict BuildPly(const std::string& path, const std::string& ply_path, const BuildArgs& a) {
  std::unique_ptr<SurfelSource> src = Check(OpenPly(ply_path));
  return Build(path, *src, a);
}

// ---- database, reader, info, verify -----------------------------------------------------------

py::dict MetaDict(const StoreMeta& m, const std::string& path, uint64_t file_bytes) {
  py::dict d;
  d["path"] = path;
  d["version"] = m.version;
  d["page_size"] = m.page_size;
  d["channels"] = HasRadiance(m.channels) ? "radiance" : "occlusion";
  d["back_radiance"] = m.channels == Channels::kRadianceBothSides;
  d["sh_order"] = m.sh_order;
  d["leaf_size"] = m.leaf_size;
  d["bounds_lo"] = std::vector<float>{m.bounds.lo.x, m.bounds.lo.y, m.bounds.lo.z};
  d["bounds_hi"] = std::vector<float>{m.bounds.hi.x, m.bounds.hi.y, m.bounds.hi.z};
  d["point_count"] = m.point_count;
  d["node_count"] = m.node_count;
  d["node_pages"] = m.node_pages;
  d["point_pages"] = m.point_pages;
  d["max_depth"] = m.max_depth;
  d["layout"] = m.layout;
  d["file_bytes"] = file_bytes;
  py::dict stats;
  for (const auto& [k, v] : m.stats) stats[py::str(k)] = v;
  d["stats"] = stats;
  return d;
}

py::dict Info(const std::string& path) {
  std::unique_ptr<PageStore> store = Check(PageStore::Open(path));
  return MetaDict(store->meta(), store->path(), store->FileBytes());
}

py::dict Verify(const std::string& path, bool pages_only) {
  StoreCheckReport report;
  {
    py::gil_scoped_release release;
    absl::Status s = [&]() -> absl::Status {
      PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PageStore> store, PageStore::Open(path));
      PBGI_ASSIGN_OR_RETURN(report, CheckAllPages(*store));
      if (!report.ok()) return report.first_error;
      if (!pages_only) PBGI_RETURN_IF_ERROR(VerifyTree(*store));
      return absl::OkStatus();
    }();
    if (!s.ok()) {
      py::gil_scoped_acquire acquire;
      Check(s);
    }
  }
  py::dict d;
  d["node_pages"] = report.nodes.pages;
  d["node_records"] = report.nodes.records;
  d["point_pages"] = report.points.pages;
  d["point_records"] = report.points.records;
  d["bad_pages"] = report.bad_pages;
  d["tree_checked"] = !pages_only;
  return d;
}

// Shared by the Python Database and its Readers, so that a Reader keeps its Database alive.
struct DatabaseHandle {
  std::unique_ptr<Database> db;
};

class PyReader {
 public:
  explicit PyReader(std::shared_ptr<DatabaseHandle> db)
      : db_(std::move(db)), reader_(Check(db_->db->NewReader())) {}

  py::tuple Gather(py::handle position, py::handle normal, float max_solid_angle,
                   float max_distance, bool cosine_weighted) {
    FloatView p(position, "position", 0, 3);
    FloatView n(normal, "normal", 0, 3);
    const Receiver r{glm::vec3(p.At(0), p.At(1), p.At(2)), glm::vec3(n.At(0), n.At(1), n.At(2))};
    Cut cut;
    cut.max_solid_angle = max_solid_angle;
    cut.max_distance = max_distance;
    cut.cosine_weighted = cosine_weighted;
    absl::Status s;
    Gathered g;
    {
      // A Reader belongs to one thread at a time: the lock makes sharing one between Python
      // threads safe (they wait), never a data race. The GIL is released before the lock is
      // taken and never waited for under it. The result is copied out under the lock, as the
      // next thread's gather reuses the Reader's Gathered.
      py::gil_scoped_release release;
      std::lock_guard<std::mutex> lock(mu_);
      s = reader_->Gather(r, cut, &gathered_);
      if (s.ok()) g = gathered_;
    }
    Check(s);
    static const py::dtype* cluster_dtype = new py::dtype(ClusterDtype());
    static const py::dtype* surfel_dtype = new py::dtype(SurfelDtype());
    py::array ids = py::array_t<uint64_t>({static_cast<py::ssize_t>(g.surfel_ids.size())});
    if (!g.surfel_ids.empty()) {
      std::memcpy(ids.mutable_data(), g.surfel_ids.data(), g.surfel_ids.size() * sizeof(uint64_t));
    }
    return py::make_tuple(StructArray(g.clusters, *cluster_dtype),
                          StructArray(g.surfels, *surfel_dtype), ids);
  }

  py::array ReadPoints(uint64_t first, uint64_t count) {
    std::vector<Surfel> out;
    absl::Status s;
    {
      py::gil_scoped_release release;
      std::lock_guard<std::mutex> lock(mu_);
      s = reader_->ReadPoints(first, count, &out);
    }
    Check(s);
    return StructArray(out, SurfelDtype());
  }

 private:
  std::shared_ptr<DatabaseHandle> db_;
  std::unique_ptr<Reader> reader_;
  std::mutex mu_;
  Gathered gathered_;
};

HitSides ParseHitSides(const std::string& s) {
  if (s == "front") return HitSides::kFront;
  if (s == "back") return HitSides::kBack;
  if (s == "both") return HitSides::kBoth;
  Invalid(absl::StrFormat("hitsides must be 'front', 'back' or 'both', not '%s'", s));
}

GlossyLobe ParseLobe(const std::string& s) {
  if (s == "none") return GlossyLobe::kNone;
  if (s == "phong") return GlossyLobe::kPhong;
  if (s == "ggx") return GlossyLobe::kGgx;
  Invalid(absl::StrFormat("lobe must be 'none', 'phong' or 'ggx', not '%s'", s));
}

// What pbgi.Database.shade() passes down (python/pbgi/__init__.py documents each field).
struct ShadeArgs {
  bool radiance = true;
  std::string lobe = "none";
  int threads = 0;
  float max_solid_angle = 0.03f;
  float max_distance = std::numeric_limits<float>::infinity();
  bool cosine_weighted = true;
  int resolution = 12;
  float bias = 0.0f;
  bool clamp = true;
  std::string hitsides = "front";
  float near_field_factor = 4.0f;
  int near_field_samples = 4;
  float phong_exponent = 32.0f;
  float ggx_roughness = 0.2f;
  bool z_order = true;
  py::object progress;  // None or callable(done, total)
  double progress_interval = 0.1;
  float radiance_contrast = kRecommendedRadianceContrast;
};

py::dict Shade(DatabaseHandle& h, py::handle positions, py::handle normals, py::handle reflections,
               const ShadeArgs& a) {
  FloatView p(positions, "positions", 3);
  FloatView n(normals, "normals", 3, p.size(), "positions");
  FloatView r;
  if (!reflections.is_none()) r = FloatView(reflections, "reflections", 3, p.size(), "positions");
  if (p.size() > std::numeric_limits<uint32_t>::max()) {
    Invalid(absl::StrFormat("positions: %d receivers, at most 2^32 - 1 per call", p.size()));
  }
  ShadeOptions o;
  o.cut.max_solid_angle = a.max_solid_angle;
  o.cut.max_distance = a.max_distance;
  o.cut.cosine_weighted = a.cosine_weighted;
  o.raster.resolution = a.resolution;
  o.raster.bias = a.bias;
  o.raster.clamp = a.clamp;
  o.raster.max_distance = a.max_distance;
  o.raster.hitsides = ParseHitSides(a.hitsides);
  o.raster.near_field_factor = a.near_field_factor;
  o.raster.near_field_samples = a.near_field_samples;
  o.raster.compute_radiance = a.radiance;
  o.raster.lobe = ParseLobe(a.lobe);
  o.raster.phong_exponent = a.phong_exponent;
  o.raster.ggx_roughness = a.ggx_roughness;
  if (a.threads < 0) Invalid(absl::StrFormat("threads must be >= 0, not %d", a.threads));
  o.threads = a.threads;
  o.z_order = a.z_order;
  o.radiance_contrast = a.radiance_contrast;
  if (!(a.radiance_contrast >= 0.0f) || !std::isfinite(a.radiance_contrast)) {
    Invalid(
        absl::StrFormat("radiance_contrast must be finite and >= 0, not %g", a.radiance_contrast));
  }
  Check(ValidateRasterOptions(o.raster));
  if (!(a.max_solid_angle >= 0.0f)) {
    Invalid(absl::StrFormat("max_solid_angle must be >= 0, not %g", a.max_solid_angle));
  }
  if (a.radiance && !HasRadiance(h.db->meta().channels)) {
    throw StatusError(absl::FailedPreconditionError(
        absl::StrFormat("%s stores occlusion only (built with channels='occlusion'): shade it with "
                        "mode='occlusion'",
                        h.db->path())));
  }

  const py::ssize_t count = p.size();
  std::vector<ShadeReceiver> receivers(static_cast<size_t>(count));
  for (py::ssize_t i = 0; i < count; ++i) {
    ShadeReceiver& sr = receivers[i];
    sr.position = p.Vec3(i);
    sr.normal = n.Vec3(i);
    sr.reflection = r.size() > 0 ? r.Vec3(i) : sr.normal;
    if (!Finite(sr.position)) {
      Invalid(
          absl::StrFormat("positions[%d] is not finite (as float32): %s", i, Format(sr.position)));
    }
    if (!Finite(sr.normal)) {
      Invalid(absl::StrFormat("normals[%d] is not finite (as float32): %s", i, Format(sr.normal)));
    }
    if (sr.normal == glm::vec3(0.0f)) Invalid(absl::StrFormat("normals[%d] is zero", i));
    if (r.size() > 0 && !Finite(sr.reflection)) {
      Invalid(absl::StrFormat("reflections[%d] is not finite (as float32): %s", i,
                              Format(sr.reflection)));
    }
  }

  std::vector<ShadeResult> results(static_cast<size_t>(count));
  std::atomic<bool> cancel{false};
  o.cancel = &cancel;
  std::atomic<uint64_t> done{0};
  if (!a.progress.is_none()) {
    o.progress_interval_seconds = std::max(0.0, a.progress_interval / 2);
    o.progress = [&](const ShadeProgress& sp) { done.store(sp.done); };
  }
  uint64_t shown = 0;
  auto tick = [&] {
    const uint64_t d = done.load();
    if (a.progress.is_none() || d == shown) return;
    shown = d;
    a.progress(d, static_cast<uint64_t>(count));
  };
  ShadeStats stats;
  Check(
      RunReleased([&] { return ShadeBatch(*h.db, receivers, o, absl::MakeSpan(results), &stats); },
                  &cancel, tick, a.progress_interval));
  if (!a.progress.is_none() && shown != static_cast<uint64_t>(count)) {
    a.progress(static_cast<uint64_t>(count), static_cast<uint64_t>(count));
  }

  py::array_t<float> occlusion = NewFloats(count, 0), coverage = NewFloats(count, 0);
  float* occ = occlusion.mutable_data();
  float* cov = coverage.mutable_data();
  for (py::ssize_t i = 0; i < count; ++i) {
    occ[i] = results[i].occlusion;
    cov[i] = results[i].coverage;
  }
  py::dict out;
  out["occlusion"] = occlusion;
  out["coverage"] = coverage;
  auto vec3s = [&](glm::vec3 ShadeResult::*field) {
    py::array_t<float> a3 = NewFloats(count, 3);
    float* d = a3.mutable_data();
    for (py::ssize_t i = 0; i < count; ++i) {
      const glm::vec3& v = results[i].*field;
      d[3 * i] = v.x, d[3 * i + 1] = v.y, d[3 * i + 2] = v.z;
    }
    return a3;
  };
  if (a.radiance) out["irradiance"] = vec3s(&ShadeResult::irradiance);
  if (o.raster.lobe != GlossyLobe::kNone) out["glossy"] = vec3s(&ShadeResult::glossy);
  py::dict st;
  st["receivers"] = stats.receivers;
  st["seconds"] = stats.seconds;
  st["gather_seconds"] = stats.gather_seconds;
  st["raster_seconds"] = stats.raster_seconds;
  st["clusters"] = stats.query.clusters;
  st["surfels"] = stats.query.surfels;
  st["nodes_visited"] = stats.query.nodes_visited;
  st["pages_read"] = stats.cache.shared.pages_read;
  st["threads"] = o.threads > 0 ? o.threads : DefaultShadeThreads();
  out["stats"] = st;
  return out;
}

}  // namespace

void Init(py::module_& m) {
  m.doc() = "Coherent PBGI's C++ extension; use the pbgi package, which wraps it.";

  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const StatusError& e) {
      RaiseStatus(e.status());
    }
  });

  m.attr("__version__") = PBGI_VERSION_STRING;
  m.attr("DEFAULT_PAGE_SIZE") = kDefaultBuildPageSize;
  m.def("cluster_dtype", &ClusterDtype, "The numpy dtype of gathered clusters.");
  m.def("surfel_dtype", &SurfelDtype, "The numpy dtype of surfels.");
  m.def("default_threads", &DefaultShadeThreads);

  auto build_args = [](uint64_t memory_bytes, uint32_t leaf_size, uint32_t page_size,
                       const std::string& channels, const std::string& layout, int threads,
                       const std::string& tmp_dir, bool skip_invalid, uint64_t shuffle_seed,
                       py::object progress, double progress_interval) {
    return ToBuildArgs(memory_bytes, leaf_size, page_size, channels, layout, threads, tmp_dir,
                       skip_invalid, shuffle_seed, std::move(progress), progress_interval);
  };
  m.def(
      "build_arrays",
      [build_args](const std::string& path, py::handle positions, py::handle normals,
                   py::handle radii, py::handle radiance, py::handle two_sided,
                   py::handle back_radiance, uint64_t memory_bytes, uint32_t leaf_size,
                   uint32_t page_size, const std::string& channels, const std::string& layout,
                   int threads, const std::string& tmp_dir, bool skip_invalid,
                   uint64_t shuffle_seed, py::object progress, double progress_interval) {
        return BuildArrays(
            path, positions, normals, radii, radiance, two_sided, back_radiance,
            build_args(memory_bytes, leaf_size, page_size, channels, layout, threads, tmp_dir,
                       skip_invalid, shuffle_seed, std::move(progress), progress_interval));
      },
      py::arg("path"), py::arg("positions"), py::arg("normals"), py::arg("radii"),
      py::arg("radiance"), py::arg("two_sided"), py::arg("back_radiance"), py::arg("memory_bytes"),
      py::arg("leaf_size"), py::arg("page_size"), py::arg("channels"), py::arg("layout"),
      py::arg("threads"), py::arg("tmp_dir"), py::arg("skip_invalid"), py::arg("shuffle_seed"),
      py::arg("progress"), py::arg("progress_interval"));
  m.def(
      "build_ply",
      [build_args](const std::string& path, const std::string& ply_path, uint64_t memory_bytes,
                   uint32_t leaf_size, uint32_t page_size, const std::string& channels,
                   const std::string& layout, int threads, const std::string& tmp_dir,
                   bool skip_invalid, uint64_t shuffle_seed, py::object progress,
                   double progress_interval) {
        return BuildPly(
            path, ply_path,
            build_args(memory_bytes, leaf_size, page_size, channels, layout, threads, tmp_dir,
                       skip_invalid, shuffle_seed, std::move(progress), progress_interval));
      },
      py::arg("path"), py::arg("ply_path"), py::arg("memory_bytes"), py::arg("leaf_size"),
      py::arg("page_size"), py::arg("channels"), py::arg("layout"), py::arg("threads"),
      py::arg("tmp_dir"), py::arg("skip_invalid"), py::arg("shuffle_seed"), py::arg("progress"),
      py::arg("progress_interval"));
  m.def("info", &Info, py::arg("path"));
  m.def("verify", &Verify, py::arg("path"), py::arg("pages_only") = false);

  py::class_<DatabaseHandle, std::shared_ptr<DatabaseHandle>>(m, "Database")
      .def(py::init([](const std::string& path, uint64_t cache_bytes, uint64_t reader_cache_bytes,
                       bool verify_checksums, bool copy_pages) {
             DatabaseOptions o;
             o.cache_bytes = cache_bytes;
             o.reader_cache_bytes = reader_cache_bytes;
             o.verify_checksums = verify_checksums;
             o.copy_pages = copy_pages;
             auto h = std::make_shared<DatabaseHandle>();
             {
               py::gil_scoped_release release;
               absl::StatusOr<std::unique_ptr<Database>> db = Database::Open(path, o);
               py::gil_scoped_acquire acquire;
               h->db = Check(std::move(db));
             }
             return h;
           }),
           py::arg("path"), py::arg("cache_bytes"), py::arg("reader_cache_bytes"),
           py::arg("verify_checksums"), py::arg("copy_pages"))
      .def_property_readonly("path", [](const DatabaseHandle& h) { return h.db->path(); })
      .def("info",
           [](const DatabaseHandle& h) {
             return MetaDict(h.db->meta(), h.db->path(), h.db->FileBytes());
           })
      .def("reader",
           [](std::shared_ptr<DatabaseHandle> h) { return std::make_unique<PyReader>(h); })
      .def("cache_stats",
           [](const DatabaseHandle& h) {
             const CacheStats s = h.db->TotalStats();
             py::dict d;
             d["reader_hits"] = s.reader.hits;
             d["reader_misses"] = s.reader.misses;
             d["shared_hits"] = s.shared.hits;
             d["shared_misses"] = s.shared.misses;
             d["pages_read"] = s.shared.pages_read;
             d["bytes_read"] = s.shared.bytes_read;
             d["cache_usage_bytes"] = h.db->CacheUsageBytes();
             return d;
           })
      .def(
          "shade",
          [](DatabaseHandle& h, py::handle positions, py::handle normals, py::handle reflections,
             bool radiance, const std::string& lobe, int threads, float max_solid_angle,
             float max_distance, bool cosine_weighted, int resolution, float bias, bool clamp,
             const std::string& hitsides, float near_field_factor, int near_field_samples,
             float phong_exponent, float ggx_roughness, bool z_order, py::object progress,
             double progress_interval, float radiance_contrast) {
            ShadeArgs a;
            a.radiance = radiance;
            a.lobe = lobe;
            a.threads = threads;
            a.max_solid_angle = max_solid_angle;
            a.max_distance = max_distance;
            a.cosine_weighted = cosine_weighted;
            a.resolution = resolution;
            a.bias = bias;
            a.clamp = clamp;
            a.hitsides = hitsides;
            a.near_field_factor = near_field_factor;
            a.near_field_samples = near_field_samples;
            a.phong_exponent = phong_exponent;
            a.ggx_roughness = ggx_roughness;
            a.z_order = z_order;
            a.progress = std::move(progress);
            a.progress_interval = progress_interval;
            a.radiance_contrast = radiance_contrast;
            return Shade(h, positions, normals, reflections, a);
          },
          py::arg("positions"), py::arg("normals"), py::arg("reflections"), py::arg("radiance"),
          py::arg("lobe"), py::arg("threads"), py::arg("max_solid_angle"), py::arg("max_distance"),
          py::arg("cosine_weighted"), py::arg("resolution"), py::arg("bias"), py::arg("clamp"),
          py::arg("hitsides"), py::arg("near_field_factor"), py::arg("near_field_samples"),
          py::arg("phong_exponent"), py::arg("ggx_roughness"), py::arg("z_order"),
          py::arg("progress"), py::arg("progress_interval"), py::arg("radiance_contrast"));

  py::class_<PyReader>(m, "Reader")
      .def("gather", &PyReader::Gather, py::arg("position"), py::arg("normal"),
           py::arg("max_solid_angle"), py::arg("max_distance"), py::arg("cosine_weighted"))
      .def("read_points", &PyReader::ReadPoints, py::arg("first"), py::arg("count"));
}

}  // namespace pbgi::python

PYBIND11_MODULE(_pbgi, m) { pbgi::python::Init(m); }
