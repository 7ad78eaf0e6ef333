#!/usr/bin/env bash
# The ablation table of docs/benchmarks.md and weights/MODEL_CARD.md: the weight file's features
# against the same file scrambled, a fresh initialisation and FPFH, under the paper's head, the
# consensus without re-pointing and the full head (benchmarks/ablation.py).
#
#   bash benchmarks/ablation.sh [WORK_DIR] [WEIGHTS] [KITTI_SAMPLE_ROOT]
#
# The synthetic drives were chosen before any figure was seen; no training run and no setting reads
# them (seeds 9xx). KITTI: the sample's test block, frames 40-59 (its frames 0-39 are trained on).
# A drive already under WORK_DIR/synth is reused. Extra options go to ablation.py through ABLATION_ARGS
# (e.g. "--json out.json --limit 10").
set -euo pipefail
cd "$(dirname "$0")/.."
WORK=${1:-runs/ablation}
WEIGHTS=${2:-weights/vcr-default.safetensors}
KITTI=${3:-../shared/data/kitti-sample}
VCR=${VCR:-.venv/bin/vcr-odom}
mkdir -p "$WORK"
# shellcheck source=benchmarks/synth_drives.sh
. benchmarks/synth_drives.sh
two_hz=$(make_drive "$WORK" "$VCR" "911 60|--sensor hdl32 --scene suburban --rate-hz 2")
avia=$(make_drive "$WORK" "$VCR" "912 120|--sensor avia --scene avenue --speed 10")
mid=$(make_drive "$WORK" "$VCR" "913 120|--sensor mid360 --scene oldtown --speed 8")
avia_key=$(make_drive "$WORK" "$VCR" "914 400|--sensor avia --scene suburban --motion handheld --keyframes 1.0 --thin 0.3")
mid_key=$(make_drive "$WORK" "$VCR" "915 400|--sensor mid360 --scene avenue --keyframes 2.0 --thin 0.3")
walk_a=$(make_drive "$WORK" "$VCR" "916 600|--sensor os0 --scene suburban --motion handheld --route return")
walk_b=$(make_drive "$WORK" "$VCR" "917 600|--sensor os0 --scene oldtown --motion handheld --route loop")
kitti=()
[ -d "$KITTI/sequences/00" ] && kitti=(--kitti "$KITTI")
# shellcheck disable=SC2086  # ABLATION_ARGS are words
.venv/bin/python benchmarks/ablation.py --weights "$WEIGHTS" "${kitti[@]}" \
  --gaps "$two_hz" "32-beam 2 Hz" 1,3 \
  --gaps "$avia" "solid-state raw" 1,5 --gaps "$mid" "solid-state raw" 1,5 \
  --gaps "$avia_key" "solid-state keyframes" 1,5 --gaps "$mid_key" "solid-state keyframes" 1,5 \
  --revisits "$walk_a" "OS0 handheld" --revisits "$walk_b" "OS0 handheld" ${ABLATION_ARGS:-}
