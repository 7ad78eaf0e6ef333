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
from typing import TYPE_CHECKING

import numpy as np
from ablation import HEADING_BINS, spread  # beside this script
from numpy.typing import NDArray

if TYPE_CHECKING:
    from torch import Tensor

    from vcr_odom.model.config import VcrConfig
    from vcr_odom.model.correspondence import VirtualCorrespondences
    from vcr_odom.model.network import VCRNet

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


def head_estimate(
    net: VCRNet,
    config: VcrConfig,
    matches: VirtualCorrespondences,
    key_weights: Tensor,
    target: Tensor,
    head: str,
) -> NDArray[np.float64]:
    """``net.pose_head`` run under ``config`` (the head reads its settings from the network)."""
    from vcr_odom.model.correspondence import to_homogeneous

    own, net.config = net.config, config
    try:
        rotation, translation = net.pose_head(matches, key_weights, target, head)
    finally:
        net.config = own
    return to_homogeneous(rotation, translation)[0].double().numpy()


def stage_outcomes(
    net: VCRNet, source: Tensor, target: Tensor, truth: NDArray[np.float64], scales: dict[str, float]
) -> dict[str, list[bool]]:
    """Per kernel, whether the consensus start, the re-weighting and the full head are right."""
    from vcr_odom.metrics import pair_errors

    found = net.match_features(source, net.encode(source), target, net.encode(target))
    matches, key_weights, base = found.correspondences, found.key_weights, net.config
    outcomes = {}
    for kernel, scale in scales.items():
        config = base.with_changes(robust_kernel=kernel, robust_scale=scale)
        stages = (
            (config.with_changes(robust_iterations=0), "consensus"),
            (config, "consensus"),
            (config, "full"),
        )
        estimates = [head_estimate(net, c, matches, key_weights, target, head) for c, head in stages]
        outcomes[kernel] = [pair_errors(e[None], truth[None]).success_rate == 1.0 for e in estimates]
    return outcomes


def main() -> None:
    args = parse_args()
    warnings.simplefilter("ignore")
    import torch

    from vcr_odom.data import open_sequence
    from vcr_odom.evaluation.ablation import feature_networks
    from vcr_odom.evaluation.gap_sweep import true_motions
    from vcr_odom.evaluation.revisits import RevisitOptions, candidate_pairs
    from vcr_odom.model.config import ROBUST_KERNELS
    from vcr_odom.registration.vcr import VcrRegistrar

    registrar = VcrRegistrar(args.weights, device="cpu", seed=args.seed)
    scales = {kernel: registrar.config.robust_scale for kernel in ROBUST_KERNELS}
    for item in args.scale:
        kernel, _, metres = item.partition("=")
        if kernel not in scales:
            raise SystemExit(f"--scale: kernel must be one of {', '.join(ROBUST_KERNELS)}; got {item!r}")
        scales[kernel] = float(metres)
    nets = {
        name: net
        for name, net in feature_networks(registrar.model, args.seed).items()
        if name != "random-init"
    }
    rng = np.random.default_rng(args.seed)
    right: dict[tuple[str, str], list[list[bool]]] = {}
    for folder in args.sequences:
        sequence = open_sequence(folder=folder)
        if sequence.gt_poses is None:
            raise SystemExit(f"{folder}: no ground-truth poses")
        found = candidate_pairs(sequence.gt_poses, RevisitOptions(max_heading_deg=180.0, limit=None))
        chosen = [
            pair
            for low, high in HEADING_BINS
            for pair in spread(
                sorted([p for p in found if low <= p.heading_deg < high], key=lambda p: p.distance_m),
                args.per_bin,
                rng,
            )
        ]
        truths = true_motions(sequence.gt_poses, [(p.target, p.source) for p in chosen]) if chosen else []
        for pair, truth in zip(chosen, truths, strict=True):
            source, target = (
                torch.from_numpy(registrar.network_input(np.asarray(sequence.frame(i), np.float32)))[None]
                for i in (pair.source, pair.target)
            )
            for name, net in nets.items():
                with torch.inference_mode():
                    for kernel, outcome in stage_outcomes(net, source, target, truth, scales).items():
                        right.setdefault((name, kernel), []).append(outcome)
    if not right:
        raise SystemExit("no revisit pairs in the given sequences")
    print(f"{len(next(iter(right.values())))} revisit pairs; share registered right after each stage\n")
    print("| features | kernel (final scale) | " + " | ".join(STAGES) + " |")
    print("|---|---|" + "---|" * len(STAGES))
    for (name, kernel), outcomes in right.items():
        shares = " | ".join(f"{100 * share:.0f} %" for share in np.mean(outcomes, axis=0))
        print(f"| {name} | {kernel} ({scales[kernel]} m) | {shares} |")


if __name__ == "__main__":
    main()
