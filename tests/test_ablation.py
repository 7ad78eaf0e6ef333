"""The ablation benchmark's parts: the scrambled control, the scoring, and one run on a short drive."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vcr_odom.errors import ConfigError
from vcr_odom.evaluation.ablation import (
    FEATURES,
    AblationPair,
    PairSet,
    _Outcome,
    markdown_table,
    run_ablation,
    scrambled_copy,
    summarise,
    surest,
)
from vcr_odom.evaluation.gap_sweep import true_motions
from vcr_odom.model import VcrConfig
from vcr_odom.model.correspondence import virtual_correspondences
from vcr_odom.model.network import POSE_HEADS, VCRNet
from vcr_odom.model.weights import default_weights_path
from vcr_odom.synth import SynthSequence


def test_scrambling_keeps_every_tensor_s_values_and_moves_them() -> None:
    torch.manual_seed(0)
    net = VCRNet(VcrConfig(num_points=64, k=8, point_dim=16, graph_dim=16, spatial_dim=16, feature_dim=32))
    scrambled = scrambled_copy(net, seed=1)
    original, shuffled = net.state_dict(), scrambled.state_dict()
    assert original.keys() == shuffled.keys()
    moved = 0
    for name, tensor in original.items():
        assert shuffled[name].shape == tensor.shape
        assert torch.equal(shuffled[name].reshape(-1).sort().values, tensor.reshape(-1).sort().values), name
        moved += int(not torch.equal(shuffled[name], tensor))
    assert moved > len(original) // 2  # constant tensors (LayerNorm's ones) cannot move
    assert torch.equal(
        scrambled_copy(net, seed=1).state_dict()["log_temperature"], shuffled["log_temperature"]
    )


def _turned(yaw_deg: float, shift: float) -> np.ndarray:
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    transform = np.eye(4)
    transform[:2, :2] = [[c, -s], [s, c]]
    transform[0, 3] = shift
    return transform


def test_rows_score_success_rmse_and_length_against_hand_computed_figures() -> None:
    truth = _turned(0.0, 4.0)
    outcomes = [
        _Outcome(0.5, 0.9, {head: truth for head in POSE_HEADS}),  # right
        _Outcome(0.3, 0.8, {head: truth @ _turned(3.0, 0.0) for head in POSE_HEADS}),  # 3 deg off
        _Outcome(0.1, 0.7, {head: _turned(0.0, 3.0) for head in POSE_HEADS}),  # 1 m short
    ]
    row = summarise("r", "weights", "full", outcomes, [truth] * 3)
    assert row.num_pairs == 3
    assert row.inlier_ratio == pytest.approx(0.3)
    assert row.overlap == pytest.approx(0.8)
    assert row.success_rate == pytest.approx(1 / 3)
    assert row.rot_rmse_deg == pytest.approx(np.sqrt(9 / 3), rel=1e-6)
    # The turned estimate keeps its translation; the short one is 1 m off.
    assert row.trans_rmse_m == pytest.approx(np.sqrt(1 / 3), rel=1e-6)
    assert row.length_ratio == pytest.approx(11 / 12)


@pytest.fixture(scope="module")
def drive() -> SynthSequence:
    return SynthSequence(frames=4, seed=5, speed=10.0)


def test_an_ablation_run_gives_every_regime_feature_set_and_head(drive: SynthSequence) -> None:
    poses = drive.gt_poses
    pairs = [(0, 1), (1, 2), (2, 3)]
    truths = true_motions(poses, pairs)
    pair_set = PairSet(
        "drive",
        drive.frame,
        [AblationPair("drive, 1 apart", "drive", t, s, m) for (t, s), m in zip(pairs, truths, strict=True)],
    )
    rows = run_ablation(default_weights_path("default"), [pair_set], features=("weights", "fpfh"))
    assert [(r.features, r.head) for r in rows] == [(f, h) for f in ("weights", "fpfh") for h in POSE_HEADS]
    assert all(r.num_pairs == 3 and 0.0 <= r.inlier_ratio <= 1.0 and 0.5 < r.overlap <= 1.0 for r in rows)
    full = next(r for r in rows if r.features == "weights" and r.head == "full")
    assert full.success_rate == 1.0  # the shipped file registers consecutive frames of a car drive
    table = markdown_table(rows)
    assert table.count("| drive, 1 apart |") == 2
    with pytest.raises(ConfigError, match="--features"):
        run_ablation(default_weights_path("default"), [pair_set], features=("sift",))
    assert set(FEATURES) == {"weights", "scrambled", "random-init", "fpfh"}


def test_the_paper_head_reads_the_best_ranked_quarter_of_the_key_points() -> None:
    source = torch.randn(1, 40, 3)
    target = source + 1.0
    affinity = torch.full((1, 40, 40), -10.0)  # each row's best match is its own point
    affinity[0, torch.arange(40), torch.arange(40)] = torch.linspace(-4.0, 0.0, 40)  # surer down the rows
    matches = virtual_correspondences(source, target, affinity, 40, 4)
    kept, weights = surest(matches, torch.arange(40.0).unsqueeze(0))
    assert kept.key_points.shape == (1, 10, 3) and weights.shape == (1, 10)
    assert kept.key_indices[0].tolist() == list(range(39, 29, -1))  # the ten surest rows, surest first
    assert torch.equal(kept.virtual_points, matches.virtual_points[:, :10])
