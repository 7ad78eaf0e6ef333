#!/usr/bin/env bash
# Where a frame's time goes, for make tables: the default (network on doubt), the network on every
# pair, the network alone, and kiss-icp, on the same frames in one run each (medians of 3 interleaved
# rounds; each method in its own process), with accuracy against the ground truth beside the speed.
# Data: the real KITTI sample, Avia and Mid-360 handheld keyframe walks (thinned to 0.2 m) and a
# handheld OS0 walk. Measure on a quiet machine: frames/s are wall time. About 15 min on 2 cores.
#
#   bash benchmarks/frame_time.sh [WORK_DIR] [KITTI_ROOT] > table.md
set -euo pipefail
cd "$(dirname "$0")/.."
WORK=${1:-runs/frame-time}
KITTI=${2:-../shared/data/kitti-sample}
PY=${PYTHON:-.venv/bin/python}
VCR=${VCR:-.venv/bin/vcr-odom}
mkdir -p "$WORK"
. benchmarks/synth_drives.sh

METHODS=(--method vcr+kiss-icp --method vcr+kiss-icp@every-frame --method vcr+none --baseline kiss-icp --repeat 3)
speed() {  # label data-root seq [header] [more options]
  local label=$1 root=$2 seq=$3 header=$4
  shift 4
  "$PY" benchmarks/pipeline_speed.py --data-root "$root" --seq "$seq" "${METHODS[@]}" --markdown \
    --label "$label" $header "$@"
}
speed "KITTI sample (HDL-64E)" "$KITTI" 00 ""
for spec in \
  "714 300|--sensor avia --scene oldtown --motion handheld --keyframes 1.0 --thin 0.2" \
  "717 300|--sensor mid360 --scene oldtown --motion handheld --keyframes 1.0 --thin 0.2" \
  "720 200|--sensor os0 --scene oldtown --motion handheld"; do
  folder=$(make_drive "$WORK" "$VCR" "$spec")
  case "$spec" in
    714*) label="Avia handheld keyframes" ;;
    717*) label="Mid-360 handheld keyframes" ;;
    *) label="OS0 handheld walk" ;;
  esac
  speed "$label (${spec%% *})" "$WORK/synth" "$(basename "$folder")" --no-header --frames 0:100
done
