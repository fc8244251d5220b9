#!/usr/bin/python3
"""What shading through Python costs over the C++ call: pbgi.Database.shade() against
pbgi::ShadeBatch() (bench/python/shade_driver.cc), same database, receivers and options.

Builds a room of surfels in numpy (five walls, two of them coloured, and spheres; radiance
baked as a plain albedo * light), picks receivers on its surfaces, and times both sides on a
warm cache (one warm-up run each) in alternating single runs, the driver a process that runs
once per line it reads, so that the shared machine's load drifts over both sides alike.
Reports the medians and the median of the pairs' ratios, and, free of the load's drift between
runs, the time each Python call spends outside ShadeBatch (Shading.stats["seconds"] is
ShadeBatch's own wall time); the checksums show that both sides computed the same results. docs/bindings.md has the figures.

    /usr/bin/python3 bench/python/shade_overhead.py --build out/release
"""
import argparse
import json
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np


def room_scene(count, seed=1):
    """positions, normals, radii, radiance of `count` surfels on a unit room with two spheres."""
    rng = np.random.default_rng(seed)
    # (origin, u, v, normal, albedo) of the walls: floor, ceiling, back, left (red), right (green)
    walls = [
        ((0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (0.7, 0.7, 0.7)),
        ((0, 0, 1), (1, 0, 0), (0, 1, 0), (0, 0, -1), (0.7, 0.7, 0.7)),
        ((0, 1, 0), (1, 0, 0), (0, 0, 1), (0, -1, 0), (0.7, 0.7, 0.7)),
        ((0, 0, 0), (0, 1, 0), (0, 0, 1), (1, 0, 0), (0.7, 0.1, 0.1)),
        ((1, 0, 0), (0, 1, 0), (0, 0, 1), (-1, 0, 0), (0.1, 0.7, 0.1)),
    ]
    spheres = [((0.3, 0.4, 0.2), 0.2, (0.8, 0.8, 0.2)), ((0.7, 0.6, 0.3), 0.3, (0.2, 0.3, 0.8))]
    areas = [1.0] * len(walls) + [4 * np.pi * r * r for _, r, _ in spheres]
    share = np.array(areas) / sum(areas)
    counts = np.maximum(1, (share * count).astype(int))
    light = np.array([0.0, 0.3, 1.0]) / np.linalg.norm([0.0, 0.3, 1.0])
    p, n, r, c = [], [], [], []
    for k, (origin, u, v, normal, albedo) in enumerate(walls):
        m = counts[k]
        s, t = rng.random(m), rng.random(m)
        p.append(np.asarray(origin) + s[:, None] * np.asarray(u) + t[:, None] * np.asarray(v))
        n.append(np.tile(normal, (m, 1)))
        r.append(np.full(m, np.sqrt(areas[k] / m / np.pi)))
        c.append(np.outer(np.full(m, max(0.1, float(np.dot(normal, light)))), albedo))
    for k, (centre, radius, albedo) in enumerate(spheres):
        m = counts[len(walls) + k]
        d = rng.normal(size=(m, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        p.append(np.asarray(centre) + radius * d)
        n.append(d)
        r.append(np.full(m, np.sqrt(areas[len(walls) + k] / m / np.pi)))
        c.append(np.outer(np.maximum(0.1, d @ light), albedo))
    return (np.concatenate(p), np.concatenate(n), np.concatenate(r), np.concatenate(c))


def find_build(root):
    for name in ("release", "ci", "dev"):
        b = root / "out" / name
        if (b / "bench/python/pbgi_shade_driver").exists() and (b / "python/pbgi").exists():
            return b
    sys.exit("no build tree with the Python module and bench/python/pbgi_shade_driver: "
             "build one (cmake --build out/release) or pass --build")


def main():
    root = pathlib.Path(__file__).resolve().parents[2]
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--build", type=pathlib.Path, help="build tree (default: out/release, ci, dev)")
    ap.add_argument("--surfels", type=int, default=300_000)
    ap.add_argument("--receivers", type=int, default=100_000)
    ap.add_argument("--mode", choices=("occlusion", "irradiance"), default="irradiance")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--pairs", type=int, default=9, help="timed runs per side, alternating")
    ap.add_argument("--json", type=pathlib.Path, help="also write the figures here")
    args = ap.parse_args()
    build = args.build or find_build(root)
    sys.path.insert(0, str(build / "python"))
    import pbgi

    work = pathlib.Path(tempfile.mkdtemp(prefix="pbgi-bench-"))
    db_path = work / "room.pbgi"
    p, n, r, c = room_scene(args.surfels)
    stats = pbgi.build(db_path, p, n, r, c)
    print(f"database: {stats['points']} surfels, {stats['nodes']} nodes, "
          f"{stats['bytes_on_disk'] / 2**20:.1f} MiB")
    rng = np.random.default_rng(7)
    pick = rng.choice(len(p), args.receivers, replace=False)
    rp = (p[pick] + 1e-3 * n[pick]).astype(np.float32)
    rn = n[pick].astype(np.float32)
    receivers_file = work / "receivers.f32"
    np.concatenate([rp, rn], axis=1).astype("<f4").tofile(receivers_file)

    db = pbgi.open(db_path)
    driver = subprocess.Popen(
        [str(build / "bench/python/pbgi_shade_driver"), str(db_path), str(receivers_file), "0",
         str(args.threads), args.mode], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    if driver.stdout.readline().strip() != "ready":
        sys.exit("the driver did not start")

    def cxx_run():
        driver.stdin.write("run\n")
        driver.stdin.flush()
        seconds, cpu, checksum = map(float, driver.stdout.readline().split())
        return seconds, cpu, round(checksum, 3)

    inner = []  # ShadeBatch's own wall time inside each Python call (Shading.stats["seconds"])

    def py_run():
        start, cpu = time.perf_counter(), time.process_time()
        res = db.shade(rp, rn, mode=args.mode, threads=args.threads)
        seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
        inner.append((seconds, res.stats["seconds"]))
        irr = res.irradiance[:, 0] if res.irradiance is not None else 0.0
        return seconds, cpu, round(float(np.sum(res.occlusion.astype(np.float64) + irr)), 3)

    py_run()  # warm-up (the driver warmed up before "ready")
    cxx, py, ratios, cpu_ratios, sums = [], [], [], [], set()
    for pair in range(args.pairs):
        # Single runs alternate, the order flipping every pair, so that the machine's load
        # drifts over both sides alike; a pair's ratio compares neighbours in time.
        first, second = (cxx_run, py_run) if pair % 2 == 0 else (py_run, cxx_run)
        a, b = first(), second()
        (c, c_cpu, s_c), (p_, p_cpu, s_p) = (a, b) if first is cxx_run else (b, a)
        cxx.append(c)
        py.append(p_)
        ratios.append(p_ / c)
        cpu_ratios.append(p_cpu / c_cpu)
        sums |= {s_c, s_p}
        print(f"pair {pair + 1}: C++ {c:.4f} s ({c_cpu:.3f} s CPU), Python {p_:.4f} s "
              f"({p_cpu:.3f} s CPU), ratio {p_ / c:.4f} (CPU {p_cpu / c_cpu:.4f})", flush=True)
    driver.stdin.close()
    driver.wait()
    mc, mp = statistics.median(cxx), statistics.median(py)
    ratio = statistics.median(ratios)
    print(f"{args.receivers} receivers, {args.mode}, {args.threads} threads, {args.pairs} pairs")
    print(f"median C++ ShadeBatch   {mc:.4f} s  ({mc / args.receivers * 1e6:.2f} us/receiver)")
    print(f"median pbgi shade()     {mp:.4f} s")
    print(f"median ratio of pairs   {ratio:.4f}  ({(ratio - 1) * 100:+.2f}%); ratio of medians "
          f"{mp / mc:.4f}")
    cpu_ratio = statistics.median(cpu_ratios)
    print(f"median CPU-time ratio   {cpu_ratio:.4f}  ({(cpu_ratio - 1) * 100:+.2f}%)")
    # The layer's own cost, free of the load's drift between runs: each call's time outside
    # ShadeBatch (argument checks, conversions, the thread, the result arrays).
    timed = inner[1:]
    overhead = [t - i for t, i in timed]
    layer = statistics.median(t / i for t, i in timed)
    print(f"layer: median {statistics.median(overhead) * 1e3:.2f} ms outside ShadeBatch per call "
          f"(max {max(overhead) * 1e3:.2f} ms); median call / ShadeBatch {layer:.5f}")
    print(f"checksums: {sorted(sums)}")
    same = len(sums) == 1
    if not same:
        print("warning: the two sides' results differ", file=sys.stderr)
    if args.json:
        args.json.write_text(json.dumps(dict(
            receivers=args.receivers, surfels=int(stats["points"]), mode=args.mode,
            threads=args.threads, cxx_seconds=cxx, python_seconds=py, pair_ratios=ratios,
            median_cxx=mc, median_python=mp, median_pair_ratio=ratio,
            cpu_ratios=cpu_ratios, median_cpu_ratio=cpu_ratio,
            python_outside_shadebatch_seconds=overhead, median_call_over_shadebatch=layer,
            same_results=same),
            indent=2) + "\n")
    subprocess.run(["rm", "-rf", str(work)], check=False)
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
