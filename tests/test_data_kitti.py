"""KITTI loader: exact round trips, camera <-> LiDAR frames, every bad input named, and the real sample."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

import vcr_odom.data.scans as scans
from vcr_odom.data import (
    DATA_ROOT_ENV,
    FolderSequence,
    KittiSequence,
    LidarSequence,
    open_sequence,
    read_bin_scan,
    resolve_data_root,
)
from vcr_odom.errors import ConfigError, DataError, DataWarning
from vcr_odom.geometry import (
    lidar_to_camera_poses,
    make_transform,
    relative,
    rotation_from_euler_zyx,
)
from vcr_odom.io import write_kitti_calib, write_kitti_poses, write_times

# A KITTI-like Tr: LiDAR (x fwd, y left, z up) -> camera (x right, y down, z fwd), slightly tilted.
AXES = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
TR = make_transform(AXES @ rotation_from_euler_zyx(0.004, -0.007, 0.008), [-0.012, -0.054, -0.292])


def lidar_drive(count: int) -> np.ndarray:
    """LiDAR-frame poses of a car driving forward (+x) about 0.8 m a frame with a gentle left turn."""
    return np.stack(
        [
            make_transform(rotation_from_euler_zyx(0.02 * i, 0.0, 0.0), [0.8 * i, 0.01 * i**2, 0.0])
            for i in range(count)
        ]
    )


def random_frames(count: int, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.normal(size=(int(rng.integers(50, 200)), 4)).astype(np.float32) for _ in range(count)]


def write_bin(path: Path, points: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.asarray(points, dtype=np.float32).tofile(path)


def make_kitti(
    root: Path,
    seq: str = "03",
    frames: list[np.ndarray] | None = None,
    poses_camera: np.ndarray | None = None,
    calib: bool = True,
    times: np.ndarray | None = None,
) -> Path:
    """Write a tiny KITTI odometry layout and return its root."""
    frames = random_frames(5) if frames is None else frames
    folder = root / "sequences" / seq
    for index, points in enumerate(frames):
        write_bin(folder / "velodyne" / f"{index:06d}.bin", points)
    if calib:
        write_kitti_calib(folder / "calib.txt", {"P0": np.eye(3, 4), "Tr": TR})
    if poses_camera is not None:
        write_kitti_poses(root / "poses" / f"{seq}.txt", poses_camera)
    if times is not None:
        write_times(folder / "times.txt", times)
    return root


def quiet(factory, *args, **kwargs):
    """Build a sequence with the expected 'no times.txt' warning silenced."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        return factory(*args, **kwargs)


# --- round trips -------------------------------------------------------------------------------------


def test_round_trip_frames_poses_calib_times(tmp_path):
    frames = random_frames(6)
    offset = make_transform(rotation_from_euler_zyx(0.3, 0.01, -0.02), [5.0, -2.0, 0.5])
    truth = lidar_drive(6)
    camera = lidar_to_camera_poses(offset[None] @ truth, TR)  # a file that does not start at identity
    times = np.arange(6) * 0.103 + 1.5
    root = make_kitti(tmp_path, frames=frames, poses_camera=camera, times=times)

    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)  # nothing to warn about here
        sequence = KittiSequence(root, "03")

    assert isinstance(sequence, LidarSequence)
    assert sequence.name == "kitti/03" and len(sequence) == 6
    assert sequence.sequence_path == root / "sequences" / "03"
    for index, expected in enumerate(frames):
        loaded = sequence.frame(index)
        assert loaded.dtype == np.float32 and loaded.shape == expected.shape
        np.testing.assert_array_equal(loaded, expected)
    np.testing.assert_array_equal(sequence.frame(-1), frames[-1])
    np.testing.assert_array_equal(np.concatenate(list(sequence)), np.concatenate(frames))

    np.testing.assert_allclose(sequence.tr_velo_to_cam, TR, atol=1e-11)
    np.testing.assert_allclose(sequence.timestamps, times, rtol=1e-6)
    gt = sequence.gt_poses
    assert gt.shape == (6, 4, 4) and gt.dtype == np.float64
    np.testing.assert_allclose(gt[0], np.eye(4), atol=1e-9)
    np.testing.assert_allclose(gt, truth, atol=1e-7)  # the LiDAR-frame drive comes back, offset removed
    np.testing.assert_allclose(sequence.gt_poses_camera[0], np.eye(4), atol=1e-9)
    np.testing.assert_allclose(lidar_to_camera_poses(gt, TR), sequence.gt_poses_camera, atol=1e-9)


