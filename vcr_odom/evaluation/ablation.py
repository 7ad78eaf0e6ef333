"""Ablation of VCR-Net: which part of a registration is the network's, regime by regime.

Why: the pose head (a consensus of random triples and compatible seeds, robust re-weighting, gated
re-pointing) is RANSAC and ICP in all but name; fed any reasonable correspondences it may register two
scans by itself. So the same pairs are registered with the head fed by the features of

- ``weights``: the weight file under test;
- ``scrambled``: the same file with every tensor's values randomly permuted (same shapes, same value
  distribution; the checks on load accept it);
- ``random-init``: a fresh initialisation of the same configuration;
- ``fpfh``: a hand-crafted descriptor (open3d's FPFH, computed on the scan as the FPFH baseline
  prepares it and read at the network's points), with the same affinity, key points and pointer;

and each feature set is read by the three heads of :meth:`VCRNet.pose_head` (``paper``: virtual points +
SVD; ``consensus``: no re-pointing; ``full``). The paper's head reads the surest ``PAPER_KEY_FRACTION``
of the key points (the paper's Top-K, with K = N / 4 rather than 7 N / 8): an SVD has no outlier
rejection, and at 7 N / 8 it reads the worst-matched points too (docs/benchmarks.md, "What the
network contributes", gives the choice). A figure that does not move when the weights are scrambled
is not the network's. The network's own correspondence quality is reported before any head:
the share of key points whose virtual point lies within ``INLIER_RADIUS_M`` of where the truth puts
them.

Every variant sees the same network inputs (each frame pre-processed once, as ``run`` does it) and each
frame is encoded once per variant, for every pair it belongs to.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from vcr_odom.errors import ConfigError
from vcr_odom.jsonsafe import json_safe
from vcr_odom.metrics import pair_errors
from vcr_odom.model.config import VcrConfig
from vcr_odom.model.correspondence import VirtualCorrespondences, feature_affinity, virtual_correspondences
from vcr_odom.model.network import POSE_HEADS, VCRNet

FEATURES: tuple[str, ...] = ("weights", "scrambled", "random-init", "fpfh")
INLIER_RADIUS_M = 1.0
"""A virtual point within this distance of the truth is right: the consensus's support radius."""
FPFH_MAX_RANGE_M = 80.0
"""FPFH is computed on the scan as the FPFH baseline thins it (0.5 m voxels), not on the network's
sparse points, where it would see too little; over the crop the shipped file sees."""
PAPER_KEY_FRACTION = 0.25
"""Share of the key points (the best-matched, as the network ranks them) the paper's head reads."""


@dataclass
class AblationPair:
    """One registration problem: frame ``source`` onto frame ``target`` of ``sequence``, truth
    ``T_target_source``; ``label`` names its regime row (e.g. ``kitti 5 apart``)."""

    label: str
    sequence: str
    target: int
    source: int
    truth: NDArray[np.float64]


@dataclass
class PairSet:
    """The pairs of one sequence and how to read its frames (``frame(index)`` -> raw points)."""

    sequence: str
    frame: Callable[[int], NDArray[np.float32]]
    pairs: list[AblationPair]


@dataclass
class AblationRow:
    """One regime x feature set x head: success, errors and the correspondences' inlier ratio."""

    regime: str
    features: str
    head: str
    num_pairs: int
    inlier_ratio: float
    overlap: float  # the most any features could match: points with a counterpart within 1 m
    success_rate: float
    rot_rmse_deg: float
    trans_rmse_m: float
    length_ratio: float

    def to_dict(self) -> dict[str, Any]:
        return json_safe(dict(self.__dict__))


# ---------------------------------------------------------------------------------- feature sets


def scrambled_copy(net: VCRNet, seed: int = 0) -> VCRNet:
    """The same network with each tensor's values permuted (seeded): same shapes, same distribution of
    values per tensor, none of the learned arrangement."""
    generator = torch.Generator().manual_seed(seed)
    scrambled = VCRNet(net.config)
    state = {}
    for name, tensor in net.state_dict().items():
        flat = tensor.detach().reshape(-1)
        state[name] = flat[torch.randperm(flat.numel(), generator=generator)].reshape(tensor.shape).clone()
    scrambled.load_state_dict(state)
    return scrambled.eval()


def random_init(config: VcrConfig, seed: int = 0) -> VCRNet:
    """A fresh initialisation of ``config`` (seeded), never trained."""
    torch.manual_seed(seed)
    return VCRNet(config).eval()


def feature_networks(net: VCRNet, seed: int = 0) -> dict[str, VCRNet]:
    """The network of each learned feature set, from the file's ``net``; every one runs with the file's
    inference settings."""
    net.eval()
    return {
        "weights": net,
        "scrambled": scrambled_copy(net, seed),
        "random-init": random_init(net.config, seed),
    }


