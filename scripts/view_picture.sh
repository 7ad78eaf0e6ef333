#!/usr/bin/env bash
# The README's 3-D picture, docs/view.png: a synthetic drive round a loop (120 frames at 2 Hz, about
# 650 m, seed 3), mapped with vcr-odom map (VCR-Net + kiss-icp, loop closure), then drawn off-screen
# by vcr-odom view --screenshot (polyscope through EGL: no display needed). About 2 minutes on 2 cores.
#   VENV  the environment (default .venv, as make setup makes it)
#   WORK  where the drive and its result go (default runs/view-picture)
#   OUT   the picture (default docs/view.png)
set -euo pipefail
cd "$(dirname "$0")/.."

BIN=${VENV:-.venv}/bin
WORK=${WORK:-runs/view-picture}
OUT=${OUT:-docs/view.png}

"$BIN/vcr-odom" synth --out "$WORK/data" --route loop --frames 120 --rate-hz 2 --speed 15 --seed 3
rm -rf "$WORK/results"
"$BIN/vcr-odom" map --data-root "$WORK/data" --seq 00 --results-dir "$WORK/results"
"$BIN/vcr-odom" view "$WORK/results/latest" --rejected --screenshot "$OUT"
