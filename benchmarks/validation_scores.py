"""Validation RMSE of weight files on the held-out blocks of frame caches, per pair protocol.

Not a test. The same split as training (`train_val_datasets`: a contiguous 20 % block of each cache),
transforms drawn with a fixed seed so that every file sees the same pairs:

    .venv/bin/python benchmarks/validation_scores.py --cache kitti_0_40.npz --cache synth_21.npz ... \\
        weights/vcr-default.safetensors weights/legacy/vcr-default-xyz.safetensors [--max-motion 15]

``--max-motion M`` draws the odometry pairs as a run with ``vcr-odom train --max-motion M`` does (every
pair of frames within M metres), rather than the pairs 1, 2, 3 and 5 frames apart; success is the
share within 2° and 0.5 m, the gap sweep's test.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from vcr_odom.data.frame_cache import FrameCache
from vcr_odom.model.weights import load_weights
from vcr_odom.training import PairConfig, pose_errors, train_val_datasets


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("weights", type=Path, nargs="+")
    parser.add_argument("--cache", type=Path, action="append", required=True, help="frame cache (repeat)")
    parser.add_argument("--val-fraction", type=float, default=0.2)
    parser.add_argument("--seed", type=int, default=123)
    parser.add_argument("--max-motion", type=float, default=None, help="metres (as train --max-motion)")
    args = parser.parse_args()
    caches = [FrameCache.load(path) for path in args.cache]
    for path in args.weights:
        model, config, _ = load_weights(path)
        for protocol in ("same-scan", "odometry"):
            pairs = PairConfig(
                protocol=protocol,
                num_points=config.num_points,
                augment=protocol == "odometry",
                seed=args.seed,
                max_motion=args.max_motion,
            )
            _, val = train_val_datasets(caches, pairs, args.val_fraction)
            val.set_epoch(0)
            rotation, translation = [], []
            with torch.inference_mode():
                for start in range(0, len(val), 16):
                    batch = [val[i] for i in range(start, min(len(val), start + 16))]
                    transform = torch.stack([b["transform"] for b in batch]).float()
                    out = model(
                        torch.stack([b["source"] for b in batch]), torch.stack([b["target"] for b in batch])
                    )
                    r, t = pose_errors(
                        out.rotation, out.translation, transform[:, :3, :3], transform[:, :3, 3]
                    )
                    rotation += r.tolist()
                    translation += t.tolist()
            r, t = np.array(rotation), np.array(translation)
            if not len(r):
                print(
                    f"{path.name} {protocol}: no validation pairs (try --max-motion for stride-cached drives)"
                )
                continue
            print(
                f"{path.name} {protocol}: {len(r)} pairs, rot RMSE {np.sqrt((r**2).mean()):.3f} deg, "
                f"trans RMSE {np.sqrt((t**2).mean()):.3f} m, success {100 * np.mean((r < 2) & (t < 0.5)):.0f} %"
            )


if __name__ == "__main__":
    main()