def fpfh_descriptors(raw: NDArray[np.float32], points: NDArray[np.float32]) -> NDArray[np.float32]:
    """Unit-length FPFH at each of ``points``, computed as the project's FPFH baseline computes it on
    the scan ``raw`` (:class:`~vcr_odom.registration.fpfh.FpfhRansac`'s voxel and radii), over the
    network's crop, and read at each point's nearest voxel."""
    import open3d as o3d

    from vcr_odom.registration.fpfh import FpfhRansac

    prepared = FpfhRansac(max_range=FPFH_MAX_RANGE_M).prepare(raw)
    descriptors = np.asarray(prepared.features.data, dtype=np.float32).T  # (V, 33)
    tree = o3d.geometry.KDTreeFlann(prepared.cloud)
    rows = [tree.search_knn_vector_3d(p.astype(np.float64), 1)[1][0] for p in points]
    chosen = descriptors[rows]
    return chosen / np.maximum(np.linalg.norm(chosen, axis=1, keepdims=True), 1e-9)


# ------------------------------------------------------------------------------------ evaluation


@dataclass
class _Frame:
    points: torch.Tensor  # (1, N, 3) the network input
    raw: NDArray[np.float32]


class _FeatureSet:
    """One feature set's per-frame work (encoder and self-attention, or FPFH), done once per frame."""

    def __init__(self, name: str, net: VCRNet | None) -> None:
        self.name, self.net = name, net
        self._done: dict[int, Any] = {}

    def of(self, frame: _Frame) -> Any:
        key = id(frame)
        if key not in self._done:
            if self.net is None:
                descriptors = fpfh_descriptors(frame.raw, frame.points[0].numpy())
                self._done[key] = torch.from_numpy(descriptors).unsqueeze(0)
            else:
                features = self.net.encode(frame.points)
                self._done[key] = (features, self.net.attend(frame.points, features))
        return self._done[key]


@dataclass
class _Outcome:
    inlier_ratio: float
    overlap: float  # source points with a target point within INLIER_RADIUS_M of their true position
    estimates: dict[str, NDArray[np.float64]]  # head -> T_target_source


@torch.inference_mode()
def register_variants(
    reference: VCRNet, feature_set: _FeatureSet, source: _Frame, target: _Frame, truth: NDArray[np.float64]
) -> _Outcome:
    """One feature set's correspondences on one pair, their inlier ratio, and every head's pose.
    FPFH's correspondences are made and solved by ``reference`` (the file under test) with unit
    weights; a network's by that network."""
    src, tgt = source.points, target.points
    if feature_set.net is None:
        sharpened = reference.temperature / reference.config.inference_sharpening
        affinity = feature_affinity(feature_set.of(source), feature_set.of(target), sharpened)
        config = reference.config
        matches = virtual_correspondences(src, tgt, affinity, config.key_points(src.shape[1]), config.top_j)
        key_weights = torch.ones(matches.key_indices.shape, dtype=src.dtype)
        head_net = reference
    else:
        head_net = feature_set.net
        (f_src, a_src), (f_tgt, a_tgt) = feature_set.of(source), feature_set.of(target)
        found = head_net.match_features(src, f_src, tgt, f_tgt, source_attended=a_src, target_attended=a_tgt)
        matches, key_weights = found.correspondences, found.key_weights
    r_gt = torch.as_tensor(truth[:3, :3], dtype=src.dtype)
    t_gt = torch.as_tensor(truth[:3, 3], dtype=src.dtype)
    expected = matches.key_points[0] @ r_gt.T + t_gt
    inliers = (matches.virtual_points[0] - expected).norm(dim=-1) <= INLIER_RADIUS_M
    moved = src[0] @ r_gt.T + t_gt
    overlap = float((torch.cdist(moved, tgt[0]).amin(dim=1) <= INLIER_RADIUS_M).float().mean())
    estimates = {}
    for head in POSE_HEADS:
        read, weights = surest(matches, key_weights) if head == "paper" else (matches, key_weights)
        rotation, translation = head_net.pose_head(read, weights, tgt, head)
        transform = np.eye(4)
        transform[:3, :3] = rotation[0].double().numpy()
        transform[:3, 3] = translation[0].double().numpy()
        estimates[head] = transform
    return _Outcome(float(inliers.float().mean()), overlap, estimates)


