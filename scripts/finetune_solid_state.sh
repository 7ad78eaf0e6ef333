#!/usr/bin/env bash
# Fine-tunes the shipped weights on solid-state, handheld and keyframe drives beside spinning ones, so
# that the network learns the Livox-like patterns without forgetting spinning LiDARs.
#
#   bash scripts/finetune_solid_state.sh [WORK_DIR] [KITTI_SAMPLE_ROOT]
#
# WORK_DIR (default runs/solid-state) receives the synthetic drives, the caches and the run. The run
# writes last.pt every 100 steps: re-running continues a killed run from its last step (--resume).
# Held out: synthetic seeds 7xx (benchmarks/robust_default.sh, revisit tables), 6xx (the doubt rule's
# tuning drives) and kitti-sample frames 40-59. THREADS (default 2) sets torch's CPU threads.
set -euo pipefail
cd "$(dirname "$0")/.."
WORK=${1:-runs/solid-state}
KITTI=${2:-../shared/data/kitti-sample}
VCR=${VCR:-.venv/bin/vcr-odom}
WEIGHTS=${WEIGHTS:-weights/vcr-default.safetensors}
export OMP_NUM_THREADS=${THREADS:-2}
mkdir -p "$WORK"

# seed frames | synth options: six spinning drives of the shipped training set (no forgetting), then
# solid-state cars, handheld walks and keyframe sets (seeds 71-79 are used nowhere else).
DRIVES=(
  "21 200|--sensor hdl64 --scene suburban --speed 8 --height 1.73"
  "24 200|--sensor hdl64 --scene suburban --speed 20 --height 1.73"
  "31 200|--sensor hdl32 --scene avenue --speed 15 --height 1.9"
  "32 200|--sensor vlp16 --scene oldtown --speed 6 --height 1.6 --stops"
  "36 200|--sensor os128 --scene oldtown --speed 8 --height 1.5 --stops"
  "52 200|--sensor os128 --scene oldtown --speed 10 --height 1.8"
  "71 200|--sensor avia --scene suburban --speed 10"
  "72 200|--sensor avia --scene oldtown --speed 6 --stops"
  "73 200|--sensor mid360 --scene avenue --speed 12"
  "74 200|--sensor mid360 --scene oldtown --speed 8"
  "75 300|--sensor avia --scene suburban --motion handheld"
  "76 300|--sensor mid360 --scene oldtown --motion handheld"
  "77 400|--sensor avia --scene oldtown --motion handheld --keyframes 1.0 --thin 0.3"
  "78 400|--sensor os128 --scene suburban --motion handheld --keyframes 1.0 --thin 0.5"
  "79 400|--sensor mid360 --scene avenue --keyframes 3.0 --thin 0.3"
)
CACHES=()
# shellcheck source=benchmarks/synth_drives.sh
. benchmarks/synth_drives.sh
for spec in "${DRIVES[@]}"; do
  CACHES+=(--cache "$(cache_drive "$WORK" "$VCR" "$spec" 4 1024)")
done
[ -f "$WORK/cache_kitti_0_40.npz" ] || "$VCR" cache --data-root "$KITTI" --seq 00 --frames 0:40 --copies 4 \
  --input-max-range 80 --num-points 1024 --out "$WORK/cache_kitti_0_40.npz"
CACHES+=(--cache "$WORK/cache_kitti_0_40.npz")

# One epoch at lr 1e-4 from the shipped weights, both protocols, as the shipped fine-tune; the best
# epoch by validation pose RMSE (each cache's contiguous 20 % block).
resume_flag() { [ -f "$1/last.pt" ] && echo --resume || true; }
# shellcheck disable=SC2046  # resume_flag prints one word or none
"$VCR" train "${CACHES[@]}" --protocol odometry --protocol same-scan --max-motion 15 --reverse \
  --epochs 1 --batch-size 8 --lr 1e-4 --seed 5 --device cpu --select-on rmse \
  --input-max-range 80 --num-points 1024 --init-weights "$WEIGHTS" --checkpoint-every 100 \
  --out "$WORK/train" $(resume_flag "$WORK/train")
echo "weights: $WORK/train/best.safetensors"
