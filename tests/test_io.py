"""File formats round-trip, bad files are named in errors, and writes are atomic."""

import os
import threading

import numpy as np
import pytest
from evo.tools import file_interface
from scipy.spatial.transform import Rotation

from vcr_odom import io
from vcr_odom.errors import DataError
from vcr_odom.geometry import make_transform


def poses(count: int = 5) -> np.ndarray:
    rotations = Rotation.random(count, random_state=0).as_matrix()
    return np.stack([make_transform(r, [i, 2.0 * i, -0.5 * i]) for i, r in enumerate(rotations)])


def test_kitti_poses_round_trip_and_evo_reads_them(tmp_path):
    path = io.write_kitti_poses(tmp_path / "poses.txt", poses())
    np.testing.assert_allclose(io.read_kitti_poses(path), poses(), atol=1e-9)
    evo_path = file_interface.read_kitti_poses_file(str(path))
    np.testing.assert_allclose(np.stack(evo_path.poses_se3), poses(), atol=1e-9)


def test_tum_trajectory_matches_evo_reader(tmp_path):
    stamps = np.arange(5) * 0.1
    path = io.write_tum_trajectory(tmp_path / "traj.tum", poses(), stamps)
    trajectory = file_interface.read_tum_trajectory_file(str(path))
    np.testing.assert_allclose(trajectory.timestamps, stamps)
    np.testing.assert_allclose(np.stack(trajectory.poses_se3), poses(), atol=1e-8)


@pytest.mark.parametrize(
    ("content", "expected"),
    [("1 2 3\n", "expected 12 numbers"), ("", "empty"), ("a " * 12 + "\n", "expected 12 numbers")],
)
def test_bad_pose_files_are_named(tmp_path, content, expected):
    path = tmp_path / "bad.txt"
    path.write_text(content)
    with pytest.raises(DataError, match=expected) as error:
        io.read_kitti_poses(path)
    assert "bad.txt" in str(error.value)


def test_calib_round_trip_and_errors(tmp_path):
    tr = poses(2)[1]
    path = io.write_kitti_calib(tmp_path / "calib.txt", {"P0": np.arange(12.0), "Tr": tr})
    calib = io.read_kitti_calib(path)
    np.testing.assert_allclose(calib["Tr"], tr, atol=1e-12)
    np.testing.assert_allclose(calib["P0"], np.arange(12.0))
    (tmp_path / "broken.txt").write_text("Tr: 1 2 3\n")
    with pytest.raises(DataError, match=r"broken\.txt.*12 numbers"):
        io.read_kitti_calib(tmp_path / "broken.txt")


def test_atomic_write_keeps_old_file_when_interrupted(tmp_path, monkeypatch):
    target = tmp_path / "out.txt"
    target.write_text("old")

    def failing_replace(*_args):
        raise KeyboardInterrupt

    monkeypatch.setattr(io.os, "replace", failing_replace)
    with pytest.raises(KeyboardInterrupt):
        io.atomic_write_text(target, "new")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_pose_rotations_are_projected_and_non_rotations_rejected(tmp_path):
    noisy = poses()
    noisy[:, :3, :3] += 2e-7  # what 7 printed digits do to a rotation
    path = io.write_kitti_poses(tmp_path / "noisy.txt", noisy)
    rotations = io.read_kitti_poses(path)[:, :3, :3]
    np.testing.assert_allclose(
        np.swapaxes(rotations, 1, 2) @ rotations, np.broadcast_to(np.eye(3), (5, 3, 3)), atol=1e-14
    )
    scaled = poses()
    scaled[2, :3, :3] *= 2.0
    io.write_kitti_poses(tmp_path / "scaled.txt", scaled)
    with pytest.raises(DataError, match=r"scaled\.txt: pose 3 .*not a rotation"):
        io.read_kitti_poses(tmp_path / "scaled.txt")


def test_written_files_follow_the_umask_like_any_other_file(tmp_path):
    reference = tmp_path / "plain.txt"
    reference.write_text("x")
    written = io.atomic_write_text(tmp_path / "atomic.txt", "x")
    assert written.stat().st_mode == reference.stat().st_mode


