"""Ablation of VCR-Net: the weight file's features against the same file scrambled, a fresh
initialisation and FPFH, each read by the paper's head, the consensus without re-pointing and the full
head (vcr_odom/evaluation/ablation.py says why). Not a test.

Regimes are given as sequences and how to pair their frames; rows with the same label pool pairs of
several sequences:

    --kitti ROOT                  KITTI sample (seq 00), --kitti-frames (default 40:60), gaps 1/5/10/15
    --gaps DIR LABEL GAPS         frames GAPS apart (comma-separated) of the KITTI-layout sequence folder
                                  DIR; one row per gap, "LABEL, G apart"
    --revisits DIR LABEL          pairs 3-6 m apart (any time apart), one row per heading bin:
                                  "LABEL revisits 0-30°", 30-60, 60-90, 90-180

At most --limit pairs per row and sequence (evenly spread, seeded). Prints one markdown table: pairs,
the correspondences' inlier ratio (virtual point within 1 m of the truth, before any head), then
success (2° and 0.5 m) and rotation / translation RMSE under each head, and the full head's length
ratio. `bash benchmarks/ablation.sh` runs the regimes of docs/benchmarks.md.

    .venv/bin/python benchmarks/ablation.py --weights weights/vcr-default.safetensors \\
        --kitti ../shared/data/kitti-sample --gaps runs/abl/synth/sequences/912 "Avia raw" 1,5 --json a.json
"""

from __future__ import annotations

import argparse
import itertools
import sys
import warnings
from pathlib import Path

import numpy as np

HEADING_BINS = ((0.0, 30.0), (30.0, 60.0), (60.0, 90.0), (90.0, 180.0))


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--weights", type=Path, default=None, help="weight file (default: the shipped one)")
    parser.add_argument("--kitti", type=Path, default=None, help="KITTI-layout root holding sequence 00")
    parser.add_argument("--kitti-frames", default="40:60", help="A:B of the KITTI sequence (B exclusive)")
    parser.add_argument("--kitti-gaps", default="1,5,10,15", help="comma-separated frames apart")
    parser.add_argument("--gaps", nargs=3, action="append", default=[], metavar=("DIR", "LABEL", "GAPS"))
    parser.add_argument("--revisits", nargs=2, action="append", default=[], metavar=("DIR", "LABEL"))
    parser.add_argument("--features", action="append", default=None, help="feature sets (default: all)")
    parser.add_argument("--limit", type=int, default=20, help="most pairs per row and sequence")
    parser.add_argument("--seed", type=int, default=0, help="seed of the pair sample and the scrambling")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    parser.add_argument("--json", type=Path, default=None, help="write every row here (atomic)")
    return parser.parse_args()


def spread(items: list, limit: int, rng: np.random.Generator) -> list:
    """At most ``limit`` of ``items``, one drawn from each of ``limit`` equal slices (order kept)."""
    if len(items) <= limit:
        return items
    edges = np.linspace(0, len(items), limit + 1).astype(int)
    return [items[int(rng.integers(a, b))] for a, b in itertools.pairwise(edges) if b > a]


def gaps_list(text: str, option: str) -> list[int]:
    try:
        gaps = [int(g) for g in text.split(",") if g.strip()]
    except ValueError:
        raise SystemExit(
            f"{option}: expected comma-separated whole numbers of frames; got {text!r}"
        ) from None
    if not gaps or min(gaps) < 1:
        raise SystemExit(f"{option}: expected positive frame gaps; got {text!r}")
    return gaps


def main() -> None:
    args = parse_args()
    warnings.simplefilter("ignore")
    import torch

    if args.threads:
        torch.set_num_threads(args.threads)
    from vcr_odom.data import open_sequence
    from vcr_odom.data.selection import select_frames
    from vcr_odom.errors import VcrOdomError
    from vcr_odom.evaluation.ablation import FEATURES, AblationPair, PairSet, markdown_table, run_ablation
    from vcr_odom.evaluation.gap_sweep import gap_pairs, true_motions
    from vcr_odom.evaluation.revisits import RevisitOptions, candidate_pairs
    from vcr_odom.model.weights import default_weights_path
    from vcr_odom.results import write_json

    rng = np.random.default_rng(args.seed)
    pair_sets: list[PairSet] = []

    def add_gaps(sequence, name: str, label: str, frames: list[int], gaps: list[int]) -> None:
        poses = sequence.gt_poses
        if poses is None:
            raise SystemExit(f"{name}: no ground-truth poses")
        pairs = []
        for gap in gaps:
            chosen = spread(gap_pairs(frames, gap), args.limit, rng)
            for (target, source), truth in zip(
                chosen, true_motions(poses, chosen) if chosen else [], strict=True
            ):
                pairs.append(AblationPair(f"{label}, {gap} apart", name, target, source, truth))
        pair_sets.append(PairSet(name, sequence.frame, pairs))

    try:
        if args.kitti is not None:
            kitti = open_sequence("00", data_root=args.kitti)
            frames = select_frames(len(kitti), args.kitti_frames, 1)
            add_gaps(
                kitti, f"{args.kitti}:00", "KITTI HDL-64E", frames, gaps_list(args.kitti_gaps, "--kitti-gaps")
            )
        for folder, label, gaps in args.gaps:
            sequence = open_sequence(folder=folder)
            add_gaps(sequence, folder, label, list(range(len(sequence))), gaps_list(gaps, "--gaps"))
        for folder, label in args.revisits:
            sequence = open_sequence(folder=folder)
            poses = sequence.gt_poses
            if poses is None:
                raise SystemExit(f"{folder}: no ground-truth poses")
            found = candidate_pairs(poses, RevisitOptions(max_heading_deg=180.0, limit=None))
            pairs = []
            for low, high in HEADING_BINS:
                in_bin = [
                    p
                    for p in found
                    if low <= p.heading_deg < high or (high == 180.0 and p.heading_deg == 180.0)
                ]
                chosen = spread(sorted(in_bin, key=lambda p: p.distance_m), args.limit, rng)
                truths = true_motions(poses, [(p.target, p.source) for p in chosen]) if chosen else []
                for p, truth in zip(chosen, truths, strict=True):
                    row = f"{label} revisits {low:.0f}-{high:.0f}°"
                    pairs.append(AblationPair(row, folder, p.target, p.source, truth))
            pair_sets.append(PairSet(folder, sequence.frame, pairs))
        if not any(s.pairs for s in pair_sets):
            raise SystemExit("no pairs: give --kitti, --gaps or --revisits with frames that form pairs")

        def progress(done: int, total: int) -> None:
            print(f"\r{done}/{total} pair registrations", end="", file=sys.stderr, flush=True)

        weights = args.weights or default_weights_path("default")
        rows = run_ablation(weights, pair_sets, args.features or FEATURES, args.seed, progress)
        print(file=sys.stderr)
    except VcrOdomError as error:
        raise SystemExit(f"error: {error}") from None
    print(markdown_table(rows))
    if args.json is not None:
        write_json(args.json, {"weights": str(weights), "rows": [row.to_dict() for row in rows]})


if __name__ == "__main__":
    main()
