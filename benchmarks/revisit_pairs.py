"""Revisit pairs: each method on frames a few metres apart in space (not necessarily in time) with a
heading change, registered with no initial guess.

Not a test. Pairs (i, j), i < j, of each sequence's ground truth with the sensors 3-6 m apart (3-D)
and a yaw change about the vertical of at most 90 deg; at most --limit of them, shared between the
heading bins 0-30, 30-60, 60-90 deg and spread over distance (seeded). Source = frame j, target =
frame i, truth = inv(P_i) @ P_j; methods get the raw frames (see vcr_odom/evaluation/revisits.py).
Prints one markdown table (rows sequence x method, plus every method over all sequences when there
are several): pairs, success within 0.5 m / 2 deg overall and per heading bin, rotation and
translation RMSE, ms per pair. Acceptance: >= 90 % success.

    .venv/bin/vcr-odom synth --out /tmp/rv --seq 01 --seed 5 --frames 120 --motion handheld --sensor os128
    .venv/bin/python benchmarks/revisit_pairs.py --data-root /tmp/rv --seq 01 --method vcr --limit 30
    .venv/bin/python benchmarks/revisit_pairs.py --data-root ../shared/data/kitti-sample --seq 00 \\
        --method vcr --method fpfh --weights weights/vcr-default.safetensors --json /tmp/revisits.json
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

from gap_sweep import add_method_options, build_methods, progress_line, set_threads


def parse_args() -> argparse.Namespace:
    # Not sequence_args.sequence_parser: its --seq names one sequence, here it repeats.
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data-root", type=Path, required=True, help="root of the KITTI layout")
    parser.add_argument("--seq", action="append", help="sequence id (repeat to pool several; default 00)")
    parser.add_argument("--frames", default=None, help="A:B (B exclusive), the same for every --seq")
    add_method_options(parser)
    parser.add_argument("--min-m", type=float, default=3.0, help="least distance between the sensors [m]")
    parser.add_argument("--max-m", type=float, default=6.0, help="largest distance between the sensors [m]")
    parser.add_argument("--max-heading", type=float, default=90.0, help="largest yaw change [deg]")
    parser.add_argument("--heading-bin", type=float, default=30.0, help="width of the heading bins [deg]")
    parser.add_argument("--min-frame-gap", type=int, default=1, help="least |i - j| in frames")
    parser.add_argument("--limit", type=int, default=60, help="most pairs per sequence")
    parser.add_argument("--seed", type=int, default=0, help="seed of the pair sample")
    parser.add_argument("--json", type=Path, default=None, help="write every figure here (atomic)")
    return parser.parse_args()


def main() -> None:
    args = parse_args()
    warnings.simplefilter("ignore")
    threads = set_threads(args.threads)

    from vcr_odom.data import open_sequence
    from vcr_odom.data.selection import select_frames
    from vcr_odom.errors import VcrOdomError
    from vcr_odom.evaluation.revisits import RevisitOptions, markdown_table, pool_rows, run_revisits
    from vcr_odom.results import write_json

    runs = []
    try:
        options = RevisitOptions(
            min_m=args.min_m,
            max_m=args.max_m,
            max_heading_deg=args.max_heading,
            min_frame_gap=args.min_frame_gap,
            limit=args.limit,
            seed=args.seed,
            bin_deg=args.heading_bin,
        )
        methods = build_methods(args)
        for seq in dict.fromkeys(args.seq or ["00"]):
            sequence = open_sequence(seq, data_root=args.data_root)
            frames = select_frames(len(sequence), args.frames)
            run = run_revisits(sequence, methods, options, frames=frames, progress=progress_line)
            print(
                f"{run.sequence}: {len(run.pairs)} of {run.num_candidates} revisit pairs in {run.num_frames} frames",
                file=sys.stderr,
            )
            runs.append(run)
        rows = [row for run in runs for row in run.rows]
        pooled = pool_rows(rows) if len(runs) > 1 else []
    except VcrOdomError as error:
        sys.exit(f"error: {error}")
    print(
        f"\nrevisit pairs {args.min_m:g}-{args.max_m:g} m apart, heading change <= {args.max_heading:g} deg, "
        f"|i - j| >= {args.min_frame_gap}, at most {args.limit} per sequence (seed {args.seed}); raw frames, "
        f"no initial guess, {threads} torch thread(s)\n"
    )
    print(markdown_table(rows + pooled))
    if args.json is not None:
        write_json(
            args.json,
            {
                "command": sys.argv,
                "threads": threads,
                "runs": [run.to_dict(include_arrays=True) for run in runs],
                "pooled": [row.to_dict() for row in pooled],
            },
        )
        print(f"\nfigures in {args.json}", file=sys.stderr)


if __name__ == "__main__":
    main()