@pytest.mark.parametrize(
    ("content", "line", "expected"),
    [
        (b"0\n0\n0\n", 2, "strictly increasing.*repeats"),
        (b"0.0\n0.2\n0.1\n", 3, "strictly increasing.*goes back"),
        (b"0.0 1\n0.1 2\n", 1, "one number.*2 columns"),
        (b"time\n0.0\n", 1, "one number.*'time'"),
        (b"0.0\nnan\n", 2, "one number.*'nan'"),
        (b"0.0\n0.1\n\xff\xfe\n", 3, "not UTF-8"),
    ],
    ids=["all-zero", "decreasing", "two-columns", "header-word", "nan", "not-utf8"],
)
def test_bad_times_files_name_the_file_the_line_and_what_was_expected(tmp_path, content, line, expected):
    path = tmp_path / "times.txt"
    path.write_bytes(content)
    with pytest.raises(DataError, match=expected) as error:
        io.read_times(path)
    assert str(error.value).startswith(f"{path}:{line}:")


def test_times_round_trip_exactly_skip_blank_lines_and_reject_empty_files(tmp_path):
    stamps = np.array([0.0, 0.1037, 0.2071, 1.7e9 + 0.123456789])  # an epoch stamp keeps its ns
    np.testing.assert_array_equal(io.read_times(io.write_times(tmp_path / "times.txt", stamps)), stamps)
    (tmp_path / "gaps.txt").write_text("\ufeff0.5\n\n0.6\n  \n")  # a BOM and blank lines are harmless
    np.testing.assert_array_equal(io.read_times(tmp_path / "gaps.txt"), [0.5, 0.6])
    (tmp_path / "empty.txt").write_text("\n")
    with pytest.raises(DataError, match=r"empty\.txt: no timestamps"):
        io.read_times(tmp_path / "empty.txt")
    with pytest.raises(DataError, match=r"not found.*missing\.txt"):
        io.read_times(tmp_path / "missing.txt")


@pytest.mark.parametrize("reader", [io.read_kitti_poses, io.read_kitti_calib])
def test_a_file_that_is_not_utf8_is_a_data_error_naming_it(tmp_path, reader) -> None:
    path = tmp_path / "latin1.txt"
    path.write_bytes("P0: 1 0 0\nTr: caf\xe9\n".encode("latin-1"))
    with pytest.raises(DataError, match=r"latin1\.txt:2: not UTF-8 text"):
        reader(path)


def test_an_output_that_is_a_link_updates_what_it_points_at_and_stays_a_link(tmp_path) -> None:
    target = tmp_path / "real.txt"
    target.write_text("old")
    link = tmp_path / "link.txt"
    link.symlink_to(target)
    io.atomic_write_text(link, "new")
    assert link.is_symlink() and target.read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.txt", "real.txt"], "no temporary left"


def test_an_output_that_is_a_fifo_is_written_into_not_replaced(tmp_path) -> None:
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    received: list[bytes] = []
    reader = threading.Thread(target=lambda: received.append(fifo.read_bytes()))
    reader.start()
    io.atomic_write_text(fifo, "through the pipe")
    reader.join(timeout=10)
    assert received == [b"through the pipe"]
    assert fifo.is_fifo(), "still a FIFO, not a regular file that no reader sees"


def test_a_plot_and_a_map_written_to_a_link_keep_the_link(tmp_path) -> None:
    from vcr_odom.mapping import VoxelMap
    from vcr_odom.plots import plot_trajectories

    voxel_map = VoxelMap(voxel_size=0.5)
    voxel_map.add(np.random.default_rng(0).uniform(-10, 10, (500, 4)).astype(np.float32), np.eye(4))

    poses = np.stack([make_transform(np.eye(3), [float(k), 0.0, 0.0]) for k in range(3)])
    for name, write in (
        ("plot.png", lambda path: plot_trajectories(path, {"run": poses})),
        ("map.ply", voxel_map.save),
    ):
        target = tmp_path / f"real-{name}"
        target.write_bytes(b"old")
        link = tmp_path / name
        link.symlink_to(target)
        write(link)
        assert link.is_symlink() and target.stat().st_size > 100, name
