#!/usr/bin/python3
"""What shading through Python costs over the C++ call, in instructions (valgrind's callgrind),
which the shared machine's load does not disturb: the same database and receivers as
shade_overhead.py (fewer of them: callgrind runs some 50 times slower), shaded twice on one
thread by pbgi_shade_driver and by pbgi.Database.shade(). Reports, from callgrind_annotate's
inclusive counts, the instructions inside pbgi::ShadeBatch on each side and those the Python call
adds on its calling thread (argument checks, conversions, the thread, the result arrays).
docs/bindings.md has the figures.

    /usr/bin/python3 bench/python/shade_instructions.py --build out/dev
"""
import argparse
import pathlib
import re
import shutil
import subprocess
import sys
import tempfile

import numpy as np

from shade_overhead import find_build, room_scene

_PY_SIDE = """
import sys, numpy as np
sys.path.insert(0, sys.argv[1])
import pbgi
a = np.fromfile(sys.argv[3], dtype="<f4").reshape(-1, 6)
db = pbgi.open(sys.argv[2])
for _ in range(2):
    res = db.shade(a[:, :3], a[:, 3:], mode=sys.argv[4], threads=1)
irr = res.irradiance[:, 0] if res.irradiance is not None else 0.0
print(float(np.sum(res.occlusion.astype(np.float64) + irr)))
"""


def inclusive(profile, pattern):
    """The largest inclusive Ir of the functions whose name matches `pattern`."""
    out = subprocess.run(["callgrind_annotate", "--inclusive=yes", "--threshold=100", profile],
                         capture_output=True, text=True, check=True).stdout
    best = 0
    for line in out.splitlines():
        m = re.match(r"\s*([\d,]+) \(\s*[\d.]+%\)\s+\S*?:(.*)", line)
        if m and re.match(pattern, m.group(2)):
            best = max(best, int(m.group(1).replace(",", "")))
    if best == 0:
        sys.exit(f"no function matching {pattern!r} in {profile}")
    return best


def main():
    root = pathlib.Path(__file__).resolve().parents[2]
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--build", type=pathlib.Path, help="build tree (default: out/release, ci, dev)")
    ap.add_argument("--surfels", type=int, default=300_000)
    ap.add_argument("--receivers", type=int, default=2_000)
    ap.add_argument("--mode", choices=("occlusion", "irradiance"), default="irradiance")
    args = ap.parse_args()
    if shutil.which("valgrind") is None:
        sys.exit("valgrind is not installed (apt-get install valgrind)")
    build = args.build or find_build(root)
    sys.path.insert(0, str(build / "python"))
    import pbgi

    work = pathlib.Path(tempfile.mkdtemp(prefix="pbgi-bench-"))
    try:
        db_path, receivers_file = work / "room.pbgi", work / "receivers.f32"
        p, n, r, c = room_scene(args.surfels)
        pbgi.build(db_path, p, n, r, c)
        pick = np.random.default_rng(7).choice(len(p), args.receivers, replace=False)
        rp, rn = (p[pick] + 1e-3 * n[pick]).astype(np.float32), n[pick].astype(np.float32)
        np.concatenate([rp, rn], axis=1).astype("<f4").tofile(receivers_file)
        grind = ["valgrind", "--tool=callgrind", "--quiet"]
        cxx_out, py_out = str(work / "cg.cxx"), str(work / "cg.py")
        # RUNS = 1: the driver's warm-up and one timed run, the two calls the Python side makes.
        c_sum = subprocess.run(
            grind + [f"--callgrind-out-file={cxx_out}",
                     str(build / "bench/python/pbgi_shade_driver"), str(db_path),
                     str(receivers_file), "1", "1", args.mode],
            capture_output=True, text=True, check=True).stdout.split()[-1]
        p_sum = subprocess.run(
            grind + [f"--callgrind-out-file={py_out}", sys.executable, "-c", _PY_SIDE,
                     str(build / "python"), str(db_path), str(receivers_file), args.mode],
            capture_output=True, text=True, check=True).stdout.split()[-1]
        batch = r"pbgi::ShadeBatch\(pbgi::Database&"
        c_batch, p_batch = inclusive(cxx_out, batch), inclusive(py_out, batch)
        # The pybind11 method on the calling thread; ShadeBatch runs on a thread of its own.
        p_call = inclusive(py_out, r"pbgi::python::\(anonymous namespace\)::Shade\(")
        calls = 2 * args.receivers
        print(f"{args.receivers} receivers x 2 calls, {args.mode}, 1 thread, "
              f"{args.surfels} surfels")
        print(f"C++:    ShadeBatch {c_batch:,} Ir ({c_batch / calls:,.0f} per receiver)")
        print(f"Python: ShadeBatch {p_batch:,} Ir ({p_batch / calls:,.0f} per receiver), "
              f"ratio {p_batch / c_batch:.5f}")
        print(f"Python: the call's own thread {p_call:,} Ir ({p_call / calls:,.0f} per receiver), "
              f"{p_call / p_batch * 100:.4f}% of ShadeBatch")
        total = (p_batch + p_call) / c_batch
        print(f"Python call / C++ call {total:.5f} ({(total - 1) * 100:+.3f}%)")
        print(f"checksums: C++ {float(c_sum):.3f}, Python {float(p_sum):.3f}")
        return 0 if abs(float(c_sum) - float(p_sum)) < 1e-3 * max(1.0, abs(float(c_sum))) else 1
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
