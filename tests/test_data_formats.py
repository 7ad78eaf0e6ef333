"""Scan files as users have them: float64 .bin, 5-column .bin, macOS ._* files, cut-short .ply/.pcd."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
from click.testing import CliRunner

import vcr_odom.data.bin_scans as bin_scans
from vcr_odom.cli.main import cli
from vcr_odom.data import FolderSequence, KittiSequence, read_bin_scan, read_scan
from vcr_odom.data.bin_scans import bin_dtype
from vcr_odom.errors import ConfigError, DataError, DataWarning

EXIT_ERROR, EXIT_USAGE = 1, 2


def lidar_points(count: int = 2000, seed: int = 0) -> np.ndarray:
    """Points like a real scan: 2-80 m around the sensor, a few metres up or down, reflectance 0-1."""
    rng = np.random.default_rng(seed)
    azimuth, distance = rng.uniform(-np.pi, np.pi, count), rng.uniform(2.0, 80.0, count)
    return np.column_stack(
        [
            distance * np.cos(azimuth),
            distance * np.sin(azimuth),
            rng.uniform(-2.5, 3.0, count),
            rng.random(count),
        ]
    )


def quiet(factory, *args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        return factory(*args, **kwargs)


@pytest.fixture(autouse=True)
def _fresh_float64_warnings(monkeypatch):
    monkeypatch.setattr(bin_scans, "_float64_warned", set())


# --- float64 .bin -----------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["measured", "upcast-float32", "integers"])
def test_float64_bin_is_read_correctly_with_one_warning(tmp_path, kind):
    points = lidar_points()
    if kind == "upcast-float32":  # a float32 scan through numpy arithmetic, then .tofile()
        points = points.astype(np.float32).astype(np.float64)
    elif kind == "integers":
        points = np.round(points)
    for index in range(3):
        points.astype(np.float64).tofile(tmp_path / f"{index}.bin")
    sequence = quiet(FolderSequence, tmp_path)
    with pytest.warns(DataWarning, match=r"0\.bin.*float64.*astype\(np\.float32\)") as caught:
        frames = [sequence.frame(index) for index in range(3)]
    assert len([w for w in caught if issubclass(w.category, DataWarning)]) == 1  # once per folder
    for frame in frames:
        assert frame.dtype == np.float32 and frame.shape == (len(points), 4)
        np.testing.assert_allclose(frame, points, rtol=1e-6, atol=1e-5)


def test_float32_bins_are_never_reread_as_float64(tmp_path):
    rng = np.random.default_rng(3)
    cases = {
        "scan": lidar_points(4000).astype(np.float32),  # 64000 bytes: whole float64 records too
        "unit": rng.normal(size=(400, 4)).astype(np.float32),  # tiny values, as in the unit tests
        "zeros": np.zeros((8, 4), dtype=np.float32),
        "sparse": np.where(rng.random((400, 1)) < 0.7, 0.0, lidar_points(400)).astype(np.float32),
    }
    for name, points in cases.items():
        assert bin_dtype(points.tobytes()) == np.dtype("<f4"), name
        points.tofile(tmp_path / f"{name}.bin")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", DataWarning)
            np.testing.assert_array_equal(read_bin_scan(tmp_path / f"{name}.bin"), points)
        said = [str(w.message) for w in caught if issubclass(w.category, DataWarning)]
        only_for_zeros = [True] if name == "zeros" else []  # every point at the sensor is named, as such
        assert ["no returns" in message for message in said] == only_for_zeros, said


def test_float64_five_column_bin_is_detected_too(tmp_path):
    points = np.column_stack([lidar_points(500), np.arange(500) % 64])
    points.tofile(tmp_path / "scan.bin")
    with pytest.warns(DataWarning, match="float64"):
        frame = read_bin_scan(tmp_path / "scan.bin", columns=5)
    np.testing.assert_allclose(frame, points[:, :4], rtol=1e-6, atol=1e-5)


# --- column layouts ---------------------------------------------------------------------------------


def test_five_column_bins_in_a_folder_and_a_kitti_sequence(tmp_path):
    points = np.column_stack([lidar_points(300), np.arange(300) % 64]).astype(np.float32)  # x y z i ring
    for folder in (tmp_path / "scans", tmp_path / "kitti" / "sequences" / "00" / "velodyne"):
        folder.mkdir(parents=True)
        for index in range(2):
            points.tofile(folder / f"{index:06d}.bin")
    for sequence in (
        quiet(FolderSequence, tmp_path / "scans", bin_columns=5),
        quiet(KittiSequence, tmp_path / "kitti", "00", bin_columns=5),
    ):
        np.testing.assert_array_equal(sequence.frame(1), points[:, :4])
    xyz_only = tmp_path / "xyz"
    xyz_only.mkdir()
    points[:, :3].tofile(xyz_only / "0.bin")
    frame = read_scan(xyz_only / "0.bin", bin_columns=3)
    np.testing.assert_array_equal(frame[:, :3], points[:, :3])
    assert not frame[:, 3].any()


def test_wrong_column_count_names_the_file_and_the_option_that_fits(tmp_path):
    np.zeros((7, 5), dtype=np.float32).tofile(tmp_path / "0.bin")  # 140 bytes: not whole 16-byte records
    with pytest.raises(DataError) as error:
        FolderSequence(tmp_path)
    message = str(error.value)
    assert "0.bin" in message and "140 bytes" in message and "--bin-columns 5" in message
    with pytest.raises(ConfigError, match="--bin-columns"):
        FolderSequence(tmp_path, bin_columns=2)


def test_cli_bin_columns_option(tmp_path):
    from vcr_odom.synth import SynthSequence

    synth = SynthSequence(frames=3, seed=0)
    scans = tmp_path / "scans"
    scans.mkdir()
    for index in range(3):
        frame = synth.frame(index)
        np.column_stack([frame, np.zeros(len(frame), np.float32)]).tofile(scans / f"{index}.bin")
    run = ["run", "--folder", str(scans), "--method", "icp", "--results-dir", str(tmp_path / "results")]
    wrong = CliRunner().invoke(cli, run)
    assert wrong.exit_code == EXIT_ERROR and "0.bin" in wrong.output and "--bin-columns 5" in wrong.output
    right = CliRunner().invoke(cli, [*run, "--bin-columns", "5"])
    assert right.exit_code == 0, right.output
    bad = CliRunner().invoke(cli, [*run, "--bin-columns", "2"])
    assert bad.exit_code == EXIT_USAGE and "--bin-columns" in bad.output


# --- hidden files -----------------------------------------------------------------------------------


def test_macos_resource_forks_and_dot_files_are_not_frames(tmp_path):
    folder = tmp_path / "sequences" / "00" / "velodyne"
    folder.mkdir(parents=True)
    for index in range(2):
        lidar_points(100).astype(np.float32).tofile(folder / f"{index:06d}.bin")
        (folder / f"._{index:06d}.bin").write_bytes(b"\x00\x05\x16\x07" + b"\0" * 4000)  # AppleDouble
    (folder / ".hidden.pcd").write_text("not a scan")  # would otherwise be "mixed formats"
    assert len(quiet(FolderSequence, folder)) == 2
    assert [path.name for path in quiet(KittiSequence, tmp_path, "00").files] == ["000000.bin", "000001.bin"]


# --- cut-short .ply / .pcd --------------------------------------------------------------------------


def write_cloud(path: Path, count: int = 200, *, ascii_: bool = False) -> bytes:
    cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(lidar_points(count)[:, :3].astype(np.float32)))
    cloud.point["intensity"] = o3d.core.Tensor(np.ones((count, 1), dtype=np.float32))
    assert o3d.t.io.write_point_cloud(str(path), cloud, write_ascii=ascii_)
    return path.read_bytes()


@pytest.mark.parametrize("ext", ["ply", "pcd"])
@pytest.mark.parametrize("ascii_", [False, True], ids=["binary", "ascii"])
@pytest.mark.parametrize("keep", [0.5, 0.999])
def test_cut_short_clouds_are_a_data_error_naming_the_file(tmp_path, ext, ascii_, keep):
    whole = write_cloud(tmp_path / f"whole.{ext}", ascii_=ascii_)
    assert read_scan(tmp_path / f"whole.{ext}").shape == (200, 4)
    cut = tmp_path / f"cut.{ext}"
    cut.write_bytes(whole[: int(len(whole) * keep) - 1])
    with pytest.raises(DataError, match=rf"cut\.{ext}.*truncated"):
        read_scan(cut)


def test_compressed_pcd_cut_short_and_a_foreign_header(tmp_path):
    whole = write_cloud(tmp_path / "whole.pcd")
    compressed = whole.replace(b"DATA binary", b"DATA binary_compressed")
    header_end = compressed.index(b"binary_compressed\n") + len(b"binary_compressed\n")
    (tmp_path / "cut.pcd").write_bytes(compressed[:header_end] + (10_000).to_bytes(4, "little") + b"\0" * 20)
    with pytest.raises(DataError, match=r"cut\.pcd: truncated.*compressed"):
        read_scan(tmp_path / "cut.pcd")
    (tmp_path / "junk.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\n")  # no end_header
    with pytest.raises(DataError, match=r"junk\.ply"):
        read_scan(tmp_path / "junk.ply")


def test_cli_cut_short_cloud_exits_1_naming_the_file(tmp_path):
    scans = tmp_path / "scans"
    scans.mkdir()
    for index in range(2):
        write_cloud(scans / f"{index}.ply")
    data = (scans / "1.ply").read_bytes()
    (scans / "1.ply").write_bytes(data[: len(data) // 2])
    result = CliRunner().invoke(
        cli, ["run", "--folder", str(scans), "--method", "icp", "--results-dir", str(tmp_path / "r")]
    )
    assert result.exit_code == EXIT_ERROR, result.output
    assert "1.ply" in result.output and "truncated" in result.output
