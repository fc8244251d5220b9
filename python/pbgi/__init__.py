"""Coherent PBGI from Python: build an out-of-core point-based GI database from numpy arrays or
a PLY file, gather the octree cut for a receiver, and shade arrays of receivers (ambient
occlusion, irradiance, glossy light) on several threads with the GIL released.

    import numpy as np, pbgi
    pbgi.build("scene.pbgi", positions, normals, radii, radiance)   # (n, 3), (n, 3), (n,), (n, 3)
    db = pbgi.open("scene.pbgi")
    out = db.shade(receiver_positions, receiver_normals, threads=8)
    out.occlusion, out.irradiance                                    # (m,), (m, 3) float32

Arrays are float32 or float64 of any strides (read in place, converted to float32). Shapes,
dtypes, NaN and zero normals are refused with pbgi.InvalidArgumentError (also a ValueError)
naming the argument, what was expected and the first bad index. Every failure of the library is
a pbgi.Error carrying its message and its absl::StatusCode (``e.code``, ``e.code_name``), of
the subclass for its code (NotFoundError, DataLossError, ...). Ctrl-C during a build or a
shade raises KeyboardInterrupt and cancels the work.

Progress: ``progress=True`` shows a tqdm bar when tqdm is installed (lines on stderr
otherwise); a callable gets ``(pass_name, done, total)`` for a build and ``(done, total)`` for
a shade, on the calling thread, at most every ``progress_interval`` seconds.

Thread safety: a Database may be shared between threads (shade() and gather() from several
Python threads at once run in parallel); a Reader serializes the threads that share it.
The C++ API behind each call is documented in include/pbgi/*.h (docs/design.md, "Bindings").
"""

import math as _math
import re as _re
import sys as _sys
import threading as _threading

import numpy as _np

from . import _errors
from ._errors import (  # noqa: F401  (re-exported)
    AbortedError,
    AlreadyExistsError,
    CancelledError,
    DataLossError,
    DeadlineExceededError,
    Error,
    FailedPreconditionError,
    InternalError,
    InvalidArgumentError,
    NotFoundError,
    OutOfRangeError,
    PermissionDeniedError,
    ResourceExhaustedError,
    UnauthenticatedError,
    UnavailableError,
    UnimplementedError,
    UnknownError,
)
from . import _pbgi

__version__ = _pbgi.__version__
DEFAULT_PAGE_SIZE = _pbgi.DEFAULT_PAGE_SIZE
CLUSTER_DTYPE = _pbgi.cluster_dtype()
SURFEL_DTYPE = _pbgi.surfel_dtype()

__all__ = [
    "build", "build_ply", "open", "info", "verify", "Database", "Reader", "Gathered", "Shading",
    "Error", "CLUSTER_DTYPE", "SURFEL_DTYPE", "DEFAULT_PAGE_SIZE",
] + [name for name in dir(_errors) if name.endswith("Error")]

_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


def _bytes(value, name):
    """An int, or a string like '512M', '1.5G', '64K' (binary units), as bytes."""
    if isinstance(value, bool):
        raise InvalidArgumentError(f"{name}: expected bytes (int or '512M'), got {value!r}", 3)
    if isinstance(value, int):
        if value < 0:
            raise InvalidArgumentError(f"{name}: {value} is negative", 3)
        return value
    if isinstance(value, str):
        m = _re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([KMGT]?)i?B?\s*", value, _re.IGNORECASE)
        if m:
            return int(float(m.group(1)) * _UNITS[m.group(2).upper()])
    raise InvalidArgumentError(f"{name}: expected bytes (int or '512M'), got {value!r}", 3)


class _LineProgress:
    """Progress as lines on stderr, when tqdm is not installed."""

    def __init__(self, unit):
        self.unit = unit

    def __call__(self, *args):
        *label, done, total = args
        what = f"{label[0]}: " if label else ""
        of = f" / {total}" if total is not None and total >= 0 else ""
        print(f"pbgi: {what}{done}{of} {self.unit}", file=_sys.stderr, flush=True)

    def close(self):
        pass


