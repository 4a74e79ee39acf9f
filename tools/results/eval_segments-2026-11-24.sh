#!/usr/bin/env bash
# The runs behind eval_segments-2026-11-24.txt (from the repo root, with ../shared/data beside it).
set -euo pipefail
T="python tools/eval_segments.py"
OUT=tools/results/eval_segments-2026-11-24.txt
D=../shared/data
$T --city 1000000 --out $OUT --title "run 1: synthetic city 1M, default parameters"
$T --city 1000000 --rs 0.4 --rl 4 --threshold 0.25 --tolerance 0.35 --out $OUT --append --title "run 2: synthetic city 1M, alternative A (poles, trees)"
$T --city 1000000 --rs 0.5 --rl 2 --threshold 0.15 --tolerance 0.5 --out $OUT --append --title "run 3: synthetic city 1M, alternative B (cars)"
$T --city 4000000 --out $OUT --append --title "run 4: synthetic city 4M, default parameters"
$T --city 4000000 --rs 0.4 --rl 4 --threshold 0.25 --tolerance 0.35 --out $OUT --append --title "run 5: synthetic city 4M, alternative A"
$T --city 4000000 --rs 0.5 --rl 2 --threshold 0.15 --tolerance 0.5 --out $OUT --append --title "run 6: synthetic city 4M, alternative B"
$T $D/lidar-ign-stbarth/*.laz $D/lidar-lastools/house.laz $D/lidar-lastools/fusa.laz $D/lidar-ign-lidarhd-tiles/*.laz \
   $D/lidar-pdal-sample/sample_c.las --rs 1 --rl 5 --tolerance 1 --out $OUT --append --title "run 7: airborne LAS/LAZ, radii for 5-35 points/m2"
$T $D/labelled-isprs-filtertest/samp{11,12,61}-utm.pcd --rs 2 --rl 10 --tolerance 2 --min-points 20 --out $OUT --append \
   --title "run 8: ISPRS filter test (ground / non-ground)"
$T $D/labelled-isprs-filtertest/samp61-utm.pcd --rs 4 --rl 20 --tolerance 4 --min-points 10 --out $OUT --append \
   --title "run 9: ISPRS samp61 (0.16 points/m2), larger radii"
