#!/usr/bin/env bash
# The orientation change of 2026-11-29 (rough leaves: links only on one surface, no prior; up: concave patches a
# weaker prior): points of ground and roofs facing down before it (a95925a) and at HEAD.
# Run from the repository root with its .venv: bash tools/results/orient_down-2026-11-29.sh > tools/results/orient_down-2026-11-29.txt
exec bash tools/down_counts.sh a95925a
