#!/usr/bin/env bash
# The loop-closure table of docs/benchmarks.md: vcr-odom map against its odometry on unseen
# synthetic drives that come back (seeds 801-810: nothing was tuned on them; the verification and the
# drift bound were chosen on seeds 501-506 and the KITTI sample), one per sensor model, plus streets
# of identical blocks (the false-closure trap) and a long street without revisits.
#
#   bash benchmarks/loop_drives.sh [WORK_DIR] [--kiss-slam] > table.md
#
# WORK_DIR (default runs/loop-drives) receives the drives and loops.json. --kiss-slam adds KISS-SLAM's
# ATE, closures and time (needs vcr-odom[slam]). Times are of one process running everything in turn.
set -euo pipefail
cd "$(dirname "$0")/.."
WORK=runs/loop-drives
if [ $# -gt 0 ] && [ "${1#--}" = "$1" ]; then WORK=$1; shift; fi
PY=${PYTHON:-.venv/bin/python}
VCR=${VCR:-.venv/bin/vcr-odom}
mkdir -p "$WORK"

DRIVES=(  # seed frames|synth options|what the table calls it
  "801 800|--sensor hdl64 --route loop --scene suburban|HDL-64E loop"
  "802 800|--sensor hdl32 --route return --scene suburban|HDL-32E return (180°)"
  "803 800|--sensor vlp16 --route figure8 --scene oldtown|VLP-16 figure eight"
  "804 800|--sensor os128 --route loop --scene highway|OS1-128 loop, highway"
  "805 800|--sensor avia --route return --scene suburban|Avia return (180°)"
  "806 800|--sensor mid360 --route loop --scene oldtown|Mid-360 loop"
  "807 800|--sensor avia --route figure8 --scene avenue|Avia figure eight"
  "808 800|--sensor hdl64 --route blocks --scene suburban|HDL-64E identical blocks"
  "809 600|--sensor vlp16 --route blocks --scene oldtown|VLP-16 identical blocks"
  "810 1000|--sensor hdl64 --route street --scene suburban|HDL-64E street, no revisit"
)
SEQUENCES=()
# shellcheck source=benchmarks/synth_drives.sh
. benchmarks/synth_drives.sh
for spec in "${DRIVES[@]}"; do
  folder=$(make_drive "$WORK" "$VCR" "${spec%|*}")  # a failed synth stops the script (set -e)
  SEQUENCES+=(--sequence "$folder" --name "${spec##*|}")
done
"$PY" benchmarks/loop_closure.py "${SEQUENCES[@]}" "$@" --json "$WORK/loops.json" --markdown "$WORK/loops.md" >&2
cat "$WORK/loops.md"
