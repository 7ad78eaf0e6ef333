"""benchmarks/odometry_error_split.py and benchmarks/loop_bound.py: what of an odometry's error loops
can undo, and the bound perfect loops reach on a random-walk odometry."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from vcr_odom.geometry import make_transform, rotation_from_euler_zyx
from vcr_odom.metrics.evo_errors import ate_rpe

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture
def bench(monkeypatch: pytest.MonkeyPatch) -> tuple[Any, Any]:
    """The two benchmark modules, importable from beside their scripts."""
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    import loop_bound
    import odometry_error_split

    return loop_bound, odometry_error_split


def _drift(truth: np.ndarray, step_error: np.ndarray) -> np.ndarray:
    poses = [truth[0]]
    for k in range(len(truth) - 1):
        poses.append(poses[-1] @ np.linalg.inv(truth[k]) @ truth[k + 1] @ step_error)
    return np.stack(poses)


def test_the_split_puts_a_heading_error_on_rotation_and_a_sideways_slip_on_translation(bench) -> None:
    loop_bound, split_module = bench
    truth = loop_bound.route_poses(loop_bound.ROUTES["loop"])
    turned = _drift(
        truth, make_transform(rotation_from_euler_zyx(math.radians(0.1), 0.0, 0.0), [0.0, 0.0, 0.0])
    )
    slipped = _drift(truth, make_transform(np.eye(3), [0.0, 0.02, 0.0]))

    heading = split_module.error_split(turned, truth)
    sideways = split_module.error_split(slipped, truth)
    assert heading.rotation_only_ate_m == pytest.approx(
        ate_rpe(turned, truth, alignment="se3").ate_trans_rmse_m
    )
    assert heading.translation_only_ate_m < 1e-9 and heading.rotation_share == pytest.approx(1.0)
    assert sideways.translation_only_ate_m == pytest.approx(
        ate_rpe(slipped, truth, alignment="se3").ate_trans_rmse_m
    )
    assert sideways.rotation_only_ate_m < 1e-9 and sideways.rotation_share == pytest.approx(0.0, abs=1e-9)
    exact = split_module.error_split(truth, truth)
    assert max(exact.rotation_only_ate_m, exact.translation_only_ate_m) < 1e-9
    with pytest.raises(ValueError, match="N x 4 x 4"):
        split_module.error_split(truth[:5], truth)


def test_perfect_loops_give_back_the_truth_and_undo_a_heading_bias(bench) -> None:
    loop_bound, _ = bench
    truth = loop_bound.route_poses(loop_bound.ROUTES["figure eight"])
    rng = np.random.default_rng(0)
    still = loop_bound.Regime("none", 1e-6, 1e-6)
    mapped, loops = loop_bound.perfect_loop_map(truth, loop_bound.noisy_odometry(truth, still, rng), still)
    assert loops >= 4  # the crossing and the way back to the start
    np.testing.assert_allclose(mapped, truth, atol=1e-4)  # the odometry is 4e-5 m off at most

    biased = loop_bound.Regime("bias", 0.01, 0.002, heading_bias_deg=0.05)
    result = loop_bound.trial(truth, biased, rng)
    assert result.odometry_ate_m > 1.0
    assert result.map_ate_m < 0.05 * result.odometry_ate_m


def test_no_loop_undoes_translation_noise_between_revisits(bench) -> None:
    """The bound the benchmark reports: with every loop perfect and the graph weighted by the true
    sigmas, a block driven once round keeps over a third of a translation random walk's ATE."""
    loop_bound, _ = bench
    truth = loop_bound.route_poses(loop_bound.ROUTES["loop"])
    rng = np.random.default_rng(1)
    noise = loop_bound.Regime("translation", 0.001, 0.03)
    trials = [loop_bound.trial(truth, noise, rng) for _ in range(8)]
    ratios = [t.map_ate_m / t.odometry_ate_m for t in trials]
    assert np.median(ratios) > 0.4
    assert all(t.rotation_share < 0.5 for t in trials)


def test_a_scale_error_is_invisible_to_loops(bench) -> None:
    """A route measured 3 % short still comes back to where it started: the loops agree with it."""
    loop_bound, split_module = bench
    error_split = split_module.error_split
    truth = loop_bound.route_poses(loop_bound.ROUTES["return"])
    short = loop_bound.Regime("short", 1e-4, 1e-4, scale_bias=-0.03)
    result = loop_bound.trial(truth, short, np.random.default_rng(2))
    odometry = loop_bound.noisy_odometry(truth, short, np.random.default_rng(2))

    def lengths(poses: np.ndarray) -> np.ndarray:
        return np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)

    np.testing.assert_allclose(lengths(odometry), 0.97 * lengths(truth), rtol=1e-3)
    assert error_split(odometry, truth).scale_error == pytest.approx(-0.03, abs=1e-3)
    assert result.odometry_ate_m > 1.0
    assert result.map_ate_m > 0.9 * result.odometry_ate_m
