#!/usr/bin/env python3
"""Table and chart of scripts/convergence.sh: MAE against max_solid_angle, raster resolution and
surfel density, per scene, from the eval.json files that `pbgi eval` wrote."""
import glob
import json
import os
import re
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def load(out):
    runs = {}
    for path in sorted(glob.glob(os.path.join(out, "*", "eval.json"))):
        with open(path) as f:
            j = json.load(f)
        scene = os.path.basename(os.path.dirname(path)).rsplit("-", 1)[0]
        n = int(j.get("points", j.get("surfels", 0)))
        for row in j["rows"]:
            if row["method"] != "pbgi":
                continue
            m = re.match(r"msa ([0-9.e-]+) res (\d+)", row["setting"])
            if not m:
                continue
            runs.setdefault(scene, {})[(n, float(m.group(1)), int(m.group(2)))] = (
                row["mae"], row.get("bias", float("nan")))
    return runs


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else "out/convergence"
    runs = load(out)
    if not runs:
        sys.exit("convergence_chart: no eval.json under " + out)
    scenes = sorted(runs)
    lines = ["| scene | surfels | res | msa 0.1 | 0.03 | 0.01 | 0.005 |", "|---|---|---|---|---|---|---|"]
    for s in scenes:
        keys = runs[s]
        for n in sorted({k[0] for k in keys}):
            for res in sorted({k[2] for k in keys}):
                cells = []
                for msa in (0.1, 0.03, 0.01, 0.005):
                    v = keys.get((n, msa, res))
                    cells.append("%.4f (%+.4f)" % v if v else "")
                lines.append("| %s | %d | %d | %s |" % (s, n, res, " | ".join(cells)))
    table = "\n".join(lines) + "\n"
    with open(os.path.join(out, "convergence.md"), "w") as f:
        f.write("MAE (bias) against the Embree reference\n\n" + table)
    print(table)
    cols = min(3, len(scenes))
    rows = (len(scenes) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.4 * rows), squeeze=False)
    for ax, s in zip(axes.flat, scenes):
        keys = runs[s]
        for ci, n in enumerate(sorted({k[0] for k in keys})):
            for res, style in ((8, ":"), (12, "-o"), (24, "--")):
                pts = sorted((msa, v[0]) for (nn, msa, r), v in keys.items() if nn == n and r == res)
                if pts:
                    ax.plot([p[0] for p in pts], [p[1] for p in pts], style, ms=3, color="C%d" % ci,
                            label="%dk surfels, res %d" % (round(n / 1000), res))
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.invert_xaxis()
        ax.set_title(s)
        ax.set_xlabel("max solid angle (sr), finer to the right")
        ax.set_ylabel("occlusion MAE")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6)
    for ax in list(axes.flat)[len(scenes):]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(os.path.join(out, "convergence.png"), dpi=90)
    print("wrote %s/convergence.md and %s/convergence.png" % (out, out))


if __name__ == "__main__":
    main()
