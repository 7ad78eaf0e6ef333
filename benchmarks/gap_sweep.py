"""Gap sweep: each method on every pair (i, i + d) of the chosen frames, for growing gaps d.

Not a test. Methods get the raw frames (each does its own pre-processing, as in `run`) and no
initial guess; source = frame i + d, target = frame i, truth = inv(P_i) @ P_(i+d). Prints one
markdown table (rows method x gap): mean true motion, estimated/true motion length ratio, rotation
and translation RMSE/MAE, success rate and ms per pair (see vcr_odom/evaluation/gap_sweep.py).

    .venv/bin/python benchmarks/gap_sweep.py --data-root ../shared/data/kitti-sample --seq 00 \\
        --frames 40:60
    .venv/bin/python benchmarks/gap_sweep.py --synth 3 --synth-frames 40 --gap 1 --gap 5 \\
        --method vcr --weights weights/vcr-default.safetensors --json /tmp/gaps.json
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from pathlib import Path
from typing import Any

from sequence_args import sequence_parser


def parse_args() -> argparse.Namespace:
    parser = sequence_parser(__doc__)
    for action in parser._actions:  # --data-root is required there; here --synth may replace it
        if "--data-root" in action.option_strings:
            action.required = False
    parser.add_argument("--synth", type=int, metavar="SEED", help="a synthetic drive instead of KITTI")
    parser.add_argument("--sensor", default=None, help="synthetic sensor model: hdl64, hdl32, vlp16, os128")
    parser.add_argument(
        "--scene", default="suburban", help="synthetic scene: suburban, avenue, highway, oldtown"
    )
    parser.add_argument("--synth-frames", type=int, default=40, help="frames of the synthetic drive")
    parser.add_argument("--speed", type=float, default=10.0, help="synthetic drive speed [m/s]")
    parser.add_argument("--gap", type=int, action="append", help="frames apart (repeat; default 1 2 5 10 15)")
    add_method_options(parser)
    parser.add_argument("--json", type=Path, default=None, help="write every figure here (atomic)")
    args = parser.parse_args()
    if (args.data_root is None) == (args.synth is None):
        parser.error("give exactly one of --data-root (KITTI layout) and --synth SEED")
    return args


def add_method_options(parser: argparse.ArgumentParser) -> None:
    """The options :func:`build_methods` and :func:`set_threads` read (shared with revisit_pairs.py)."""
    parser.add_argument("--method", action="append", help="registration method (repeat; default vcr, fpfh)")
    parser.add_argument("--weights", type=Path, action="append", help="VCR weights, one row each (repeat)")
    parser.add_argument(
        "--vcr-passes", type=int, default=1, help="VCR-Net passes per pair (1: network alone)"
    )
    parser.add_argument(
        "--device", default="auto", choices=["auto", "cpu", "cuda"], help="where VCR-Net runs"
    )
    parser.add_argument(
        "--threads", type=int, default=None, help="torch threads (default: $OMP_NUM_THREADS or 1)"
    )


def set_threads(threads: int | None) -> int:
    """One torch thread unless told otherwise: the benchmark must not fight a training job for cores."""
    import torch

    count = threads or int(os.environ.get("OMP_NUM_THREADS", "1") or 1)
    torch.set_num_threads(max(1, count))
    return torch.get_num_threads()


def open_selection(args: argparse.Namespace) -> tuple[Any, list[int]]:
    from vcr_odom.data import open_sequence
    from vcr_odom.data.selection import select_frames
    from vcr_odom.evaluation.gap_sweep import synth_sequence

    if args.synth is not None:
        sequence = synth_sequence(args.synth, args.synth_frames, args.speed, args.sensor, args.scene)
    else:
        sequence = open_sequence(args.seq, data_root=args.data_root)
    return sequence, select_frames(len(sequence), args.frames)


def build_methods(args: argparse.Namespace) -> list[Any]:
    """One registrar per method; VCR once per weights file, named by the file and its passes."""
    from vcr_odom.errors import ConfigError
    from vcr_odom.model.weights import default_weights_path
    from vcr_odom.registration import SequentialOdometry, make_method

    methods = []
    for name in dict.fromkeys(args.method or ["vcr", "fpfh"]):
        if name.strip().lower() != "vcr":
            method = make_method(name)
            if isinstance(method, SequentialOdometry):
                raise ConfigError(f"--method {name}: a sequential odometry method has no meaning on pairs")
            methods.append(method)
            continue
        for path in args.weights or [default_weights_path("default")]:
            method = make_method("vcr", weights=path, device=args.device, passes=args.vcr_passes)
            passes = f"{args.vcr_passes} pass{'es' if args.vcr_passes > 1 else ''}"
            method.name = f"vcr ({Path(path).stem}, {passes})"
            methods.append(method)
    return methods


def progress_line(stage: str, done: int, total: int) -> None:
    end = "\n" if done == total else ""
    print(f"\r{stage}: {done}/{total}", end=end, file=sys.stderr, flush=True)


def main() -> None:
    args = parse_args()
    warnings.simplefilter("ignore")
    threads = set_threads(args.threads)

    from vcr_odom.errors import VcrOdomError
    from vcr_odom.evaluation.gap_sweep import DEFAULT_GAPS, markdown_table, run_gap_sweep
    from vcr_odom.results import write_json

    try:
        sequence, frames = open_selection(args)
        methods = build_methods(args)
        sweep = run_gap_sweep(sequence, frames, methods, args.gap or DEFAULT_GAPS, progress=progress_line)
    except VcrOdomError as error:
        sys.exit(f"error: {error}")
    print(
        f"\n{sweep.sequence}: frames {frames[0]}-{frames[-1]} ({len(frames)}), raw frames, no initial guess, "
        f"{threads} torch thread(s)\n"
    )
    print(markdown_table(sweep))
    if args.json is not None:
        write_json(args.json, {"command": sys.argv, "threads": threads, **sweep.to_dict(include_arrays=True)})
        print(f"\nfigures in {args.json}", file=sys.stderr)


if __name__ == "__main__":
    main()
