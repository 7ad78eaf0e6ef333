"""benchmarks/odometry_error_growth.py: the growth it reports tells errors that add up as independent
edge errors (what the loop phase's chain assumes) from a bias, and its shape ratio reads the blocks'
own scales."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vcr_odom.geometry import invert, make_transform, rotation_from_euler_zyx
from vcr_odom.loops.candidates import Chain
from vcr_odom.loops.nodes import Node

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "odometry_error_growth.py"
SIGMA_RAD, SIGMA_M = 0.002, 0.02
INFORMATION = np.diag([SIGMA_RAD**-2] * 3 + [SIGMA_M**-2] * 3)


def _drive(errors: np.ndarray) -> tuple[list[Node], np.ndarray]:
    """A winding drive of 3 m steps and an odometry whose step k errs by ``errors[k]`` (rotation
    vector, translation) on its earlier node's side, as a fit's information describes."""
    rng = np.random.default_rng(0)
    truth = [np.eye(4)]
    for _ in range(len(errors)):
        step = make_transform(rotation_from_euler_zyx(rng.normal(0, 0.1), 0.0, 0.0), [3.0, 0.0, 0.0])
        truth.append(truth[-1] @ step)
    odometry = [truth[0]]
    for k, error in enumerate(errors):
        wrong = make_transform(Rotation.from_rotvec(error[:3]).as_matrix(), error[3:])
        odometry.append(odometry[-1] @ wrong @ invert(truth[k]) @ truth[k + 1])
    nodes = [Node(k, k, pose, 3.0 * k, np.zeros((0, 3), np.float32)) for k, pose in enumerate(odometry)]
    return nodes, np.stack(truth)


@pytest.fixture
def growth(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.syspath_prepend(str(SCRIPT.parent))
    import odometry_error_growth

    return odometry_error_growth


def _medians(growth, nodes, truth, length):
    chain = Chain(np.stack([node.pose for node in nodes]), [INFORMATION] * (len(nodes) - 1))
    single = growth.stretch_growth(nodes, truth, chain, 1)
    stretch = growth.stretch_growth(nodes, truth, chain, length)
    return [float(np.median(s) / np.median(o)) for s, o in zip(stretch, single, strict=True)]


def test_independent_edge_errors_grow_as_the_chain_predicts_and_a_heading_bias_does_not(growth) -> None:
    rng = np.random.default_rng(1)
    count = 16 * 40
    scales = np.array([SIGMA_RAD] * 3 + [SIGMA_M] * 3)
    nodes, truth = _drive(rng.normal(size=(count, 6)) * scales)
    rotation, translation = _medians(growth, nodes, truth, 16)
    assert 0.6 < rotation < 1.6 and 0.6 < translation < 1.6, (rotation, translation)

    biased = rng.normal(size=(count, 6)) * scales
    biased[:, 2] += 2 * SIGMA_RAD  # the same heading error on every step
    nodes, truth = _drive(biased)
    rotation, _ = _medians(growth, nodes, truth, 16)
    assert rotation > 5, rotation


def test_the_shape_ratio_reads_how_much_more_the_rotation_errs_than_its_information_says(growth) -> None:
    rng = np.random.default_rng(2)
    count = 400
    for factor in (1.0, 9.0):
        scales = np.array([SIGMA_RAD * factor**0.5] * 3 + [SIGMA_M] * 3)
        nodes, truth = _drive(rng.normal(size=(count, 6)) * scales)
        rotation, translation = growth.edge_shape(nodes, truth, [INFORMATION] * count)
        ratio = float(np.median(rotation) / np.median(translation))
        assert ratio == pytest.approx(factor, rel=0.3), (factor, ratio)
