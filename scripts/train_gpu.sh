#!/usr/bin/env bash
# One-shot training of VCR-Net's `paper` preset on a lent GPU, from caches carried there.
#
# The GPU machine has torch but neither open3d nor kiss-icp, and no network: pre-processing (ground
# removal, farthest point sampling) runs here, into compact frame caches (int16 points), and the GPU
# side needs torch + numpy only.
#
#   bash scripts/train_gpu.sh prepare runs/gpu              # here: synthetic drives + caches (open3d)
#   # on the device (the `run` tool), carrying runs/gpu/caches:
#   bash scripts/train_gpu.sh train runs/gpu/caches "$OUT"   # trains, copies the weights to $OUT
#
# `prepare` reuses scripts/train_default.sh's drives (same seeds and sensors) with the preset's N.
# `train` stops starting epochs once MINUTES (default 8) would be exceeded, keeps a checkpoint every
# epoch, and writes best.safetensors (chosen on the validation blocks), history.json and run.json to
# the output folder. PRESET (default paper), EPOCHS (default 40), BATCH (default 32), DEVICE (default
# cuda) and MAX_PAIRS (default 0: all; a small number rehearses the script on a CPU, as the tests do)
# override the defaults.
set -euo pipefail
MODE=${1:?usage: train_gpu.sh prepare WORK | train CACHE_DIR OUT_DIR}
PRESET=${PRESET:-paper}
PYTHON=${PYTHON:-.venv/bin/python}

case "$MODE" in
prepare)
  WORK=${2:?usage: train_gpu.sh prepare WORK}
  KITTI=${KITTI:-../shared/data/kitti-sample}
  VCR=${VCR:-.venv/bin/vcr-odom}
  mkdir -p "$WORK/caches"
  for spec in "21 hdl64 suburban 8 1.73 --no-stops" "24 hdl64 suburban 20 1.73 --no-stops" \
              "31 hdl32 avenue 15 1.9 --no-stops" "32 vlp16 oldtown 6 1.6 --stops" \
              "33 os128 highway 25 2.0 --no-stops" "37 hdl64 avenue 12 2.1 --stops"; do
    read -r seed sensor scene speed height stops <<<"$spec"
    [ -f "$WORK/synth/poses/$seed.txt" ] || "$VCR" synth --out "$WORK/synth" --seq "$seed" --frames 200 \
      --seed "$seed" --sensor "$sensor" --scene "$scene" --speed "$speed" --height "$height" "$stops"
    [ -f "$WORK/caches/synth_$seed.npz" ] || "$VCR" cache --preset "$PRESET" --data-root "$WORK/synth" \
      --seq "$seed" --stride 4 --copies 4 --out "$WORK/caches/synth_$seed.npz"
  done
  [ -f "$WORK/caches/kitti_0_40.npz" ] || "$VCR" cache --preset "$PRESET" --data-root "$KITTI" --seq 00 \
    --frames 0:40 --copies 4 --out "$WORK/caches/kitti_0_40.npz"
  du -sh "$WORK/caches"
  ;;
train)
  CACHES=${2:?usage: train_gpu.sh train CACHE_DIR OUT_DIR}
  OUT_DIR=${3:?usage: train_gpu.sh train CACHE_DIR OUT_DIR}
  PYTHONPATH=${PYTHONPATH:+$PYTHONPATH:}. "$PYTHON" - "$CACHES" "$OUT_DIR" <<'PY'
import os
import sys
import time
from pathlib import Path

from torch.utils.data import Subset

from vcr_odom.model.config import VcrConfig
from vcr_odom.training import TrainConfig, TrainingData, train, training_sets

caches_dir, out_dir = Path(sys.argv[1]), Path(sys.argv[2])
preset = os.environ.get("PRESET", "paper")
minutes = float(os.environ.get("MINUTES", "8"))
max_pairs = int(os.environ.get("MAX_PAIRS", "0"))
model = VcrConfig.preset(preset)
paths = sorted(caches_dir.glob("*.npz"))
if not paths:
    sys.exit(f"error: no .npz frame caches in {caches_dir} (run `train_gpu.sh prepare` first)")
data = TrainingData(caches=paths, protocols=("odometry", "same-scan"), max_motion=15.0, reverse=True)
train_set, val_set = training_sets(data, model, seed=0)
if max_pairs:  # a rehearsal: the same code path on a handful of pairs
    train_set = Subset(train_set, range(min(max_pairs, len(train_set))))
    val_set = Subset(val_set, range(min(max_pairs, len(val_set))))
config = TrainConfig(
    epochs=int(os.environ.get("EPOCHS", "40")),
    batch_size=int(os.environ.get("BATCH", "32")),
    lr=1e-3,
    seed=0,
    device=os.environ.get("DEVICE", "cuda"),
    out=out_dir,
    select_on="rmse",
    time_limit_s=minutes * 60.0,
)
resume = (out_dir / "last.pt").exists()
start = time.perf_counter()
result = train(model, train_set, val_set, config, resume=resume)
print(
    f"{len(train_set)} training / {len(val_set)} validation pairs, {len(result.history)} epochs in "
    f"{time.perf_counter() - start:.0f} s; best epoch {result.best_epoch + 1}: {result.best_path}"
)
PY
  ;;
*)
  echo "usage: train_gpu.sh prepare WORK | train CACHE_DIR OUT_DIR" >&2
  exit 2
  ;;
esac
