"""The polish's vgicp engine: small_gicp's Gaussian voxel map registers a frame started a metre and
five degrees off onto its true pose, a run with it follows a synthetic drive's ground truth as closely
as kiss-icp's own engine, the result says which engine ran, and an unknown engine is named."""

from __future__ import annotations

import json
from pathlib import Path
from typing import get_args

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vcr_odom.data import open_sequence
from vcr_odom.errors import ConfigError
from vcr_odom.geometry import invert, make_transform, motion_difference, transform_points
from vcr_odom.odometry.gaussian_map import GaussianMap
from vcr_odom.odometry.guided_kiss import ENGINES, PolishEngine
from vcr_odom.odometry.polish import KissIcpPolish


def _street(rng: np.random.Generator) -> np.ndarray:
    """Facades on both sides with doorways, a wall ahead and the road: every direction is measured."""
    along, up = np.meshgrid(np.arange(0.0, 30.0, 0.15), np.arange(0.0, 8.0, 0.15), indexing="ij")
    along, up = along.ravel(), up.ravel()
    doors = (np.floor(along / 3.0) % 2 == 0) | (up > 2.5)
    left = np.stack([along, np.full(along.size, 6.0) + 0.8 * ~doors, up - 1.5], axis=1)
    right = np.stack([along, np.full(along.size, -6.0), up - 1.5], axis=1)
    across, up2 = np.meshgrid(np.arange(-6.0, 6.0, 0.15), np.arange(0.0, 8.0, 0.15), indexing="ij")
    ahead = np.stack([np.full(across.size, 30.0), across.ravel(), up2.ravel() - 1.5], axis=1)
    a, b = np.meshgrid(np.arange(0.0, 30.0, 0.2), np.arange(-6.0, 6.0, 0.2), indexing="ij")
    road = np.stack([a.ravel(), b.ravel(), np.full(a.size, -1.5)], axis=1)
    cloud = np.concatenate([left, right, ahead, road])
    return cloud + rng.normal(scale=0.003, size=cloud.shape)


def test_a_frame_started_a_metre_off_lands_on_its_true_pose() -> None:
    world = _street(np.random.default_rng(0))
    true_pose = make_transform(Rotation.from_euler("z", 4.0, degrees=True).as_matrix(), [1.5, 0.3, 0.05])
    gaussian_map = GaussianMap(voxel_size=1.0, threads=1)
    gaussian_map.insert(world, np.eye(4))
    frame = transform_points(invert(true_pose), world)[::3]
    start = make_transform(Rotation.from_euler("zy", [5.0, 1.0], degrees=True).as_matrix(), [0.9, -0.5, 0.2])
    start = start @ true_pose
    assert motion_difference(start, true_pose)[0] > 0.9
    moved_m, turned_deg = motion_difference(gaussian_map.align(frame, start), true_pose)
    assert moved_m < 0.01 and turned_deg < 0.1
    assert np.array_equal(GaussianMap(voxel_size=1.0).align(frame, start), start)  # nothing to measure
    assert np.array_equal(gaussian_map.align(frame[:3], start), start)


@pytest.mark.filterwarnings("ignore:.*no timestamps")
def test_a_run_with_the_vgicp_engine_follows_the_ground_truth(
    small_synthetic_root: Path, tmp_path: Path
) -> None:
    from vcr_odom.data.selection import FrameSelection
    from vcr_odom.odometry.run import RunSettings, run_sequence

    selection = FrameSelection(data_root=small_synthetic_root, seq="00")
    truth = open_sequence("00", data_root=small_synthetic_root).gt_poses
    errors = {}
    for engine in ("kiss-icp", "vgicp"):
        settings = RunSettings(
            selection=selection, method="icp10", polish="kiss-icp", polish_engine=engine, results_dir=tmp_path
        )
        outcome = run_sequence(settings)
        assert json.loads((outcome.folder / "config.json").read_text())["config"]["polish_engine"] == engine
        poses = outcome.run.poses
        errors[engine] = max(
            motion_difference(invert(truth[0]) @ truth[i], poses[i])[0] for i in range(len(poses))
        )
    assert errors["vgicp"] < 0.06
    assert errors["vgicp"] < errors["kiss-icp"] + 0.01


def test_an_unknown_engine_is_named_with_the_choices() -> None:
    with pytest.raises(ConfigError, match=r"'gicp'.*kiss-icp, vgicp, vgicp-start"):
        KissIcpPolish(engine="gicp")  # type: ignore[arg-type]
    assert set(get_args(PolishEngine)) == set(ENGINES)  # the settings' choices are the engines


def _run(sequence, indices: list[int], engine: str, truth: np.ndarray):
    from scripted_registrar import ScriptedRegistrar

    from vcr_odom.odometry import Odometry, run_odometry

    polish = KissIcpPolish(engine=engine)  # type: ignore[arg-type]
    run = run_odometry(sequence, Odometry(ScriptedRegistrar(truth), polish, consult="on-doubt"), indices)
    return run, polish.kiss


def test_vgicp_start_is_kiss_icp_itself_where_its_predictions_hold(monkeypatch: pytest.MonkeyPatch) -> None:
    """Consecutive frames of a synthetic drive: kiss-icp's threshold stays below its initial one, so the
    engine never starts from VGICP, keeps no Gaussian map and gives kiss-icp's engine's poses."""
    from vcr_odom.geometry import normalise_to_first
    from vcr_odom.synth import SynthSequence

    sequence = SynthSequence(frames=12, seed=3)
    indices = list(range(12))
    truth = normalise_to_first(sequence.gt_poses[indices])
    own, _ = _run(sequence, indices, "kiss-icp", truth)
    starts: list[int] = []
    align = GaussianMap.align
    monkeypatch.setattr(GaussianMap, "align", lambda self, *args: starts.append(1) or align(self, *args))
    started, kiss = _run(sequence, indices, "vgicp-start", truth)
    assert not starts and kiss.gaussian_map is None
    np.testing.assert_allclose(started.poses, own.poses, atol=1e-9)


def test_vgicp_start_takes_over_where_kiss_icp_predictions_err_by_metres() -> None:
    """Frames one and eight apart in turn (keyframes of a stop-and-go): kiss-icp's constant-velocity
    prediction errs by metres, its threshold passes its initial one, and the engine starts kiss-icp's
    registration from VGICP's on a Gaussian map begun from kiss-icp's. kiss-icp's registration still
    places every frame (its accuracy on these scans, 0.1-0.3 m), and the starts VGICP gives it agree
    with the second start from standing still, so the network is asked on fewer pairs."""
    from vcr_odom.geometry import normalise_to_first
    from vcr_odom.metrics import trajectory_pair_errors
    from vcr_odom.odometry.chain import network_asked
    from vcr_odom.synth import SynthSequence

    sequence = SynthSequence(frames=29, seed=0)
    indices = [0, 1, 9, 10, 18, 19, 27, 28]
    truth = normalise_to_first(sequence.gt_poses[indices])
    own, _ = _run(sequence, indices, "kiss-icp", truth)
    started, kiss = _run(sequence, indices, "vgicp-start", truth)
    assert kiss.gaussian_map is not None and len(kiss.gaussian_map.voxels) > 0
    errors = [trajectory_pair_errors(run.poses, truth).trans_errors_m for run in (own, started)]
    assert np.all(errors[1] < errors[0] + 0.05)
    asked = [sum(map(network_asked, run.per_frame_info[1:])) for run in (own, started)]
    assert asked[1] < asked[0]
