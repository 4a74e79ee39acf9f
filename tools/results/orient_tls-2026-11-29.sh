#!/usr/bin/env bash
# lone-star.laz (terrestrial scan: terrain, trees), --orient up (the default): how many points the orientation change of
# 2026-11-29 (rough leaves, concave patches) turned to the other side, by how steep their normal is, and how many face
# up before (a95925a) and after (1c16fec when it was run; HEAD when run again).
# Run from the repository root with its .venv: bash tools/results/orient_tls-2026-11-29.sh > tools/results/orient_tls-2026-11-29.txt
exec bash tools/turned_sides.sh a95925a