def test_camera_frame_motion_is_along_z_and_lidar_motion_along_x(tmp_path):
    root = make_kitti(tmp_path, poses_camera=lidar_to_camera_poses(lidar_drive(5), TR))
    sequence = quiet(KittiSequence, root, 3)
    lidar_step = relative(sequence.gt_poses[:-1], sequence.gt_poses[1:])[:, :3, 3]
    camera_step = relative(sequence.gt_poses_camera[:-1], sequence.gt_poses_camera[1:])[:, :3, 3]
    assert np.all(lidar_step[:, 0] > 0.75) and np.all(np.abs(lidar_step[:, 2]) < 0.05)
    assert np.all(camera_step[:, 2] > 0.75) and np.all(np.abs(camera_step[:, 0]) < 0.1)


@pytest.mark.parametrize("seq", ["3", "03", 3])
def test_sequence_id_is_normalised_to_two_digits(tmp_path, seq):
    root = make_kitti(tmp_path, seq="03")
    sequence = quiet(KittiSequence, root, seq)
    assert sequence.seq == "03" and sequence.name == "kitti/03"


def test_frames_load_lazily(tmp_path, monkeypatch):
    folder = tmp_path / "sequences" / "00" / "velodyne"
    folder.mkdir(parents=True)
    point = np.zeros((1, 4), dtype=np.float32).tobytes()
    for index in range(4500):
        (folder / f"{index:06d}.bin").write_bytes(point)

    def forbidden(*args, **kwargs):
        raise AssertionError("a frame was read at construction")

    monkeypatch.setattr(scans, "read_bin_scan", forbidden)
    monkeypatch.setattr(scans, "clean_points", forbidden)
    sequence = quiet(KittiSequence, tmp_path, "00")
    assert len(sequence) == 4500 and len(sequence.timestamps) == 4500


# --- missing or optional files -----------------------------------------------------------------------


