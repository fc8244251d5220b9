#!/usr/bin/python3
"""From a mesh to a shaded image with the pbgi Python module, numpy and matplotlib.

1. A mesh: the one given, or a small scene written here as OBJ + MTL (a ground, a red wall, a
   white torus around a blue sphere).
2. Its points: `pbgi import` samples the mesh into surfels and bakes direct light (a sun and a
   sky) into them with Embree shadow rays, to a PLY file.
3. pbgi.build_ply() builds the database; numpy reads the same PLY.
4. A pinhole camera: the surfels are projected with a z-buffer in numpy, and the surfel seen in
   each pixel becomes a receiver (its position lifted by a bias along its normal).
5. db.shade() computes occlusion and one-bounce irradiance for all of them at once.
6. matplotlib saves three panels: ambient occlusion, the baked direct light, and the indirect
   irradiance (/ pi: the colour bleeding a white surface would reflect).

    PYTHONPATH=out/release/python /usr/bin/python3 docs/examples/mesh_to_image.py \
        --pbgi out/release/tools/pbgi -o docs/examples/mesh_to_image.png
"""
import argparse
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]

try:
    import pbgi
except ImportError:  # run from a checkout: use a build tree's package
    for build in ("release", "ci", "dev"):
        if (ROOT / "out" / build / "python" / "pbgi").is_dir():
            sys.path.insert(0, str(ROOT / "out" / build / "python"))
            break
    import pbgi

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def write_scene(directory):
    """The default mesh: OBJ + MTL, z up, in a 4 x 4 box of ground."""
    verts, faces = [], []  # faces: (material, [v0, v1, v2])

    def quad(a, b, c, d, mat):
        base = len(verts)
        verts.extend([a, b, c, d])
        faces.append((mat, [base, base + 1, base + 2]))
        faces.append((mat, [base, base + 2, base + 3]))

    def surface(fn, nu, nv, mat):
        """A closed parametric surface fn(u, v) -> xyz on [0, 1)^2, wrapped in both directions."""
        base = len(verts)
        for j in range(nv):
            for i in range(nu):
                verts.append(fn(i / nu, j / nv))
        for j in range(nv):
            for i in range(nu):
                a = base + j * nu + i
                b = base + j * nu + (i + 1) % nu
                c = base + ((j + 1) % nv) * nu + (i + 1) % nu
                d = base + ((j + 1) % nv) * nu + i
                faces.append((mat, [a, b, c]))
                faces.append((mat, [a, c, d]))

    quad((-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0), "ground")
    # A red wall behind, facing the camera (+y is away from it), both sides.
    quad((-2, 1.2, 0), (2, 1.2, 0), (2, 1.2, 1.6), (-2, 1.2, 1.6), "red")
    quad((-2, 1.3, 0), (-2, 1.3, 1.6), (2, 1.3, 1.6), (2, 1.3, 0), "red")
    big, small = 0.8, 0.3

    def torus(u, v):
        a, b = 2 * np.pi * u, 2 * np.pi * v
        return ((big + small * np.cos(b)) * np.cos(a), (big + small * np.cos(b)) * np.sin(a),
                small + small * np.sin(b))

    surface(torus, 96, 48, "white")
    sphere_r = 0.45
    base = len(verts)
    nu, nv = 64, 32
    verts.append((0, 0, 0))  # south pole
    for j in range(1, nv):
        t = np.pi * j / nv
        for i in range(nu):
            a = 2 * np.pi * i / nu
            verts.append((sphere_r * np.sin(t) * np.cos(a), sphere_r * np.sin(t) * np.sin(a),
                          sphere_r - sphere_r * np.cos(t)))
    verts.append((0, 0, 2 * sphere_r))  # north pole
    ring = lambda j, i: base + 1 + (j - 1) * nu + i % nu  # noqa: E731
    for i in range(nu):
        faces.append(("blue", [base, ring(1, i + 1), ring(1, i)]))
        faces.append(("blue", [base + 1 + (nv - 1) * nu, ring(nv - 1, i), ring(nv - 1, i + 1)]))
    for j in range(1, nv - 1):
        for i in range(nu):
            faces.append(("blue", [ring(j, i), ring(j, i + 1), ring(j + 1, i + 1)]))
            faces.append(("blue", [ring(j, i), ring(j + 1, i + 1), ring(j + 1, i)]))

    (directory / "scene.mtl").write_text(
        "newmtl ground\nKd 0.7 0.7 0.7\nnewmtl red\nKd 0.8 0.15 0.1\n"
        "newmtl white\nKd 0.85 0.85 0.85\nnewmtl blue\nKd 0.15 0.3 0.8\n")
    lines = ["mtllib scene.mtl"] + [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in verts]
    current = None
    for mat, f in faces:
        if mat != current:
            lines.append(f"usemtl {mat}")
            current = mat
        lines.append("f " + " ".join(str(k + 1) for k in f))
    obj = directory / "scene.obj"
    obj.write_text("\n".join(lines) + "\n")
    return obj


