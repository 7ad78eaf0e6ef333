"""The frame loop: chaining convention, initial guesses, frame selection, Ctrl-C and result folders."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vcr_odom.data.selection import select_frames
from vcr_odom.errors import ConfigError
from vcr_odom.geometry import make_transform, relative, rotation_from_euler_zyx
from vcr_odom.odometry import InitialGuess, MotionLimits, Odometry, run_odometry
from vcr_odom.registration.base import RegistrationResult
from vcr_odom.results import create_result_folder, provenance, write_json


class ToySequence:
    """Frames that carry their own index, and a known trajectory to register against."""

    name = "toy"
    tr_velo_to_cam = None

    def __init__(self, poses: np.ndarray):
        self._poses = poses

    def __len__(self) -> int:
        return len(self._poses)

    def frame(self, index: int) -> np.ndarray:
        return np.full((1, 4), index, dtype=np.float32)

    @property
    def gt_poses(self) -> np.ndarray:
        return self._poses

    @property
    def timestamps(self) -> np.ndarray:
        return np.arange(len(self._poses)) * 0.1


class OracleRegistrar:
    """Returns the true T_target_source and records the initial guesses it was given."""

    name = "oracle"
    needs_initial_guess = True

    def __init__(self, poses: np.ndarray, interrupt_at: int | None = None):
        self.poses = poses
        self.guesses: list[np.ndarray] = []
        self.prepared: list[int] = []
        self.interrupt_at = interrupt_at

    def prepare(self, points: np.ndarray) -> int:
        index = int(points[0, 0])
        if index == self.interrupt_at:
            raise KeyboardInterrupt
        self.prepared.append(index)
        return index

    def register(self, source: int, target: int, initial_guess=None) -> RegistrationResult:
        self.guesses.append(initial_guess)
        return RegistrationResult(relative(self.poses[target], self.poses[source]))


def curved_poses(count: int = 12) -> np.ndarray:
    return np.stack(
        [
            make_transform(rotation_from_euler_zyx(0.05 * i, 0.0, 0.0), [i * 1.0, 0.1 * i * i, 0.0])
            for i in range(count)
        ]
    )


def test_chaining_follows_pose_t_plus_1_equals_pose_t_at_relative():
    poses = curved_poses()
    registrar = OracleRegistrar(poses)
    run = run_odometry(ToySequence(poses), Odometry(registrar), range(len(poses)))
    np.testing.assert_allclose(run.poses, poses, atol=1e-12)
    assert registrar.prepared == list(range(len(poses)))  # each frame prepared exactly once
    assert run.frame_indices == list(range(len(poses)))
    assert {"load", "prepare", "register", "advance", "waiting", "bookkeeping"} == set(run.stage_seconds)


def test_strided_run_matches_strided_ground_truth():
    poses = curved_poses(20)
    indices = select_frames(20, None, 5)
    run = run_odometry(ToySequence(poses), Odometry(OracleRegistrar(poses)), indices)
    np.testing.assert_allclose(run.poses, poses[indices], atol=1e-12)


def test_initial_guess_modes():
    poses = curved_poses(5)
    constant = OracleRegistrar(poses)
    run_odometry(
        ToySequence(poses), Odometry(constant, initial_guess=InitialGuess.CONSTANT_VELOCITY), range(5)
    )
    np.testing.assert_allclose(constant.guesses[0], np.eye(4))
    np.testing.assert_allclose(constant.guesses[2], relative(poses[1], poses[2]), atol=1e-12)
    identity = OracleRegistrar(poses)
    run_odometry(ToySequence(poses), Odometry(identity, initial_guess=InitialGuess.IDENTITY), range(5))
    assert all(np.array_equal(guess, np.eye(4)) for guess in identity.guesses)


def test_ctrl_c_returns_the_partial_trajectory():
    poses = curved_poses(10)
    run = run_odometry(ToySequence(poses), Odometry(OracleRegistrar(poses, interrupt_at=6)), range(10))
    assert run.interrupted
    assert run.frame_indices == list(range(6))
    np.testing.assert_allclose(run.poses, poses[:6], atol=1e-12)


@pytest.mark.parametrize(
    ("frames", "stride", "expected"),
    [(None, 1, list(range(10))), ("2:8", 2, [2, 4, 6]), (":4", 1, [0, 1, 2, 3]), ("-3:", 1, [7, 8, 9])],
)
def test_select_frames(frames, stride, expected):
    assert select_frames(10, frames, stride) == expected


@pytest.mark.parametrize(
    ("frames", "stride", "option"),
    [("5", 1, "--frames"), ("a:b", 1, "--frames"), ("0:1", 1, "at least 2"), (None, 0, "--stride")],
)
def test_select_frames_rejects_bad_options(frames, stride, option):
    with pytest.raises(ConfigError, match=option):
        select_frames(10, frames, stride)


def test_result_folders_are_unique_and_latest_waits_for_a_trajectory(tmp_path):
    first = create_result_folder(tmp_path, "run a/b")
    second = create_result_folder(tmp_path, "run a/b")
    assert first != second and first.is_dir() and second.is_dir()
    assert not (tmp_path / "latest").exists()  # neither holds a trajectory yet
    write_json(second / "config.json", provenance({"seed": 3, "path": second, "array": np.arange(3)}))
    saved = json.loads((second / "config.json").read_text())
    assert saved["config"] == {"seed": 3, "path": str(second), "array": [0, 1, 2]}
    assert saved["git_revision"] and saved["versions"]["numpy"] == np.__version__


class WildRegistrar(OracleRegistrar):
    """The oracle, except that one pair comes back as a 50 m jump (a failed global registration)."""

    def __init__(self, poses: np.ndarray, wild_source: int):
        super().__init__(poses)
        self.wild_source = wild_source

    def register(self, source: int, target: int, initial_guess=None) -> RegistrationResult:
        if source == self.wild_source:
            return RegistrationResult(make_transform(np.eye(3), [50.0, 0.0, 0.0]))
        return super().register(source, target, initial_guess)


def test_an_implausible_motion_is_replaced_by_the_previous_one_and_flagged():
    poses = np.stack([make_transform(np.eye(3), [1.0 * i, 0.0, 0.0]) for i in range(8)])
    run = run_odometry(ToySequence(poses), Odometry(WildRegistrar(poses, wild_source=4)), range(8))
    assert run.flagged_frames == [4]
    assert "moved 50.0 m in 0.10 s" in run.per_frame_info[4]["reason"]
    # Constant velocity (1 m per frame) stands in for the failed pair: the trajectory stays exact here.
    np.testing.assert_allclose(run.poses, poses, atol=1e-12)


def test_motion_limits_scale_with_the_time_between_frames():
    limits = MotionLimits(max_speed_m_s=40.0, max_turn_rate_deg_s=90.0)
    four_metres = make_transform(np.eye(3), [4.0, 0.0, 0.0])
    turn = make_transform(rotation_from_euler_zyx(np.radians(20.0), 0.0, 0.0), [0.0, 0.0, 0.0])
    assert limits.violation(four_metres, 0.1) is None
    assert "moved" in limits.violation(make_transform(np.eye(3), [5.0, 0.0, 0.0]), 0.1)
    assert "turned" in limits.violation(turn, 0.1)
    assert limits.violation(turn, 0.5) is None  # stride 5: the same turn over five frames is fine


class SlidingRegistrar(OracleRegistrar):
    """The oracle, except that the pair into frame ``slide_at`` slides 2.4 m along x (a scan matcher
    in a corridor: 24 m/s at 10 Hz, under the 40 m/s limit)."""

    def __init__(self, poses: np.ndarray, slide_at: int):
        super().__init__(poses)
        self.slide_at = slide_at

    def register(self, source: int, target: int, initial_guess=None) -> RegistrationResult:
        result = super().register(source, target, initial_guess)
        if source == self.slide_at:
            return RegistrationResult(make_transform(np.eye(3), [2.4, 0.0, 0.0]) @ result.transform)
        return result


def walk(steps_m: list[float]) -> np.ndarray:
    return np.stack(
        [make_transform(np.eye(3), [x, 0.0, 0.0]) for x in np.concatenate([[0.0], np.cumsum(steps_m)])]
    )


def test_a_jump_from_a_walk_to_a_sprint_in_one_pair_is_replaced_and_flagged():
    poses = walk([0.15] * 12)
    run = run_odometry(ToySequence(poses), Odometry(SlidingRegistrar(poses, slide_at=8)), range(len(poses)))
    assert run.flagged_frames == [8]
    assert "where the recent pairs moved 1.5 m/s" in run.per_frame_info[8]["reason"]
    np.testing.assert_allclose(run.poses, poses, atol=1e-9)  # the walk's own velocity stands in


def test_a_change_of_speed_that_the_next_pairs_agree_on_is_believed_after_three():
    poses = walk([0.1] * 8 + [1.5] * 8)  # 1 m/s, then 15 m/s from frame 9 (beyond any real acceleration)
    run = run_odometry(ToySequence(poses), Odometry(OracleRegistrar(poses)), range(len(poses)))
    # The median of the last five estimates (as made, not as replaced) moves on after three.
    assert run.flagged_frames == [9, 10, 11]
    steps = np.diff(run.poses[:, 0, 3])
    np.testing.assert_allclose(steps[11:], 1.5)


def step(metres: float) -> np.ndarray:
    return make_transform(np.eye(3), [metres, 0.0, 0.0])


def test_motion_limits_bound_a_change_of_speed_by_acceleration_over_the_pair_plus_noise():
    limits = MotionLimits(max_acceleration_m_s2=20.0, step_noise_m=0.75)
    assert limits.violation(step(0.15), 0.1, recent_speed=1.5) is None
    assert "recent pairs moved 1.5 m/s" in limits.violation(step(2.4), 0.1, recent_speed=1.5)
    assert limits.violation(step(2.0), 0.1, recent_speed=20.8) is None  # a car braking at 8 m/s^2
    assert limits.violation(step(0.0), 0.1, recent_speed=9.0) is None  # 0.9 m off: within the noise
    assert limits.violation(step(2.4), 0.5, recent_speed=1.5) is None  # 2 Hz keyframes: 5.75 m allowed
    assert limits.violation(step(2.4), 0.1) is None  # no history yet: speed and turn limits only
