"""How far the network should see: VCR alone, one pass, for several input crops, on KITTI frames and
on synthetic drives of each sensor model.

Not a test. The crop (``input_max_range``) acts only at inference, so one weight file runs with each;
``scripts/set_inference_settings.py`` then ships the chosen one. Choose on one set of frames and
seeds, confirm on another:

    .venv/bin/python benchmarks/input_crop.py --data-root ../shared/data/kitti-sample --seq 00 \\
        --frames 0:40 --first-seed 201 [--crop 40 --crop 50 --crop 60 --crop 80] [--gap 1 --gap 5 --gap 10]
    .venv/bin/python benchmarks/input_crop.py --data-root ../shared/data/kitti-sample --seq 00 \\
        --frames 40:60 --first-seed 301

Synthetic drives: seeds ``first-seed`` .. ``first-seed + 3`` with HDL-64E, HDL-32E, VLP-16 and OS1-128
(40 frames, 12 m/s). Prints one markdown table: success (< 2°, < 0.5 m) and est/true length per
set, gap and crop, and the mean success over the sets.
"""

from __future__ import annotations

import warnings
from pathlib import Path

from sequence_args import sequence_parser

SENSORS = ("hdl64", "hdl32", "vlp16", "os128")


def main() -> None:
    parser = sequence_parser(__doc__)
    parser.add_argument("--weights", type=Path, default=None)
    parser.add_argument("--crop", type=float, action="append", help="metres (repeat); default 40 50 60 80")
    parser.add_argument("--gap", type=int, action="append", help="frames apart (repeat); default 1 5 10")
    parser.add_argument("--first-seed", type=int, default=201)
    parser.add_argument("--synth-frames", type=int, default=40)
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    import torch

    torch.set_num_threads(1)
    from bias_leads import vcr_variant  # beside this script

    from vcr_odom.data import open_sequence
    from vcr_odom.data.selection import select_frames
    from vcr_odom.evaluation.gap_sweep import run_gap_sweep
    from vcr_odom.model.weights import default_weights_path
    from vcr_odom.synth import SynthSequence

    weights = args.weights or default_weights_path("default")
    crops = args.crop or [40.0, 50.0, 60.0, 80.0]
    gaps = args.gap or [1, 5, 10]
    variants = [vcr_variant(weights, f"{crop:g} m", input_max_range=crop) for crop in crops]
    kitti = open_sequence(args.seq, data_root=args.data_root)
    sets = [(f"{kitti.name} {args.frames or 'all'}", kitti, select_frames(len(kitti), args.frames))]
    for offset, sensor in enumerate(SENSORS):
        seed = args.first_seed + offset
        drive = SynthSequence(frames=args.synth_frames, seed=seed, sensor=sensor, speed=12.0)
        sets.append((f"{sensor} seed {seed}", drive, list(range(len(drive)))))

    success: dict[tuple[int, float], list[float]] = {}
    print("| set | gap | " + " | ".join(f"{crop:g} m: success, ratio" for crop in crops) + " |")
    print("|---|---:|" + "---|" * len(crops))
    for label, sequence, frames in sets:
        rows = run_gap_sweep(sequence, frames, variants, gaps).rows
        for gap in gaps:
            cells = []
            for crop, variant in zip(crops, variants, strict=True):
                row = next(r for r in rows if r.method == variant.name and r.gap == gap)
                success.setdefault((gap, crop), []).append(row.errors.success_rate)
                cells.append(f"{100 * row.errors.success_rate:.0f} %, {row.length_ratio:.3f}")
            print(f"| {label} | {gap} | " + " | ".join(cells) + " |")
    for gap in gaps:
        means = [100 * sum(success[gap, crop]) / len(success[gap, crop]) for crop in crops]
        print(f"| mean success | {gap} | " + " | ".join(f"{mean:.1f} %" for mean in means) + " |")


if __name__ == "__main__":
    main()