def read_ply(path):
    """positions, normals, radii, radiance of a binary little-endian float PLY."""
    with open(path, "rb") as f:
        header = []
        while True:
            line = f.readline().decode("ascii").strip()
            header.append(line)
            if line == "end_header":
                break
        count = next(int(h.split()[2]) for h in header if h.startswith("element vertex"))
        props = [h.split()[2] for h in header if h.startswith("property float")]
        data = np.fromfile(f, dtype="<f4", count=count * len(props)).reshape(count, len(props))
    col = {name: i for i, name in enumerate(props)}
    take = lambda *names: data[:, [col[n] for n in names]]  # noqa: E731
    return take("x", "y", "z"), take("nx", "ny", "nz"), data[:, col["radius"]], take("r", "g", "b")


def look_at(eye, target, fov_y, width, height):
    """A function from world points (n, 3) to pixel x, y and depth, for a pinhole camera."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    f = target - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, [0, 0, 1.0])
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    scale = 0.5 * height / np.tan(np.radians(fov_y) / 2)

    def project(p):
        d = p - eye
        z = d @ f
        with np.errstate(divide="ignore", invalid="ignore"):
            x = width / 2 + scale * (d @ r) / z
            y = height / 2 - scale * (d @ u) / z
        return x, y, z, scale
    return project


def visible_surfels(project, positions, normals, radii, width, height):
    """For each pixel, the index of the nearest front-facing surfel covering it (-1: none)."""
    x, y, z, scale = project(positions)
    ok = (z > 1e-3) & (x >= -8) & (x < width + 8) & (y >= -8) & (y < height + 8)
    idx = np.nonzero(ok)[0]
    x, y, z = x[idx], y[idx], z[idx]
    # Projected radius in pixels, padded: randomly placed disks of the surface's own area leave
    # gaps, which would show what lies behind.
    reach = np.maximum(1.0, 1.6 * radii[idx] * scale / z)
    depth = np.full(width * height, np.inf)
    owner = np.full(width * height, -1, dtype=np.int64)
    span = int(np.ceil(reach.max()))
    offsets = [(dx, dy) for dy in range(-span, span + 1) for dx in range(-span, span + 1)]
    hits = []
    for dx, dy in offsets:
        sel = np.hypot(dx, dy) <= reach
        px = np.floor(x[sel]).astype(np.int64) + dx
        py = np.floor(y[sel]).astype(np.int64) + dy
        inside = (px >= 0) & (px < width) & (py >= 0) & (py < height)
        lin = py[inside] * width + px[inside]
        which = np.nonzero(sel)[0][inside]
        np.minimum.at(depth, lin, z[which])
        hits.append((lin, which))
    for lin, which in hits:
        win = z[which] <= depth[lin]
        owner[lin[win]] = idx[which[win]]
    return owner.reshape(height, width)


def find_cli(given):
    if given:
        return given
    for build in ("release", "ci", "dev"):
        cli = ROOT / "out" / build / "tools" / "pbgi"
        if cli.exists():
            return str(cli)
    found = shutil.which("pbgi")
    if found:
        return found
    sys.exit("cannot find the pbgi command: pass --pbgi out/release/tools/pbgi")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("mesh", nargs="?", help="a mesh Assimp reads (default: a scene written here)")
    ap.add_argument("--pbgi", help="the pbgi command (default: out/*/tools/pbgi, then PATH)")
    ap.add_argument("-n", "--points", default="400k", help="surfels to sample")
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--eye", default="2.6,-3.4,2.0")
    ap.add_argument("--target", default="0,0.1,0.35")
    ap.add_argument("--fov", type=float, default=40.0)
    ap.add_argument("-o", "--output", default="mesh_to_image.png")
    args = ap.parse_args()

    work = pathlib.Path(tempfile.mkdtemp(prefix="pbgi-example-"))
    try:
        mesh = pathlib.Path(args.mesh) if args.mesh else write_scene(work)
        ply, db_path = work / "points.ply", work / "scene.pbgi"
        start = time.perf_counter()
        subprocess.run([find_cli(args.pbgi), "import", str(mesh), "-o", str(ply), "-n",
                        args.points, "--sun", "0.4,-0.6,1.0,2.5,2.4,2.2", "--sky", "0.25,0.3,0.4"],
                       check=True)
        stats = pbgi.build_ply(db_path, ply, memory="256M")
        positions, normals, radii, radiance = read_ply(ply)
        print(f"imported and built {stats['points']} surfels in "
              f"{time.perf_counter() - start:.1f} s")

        eye = np.array([float(v) for v in args.eye.split(",")])
        target = np.array([float(v) for v in args.target.split(",")])
        project = look_at(eye, target, args.fov, args.width, args.height)
        # Only surfels facing the camera can be seen.
        facing = np.einsum("ij,ij->i", normals, eye - positions) > 0
        owner = visible_surfels(project, np.where(facing[:, None], positions, np.nan),
                                normals, radii, args.width, args.height)
        pixels = owner >= 0
        seen, inverse = np.unique(owner[pixels], return_inverse=True)

        db = pbgi.open(db_path)
        bias = 2.0 * float(np.median(radii))
        start = time.perf_counter()
        out = db.shade(positions[seen] + bias * normals[seen], normals[seen], threads=args.threads,
                       progress=True)
        print(f"shaded {len(seen)} receivers ({args.width}x{args.height} view) in "
              f"{time.perf_counter() - start:.2f} s: {out.stats['clusters'] / len(seen):.0f} "
              f"clusters + {out.stats['surfels'] / len(seen):.0f} surfels per receiver")

        def image(values, background):
            img = np.empty((args.height, args.width) + values.shape[1:], np.float32)
            img[...] = background
            img[pixels] = values[inverse]
            return img

        ao = image(1.0 - out.occlusion, 1.0)
        direct = image(radiance[seen], 0.0)
        indirect = image(out.irradiance / np.pi, 0.0)
        tone = lambda c: np.clip(c / (1.0 + c), 0, 1) ** (1 / 2.2)  # noqa: E731
        fig, axes = plt.subplots(1, 3, figsize=(3 * args.width / 100, args.height / 100 + 0.35),
                                 dpi=100)
        for ax, img, title in zip(axes, (ao, tone(1.6 * direct), tone(4.0 * indirect)),
                                  ("ambient occlusion", "direct light (baked)",
                                   "indirect irradiance / pi (x4)")):
            ax.imshow(img, cmap="gray" if img.ndim == 2 else None, vmin=0, vmax=1,
                      interpolation="nearest")
            ax.set_title(title, fontsize=9)
            ax.axis("off")
        fig.tight_layout(pad=0.3)
        fig.savefig(args.output)
        print(f"wrote {args.output}")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