class _TqdmProgress:
    """One tqdm bar per pass."""

    def __init__(self, tqdm, unit):
        self.tqdm, self.unit, self.bar, self.label = tqdm, unit, None, None

    def __call__(self, *args):
        *label, done, total = args
        label = label[0] if label else "shade"
        if label == "done":
            return self.close()
        if self.bar is None or label != self.label:
            self.close()
            self.label = label
            self.bar = self.tqdm(total=total if total is not None and total >= 0 else None,
                                 desc=label, unit=self.unit, unit_scale=True)
        self.bar.update(done - self.bar.n)

    def close(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None


def _progress(progress, unit):
    """(callback for the extension or None, object to close() at the end or None)."""
    if progress is None or progress is False:
        return None, None
    if progress is True:
        try:
            from tqdm import tqdm
        except ImportError:
            p = _LineProgress(unit)
        else:
            p = _TqdmProgress(tqdm, unit)
        return p, p
    if not callable(progress):
        raise InvalidArgumentError(f"progress: expected None, True or a callable, got {progress!r}", 3)
    return progress, None


def _build_kwargs(memory, leaf_size, page_size, channels, layout, threads, tmp_dir,
                  skip_invalid, shuffle_seed, progress_interval):
    if channels not in (None, "radiance", "occlusion"):
        raise InvalidArgumentError(
            f"channels: expected None, 'radiance' or 'occlusion', got {channels!r}", 3)
    return dict(
        memory_bytes=_bytes(memory, "memory"),
        leaf_size=int(leaf_size),
        page_size=DEFAULT_PAGE_SIZE if page_size is None else _bytes(page_size, "page_size"),
        channels=channels or "",
        layout=layout,
        threads=int(threads),
        tmp_dir=tmp_dir or "",
        skip_invalid=bool(skip_invalid),
        shuffle_seed=int(shuffle_seed),
        progress_interval=float(progress_interval),
    )


def build(path, positions, normals, radii, radiance=None, *, two_sided=None, back_radiance=None,
          memory="1G", leaf_size=16, page_size=None, channels=None, layout="coherent", threads=0,
          tmp_dir=None, skip_invalid=False, shuffle_seed=12345, progress=None,
          progress_interval=0.1):
    """Builds a database at ``path`` (a directory, replaced only when the build succeeds) from
    surfels given as arrays: positions (n, 3), normals (n, 3), radii (n,), and optionally the
    baked radiance (n, 3); float32 or float64, any strides. ``two_sided`` (n,), nonzero for a
    surfel of a thin sheet seen from both sides (a leaf, a card), and ``back_radiance`` (n, 3),
    the radiance of a two-sided surfel's back (the side its normal points away from; without
    it a two-sided surfel shows its radiance on both sides). The options are those of
    ``pbgi build``: ``memory`` bounds the build's memory (bytes or '512M'); ``leaf_size``,
    ``page_size`` (default 32752), ``layout`` ('coherent', 'postorder', 'breadth-first',
    'shuffled'), ``channels`` (None: 'radiance' when radiance is given, else 'occlusion'),
    ``threads`` (0 or 1: one thread; 2+: pipelined passes), ``tmp_dir`` for the sort's runs,
    ``skip_invalid`` (drop invalid surfels instead of refusing them).
    Returns the build's statistics as a dict (points, nodes, leaves, pages, seconds_total...).
    """
    cb, closer = _progress(progress, "points")
    try:
        if two_sided is not None:
            two_sided = _np.asarray(two_sided, dtype=_np.float32)
        return _pbgi.build_arrays(
            str(path), positions, normals, radii, radiance, two_sided, back_radiance,
            progress=cb,
            **_build_kwargs(memory, leaf_size, page_size, channels, layout, threads, tmp_dir,
                            skip_invalid, shuffle_seed, progress_interval))
    finally:
        if closer is not None:
            closer.close()


def build_ply(path, ply_path, *, memory="1G", leaf_size=16, page_size=None, channels=None,
              layout="coherent", threads=0, tmp_dir=None, skip_invalid=False,
              shuffle_seed=12345, progress=None, progress_interval=0.1):
    """Builds a database at ``path`` from a PLY point file (x y z nx ny nz radius [r g b]), as
    ``pbgi build`` does, streamed; the options are those of build() (channels None: 'radiance'
    when the file has colours)."""
    cb, closer = _progress(progress, "points")
    try:
        return _pbgi.build_ply(
            str(path), str(ply_path), progress=cb,
            **_build_kwargs(memory, leaf_size, page_size, channels, layout, threads, tmp_dir,
                            skip_invalid, shuffle_seed, progress_interval))
    finally:
        if closer is not None:
            closer.close()


def info(path):
    """The database's meta record as a dict (the keys of ``pbgi info --json``)."""
    return _pbgi.info(str(path))


def verify(path, *, pages_only=False):
    """Reads every page (checksums, kinds, numbers, counts) and, unless ``pages_only``, checks
    the tree's invariants. Returns page and record counts; raises DataLossError naming the
    first problem."""
    return _pbgi.verify(str(path), pages_only)


def open(path, *, cache="256M", reader_cache=0, verify_checksums=True, copy_pages=True):  # noqa: A001
    """Opens a finished database read-only. ``cache`` bounds the decoded pages in memory
    (bytes or '512M'); ``reader_cache`` each reader's own share (0: automatic)."""
    return Database(path, cache=cache, reader_cache=reader_cache,
                    verify_checksums=verify_checksums, copy_pages=copy_pages)


class Gathered:
    """The cut for one receiver: every surfel in front of it, once, by itself or by a cluster.

    ``clusters``: structured array of CLUSTER_DTYPE (bounds_lo, bounds_hi, area, sh_area,
    sh_power, depth, first_point, point_count); ``surfels``: of SURFEL_DTYPE (position, normal,
    radius, radiance); ``surfel_ids``: uint64 global point index of each surfel.
    """

    __slots__ = ("clusters", "surfels", "surfel_ids")

    def __init__(self, clusters, surfels, surfel_ids):
        self.clusters, self.surfels, self.surfel_ids = clusters, surfels, surfel_ids

    def __len__(self):
        return len(self.clusters) + len(self.surfels)

    def __repr__(self):
        return f"Gathered({len(self.clusters)} clusters, {len(self.surfels)} surfels)"


class Shading:
    """What shade() computed, float32 arrays with one row per receiver: ``occlusion`` (m,),
    ``coverage`` (m,), ``irradiance`` (m, 3) unless mode='occlusion' (integral of L cos: a
    uniform hemisphere of radiance L gives pi L), ``glossy`` (m, 3) with mode='glossy', and
    ``stats`` (a dict: seconds, clusters, surfels, pages read...)."""

    __slots__ = ("occlusion", "coverage", "irradiance", "glossy", "stats")

    def __init__(self, d):
        self.occlusion = d["occlusion"]
        self.coverage = d["coverage"]
        self.irradiance = d.get("irradiance")
        self.glossy = d.get("glossy")
        self.stats = d["stats"]

    def __len__(self):
        return len(self.occlusion)

    def __repr__(self):
        return f"Shading({len(self)} receivers in {self.stats['seconds']:.3f} s)"


class Reader:
    """One thread's access to a Database (its own cache level and read snapshot). Threads that
    share one take turns; make one per thread for parallel gathers (Database.gather does)."""

    def __init__(self, impl):
        self._impl = impl

    def gather(self, position, normal, *, max_solid_angle=0.03, max_distance=_math.inf,
               cosine_weighted=False):
        """The cut for the receiver at ``position`` (3,) with ``normal`` (3,)."""
        return Gathered(*self._impl.gather(position, normal, float(max_solid_angle),
                                           float(max_distance), bool(cosine_weighted)))

    def read_points(self, first, count):
        """The surfels with global point indices [first, first + count) (SURFEL_DTYPE)."""
        return self._impl.read_points(int(first), int(count))


_MODES = ("occlusion", "irradiance", "glossy")


class Database:
    """An opened database; see open(). Safe to share between threads."""

    def __init__(self, path, *, cache="256M", reader_cache=0, verify_checksums=True,
                 copy_pages=True):
        self._impl = _pbgi.Database(str(path), _bytes(cache, "cache"),
                                    _bytes(reader_cache, "reader_cache"),
                                    bool(verify_checksums), bool(copy_pages))
        self._local = _threading.local()

    @property
    def path(self):
        return self._impl.path

    def info(self):
        """The meta record as a dict (as pbgi.info())."""
        return self._impl.info()

    def cache_stats(self):
        """Cache counters of all readers so far and the shared cache's usage."""
        return self._impl.cache_stats()

    def reader(self):
        """A new Reader (one per thread)."""
        return Reader(self._impl.reader())

    def gather(self, position, normal, **cut):
        """The cut for one receiver (see Reader.gather), with a reader kept per thread."""
        r = getattr(self._local, "reader", None)
        if r is None:
            r = self._local.reader = self.reader()
        return r.gather(position, normal, **cut)

    def shade(self, positions, normals, reflections=None, *, mode="irradiance", threads=0,
              max_solid_angle=0.03, max_distance=_math.inf, cut="auto", resolution=12, bias=0.0,
              clamp=True, hitsides="front", near_field_factor=4.0, near_field_samples=4,
              lobe="phong", phong_exponent=32.0, ggx_roughness=0.2, z_order=True,
              progress=None, progress_interval=0.1, radiance_contrast=16.0):
        """Shades receivers at ``positions`` (m, 3) facing ``normals`` (m, 3) on ``threads``
        threads (0: all cores), with the GIL released; returns a Shading.

        ``mode``: 'occlusion' (fastest), 'irradiance' (and occlusion) or 'glossy' (and both),
        whose lobe ('phong' or 'ggx') is centred on ``reflections`` (m, 3; default: the
        normals). ``cut``: 'cosine' weighs the cut's solid angle by the cosine to the normal,
        'plain' does not; 'auto' is cosine but for glossy. The other options are the
        rasterizer's (include/pbgi/raster.h): micro-buffer ``resolution``, ``bias`` along the
        normal, ``hitsides`` ('front', 'back', 'both'), ... ``radiance_contrast`` (irradiance
        and glossy): nodes whose parts' radiance strays from their mean are refined by this
        times their contrast (ShadeOptions::radiance_contrast, as ``pbgi shade``; 0: off).
        """
        if mode not in _MODES:
            raise InvalidArgumentError(f"mode: expected one of {_MODES}, got {mode!r}", 3)
        if cut not in ("auto", "cosine", "plain"):
            raise InvalidArgumentError(f"cut: expected 'auto', 'cosine' or 'plain', got {cut!r}", 3)
        cosine = cut == "cosine" or (cut == "auto" and mode != "glossy")
        cb, closer = _progress(progress, "receivers")
        try:
            return Shading(self._impl.shade(
                positions, normals, reflections, radiance=mode != "occlusion",
                lobe=lobe if mode == "glossy" else "none", threads=int(threads),
                max_solid_angle=float(max_solid_angle), max_distance=float(max_distance),
                cosine_weighted=cosine, resolution=int(resolution), bias=float(bias),
                clamp=bool(clamp), hitsides=hitsides,
                near_field_factor=float(near_field_factor),
                near_field_samples=int(near_field_samples),
                phong_exponent=float(phong_exponent), ggx_roughness=float(ggx_roughness),
                z_order=bool(z_order), progress=cb, progress_interval=float(progress_interval),
                radiance_contrast=float(radiance_contrast)))
        finally:
            if closer is not None:
                closer.close()

    def __repr__(self):
        return f"pbgi.Database({self.path!r})"
