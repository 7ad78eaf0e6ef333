"""The pose graph's odometry sigmas measured by the loops: an odometry noisier than the drift model
says (a handheld 16-beam walk at 10 Hz) must not make the graph drop its right loops, and a block-away
false loop must still be dropped there; an odometry within the model keeps its sigmas."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vcr_odom.geometry import invert, make_transform, rotation_angle, rotation_from_euler_zyx
from vcr_odom.loops.cycles import OUTLIER_SCALE_FLOOR, cycle_outliers, loop_cycles, odometry_scale
from vcr_odom.loops.drift import DriftModel
from vcr_odom.loops.graph import LOOP_SHARE, LoopEdge, loop_share, optimise
from vcr_odom.loops.nodes import Node

LOOP_INFORMATION = np.diag([math.radians(0.2) ** -2] * 3 + [0.05**-2] * 3)  # 0.2 deg, 5 cm


def _noisy_circle(noise_factor: float, seed: int = 7) -> tuple[list, list[Node]]:
    """True poses around a 40 m circle, a lap and a half, one node a step, and the odometry's: every
    step off by random noise ``noise_factor`` times the drift model's step sigmas."""
    rng = np.random.default_rng(seed)
    count = 60
    step = make_transform(
        rotation_from_euler_zyx(2 * math.pi / count, 0, 0), [2 * math.pi * 40 / count, 0, 0]
    )
    sigma_t, sigma_r = DriftModel().step_sigmas(float(np.linalg.norm(step[:3, 3])))
    truth, odometry = [np.eye(4)], [np.eye(4)]
    for _ in range(count + count // 2):
        noise = make_transform(
            Rotation.from_rotvec(rng.normal(0, noise_factor * sigma_r, 3)).as_matrix(),
            rng.normal(0, noise_factor * sigma_t, 3),
        )
        truth.append(truth[-1] @ step)
        odometry.append(odometry[-1] @ step @ noise)
    path = np.concatenate(
        [[0.0], np.cumsum([np.linalg.norm(b[:3, 3] - a[:3, 3]) for a, b in itertools.pairwise(odometry)])]
    )
    nodes = [
        Node(position=k, frame_index=k, pose=pose, path_m=float(path[k]), cloud=np.zeros((0, 3), np.float32))
        for k, pose in enumerate(odometry)
    ]
    return truth, nodes


def _sigmas(nodes: list[Node]) -> tuple[np.ndarray, np.ndarray]:
    poses = np.stack([node.pose for node in nodes])
    return DriftModel().chain_sigmas(poses, np.diff([node.position for node in nodes]).tolist())


def _true_loops(truth: list) -> list[LoopEdge]:
    return [LoopEdge(j, j - 60, invert(truth[j - 60]) @ truth[j], LOOP_INFORMATION) for j in range(60, 91, 2)]


@pytest.mark.parametrize("seed", [7, 8])
def test_an_odometry_within_the_model_keeps_its_sigmas(seed: int) -> None:
    truth, nodes = _noisy_circle(0.5, seed)
    scale = odometry_scale(loop_cycles(nodes, _true_loops(truth), _sigmas(nodes)))
    assert scale.cycles >= 50
    assert scale.median_ratio is not None and scale.median_ratio < 1.0
    assert scale.scale == 1.0


@pytest.mark.parametrize("seed", [7, 8])
def test_loops_measure_an_odometry_noisier_than_the_model(seed: int) -> None:
    """Noise 6x the model's sigmas: the cycles' median misclosure, in those sigmas, is near 6 (the
    median of a 3-D normal's length is 0.89 of its RMS; the larger of the rotation and translation
    ratios is taken)."""
    truth, nodes = _noisy_circle(6.0, seed)
    scale = odometry_scale(loop_cycles(nodes, _true_loops(truth), _sigmas(nodes)))
    assert 3.0 < scale.scale < 10.0


def test_few_cycles_leave_the_sigmas_alone() -> None:
    truth, nodes = _noisy_circle(6.0)
    two_loops = _true_loops(truth)[:2]
    scale = odometry_scale(loop_cycles(nodes, two_loops, _sigmas(nodes)))
    assert scale.cycles == 1 and scale.scale == 1.0


def test_a_noisy_odometry_keeps_its_right_loops_and_drops_a_block_away() -> None:
    truth, nodes = _noisy_circle(6.0)
    right = _true_loops(truth)
    block_away = make_transform(np.eye(3), [30.0, 0, 0])  # a look-alike place one block further on
    false_loop = LoopEdge(75, 25, block_away @ invert(truth[25]) @ truth[75], LOOP_INFORMATION)
    result = optimise(nodes, [*right, false_loop])
    assert result.odometry is not None and result.odometry.scale > 1.0
    assert result.kept == [True] * len(right) + [False]
    assert list(result.cycle_outliers) == [len(right)], "dropped by its cycles, before the robust rounds"
    assert result.loop_share == LOOP_SHARE, "many cycles: each loop keeps the drives' share"

    odometry = np.stack([node.pose for node in nodes])

    def apart(poses: np.ndarray, a: int, b: int) -> float:  # how far a-from-b is from the truth, metres
        error = invert(invert(truth[b]) @ truth[a]) @ invert(poses[b]) @ poses[a]
        return float(np.linalg.norm(error[:3, 3]))

    before = np.mean([apart(odometry, loop.source, loop.target) for loop in right])
    after = np.mean([apart(result.node_poses, loop.source, loop.target) for loop in right])
    assert after < before / 4  # the two laps pulled together (5.5 -> 0.7 m)
    assert apart(result.node_poses, 75, 25) < 10.0  # not a block (30 m) off; the odometry alone leaves 4 m


@pytest.mark.parametrize("seed", [7, 8])
def test_an_odometry_better_than_the_model_judges_the_cycles_by_what_they_measured(seed: int) -> None:
    """Odometry three times better than the drift model (a solid-state drive with the point-to-plane
    finish): most cycles of a loop 1 m off sideways close within 3 of the model's sigmas, but far beyond
    what the right loops' cycles measure; it is dropped by its cycles, and the right loops are all kept."""
    truth, nodes = _noisy_circle(0.3, seed)
    right = _true_loops(truth)
    sideways = make_transform(np.eye(3), [0.0, 1.0, 0.0])
    slid = LoopEdge(75, 15, sideways @ invert(truth[15]) @ truth[75], LOOP_INFORMATION)
    cycles = loop_cycles(nodes, [*right, slid], _sigmas(nodes))
    scale = odometry_scale(cycles)
    assert scale.scale == 1.0 and scale.median_ratio is not None and scale.median_ratio < 0.5
    assert not cycle_outliers(cycles, 1.0), "judged by the model's sigmas, most of its cycles close"
    assert scale.outlier_scale == OUTLIER_SCALE_FLOOR == scale.to_dict()["outlier_scale"]  # metrics.json
    result = optimise(nodes, [*right, slid])
    assert list(result.cycle_outliers) == [len(right)]
    assert result.kept == [True] * len(right) + [False]
    assert not optimise(nodes, right).cycle_outliers


def test_two_loops_that_agree_outvote_a_corroborated_one_that_slid() -> None:
    """Three loops, too few cycles to scale the sigmas, so a corroborated loop would keep its full
    weight; its fit slid 6 m along the street (both its starts slid alike: walk 1111). Its two cycles
    misclose while the other two loops close theirs: it is dropped before the rounds."""
    truth, nodes = _noisy_circle(0.5)
    right = [LoopEdge(j, j - 60, invert(truth[j - 60]) @ truth[j], LOOP_INFORMATION) for j in (62, 64)]
    slide = make_transform(np.eye(3), [6.0, 0, 0])
    slid = LoopEdge(66, 6, slide @ invert(truth[6]) @ truth[66], LOOP_INFORMATION, corroborated=True)
    result = optimise(nodes, [*right, slid])
    assert result.odometry is not None and result.odometry.cycles == 3
    assert result.cycle_outliers == {2: (2, 2)}
    assert result.kept == [True, True, False]


def test_two_loops_that_disagree_are_both_kept_by_their_cycle() -> None:
    """One cycle cannot say which of its two loops is wrong: the cycles drop neither (the graph's
    rounds weigh them)."""
    truth, nodes = _noisy_circle(0.5)
    right = LoopEdge(62, 2, invert(truth[2]) @ truth[62], LOOP_INFORMATION)
    slide = make_transform(np.eye(3), [6.0, 0, 0])
    slid = LoopEdge(66, 6, slide @ invert(truth[6]) @ truth[66], LOOP_INFORMATION)
    cycles = loop_cycles(nodes, [right, slid], _sigmas(nodes))
    assert len(cycles) == 1 and cycles[0].ratio > 3.0
    assert optimise(nodes, [right, slid]).cycle_outliers == {}


def test_a_lone_loop_closes_the_heading_it_measured() -> None:
    """One loop on a lap whose odometry drifted ~5 deg: the map takes the heading the loop measured
    (at 1/25 of its information, as where many loops pin a passage, half of the 5 deg stayed)."""
    truth, nodes = _noisy_circle(3.0)
    loop = LoopEdge(62, 2, invert(truth[2]) @ truth[62], LOOP_INFORMATION)
    result = optimise(nodes, [loop])
    assert result.loop_share == 1.0
    odometry = np.stack([node.pose for node in nodes])

    def heading_gap(poses: np.ndarray) -> float:
        error = invert(loop.transform) @ invert(poses[2]) @ poses[62]
        return math.degrees(rotation_angle(error[:3, :3]))

    assert heading_gap(odometry) > 4.0
    assert heading_gap(result.node_poses) < 0.1 * heading_gap(odometry)


def test_loops_that_weigh_each_other_keep_their_share_and_few_share_one_loops_worth() -> None:
    assert loop_share(16, cycles=50) == LOOP_SHARE
    assert loop_share(1, cycles=0) == 1.0
    assert loop_share(2, cycles=1) == 0.5
    assert loop_share(40, cycles=3) == LOOP_SHARE
