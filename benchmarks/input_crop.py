"""How far and how densely the network should see: VCR alone, one pass, for several input crops and
point counts, on KITTI frames and on synthetic drives of each sensor model.

Not a test. The crop (``input_max_range``) and the point count (``num_points``) act only at inference,
so one weight file runs with each; ``scripts/set_inference_settings.py`` then ships the chosen one.
Choose on one set of frames and seeds, confirm on another:

    .venv/bin/python benchmarks/input_crop.py --data-root ../shared/data/kitti-sample --seq 00 \\
        --frames 0:40 --first-seed 201 [--crop 40 --crop 50 --crop 60 --crop 80] [--gap 1 --gap 5 --gap 10] \\
        [--points 512 --points 1024]
    .venv/bin/python benchmarks/input_crop.py --data-root ../shared/data/kitti-sample --seq 00 \\
        --frames 0:40 --first-seed 201 --variant "shipped=" --variant "gated 2 m=gated_rounds:2,gate_radius:2"
    .venv/bin/python benchmarks/input_crop.py --data-root ../shared/data/kitti-sample --seq 00 \\
        --frames 40:60 --first-seed 301

Synthetic drives: seeds ``first-seed`` .. ``first-seed + 3`` with HDL-64E, HDL-32E, VLP-16 and OS1-128
(40 frames, 12 m/s). Prints one markdown table: success (< 2°, < 0.5 m) and est/true length per
set, gap and variant (every crop with every point count; without ``--points``, the file's own), and the
mean success over the sets. ``--variant LABEL=NAME:VALUE,...`` (repeat) instead names each column's
inference settings (:data:`~vcr_odom.model.config.INFERENCE_FIELDS`; ``LABEL=`` alone: the file as it
is), for settings other than the crop and the point count.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path
from typing import Any

from sequence_args import sequence_parser

SENSORS = ("hdl64", "hdl32", "vlp16", "os128")


def main() -> None:
    parser = sequence_parser(__doc__)
    parser.add_argument("--weights", type=Path, default=None)
    parser.add_argument("--crop", type=float, action="append", help="metres (repeat); default 40 50 60 80")
    parser.add_argument("--gap", type=int, action="append", help="frames apart (repeat); default 1 5 10")
    parser.add_argument("--points", type=int, action="append", help="points fed (repeat); default the file's")
    parser.add_argument(
        "--variant",
        action="append",
        help="LABEL=NAME:VALUE,... inference settings (repeat; replaces the grid)",
    )
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
    points = args.points or [None]
    if args.variant:
        settings = [_parse_variant(spec, parser) for spec in args.variant]
        labels = [label for label, _ in settings]
        variants = [vcr_variant(weights, label, **changes) for label, changes in settings]
    else:
        labels = [_label(crop, count) for crop in crops for count in points]
        variants = [
            vcr_variant(weights, _label(crop, count), input_max_range=crop, **_points(count))
            for crop in crops
            for count in points
        ]
    kitti = open_sequence(args.seq, data_root=args.data_root)
    sets = [(f"{kitti.name} {args.frames or 'all'}", kitti, select_frames(len(kitti), args.frames))]
    for offset, sensor in enumerate(SENSORS):
        seed = args.first_seed + offset
        drive = SynthSequence(frames=args.synth_frames, seed=seed, sensor=sensor, speed=12.0)
        sets.append((f"{sensor} seed {seed}", drive, list(range(len(drive)))))

    success: dict[tuple[int, str], list[float]] = {}
    print("| set | gap | " + " | ".join(f"{label}: success, ratio" for label in labels) + " |")
    print("|---|---:|" + "---|" * len(labels))
    for name, sequence, frames in sets:
        rows = run_gap_sweep(sequence, frames, variants, gaps).rows
        for gap in gaps:
            cells = []
            for column, variant in zip(labels, variants, strict=True):
                row = next(r for r in rows if r.method == variant.name and r.gap == gap)
                success.setdefault((gap, column), []).append(row.errors.success_rate)
                cells.append(f"{100 * row.errors.success_rate:.0f} %, {row.length_ratio:.3f}")
            print(f"| {name} | {gap} | " + " | ".join(cells) + " |")
    for gap in gaps:
        means = [100 * sum(success[gap, label]) / len(success[gap, label]) for label in labels]
        print(f"| mean success | {gap} | " + " | ".join(f"{mean:.1f} %" for mean in means) + " |")


def _parse_variant(spec: str, parser: argparse.ArgumentParser) -> tuple[str, dict[str, Any]]:
    """``LABEL=NAME:VALUE,...`` -> (label, settings), parsed as ``set_inference_settings.py --set``."""
    from vcr_odom.errors import ConfigError
    from vcr_odom.model.config import parse_inference_setting

    label, sep, rest = spec.partition("=")
    if not sep or not label:
        parser.error(f"--variant: expected LABEL=NAME:VALUE,...; got {spec!r}")
    changes: dict[str, Any] = {}
    for item in filter(None, rest.split(",")):
        name, _, value = item.partition(":")
        try:
            changes[name] = parse_inference_setting(name, value)
        except ConfigError as error:
            parser.error(f"--variant {spec!r}: {error}")
    return label, changes


def _points(count: int | None) -> dict[str, int]:
    return {} if count is None else {"num_points": count}


def _label(crop: float, points: int | None) -> str:
    return f"{crop:g} m" if points is None else f"{crop:g} m, {points} points"


if __name__ == "__main__":
    main()
