#!/usr/bin/env bash
# Reproduces weights/vcr-default.safetensors (see weights/MODEL_CARD.md for what it measured).
#
#   bash scripts/train_default.sh [WORK_DIR] [KITTI_SAMPLE_ROOT]
#
# WORK_DIR (default runs/default-weights) receives the synthetic sequences, the frame caches and the
# training run; KITTI_SAMPLE_ROOT (default ../shared/data/kitti-sample) is the real sample, of which
# only frames 0-39 are used: frames 40-59 are the test block of the model card, and synthetic seeds
# >= 100 are the unseen synthetic drives (benchmarks/gap_sweep.py). Re-running continues an
# interrupted training (--resume) instead of starting over. EPOCHS (default 8, the shipped run) sets
# the schedule of the first stage (65 min on two CPU cores); the fine-tune took 42 min.
set -euo pipefail
WORK=${1:-runs/default-weights}
KITTI=${2:-../shared/data/kitti-sample}
VCR=${VCR:-.venv/bin/vcr-odom}
EPOCHS=${EPOCHS:-8}
mkdir -p "$WORK"

# 1. Synthetic drives of 200 frames (byte-identical for a seed). Six HDL-64E drives at typical speeds
#    from 8 to 24 m/s, then eight of other sensors, mountings, scenes, speeds and stops:
#    seed sensor scene speed height stops
SYNTH=(
  "21 hdl64 suburban 8 1.73 --no-stops" "22 hdl64 suburban 12 1.73 --no-stops"
  "23 hdl64 suburban 16 1.73 --no-stops" "24 hdl64 suburban 20 1.73 --no-stops"
  "25 hdl64 suburban 10 1.73 --no-stops" "26 hdl64 suburban 24 1.73 --no-stops"
  "31 hdl32 avenue 15 1.9 --no-stops" "32 vlp16 oldtown 6 1.6 --stops"
  "33 os128 highway 25 2.0 --no-stops" "34 hdl32 suburban 10 1.8 --stops"
  "35 vlp16 highway 20 1.7 --no-stops" "36 os128 oldtown 8 1.5 --stops"
  "37 hdl64 avenue 12 2.1 --stops" "38 hdl32 highway 22 1.6 --no-stops"
)
CACHES=()
for spec in "${SYNTH[@]}"; do
  read -r seed sensor scene speed height stops <<<"$spec"
  [ -f "$WORK/synth/poses/$seed.txt" ] || "$VCR" synth --out "$WORK/synth" --seq "$seed" --frames 200 \
    --seed "$seed" --sensor "$sensor" --scene "$scene" --speed "$speed" --height "$height" "$stops"
  # Every fourth frame (neighbouring frames are near-copies), four independent down-samplings each.
  [ -f "$WORK/synth_$seed.npz" ] || "$VCR" cache --data-root "$WORK/synth" --seq "$seed" --stride 4 \
    --copies 4 --out "$WORK/synth_$seed.npz"
  CACHES+=(--cache "$WORK/synth_$seed.npz")
done
# 2. The real KITTI sample, frames 0-39 only, every frame.
[ -f "$WORK/kitti_0_40.npz" ] || "$VCR" cache --data-root "$KITTI" --seq 00 --frames 0:40 --copies 4 \
  --out "$WORK/kitti_0_40.npz"
CACHES+=(--cache "$WORK/kitti_0_40.npz")

# 3. One stage from scratch, both protocols: the paper's same-scan pairs, and odometry pairs of every
#    two cached frames at most 15 m apart (both directions, a random tilt/yaw/shift on top).
#    Validation = a contiguous 20 % block of each cache; best.safetensors = the lowest validation
#    correspondence loss (the shipped run's last epoch).
resume_flag() { [ -f "$1/last.pt" ] && echo --resume || true; }
"$VCR" train "${CACHES[@]}" --protocol odometry --protocol same-scan --max-motion 15 --reverse \
  --epochs "$EPOCHS" --batch-size 8 --lr 1e-3 --seed 0 --device cpu --select-on loss \
  --out "$WORK/train" $(resume_flag "$WORK/train")
