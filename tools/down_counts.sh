#!/usr/bin/env bash
# Ground (class 2) and roof (6) points with NormalZ < -0.5, NormalMethod shares, and the share of normals that moved by
# more than 1 degree: patchcloud normals (default options) at BEFORE (a git revision) and at HEAD, on the real aerial
# files of ../shared/data and the embedded tile.  Run from the repository root with its .venv:
#     bash tools/down_counts.sh BEFORE > tools/results/NAME.txt
# (tools/results/fold_check-2026-11-29.sh and orient_down-2026-11-29.sh are its runs of that day.)
set -euo pipefail
BEFORE=${1:?give the revision to compare with}
ROOT=$(pwd); D=$ROOT/../shared/data; W=$(mktemp -d)
git worktree add -q "$W/before" "$BEFORE"
mkdir -p "$W/pkg/patchcloud" && cp "$W/before/stream/patchcloud/"* "$W/pkg/patchcloud/"
ln -s "$W/before/core" "$W/pkg/patchcloud/core" && ln -s "$W/before/stream" "$W/pkg/patchcloud/stream"
echo "# before: $BEFORE; after: $(git rev-parse --short HEAD); columns: down = {class: points with NormalZ < -0.5}, methods % = NormalMethod 0..4"
for src in $D/lidar-lastools/house.laz $D/lidar-ign-stbarth/St_Barth_RGAF09_UTM20N_IGN_1988_SB_subset_100m.laz \
           $D/lidar-ign-km-tile-decimated/test_semis_2023_0292_6833_LA93_IGN69.laz $D/lidar-lastools/fusa.laz \
           $D/lidar-pdal-sample/sample_c.las $ROOT/data/test_data_77055_627760_LA93_IGN69.laz; do
  env PYTHONPATH="$W/pkg" $ROOT/.venv/bin/python -m patchcloud.stream.console normals $src "$W/old.laz" --overwrite -q
  $ROOT/.venv/bin/python -m patchcloud.stream.console normals $src "$W/new.laz" --overwrite -q
  $ROOT/.venv/bin/python - "$src" "$W/old.laz" "$W/new.laz" <<'PY'
import sys, laspy, numpy as np
a, b = laspy.read(sys.argv[2]), laspy.read(sys.argv[3])
c = np.asarray(a.classification)
out = []
for name, x in (("before", a), ("after", b)):
    nz, m = np.asarray(x.NormalZ), np.asarray(x.NormalMethod)
    down = {int(k): int(((c == k) & (nz < -0.5)).sum()) for k in (2, 6) if (c == k).any()}
    out.append(f"{name}: down {down} methods % {np.round(100 * np.bincount(m, minlength=5) / m.size, 2).tolist()}")
cos = np.abs(np.einsum("ij,ij->i", np.c_[a.NormalX, a.NormalY, a.NormalZ], np.c_[b.NormalX, b.NormalY, b.NormalZ]))
print(sys.argv[1].split("/")[-1], f"{len(c):,} points |", " | ".join(out), f"| moved > 1 deg {100 * np.mean(cos < np.cos(np.radians(1))):.2f} %")
PY
done
git worktree remove --force "$W/before"; rm -rf "$W"
