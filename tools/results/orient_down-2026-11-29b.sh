#!/usr/bin/env bash
# The crease links of 2026-11-29 (twenty-fourth session: surface patches more than 60 degrees apart link by the crease
# rule, thin sheets facing each other only): points of ground and roofs facing down before it (02be91c) and at dab86a6.
# Run from the repository root with its .venv: bash tools/results/orient_down-2026-11-29b.sh > tools/results/orient_down-2026-11-29b.txt
exec bash tools/down_counts.sh 02be91c
