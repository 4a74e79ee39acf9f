#!/usr/bin/env bash
# The fold check of 2026-11-29 (core.tiles.folded: surface points where their quadric folds get moment normals):
# points of ground and roofs facing down before it (b6c8cd7~1) and at HEAD.
# Run from the repository root with its .venv: bash tools/results/fold_check-2026-11-29.sh > tools/results/fold_check-2026-11-29.txt
exec bash tools/down_counts.sh b6c8cd7~1