# 4. The inference settings chosen after training on data it was not tested on (MODEL_CARD.md, "The
#    input crop", "The point count" and "Gated re-pointing"): 80 m of each scan, 1024 points (trained
#    on 40 m and 512), two gated re-pointing rounds of 2 m (today's default for a new file; set
#    here so that the step says every setting the shipped file runs with).
"${PYTHON:-.venv/bin/python}" scripts/set_inference_settings.py "$WORK/train/best.safetensors" \
  --set input_max_range=80 --set num_points=1024 --set gated_rounds=2 --set gate_radius=2 \
  --note "chosen on kitti-sample frames 0-39 and synthetic seeds 201-204" --out "$WORK/stage1.safetensors"

# 5. A fine-tune at the settings it runs with (80 m, 1024 points) on every drive above plus six
#    old-town drives, one epoch at lr 1e-4 (MODEL_CARD.md, "The old-town fine-tune"). Seeds 51-56 are
#    used nowhere else; the OS1-128 old-town drives 401-403 it was judged on are not trained on.
OLDTOWN=(
  "51 os128 oldtown 6 1.5 --stops" "52 os128 oldtown 10 1.8 --no-stops" "53 os128 oldtown 12 2.0 --stops"
  "54 hdl64 oldtown 8 1.73 --stops" "55 hdl32 oldtown 10 1.9 --no-stops" "56 vlp16 oldtown 9 1.6 --no-stops"
)
WIDE=()
for spec in "${SYNTH[@]}" "${OLDTOWN[@]}"; do
  read -r seed sensor scene speed height stops <<<"$spec"
  [ -f "$WORK/synth/poses/$seed.txt" ] || "$VCR" synth --out "$WORK/synth" --seq "$seed" --frames 200 \
    --seed "$seed" --sensor "$sensor" --scene "$scene" --speed "$speed" --height "$height" "$stops"
  [ -f "$WORK/wide_$seed.npz" ] || "$VCR" cache --data-root "$WORK/synth" --seq "$seed" --stride 4 \
    --copies 4 --input-max-range 80 --num-points 1024 --out "$WORK/wide_$seed.npz"
  WIDE+=(--cache "$WORK/wide_$seed.npz")
done
[ -f "$WORK/wide_kitti_0_40.npz" ] || "$VCR" cache --data-root "$KITTI" --seq 00 --frames 0:40 --copies 4 \
  --input-max-range 80 --num-points 1024 --out "$WORK/wide_kitti_0_40.npz"
WIDE+=(--cache "$WORK/wide_kitti_0_40.npz")
"$VCR" train "${WIDE[@]}" --protocol odometry --protocol same-scan --max-motion 15 --reverse \
  --epochs 1 --batch-size 8 --lr 1e-4 --seed 3 --device cpu --select-on loss \
  --input-max-range 80 --num-points 1024 --init-weights "$WORK/stage1.safetensors" \
  --out "$WORK/finetune" $(resume_flag "$WORK/finetune")
# 6. The pose head's search, chosen after the fine-tune on the old-town drives 401-403 and the choice set
#    (MODEL_CARD.md, "Compatible seeds"): 32 compatible seeds beside the random triples, three gated
#    rounds (today's defaults for a new file; set here for the same reason as in step 4).
"${PYTHON:-.venv/bin/python}" scripts/set_inference_settings.py "$WORK/finetune/best.safetensors" \
  --set consensus_seeds=32 --set consensus_group=16 --set gated_rounds=3 \
  --note "chosen on OS1-128 old-town seeds 401-403, kitti-sample frames 0-39 and synthetic seeds 201-204" \
  --out "$WORK/vcr-default.safetensors"
echo "weights: $WORK/vcr-default.safetensors"