def surest(
    matches: VirtualCorrespondences, key_weights: torch.Tensor, fraction: float = PAPER_KEY_FRACTION
) -> tuple[VirtualCorrespondences, torch.Tensor]:
    """The first ``fraction`` of the key points (they come ranked, best match first)."""
    keep = max(3, round(fraction * matches.key_points.shape[1]))
    return (
        VirtualCorrespondences(*(getattr(matches, f.name)[:, :keep] for f in fields(matches))),
        key_weights[:, :keep],
    )


def summarise(
    regime: str, features: str, head: str, outcomes: list[_Outcome], truths: list[NDArray[np.float64]]
) -> AblationRow:
    """One row: the pairs' errors (:func:`vcr_odom.metrics.pair_errors`, success under 2 deg and 0.5 m)
    and mean inlier ratio, and the length ratio mean |t_est| / mean |t_true|."""
    estimates = np.stack([outcome.estimates[head] for outcome in outcomes])
    truth = np.stack(truths)
    errors = pair_errors(estimates, truth)
    true_length = float(np.linalg.norm(truth[:, :3, 3], axis=1).mean())
    return AblationRow(
        regime=regime,
        features=features,
        head=head,
        num_pairs=len(outcomes),
        inlier_ratio=float(np.mean([o.inlier_ratio for o in outcomes])),
        overlap=float(np.mean([o.overlap for o in outcomes])),
        success_rate=errors.success_rate,
        rot_rmse_deg=errors.rot_rmse_deg,
        trans_rmse_m=errors.trans_rmse_m,
        length_ratio=float(np.linalg.norm(estimates[:, :3, 3], axis=1).mean()) / true_length
        if true_length > 0
        else float("nan"),
    )


def run_ablation(
    weights: Path,
    pair_sets: Sequence[PairSet],
    features: Sequence[str] = FEATURES,
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
) -> list[AblationRow]:
    """Every regime of ``pair_sets`` x feature set x head (rows in that order)."""
    unknown = sorted(set(features) - set(FEATURES))
    if unknown or not features:
        raise ConfigError(f"--features: give some of {', '.join(FEATURES)}; got {', '.join(features)}")
    from vcr_odom.registration.vcr import VcrRegistrar

    registrar = VcrRegistrar(weights, device="cpu", seed=seed)
    nets = feature_networks(registrar.model, seed)
    outcomes: dict[tuple[str, str], list[_Outcome]] = {}
    truths: dict[str, list[NDArray[np.float64]]] = {}
    total = sum(len(s.pairs) for s in pair_sets) * len(features)
    done = 0
    for pair_set in pair_sets:
        frames = {
            index: _Frame(torch.from_numpy(registrar.network_input(raw)).unsqueeze(0), raw)
            for index in sorted({i for pair in pair_set.pairs for i in (pair.source, pair.target)})
            for raw in [np.asarray(pair_set.frame(index), dtype=np.float32)]
        }
        for pair in pair_set.pairs:
            truths.setdefault(pair.label, []).append(pair.truth)
        for name in features:
            feature_set = _FeatureSet(name, nets.get(name))
            for pair in pair_set.pairs:
                outcome = register_variants(
                    nets["weights"], feature_set, frames[pair.source], frames[pair.target], pair.truth
                )
                outcomes.setdefault((pair.label, name), []).append(outcome)
                done += 1
                if progress is not None:
                    progress(done, total)
    return [
        summarise(regime, name, head, outcomes[(regime, name)], truths[regime])
        for regime in truths
        for name in features
        for head in POSE_HEADS
    ]


def markdown_table(rows: Sequence[AblationRow]) -> str:
    """One line per regime x feature set: the pairs' overlap (the points that have a counterpart within
    1 m: the most any features could match), the inlier ratio, then success and RMSE under each head."""
    lines = [
        "| regime | pairs | overlap (1 m) | features | inliers (1 m) | paper head: success, rot / trans "
        "RMSE | consensus | full head | full: length ratio |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    keyed = {(r.regime, r.features, r.head): r for r in rows}
    seen: list[tuple[str, str]] = []
    for row in rows:
        if (row.regime, row.features) not in seen:
            seen.append((row.regime, row.features))
    for regime, features in seen:
        cells = []
        for head in POSE_HEADS:
            r = keyed[(regime, features, head)]
            cells.append(f"{r.success_rate:.0%}, {r.rot_rmse_deg:.2f}° / {r.trans_rmse_m:.3f} m")
        first = keyed[(regime, features, POSE_HEADS[0])]
        full = keyed[(regime, features, "full")]
        lines.append(
            f"| {regime} | {first.num_pairs} | {first.overlap:.0%} | {features} | {first.inlier_ratio:.1%} | "
            + " | ".join(cells)
            + f" | {full.length_ratio:.3f} |"
        )
    return "\n".join(lines).replace("%", " %")
