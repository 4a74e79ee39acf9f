#!/usr/bin/env bash
# lone-star.laz (terrestrial scan: terrain, trees), --orient up (the default): how many points the crease links of
# 2026-11-29 (twenty-fourth session) turned to the other side, by how steep their normal is, and how many face up
# before (02be91c) and after (dab86a6 when it was run; HEAD when run again).
# Run from the repository root with its .venv: bash tools/results/orient_tls-2026-11-29b.sh > tools/results/orient_tls-2026-11-29b.txt
exec bash tools/turned_sides.sh 02be91c
