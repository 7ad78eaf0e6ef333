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

# seed frames | synth options
DRIVES=(
  "801 800|--sensor hdl64 --route loop --scene suburban"
  "802 800|--sensor hdl32 --route return --scene suburban"
  "803 800|--sensor vlp16 --route figure8 --scene oldtown"
  "804 800|--sensor os128 --route loop --scene highway"
  "805 800|--sensor avia --route return --scene suburban"
  "806 800|--sensor mid360 --route loop --scene oldtown"
  "807 800|--sensor avia --route figure8 --scene avenue"
  "808 800|--sensor hdl64 --route blocks --scene suburban"
  "809 600|--sensor vlp16 --route blocks --scene oldtown"
  "810 1000|--sensor hdl64 --route street --scene suburban"
)
SEQUENCES=()
# shellcheck source=benchmarks/synth_drives.sh
. benchmarks/synth_drives.sh
for spec in "${DRIVES[@]}"; do
  folder=$(make_drive "$WORK" "$VCR" "$spec")  # a failed synth stops the script (set -e)
  SEQUENCES+=(--sequence "$folder")
done
"$PY" benchmarks/loop_closure.py "${SEQUENCES[@]}" "$@" --json "$WORK/loops.json" --markdown "$WORK/loops.md" >&2
cat "$WORK/loops.md"
