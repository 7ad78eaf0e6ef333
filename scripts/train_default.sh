#!/usr/bin/env bash
# Reproduces weights/vcr-default.safetensors (see weights/MODEL_CARD.md for what it measured).
#
#   bash scripts/train_default.sh [WORK_DIR] [KITTI_SAMPLE_ROOT]
#
# WORK_DIR (default runs/default-weights) receives the synthetic sequences, the frame caches and the
# training run; KITTI_SAMPLE_ROOT (default ../shared/data/kitti-sample) is the real sample, of which
# only frames 0-39 are used: frames 40-59 are the test block of the model card. Re-running continues
# an interrupted training (--resume) instead of starting over.
set -euo pipefail
WORK=${1:-runs/default-weights}
KITTI=${2:-../shared/data/kitti-sample}
VCR=${VCR:-.venv/bin/vcr-odom}
mkdir -p "$WORK"

# 1. Four synthetic drives (byte-identical for a seed), every third frame cached: neighbouring
#    frames are near-copies. Four independent FPS down-samplings per frame.
for seed in 21 22 23 24; do
  [ -f "$WORK/synth/poses/$seed.txt" ] || "$VCR" synth --out "$WORK/synth" --seq "$seed" --frames 300 --seed "$seed"
  [ -f "$WORK/synth_$seed.npz" ] || "$VCR" cache --data-root "$WORK/synth" --seq "$seed" --stride 3 --copies 4 --out "$WORK/synth_$seed.npz"
done
# 2. The real KITTI sample, frames 0-39 only.
[ -f "$WORK/kitti_0_40.npz" ] || "$VCR" cache --data-root "$KITTI" --seq 00 --frames 0:40 --copies 4 --out "$WORK/kitti_0_40.npz"

# 3. Stage 1, the paper's same-scan protocol (-> weights/vcr-default-same-scan.safetensors).
#    Validation = a contiguous 20 % block of each cache; best.safetensors chosen on validation
#    rotation/1° + translation/0.25 m. The shipped run was stopped after 18 of the 40 epochs (for time);
#    its best epoch was 12, which a full run reaches through the same first epochs.
resume_flag() { [ -f "$1/last.pt" ] && echo --resume || true; }
CACHES=(--cache "$WORK/kitti_0_40.npz" --cache "$WORK/synth_21.npz" --cache "$WORK/synth_22.npz"
        --cache "$WORK/synth_23.npz" --cache "$WORK/synth_24.npz")
"$VCR" train "${CACHES[@]}" --protocol same-scan --epochs 40 --batch-size 8 --lr 1e-3 --seed 0 \
  --device cpu --select-on rmse --out "$WORK/stage1" $(resume_flag "$WORK/stage1")

# 4. Stage 2: both protocols (same-scan, and odometry pairs 1-5 frames apart with the random move on
#    top) from stage 1's best, so that it also registers different scans (-> weights/vcr-default.safetensors).
"$VCR" train "${CACHES[@]}" --protocol same-scan --protocol odometry --epochs 20 --batch-size 8 \
  --lr 5e-4 --seed 1 --device cpu --select-on rmse --init-weights "$WORK/stage1/best.safetensors" \
  --out "$WORK/stage2" $(resume_flag "$WORK/stage2")
echo "weights: $WORK/stage2/best.safetensors (default), $WORK/stage1/best.safetensors (same-scan)"