def test_no_times_txt_assumes_10_hz_with_one_warning(tmp_path):
    root = make_kitti(tmp_path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sequence = KittiSequence(root, "03")
        sequence.frame(0)
        _ = sequence.timestamps
    messages = [str(w.message) for w in caught if issubclass(w.category, DataWarning)]
    assert len(messages) == 1
    assert "times.txt" in messages[0] and "10 Hz" in messages[0] and "03" in messages[0]
    np.testing.assert_allclose(sequence.timestamps, np.arange(5) * 0.1)


def test_times_length_mismatch_is_an_error(tmp_path):
    root = make_kitti(tmp_path, times=np.arange(4) * 0.1)
    with pytest.raises(DataError, match=r"times\.txt.*4 timestamps but 5"):
        KittiSequence(root, "03")


def test_no_poses_file_means_no_ground_truth(tmp_path):
    sequence = quiet(KittiSequence, make_kitti(tmp_path), "03")
    assert sequence.gt_poses is None and sequence.gt_poses_camera is None and sequence.poses_path is None
    np.testing.assert_allclose(sequence.tr_velo_to_cam, TR, atol=1e-11)


def test_poses_length_mismatch_names_file_and_both_counts(tmp_path):
    root = make_kitti(tmp_path, poses_camera=lidar_to_camera_poses(lidar_drive(7), TR))
    with pytest.raises(DataError) as error:
        quiet(KittiSequence, root, "03")
    message = str(error.value)
    assert str(root / "poses" / "03.txt") in message and "7 poses" in message and "5 scan files" in message


def test_poses_without_calib_is_an_error(tmp_path):
    root = make_kitti(tmp_path, poses_camera=lidar_drive(5), calib=False)
    with pytest.raises(DataError) as error:
        quiet(KittiSequence, root, "03")
    assert "calib.txt" in str(error.value) and "03.txt" in str(error.value)


def test_poses_with_calib_lacking_tr_is_an_error(tmp_path):
    root = make_kitti(tmp_path, poses_camera=lidar_drive(5), calib=False)
    (root / "sequences" / "03" / "calib.txt").write_text("P0: " + " ".join(["0"] * 12) + "\n")
    with pytest.raises(DataError, match="no Tr line"):
        quiet(KittiSequence, root, "03")


def test_no_calib_and_no_poses_is_fine(tmp_path):
    sequence = quiet(KittiSequence, make_kitti(tmp_path, calib=False), "03")
    assert sequence.tr_velo_to_cam is None and sequence.gt_poses is None and sequence.calib_path is None


def test_non_rigid_tr_is_an_error(tmp_path):
    root = make_kitti(tmp_path, calib=False)
    write_kitti_calib(root / "sequences" / "03" / "calib.txt", {"Tr": 2.0 * np.eye(4)})
    with pytest.raises(DataError, match="orthonormal"):
        quiet(KittiSequence, root, "03")


# --- bad scans ---------------------------------------------------------------------------------------


def test_bin_size_not_multiple_of_16_names_the_file(tmp_path):
    root = make_kitti(tmp_path)
    bad = root / "sequences" / "03" / "velodyne" / "000002.bin"
    bad.write_bytes(bad.read_bytes()[:-6])
    with pytest.raises(DataError) as error:
        quiet(KittiSequence, root, "03")
    assert str(bad) in str(error.value) and "16" in str(error.value)
    with pytest.raises(DataError, match=r"000002\.bin"):
        read_bin_scan(bad)


def test_nan_and_inf_points_are_dropped_and_counted(tmp_path):
    points = np.arange(40, dtype=np.float32).reshape(10, 4)
    points[1, 0] = np.nan
    points[4, 2] = np.inf
    points[7, 3] = -np.inf
    root = make_kitti(tmp_path, frames=[points])
    sequence = quiet(KittiSequence, root, "03")
    with pytest.warns(DataWarning, match=r"000000\.bin.*dropped 3 of 10"):
        loaded = sequence.frame(0)
    np.testing.assert_array_equal(loaded, np.delete(points, [1, 4, 7], axis=0))


def test_empty_frame_warns_and_returns_0_by_4(tmp_path):
    root = make_kitti(tmp_path, frames=[np.zeros((3, 4)), np.zeros((0, 4))])
    sequence = quiet(KittiSequence, root, "03")
    with pytest.warns(DataWarning, match=r"000001\.bin.*empty"):
        loaded = sequence.frame(1)
    assert loaded.shape == (0, 4) and loaded.dtype == np.float32


def test_frame_index_out_of_range(tmp_path):
    sequence = quiet(KittiSequence, make_kitti(tmp_path), "03")
    with pytest.raises(IndexError, match=r"frame 5 out of range.*kitti/03 has 5 frames"):
        sequence.frame(5)
    with pytest.raises(IndexError, match="out of range"):
        sequence.frame(-6)
    with pytest.raises(TypeError):
        sequence.frame(1.0)
    np.testing.assert_array_equal(sequence.frame(np.int64(4)), sequence.frame(-1))


# --- missing sequences and roots ---------------------------------------------------------------------


def test_missing_sequence_lists_what_exists(tmp_path):
    make_kitti(tmp_path, seq="00")
    make_kitti(tmp_path, seq="07")
    with pytest.raises(DataError) as error:
        KittiSequence(tmp_path, "5")
    message = str(error.value)
    assert "'05'" in message and "00, 07" in message


def test_root_without_sequences_folder(tmp_path):
    with pytest.raises(DataError, match="no sequences/ folder"):
        KittiSequence(tmp_path, "00")
    with pytest.raises(DataError, match="does not exist"):
        KittiSequence(tmp_path / "nowhere", "00")


def test_sequence_without_scans(tmp_path):
    (tmp_path / "sequences" / "01").mkdir(parents=True)
    with pytest.raises(DataError, match="no velodyne/ folder"):
        KittiSequence(tmp_path, "01")
    (tmp_path / "sequences" / "01" / "velodyne").mkdir()
    with pytest.raises(DataError, match=r"no \.bin scans"):
        KittiSequence(tmp_path, "01")


# --- data root and open_sequence ---------------------------------------------------------------------


def test_resolve_data_root_option_then_environment(tmp_path, monkeypatch):
    other = tmp_path / "other"
    other.mkdir()
    monkeypatch.setenv(DATA_ROOT_ENV, str(other))
    assert resolve_data_root(tmp_path) == tmp_path  # the option wins
    assert resolve_data_root(str(tmp_path)) == tmp_path
    assert resolve_data_root(None) == other


def test_resolve_data_root_errors_name_the_option_and_variable(tmp_path, monkeypatch):
    monkeypatch.delenv(DATA_ROOT_ENV, raising=False)
    with pytest.raises(ConfigError) as error:
        resolve_data_root(None)
    assert "--data-root" in str(error.value) and DATA_ROOT_ENV in str(error.value)
    with pytest.raises(ConfigError, match=r"--data-root.*does not exist.*missing"):
        resolve_data_root(tmp_path / "missing")
    monkeypatch.setenv(DATA_ROOT_ENV, str(tmp_path / "gone"))
    with pytest.raises(ConfigError, match=rf"\${DATA_ROOT_ENV}.*gone"):
        resolve_data_root(None)


def test_open_sequence_picks_the_loader(tmp_path, monkeypatch):
    root = make_kitti(tmp_path / "kitti")
    monkeypatch.setenv(DATA_ROOT_ENV, str(root))
    assert isinstance(quiet(open_sequence, "3"), KittiSequence)
    assert isinstance(quiet(open_sequence, 3, data_root=root), KittiSequence)
    by_folder = quiet(open_sequence, folder=root / "sequences" / "03")
    assert isinstance(by_folder, KittiSequence) and by_folder.name == "kitti/03"
    plain = quiet(open_sequence, folder=root / "sequences" / "03" / "velodyne")
    assert isinstance(plain, FolderSequence) and len(plain) == 5
    with pytest.raises(ConfigError, match="exactly one"):
        open_sequence()
    with pytest.raises(ConfigError, match="exactly one"):
        open_sequence("03", folder=root)
    with pytest.raises(ConfigError, match="--poses"):
        open_sequence("03", poses=root / "poses.txt")


# --- the real KITTI sample ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sample(kitti_sample_root):
    return quiet(KittiSequence, kitti_sample_root, "00")


def test_real_sample_frames(sample):
    assert len(sample) == 60 and sample.name == "kitti/00"
    for points in sample:
        assert points.dtype == np.float32 and points.ndim == 2 and points.shape[1] == 4
        assert 113_000 <= len(points) <= 125_000
    np.testing.assert_allclose(np.diff(sample.timestamps), 0.1)


def test_real_sample_ground_truth_is_in_the_lidar_frame(sample):
    gt = sample.gt_poses
    assert gt.shape == (60, 4, 4)
    np.testing.assert_allclose(gt[0], np.eye(4), atol=1e-9)
    steps = relative(gt[:-1], gt[1:])[:, :3, 3]
    # The car drives forward: LiDAR x forward, z up; about 0.8-0.9 m a frame.
    assert np.mean(steps[:, 0] > 0.5) > 0.9
    assert np.all(np.abs(steps[:, 2]) < 0.1)
    assert np.median(np.abs(steps[:, 1])) < 0.1
    assert 0.6 < np.linalg.norm(steps, axis=1).mean() < 1.2
    camera = relative(sample.gt_poses_camera[:-1], sample.gt_poses_camera[1:])[:, :3, 3]
    assert np.mean(camera[:, 2] > 0.5) > 0.9  # camera z forward
    assert np.all(np.abs(camera[:, 1]) < 0.1)  # camera y is down: little vertical motion
