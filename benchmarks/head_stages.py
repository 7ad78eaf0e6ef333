"""Where along VCR-Net's pose head a right registration is won or lost. Not a test.

The head runs in stages (``VCRNet.pose_head``): a consensus start (random triples and compatible
seeds), the robust re-weighting rounds, the gated re-pointing rounds. For revisit pairs of each
sequence (3-6 m apart, spread over the heading bins of ``ablation.py``), this scores each stage's
motion against the truth (success: within 2° and 0.5 m), for the file's features and the same file
scrambled, under each re-weighting kernel (``robust_kernel``; the file's final scale, or
``--scale KERNEL=METRES``). A start that is right and a later stage that is not says the later stage
threw the right answer away.

    .venv/bin/python benchmarks/head_stages.py runs/ablation/synth/sequences/916 \\
        runs/ablation/synth/sequences/917 --per-bin 6 --scale geman-mcclure=0.1875
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np
from ablation import HEADING_BINS, spread  # beside this script

STAGES = ("consensus start", "+ re-weighting", "+ gated re-pointing")


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("sequences", nargs="+", type=Path, help="KITTI-layout sequence folders with poses")
    parser.add_argument("--weights", type=Path, default=None, help="weight file (default: the shipped one)")
    parser.add_argument("--per-bin", type=int, default=6, help="pairs per heading bin and sequence")
    parser.add_argument("--scale", action="append", default=[], metavar="KERNEL=METRES")
    parser.add_argument("--seed", type=int, default=0, help="seed of the pair sample and the scrambling")
    return parser.parse_args()


def main() -> None:
    args = parse_args()
    warnings.simplefilter("ignore")
    import torch

    from vcr_odom.data import open_sequence
    from vcr_odom.evaluation.ablation import feature_networks
    from vcr_odom.evaluation.gap_sweep import true_motions
    from vcr_odom.evaluation.revisits import RevisitOptions, candidate_pairs
    from vcr_odom.metrics import pair_errors
    from vcr_odom.model.config import ROBUST_KERNELS
    from vcr_odom.model.correspondence import consensus_start, robust_procrustes, to_homogeneous
    from vcr_odom.registration.vcr import VcrRegistrar

    registrar = VcrRegistrar(args.weights, device="cpu", seed=args.seed)
    config = registrar.config
    scales = {kernel: config.robust_scale for kernel in ROBUST_KERNELS}
    for item in args.scale:
        kernel, _, metres = item.partition("=")
        if kernel not in scales:
            raise SystemExit(f"--scale: kernel must be one of {', '.join(ROBUST_KERNELS)}; got {item!r}")
        scales[kernel] = float(metres)
    nets = feature_networks(registrar.model, args.seed)
    rng = np.random.default_rng(args.seed)
    right: dict[tuple[str, str], list[list[bool]]] = {}
    for folder in args.sequences:
        sequence = open_sequence(folder=folder)
        if sequence.gt_poses is None:
            raise SystemExit(f"{folder}: no ground-truth poses")
        found = candidate_pairs(sequence.gt_poses, RevisitOptions(max_heading_deg=180.0, limit=None))
        for low, high in HEADING_BINS:
            in_bin = [p for p in found if low <= p.heading_deg < high]
            chosen = spread(sorted(in_bin, key=lambda p: p.distance_m), args.per_bin, rng)
            truths = true_motions(sequence.gt_poses, [(p.target, p.source) for p in chosen]) if chosen else []
            for pair, truth in zip(chosen, truths, strict=True):
                source, target = (
                    torch.from_numpy(registrar.network_input(np.asarray(sequence.frame(i), np.float32)))[None]
                    for i in (pair.source, pair.target)
                )

                def success(rotation: torch.Tensor, translation: torch.Tensor) -> bool:
                    estimate = to_homogeneous(rotation, translation)[0].double().numpy()
                    return pair_errors(estimate[None], truth[None]).success_rate == 1.0  # noqa: B023

                for name in ("weights", "scrambled"):
                    net = nets[name]
                    with torch.inference_mode():
                        found_matches = net.match_features(
                            source, net.encode(source), target, net.encode(target)
                        )
                        matches, key_weights = found_matches.correspondences, found_matches.key_weights
                        keys, virtual = matches.key_points, matches.virtual_points
                        start = consensus_start(
                            keys,
                            virtual,
                            None,
                            config.consensus_hypotheses,
                            config.consensus_threshold,
                            config.consensus_seeds,
                            config.consensus_group,
                        )
                        for kernel, scale in scales.items():
                            net.config = config.with_changes(robust_kernel=kernel, robust_scale=scale)
                            rounds = robust_procrustes(
                                keys,
                                virtual,
                                None,
                                iterations=config.robust_iterations,
                                scale=scale,
                                hypotheses=config.consensus_hypotheses,
                                threshold=config.consensus_threshold,
                                seeds=config.consensus_seeds,
                                group=config.consensus_group,
                                kernel=kernel,
                            )
                            full = net.pose_head(matches, key_weights, target, "full")
                            outcome = [success(*start), success(*rounds), success(*full)]
                            right.setdefault((name, kernel), []).append(outcome)
                        net.config = config
    print(f"{len(next(iter(right.values())))} revisit pairs; share registered right after each stage\n")
    print("| features | kernel (final scale) | " + " | ".join(STAGES) + " |")
    print("|---|---|" + "---|" * len(STAGES))
    for (name, kernel), outcomes in right.items():
        shares = " | ".join(f"{100 * share:.0f} %" for share in np.mean(outcomes, axis=0))
        print(f"| {name} | {kernel} ({scales[kernel]} m) | {shares} |")


if __name__ == "__main__":
    main()
