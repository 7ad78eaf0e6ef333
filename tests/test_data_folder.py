"""Folder loader: .bin/.pcd/.ply read back, natural order, optional poses in either frame, bad inputs named."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

from vcr_odom.data import FolderSequence, LidarSequence, read_scan
from vcr_odom.errors import DataError, DataWarning
from vcr_odom.geometry import lidar_to_camera_poses, make_transform, rotation_from_euler_zyx
from vcr_odom.io import write_kitti_calib, write_kitti_poses, write_times

AXES = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
TR = make_transform(AXES, [-0.01, -0.05, -0.3])


def drive(count: int) -> np.ndarray:
    return np.stack(
        [
            make_transform(rotation_from_euler_zyx(0.03 * i, 0.0, 0.0), [0.9 * i, 0.0, 0.0])
            for i in range(count)
        ]
    )


def write_bins(folder: Path, names: list[str], seed: int = 0) -> dict[str, np.ndarray]:
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    frames = {}
    for name in names:
        frames[name] = rng.normal(size=(20, 4)).astype(np.float32)
        frames[name].tofile(folder / name)
    return frames


def write_o3d(path: Path, xyz: np.ndarray, **attributes: np.ndarray) -> None:
    cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(xyz.astype(np.float32)))
    for key, value in attributes.items():
        cloud.point[key] = o3d.core.Tensor(value)
    assert o3d.t.io.write_point_cloud(str(path), cloud)


def quiet(*args, **kwargs) -> FolderSequence:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        return FolderSequence(*args, **kwargs)


def test_bin_folder_is_sorted_naturally_and_read_back_exactly(tmp_path):
    names = [f"scan_{i}.bin" for i in (10, 2, 1, 0, 11)]
    frames = write_bins(tmp_path / "scans", names)
    (tmp_path / "scans" / "notes.txt").write_text("ignored")
    with pytest.warns(DataWarning, match="10 Hz") as caught:
        sequence = FolderSequence(tmp_path / "scans")
    assert len([w for w in caught if issubclass(w.category, DataWarning)]) == 1
    assert isinstance(sequence, LidarSequence)
    assert sequence.name == "folder/scans" and sequence.kind == ".bin"
    assert [p.name for p in sequence.files] == [
        "scan_0.bin",
        "scan_1.bin",
        "scan_2.bin",
        "scan_10.bin",
        "scan_11.bin",
    ]
    for index, path in enumerate(sequence.files):
        np.testing.assert_array_equal(sequence.frame(index), frames[path.name])
    np.testing.assert_allclose(sequence.timestamps, np.arange(5) * 0.1)
    assert sequence.gt_poses is None and sequence.tr_velo_to_cam is None


@pytest.mark.parametrize("ext", ["pcd", "ply"])
def test_open3d_scans_with_intensity(tmp_path, ext):
    rng = np.random.default_rng(1)
    xyz = rng.normal(size=(3, 30, 3)).astype(np.float32)
    intensity = rng.random((3, 30, 1)).astype(np.float32)
    for index in range(3):
        write_o3d(tmp_path / f"{index}.{ext}", xyz[index], intensity=intensity[index])
    sequence = quiet(tmp_path)
    for index in range(3):
        frame = sequence.frame(index)
        assert frame.dtype == np.float32 and frame.shape == (30, 4)
        np.testing.assert_array_equal(frame[:, :3], xyz[index])
        np.testing.assert_array_equal(frame[:, 3], intensity[index, :, 0])


@pytest.mark.parametrize("ext", ["pcd", "ply"])
def test_open3d_reflectance_from_colour_or_zeros(tmp_path, ext):
    xyz = np.random.default_rng(2).normal(size=(10, 3))
    colours = np.tile(np.array([[51, 0, 255]], dtype=np.uint8), (10, 1))
    write_o3d(tmp_path / f"coloured.{ext}", xyz, colors=colours)
    np.testing.assert_allclose(read_scan(tmp_path / f"coloured.{ext}")[:, 3], 0.2, atol=1e-6)
    write_o3d(tmp_path / f"plain.{ext}", xyz)
    plain = read_scan(tmp_path / f"plain.{ext}")
    assert plain.shape == (10, 4) and not plain[:, 3].any()


def test_open3d_nan_points_are_dropped(tmp_path):
    xyz = np.arange(30, dtype=np.float32).reshape(10, 3)
    xyz[3, 1] = np.nan
    write_o3d(tmp_path / "nan.ply", xyz)
    with pytest.warns(DataWarning, match=r"nan\.ply.*dropped 1 of 10"):
        points = read_scan(tmp_path / "nan.ply")
    np.testing.assert_array_equal(points[:, :3], np.delete(xyz, 3, axis=0))


def test_empty_and_corrupt_open3d_files(tmp_path):
    (tmp_path / "empty.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    )
    with pytest.warns(DataWarning, match=r"empty\.ply.*empty"):
        points = read_scan(tmp_path / "empty.ply")
    assert points.shape == (0, 4) and points.dtype == np.float32
    (tmp_path / "broken.pcd").write_text("not a point cloud")
    with pytest.raises(DataError, match=r"broken\.pcd"):
        read_scan(tmp_path / "broken.pcd")
    with pytest.raises(DataError, match=r"unsupported.*\.xyz"):
        read_scan(tmp_path / "cloud.xyz")


def test_lidar_frame_poses_without_calib(tmp_path):
    write_bins(tmp_path / "scans", [f"{i:03d}.bin" for i in range(4)])
    offset = make_transform(rotation_from_euler_zyx(1.0, 0.0, 0.0), [3.0, 4.0, 0.0])
    write_kitti_poses(tmp_path / "poses.txt", offset[None] @ drive(4))
    sequence = quiet(tmp_path / "scans", poses=tmp_path / "poses.txt")
    np.testing.assert_allclose(sequence.gt_poses, drive(4), atol=1e-7)
    assert sequence.gt_poses_camera is None


def test_camera_frame_poses_with_calib(tmp_path):
    write_bins(tmp_path / "scans", [f"{i:03d}.bin" for i in range(4)])
    write_kitti_poses(tmp_path / "poses.txt", lidar_to_camera_poses(drive(4), TR))
    write_kitti_calib(tmp_path / "calib.txt", {"Tr": TR})
    write_times(tmp_path / "times.txt", [0.0, 0.11, 0.19, 0.3])
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)
        sequence = FolderSequence(
            tmp_path / "scans",
            poses=tmp_path / "poses.txt",
            calib=tmp_path / "calib.txt",
            times=tmp_path / "times.txt",
        )
    np.testing.assert_allclose(sequence.gt_poses, drive(4), atol=1e-7)
    np.testing.assert_allclose(sequence.tr_velo_to_cam, TR, atol=1e-11)
    np.testing.assert_allclose(sequence.gt_poses_camera, lidar_to_camera_poses(drive(4), TR), atol=1e-7)
    assert sequence.gt_poses_camera[1][2, 3] > 0.85  # camera z is forward
    np.testing.assert_allclose(sequence.timestamps, [0.0, 0.11, 0.19, 0.3])


def test_calib_without_tr_is_an_error(tmp_path):
    write_bins(tmp_path / "scans", ["0.bin"])
    (tmp_path / "calib.txt").write_text("P0: " + " ".join(["1"] * 12) + "\n")
    with pytest.raises(DataError, match=r"calib\.txt.*Tr"):
        quiet(tmp_path / "scans", calib=tmp_path / "calib.txt")


def test_poses_length_mismatch(tmp_path):
    write_bins(tmp_path / "scans", ["0.bin", "1.bin"])
    write_kitti_poses(tmp_path / "poses.txt", drive(3))
    with pytest.raises(DataError) as error:
        quiet(tmp_path / "scans", poses=tmp_path / "poses.txt")
    assert (
        "poses.txt" in str(error.value)
        and "3 poses" in str(error.value)
        and "2 scan files" in str(error.value)
    )


def test_mixed_extensions_are_an_error(tmp_path):
    write_bins(tmp_path, ["0.bin"])
    write_o3d(tmp_path / "1.pcd", np.zeros((2, 3)))
    with pytest.raises(DataError, match=r"mixes scan formats \(\.bin, \.pcd\)"):
        FolderSequence(tmp_path)


def test_no_scans_names_the_folder(tmp_path):
    (tmp_path / "velodyne").mkdir()
    with pytest.raises(DataError) as error:
        FolderSequence(tmp_path)
    assert str(tmp_path) in str(error.value) and "velodyne" in str(error.value)
    with pytest.raises(DataError, match="does not exist"):
        FolderSequence(tmp_path / "nowhere")


def test_bad_bin_in_folder_names_the_file(tmp_path):
    write_bins(tmp_path, ["0.bin", "1.bin"])
    (tmp_path / "1.bin").write_bytes(b"\0" * 17)
    with pytest.raises(DataError, match=r"1\.bin.*17 bytes"):
        FolderSequence(tmp_path)


def test_a_scan_without_returns_is_named_when_read(tmp_path):
    write_bins(tmp_path, ["000000.bin", "000001.bin", "000002.bin"])
    np.zeros((5000, 4), np.float32).tofile(tmp_path / "000001.bin")  # every return missing
    sequence = quiet(tmp_path)
    with pytest.warns(DataWarning, match=r"000001\.bin: no returns: all 5000 points are at the sensor"):
        sequence.frame(1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sequence.frame(2)
