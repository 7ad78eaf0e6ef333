"""The matching objective (what the features must do for a registration) and the pose heads it is
measured with: figures against hand-computed ones, and a tiny training run that must raise the
features' inlier ratio."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch
from test_train import TINY

from vcr_odom.errors import ConfigError
from vcr_odom.model.config import parse_inference_setting
from vcr_odom.model.correspondence import virtual_correspondences
from vcr_odom.model.losses import matching_loss
from vcr_odom.model.network import POSE_HEADS, VCRNet
from vcr_odom.training import TrainConfig, train


def _yaw(angle: float) -> torch.Tensor:
    c, s = math.cos(angle), math.sin(angle)
    return torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _grid_pair(shift: float = 0.0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """A 6 x 6 grid 5 m apart as the source; the target is it turned by 20 deg and moved, with the
    rows ``shift`` metres along x first (so 0 gives exact counterparts)."""
    xs = torch.arange(6, dtype=torch.float32) * 5.0
    source = torch.stack(torch.meshgrid(xs, xs, indexing="ij"), -1).reshape(-1, 2)
    source = torch.cat([source, torch.zeros(len(source), 1)], 1).unsqueeze(0)
    rotation, translation = _yaw(math.radians(20.0)), torch.tensor([3.0, -1.0, 0.5])
    target = (source + torch.tensor([shift, 0.0, 0.0])) @ rotation.T + translation
    return source, target, rotation.unsqueeze(0), translation.unsqueeze(0)


def _loss(source, target, rotation, translation, affinity, weights=None):
    n = source.shape[1]
    weights = torch.full((1, n), 0.5) if weights is None else weights
    vcp = virtual_correspondences(source, target, affinity, n, 4, source_weights=weights)
    return matching_loss(
        source,
        target,
        affinity,
        weights,
        weights,
        vcp.key_indices,
        vcp.key_points,
        vcp.virtual_points,
        rotation,
        translation,
        radius=2.0,
    )


def test_features_that_pick_the_counterpart_score_every_key_point_an_inlier() -> None:
    source, target, rotation, translation = _grid_pair()
    right = torch.full((1, 36, 36), -100.0)
    right[0, torch.arange(36), torch.arange(36)] = 0.0  # row i's best target point is point i
    # Every row points at another grid point, at least 5 m off (a shuffle: a shift along the grid
    # would keep the set's layout, and the SVD would still find the motion).
    shuffle = torch.randperm(36, generator=torch.Generator().manual_seed(0))
    shuffle = torch.where(shuffle == torch.arange(36), (shuffle + 7) % 36, shuffle)
    wrong = right[:, :, shuffle]
    good = _loss(source, target, rotation, translation, right)
    bad = _loss(source, target, rotation, translation, wrong)
    assert good.inlier_ratio == pytest.approx(1.0)
    assert bad.inlier_ratio == pytest.approx(0.0)
    # The only target point within 2 m is the counterpart: the right row's cross-entropy is ~0, the
    # wrong one pays the 100 logits it puts on the wrong point.
    assert good.matching < 1e-6
    assert bad.matching == pytest.approx(100.0, rel=1e-3)
    assert good.overlap_fraction == pytest.approx(1.0)
    # Exact virtual points: the paper's head recovers the motion, so the pose term is ~0.
    assert good.pose < 1e-3
    assert bad.pose > 1.0


def test_the_overlap_term_is_the_cross_entropy_of_each_weight_against_having_a_counterpart() -> None:
    source, target, rotation, translation = _grid_pair(shift=0.0)
    target = target.clone()
    target[0, :6] += 50.0  # the first six target points (and so six source points) lose their counterpart
    has = torch.ones(1, 36)
    has[0, :6] = 0.0
    affinity = torch.zeros(1, 36, 36)
    sure = _loss(source, target, rotation, translation, affinity, weights=has * 0.98 + 0.01)
    unsure = _loss(source, target, rotation, translation, affinity, weights=torch.full((1, 36), 0.5))
    assert sure.overlap == pytest.approx(-math.log(0.99), rel=1e-3)
    assert unsure.overlap == pytest.approx(math.log(2.0), rel=1e-3)
    assert sure.overlap_fraction == pytest.approx(30 / 36)


def test_the_pose_heads_on_exact_and_on_outlying_correspondences() -> None:
    torch.manual_seed(0)
    net = VCRNet(TINY.with_changes(consensus_seeds=0)).eval()
    source, target, _, translation = _grid_pair()
    affinity = torch.full((1, 36, 36), -100.0)
    affinity[0, torch.arange(36), torch.arange(36)] = 0.0
    affinity[0, :8] = torch.roll(affinity[0, :8], shifts=3, dims=1)  # 8 of 36 matched 15 m off
    vcp = virtual_correspondences(source, target, affinity, 36, 4)
    weights = torch.ones(1, 36)
    errors = {}
    for head in POSE_HEADS:
        _, t = net.pose_head(vcp, weights, target, head)
        errors[head] = float((t - translation).norm())
    # The SVD alone is pulled by the eight wrong matches; the consensus ignores them.
    assert errors["paper"] > 1.0
    assert errors["consensus"] < 1e-3 and errors["full"] < 1e-3
    with pytest.raises(ConfigError, match="pose head must be one of"):
        net.pose_head(vcp, weights, target, "ransac")  # type: ignore[arg-type]


def test_weighted_svd_is_an_inference_setting_given_as_true_or_false() -> None:
    assert parse_inference_setting("weighted_svd", "True") is True
    assert parse_inference_setting("weighted_svd", "false") is False
    with pytest.raises(ConfigError, match="expected true or false"):
        parse_inference_setting("weighted_svd", "1")


class _Resampled(torch.utils.data.Dataset):
    """A random street-like cloud and, as a second scan, the same cloud turned and moved, with a
    quarter of its points replaced by others (no counterpart) and the rest jittered by 5 cm."""

    def __init__(self, size: int, seed: int = 0) -> None:
        self.size, self.seed = size, seed

    def __len__(self) -> int:
        return self.size

    def __getitem__(self, index: int) -> dict[str, object]:
        g = torch.Generator().manual_seed(self.seed * 1000 + index)
        source = torch.randn(64, 3, generator=g) * torch.tensor([10.0, 10.0, 1.0])
        target = source + 0.05 * torch.randn(64, 3, generator=g)
        target[:16] = torch.randn(16, 3, generator=g) * torch.tensor([10.0, 10.0, 1.0])
        transform = torch.eye(4)
        transform[:3, :3] = _yaw(0.2 * (index % 3))
        transform[:3, 3] = torch.tensor([1.0, -0.5, 0.0]) * (index % 4)
        target = (target @ transform[:3, :3].T + transform[:3, 3])[torch.randperm(64, generator=g)]
        return {"source": source, "target": target, "transform": transform, "meta": str(index)}


def test_training_with_the_matching_objective_raises_the_inlier_ratio(tmp_path: Path) -> None:
    config = TrainConfig(
        epochs=12,
        batch_size=4,
        lr=3e-3,
        device="cpu",
        out=tmp_path,
        seed=1,
        objective="matching",
        select_on="inliers",
    )
    result = train(TINY, _Resampled(8), _Resampled(4), config)  # an overfit: validation = 4 of the 8
    first, last = result.history[0], result.history[-1]
    assert last["val_inlier_ratio"] > first["val_inlier_ratio"] + 0.05, (first, last)
    assert last["train_matching"] < 0.85 * first["train_matching"]
    assert result.best_score == pytest.approx(1.0 - max(h["val_inlier_ratio"] for h in result.history))


def test_selecting_on_inliers_needs_the_objective_that_measures_them() -> None:
    with pytest.raises(ConfigError, match="needs objective 'matching'"):
        TrainConfig(select_on="inliers")
    assert (
        TrainConfig(select_on="inliers", objective="matching", counterpart_radius=1.5).counterpart_radius
        == 1.5
    )
