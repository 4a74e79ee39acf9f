#!/usr/bin/env bash
# How many points of a file an orientation change turned to the other side, by how steep their normal is, and how many
# face up before (BEFORE, a git revision) and at HEAD: patchcloud normals with default options (--orient up).
# Run from the repository root with its .venv:
#     bash tools/turned_sides.sh BEFORE [FILE] > tools/results/NAME.txt
# (FILE: default ../shared/data/tls-lone-star/lone-star.laz, a terrestrial scan of terrain and trees;
# tools/results/orient_tls-2026-11-29*.sh are its runs of that day.)
set -euo pipefail
BEFORE=${1:?give the revision to compare with}
ROOT=$(pwd); W=$(mktemp -d); SRC=${2:-$ROOT/../shared/data/tls-lone-star/lone-star.laz}
git worktree add -q "$W/before" "$BEFORE"
mkdir -p "$W/pkg/patchcloud" && cp "$W/before/stream/patchcloud/"* "$W/pkg/patchcloud/"
ln -s "$W/before/core" "$W/pkg/patchcloud/core" && ln -s "$W/before/stream" "$W/pkg/patchcloud/stream"
env PYTHONPATH="$W/pkg" $ROOT/.venv/bin/python -m patchcloud.stream.console normals "$SRC" "$W/old.laz" --overwrite -q
$ROOT/.venv/bin/python -m patchcloud.stream.console normals "$SRC" "$W/new.laz" --overwrite -q
echo "# $(basename "$SRC"), patchcloud normals (defaults): before $BEFORE, after $(git rev-parse --short HEAD)"
$ROOT/.venv/bin/python - "$W/old.laz" "$W/new.laz" <<'PY'
import sys, laspy, numpy as np
a, b = laspy.read(sys.argv[1]), laspy.read(sys.argv[2])
na = np.c_[a.NormalX, a.NormalY, a.NormalZ].astype(float); nb = np.c_[b.NormalX, b.NormalY, b.NormalZ].astype(float)
turned = np.einsum("ij,ij->i", na, nb) < -0.5
print(f"points {len(na):,}; turned to the other side {turned.sum():,} ({turned.mean():.1%})")
print("| |NormalZ| | points | turned | of the turned, facing up before | after |")
print("|---|---:|---:|---:|---:|")
az = np.abs(na[:, 2])
for lo, hi in ((0.7, 1.01), (0.3, 0.7), (0.0, 0.3)):
    band = (az >= lo) & (az < hi)
    m = turned & band
    print(f"| {lo:g} to {min(hi, 1):g} | {band.sum():,} | {m.sum():,} | {(na[m, 2] > 0).sum():,} | {(nb[m, 2] > 0).sum():,} |")
print(f"points with NormalZ < -0.5: before {(na[:, 2] < -0.5).sum():,}, after {(nb[:, 2] < -0.5).sum():,}")
PY
git worktree remove --force "$W/before"; rm -rf "$W"
