#!/usr/bin/env bash
# The convergence sweep of docs/eval.md ("Convergence"): for every scene, `pbgi eval` at three
# surfel densities, each over max_solid_angle x raster resolution, against one Embree
# reference; then a table (Markdown) and a chart (PNG) of MAE against the three axes.
# Usage: scripts/convergence.sh [OUT_DIR] [PBGI]   (defaults: out/convergence, out/dev/tools/pbgi)
# Scenes, densities, receivers and rays come from the environment (see below). Takes about
# 15 minutes on 2 cores with the defaults.
set -euo pipefail
out=${1:-out/convergence}
pbgi=${2:-out/dev/tools/pbgi}
scenes=${SCENES:-"cornell sphere-in-box city forest /usr/share/assimp/models/PLY/Wuson.ply /usr/share/assimp/models/OBJ/spider.obj"}
points=${POINTS:-"50000 200000 800000"}
receivers=${RECEIVERS:-300}
rays=${RAYS:-16384}
mkdir -p "$out"
for scene in $scenes; do
  tag=$(basename "$scene")
  tag=${tag%.*}
  for n in $points; do
    echo "convergence: $tag, $n surfels" >&2
    "$pbgi" eval "$scene" -o "$out/$tag-$n" --points "$n" --receivers "$receivers" \
      --rays "$rays" --ray-sweep 16 --solid-angles 0.1 0.03 0.01 0.005 --raster-res 8 12 24 \
      > "$out/$tag-$n.log" 2> "$out/$tag-$n.err"
  done
done
/usr/bin/python3 "$(dirname "$0")/convergence_chart.py" "$out"
