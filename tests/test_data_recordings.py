"""Recordings through kiss-icp's loaders: ROS 1/2 bags and MCAP written here with rosbags' own writers
from a synthetic drive, read back frame for frame, and run end to end through ``vcr-odom run``."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from vcr_odom.cli.main import cli
from vcr_odom.cli.options import describe_loaders
from vcr_odom.data import LOADERS, KissLoaderSequence, LidarSequence, installed_loaders
from vcr_odom.data.pointcloud2 import points_from_pointcloud2
from vcr_odom.data.selection import FrameSelection
from vcr_odom.errors import ConfigError, DataError, DataWarning
from vcr_odom.io import write_kitti_poses, write_times
from vcr_odom.synth import SynthSequence

rosbags = pytest.importorskip("rosbags")
from rosbags.rosbag1 import Writer as Ros1Writer  # noqa: E402
from rosbags.rosbag2 import StoragePlugin  # noqa: E402
from rosbags.rosbag2 import Writer as Ros2Writer  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

EXIT_ERROR, EXIT_USAGE = 1, 2
FRAMES = 6
START = 1_700_000_000.0  # Unix-epoch stamps, as real recordings have
CLOUD = "sensor_msgs/msg/PointCloud2"


@pytest.fixture(scope="module")
def drive() -> SynthSequence:
    return SynthSequence(frames=FRAMES, seed=0)


@pytest.fixture(scope="module")
def frames(drive) -> list[np.ndarray]:
    return [drive.frame(index) for index in range(FRAMES)]


def cloud_message(store, points: np.ndarray, stamp: float, *, pad: int = 0, big_endian: bool = False):
    """A PointCloud2 of x, y, z, intensity float32 (plus ``pad`` unused bytes a point)."""
    types = store.types
    field, header, time = (
        types["sensor_msgs/msg/PointField"],
        types["std_msgs/msg/Header"],
        types["builtin_interfaces/msg/Time"],
    )
    step = 16 + pad
    order = ">f4" if big_endian else "<f4"
    record = np.zeros(
        len(points), dtype=np.dtype({"names": ["p"], "formats": [(order, 4)], "itemsize": step})
    )
    record["p"] = points
    fields = [
        field(name=name, offset=4 * k, datatype=7, count=1)
        for k, name in enumerate(["x", "y", "z", "intensity"])
    ]
    nanoseconds = round(stamp * 1e9)
    stamp_msg = time(sec=nanoseconds // 10**9, nanosec=nanoseconds % 10**9)
    header_msg = (
        header(stamp=stamp_msg, frame_id="lidar")
        if "seq" not in header.__dataclass_fields__
        else header(seq=0, stamp=stamp_msg, frame_id="lidar")
    )
    return types[CLOUD](
        header=header_msg, height=1, width=len(points), fields=fields, is_bigendian=big_endian,
        point_step=step, row_step=step * len(points), data=np.frombuffer(record.tobytes(), dtype=np.uint8), is_dense=True,
    )  # fmt: skip


def write_ros2(
    path: Path, frames: list[np.ndarray], *, storage=StoragePlugin.SQLITE3, topics=("/points",)
) -> Path:
    """A ROS 2 bag folder; message record time 1 ms after each header stamp (as a recorder would)."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    with Ros2Writer(path, version=9, storage_plugin=storage) as writer:
        connections = [writer.add_connection(topic, CLOUD, typestore=store) for topic in topics]
        for index, points in enumerate(frames):
            stamp = START + 0.1 * index
            for connection in connections:
                data = store.serialize_cdr(cloud_message(store, points, stamp), CLOUD)
                writer.write(connection, round((stamp + 0.001) * 1e9), data)
    return path


@pytest.fixture(scope="module")
def ros2_bag(tmp_path_factory, frames) -> Path:
    return write_ros2(tmp_path_factory.mktemp("ros2") / "drive", frames)


@pytest.fixture(scope="module")
def mcap_file(tmp_path_factory, frames) -> Path:
    pytest.importorskip("mcap_ros2")
    folder = write_ros2(tmp_path_factory.mktemp("mcap") / "drive", frames[:4], storage=StoragePlugin.MCAP)
    (path,) = folder.glob("*.mcap")
    return path


def run_cli(*args: str):
    return CliRunner().invoke(cli, list(args))


def result_folder(results: Path) -> Path:
    (folder,) = [path for path in results.iterdir() if not path.is_symlink()]
    return folder


# --- end to end -------------------------------------------------------------------------------------


def test_ros2_bag_runs_end_to_end_with_the_recordings_timestamps(ros2_bag, frames, tmp_path):
    results = tmp_path / "results"
    result = run_cli(
        "run",
        "--dataloader",
        "rosbag",
        "--data",
        str(ros2_bag),
        "--method",
        "icp",
        "--results-dir",
        str(results),
    )
    assert result.exit_code == 0, result.output
    assert "assuming 10 Hz" not in result.output
    folder = result_folder(results)
    assert len((folder / "trajectory_kitti.txt").read_text().splitlines()) == FRAMES
    stamps = [float(line.split()[0]) for line in (folder / "trajectory_tum.txt").read_text().splitlines()]
    np.testing.assert_allclose(stamps, START + 0.001 + 0.1 * np.arange(FRAMES), atol=1e-6)  # bag record times


def test_mcap_runs_end_to_end_with_header_stamps(mcap_file, tmp_path):
    results = tmp_path / "results"
    result = run_cli(
        "run",
        "--dataloader",
        "mcap",
        "--data",
        str(mcap_file),
        "--method",
        "icp",
        "--results-dir",
        str(results),
    )
    assert result.exit_code == 0, result.output
    lines = (result_folder(results) / "trajectory_tum.txt").read_text().splitlines()
    np.testing.assert_allclose(
        [float(line.split()[0]) for line in lines], START + 0.1 * np.arange(4), atol=1e-6
    )


# --- frames, order, timestamps, ground truth ----------------------------------------------------------


def test_bag_frames_come_back_exactly_in_any_order(ros2_bag, frames):
    with KissLoaderSequence("rosbag", ros2_bag) as sequence:
        assert isinstance(sequence, LidarSequence) and len(sequence) == FRAMES
        assert sequence.name == "rosbag/drive" and not sequence.timestamps_assumed
        assert sequence.gt_poses is None and sequence.tr_velo_to_cam is None
        for index in (3, 1, 1, 5, 0, 4):  # stride forward, back, repeat: re-opens and skips as needed
            np.testing.assert_array_equal(sequence.frame(index), frames[index])  # intensity kept too


def test_ros1_bag_is_read_too(tmp_path, frames):
    store = get_typestore(Stores.ROS1_NOETIC)
    small = [points[::50] for points in frames[:3]]
    with Ros1Writer(tmp_path / "drive.bag") as writer:
        connection = writer.add_connection("/velodyne_points", CLOUD, typestore=store)
        for index, points in enumerate(small):
            message = cloud_message(store, points, START + 0.1 * index)
            writer.write(connection, round((START + 0.1 * index) * 1e9), store.serialize_ros1(message, CLOUD))
    with KissLoaderSequence("rosbag", tmp_path / "drive.bag") as sequence:
        assert len(sequence) == 3
        np.testing.assert_allclose(sequence.timestamps, START + 0.1 * np.arange(3), atol=1e-6)
        np.testing.assert_array_equal(sequence.frame(2), small[2])


def test_user_times_and_poses_win_over_the_recording(ros2_bag, tmp_path, drive):
    write_times(tmp_path / "t.txt", np.arange(FRAMES) * 0.5)
    write_kitti_poses(tmp_path / "gt.txt", drive.gt_poses)
    selection = FrameSelection(
        dataloader="rosbag", data=ros2_bag, times=tmp_path / "t.txt", poses=tmp_path / "gt.txt"
    )
    sequence = selection.open()
    np.testing.assert_allclose(sequence.timestamps, np.arange(FRAMES) * 0.5)
    np.testing.assert_allclose(sequence.gt_poses, drive.gt_poses, atol=1e-6)
    write_times(tmp_path / "short.txt", [0.0, 0.1])
    with pytest.raises(DataError, match=r"short\.txt: 2 timestamps but 6"):
        KissLoaderSequence("rosbag", ros2_bag, times=tmp_path / "short.txt")


def test_loaders_without_timestamps_flag_them_as_assumed(tmp_path, frames):
    scans = tmp_path / "scans"
    scans.mkdir()
    for index in range(3):
        frames[index][::100].tofile(scans / f"{index}.bin")
    with pytest.warns(DataWarning, match="--times FILE"):
        sequence = KissLoaderSequence("generic", scans)
    assert sequence.timestamps_assumed and len(sequence) == 3
    np.testing.assert_array_equal(sequence.frame(1)[:, :3], frames[1][::100, :3])
    assert not sequence.frame(1)[:, 3].any()  # kiss-icp's generic reader keeps xyz only


# --- errors -----------------------------------------------------------------------------------------


def test_topic_errors_list_the_pointcloud2_topics(tmp_path, frames):
    bag = write_ros2(tmp_path / "two", [points[::100] for points in frames[:2]], topics=("/front", "/rear"))
    result = run_cli("run", "--dataloader", "rosbag", "--data", str(bag), "--method", "icp")
    assert result.exit_code == EXIT_USAGE
    assert (
        "several PointCloud2 topics" in result.output
        and "/front" in result.output
        and "--topic" in result.output
    )
    result = run_cli(
        "run", "--dataloader", "rosbag", "--data", str(bag), "--topic", "/nope", "--method", "icp"
    )
    assert result.exit_code == EXIT_USAGE and "--topic /nope" in result.output and "/rear" in result.output
    with KissLoaderSequence("rosbag", bag, topic="/rear") as sequence:
        assert sequence.topic == "/rear" and len(sequence) == 2


def test_a_file_the_loader_cannot_read_is_a_data_error_naming_it(tmp_path):
    (tmp_path / "notes.bag").write_text("not a bag")
    result = run_cli(
        "run", "--dataloader", "rosbag", "--data", str(tmp_path / "notes.bag"), "--method", "icp"
    )
    assert result.exit_code == EXIT_ERROR and "notes.bag" in result.output
    assert "Traceback" not in result.output


def test_missing_dependency_names_the_pip_extra(monkeypatch, tmp_path):
    absent = dataclasses.replace(LOADERS["mcap"], needs=("no_such_module_for_this_test",))
    monkeypatch.setitem(LOADERS, "mcap", absent)
    (tmp_path / "x.mcap").write_bytes(b"")
    result = run_cli("run", "--dataloader", "mcap", "--data", str(tmp_path / "x.mcap"), "--method", "icp")
    assert result.exit_code == EXIT_USAGE
    assert "no_such_module_for_this_test" in result.output and "pip install 'vcr-odom[mcap]'" in result.output
    assert "mcap" not in installed_loaders()
    assert "mcap (pip install 'vcr-odom[mcap]')" in describe_loaders()


def test_help_lists_the_installed_loaders():
    result = run_cli("run", "--help")
    text = " ".join(result.output.split())
    assert result.exit_code == 0 and "--dataloader" in text and "Installed here: rosbag" in text
    for name in installed_loaders():
        assert name in text


@pytest.mark.parametrize(
    ("options", "expected"),
    [
        (["--data", "{bag}"], "--data needs --dataloader"),
        (["--dataloader", "rosbag"], "needs --data"),
        (["--dataloader", "rosbag", "--data", "{bag}", "--folder", "{tmp}"], "not both"),
        (["--folder", "{tmp}", "--topic", "/points"], "--topic only applies"),
        (["--dataloader", "generic", "--data", "{tmp}", "--topic", "/points"], "--topic only applies"),
        (["--dataloader", "rosbag", "--data", "{bag}", "--bin-columns", "5"], "--bin-columns"),
    ],
)
def test_options_that_do_not_go_together_are_usage_errors(ros2_bag, tmp_path, options, expected):
    filled = [option.format(bag=ros2_bag, tmp=tmp_path) for option in options]
    result = run_cli("run", *filled, "--method", "icp")
    assert result.exit_code == EXIT_USAGE, result.output
    assert expected in result.output


def test_unknown_loader_through_the_library(tmp_path):
    with pytest.raises(ConfigError, match="not a loader"):
        KissLoaderSequence("velodyne_pcap", tmp_path)


# --- PointCloud2 decoding ---------------------------------------------------------------------------


def test_pointcloud2_padding_byte_order_and_missing_returns():
    store = get_typestore(Stores.ROS2_HUMBLE)
    points = np.array([[1.0, 2.0, 3.0, 0.5], [np.nan, np.nan, np.nan, 0.0], [-4.0, 5.5, 0.25, 1.0]])
    for options in ({}, {"pad": 16}, {"big_endian": True}):
        message = cloud_message(store, points, START, **options)
        np.testing.assert_array_equal(points_from_pointcloud2(message), points[[0, 2]])  # NaN row dropped
    no_z = cloud_message(store, points, START)
    no_z.fields = no_z.fields[:2]
    with pytest.raises(DataError, match=r"cloud\.bag.*without field\(s\) z"):
        points_from_pointcloud2(no_z, "cloud.bag")


def test_the_loader_table_matches_the_installed_kiss_icp():
    import warnings

    from kiss_icp.datasets import dataloader_types

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # kiss-icp's ncd.py has regexes Python warns about when parsed
        types = dataloader_types()
    for name, info in LOADERS.items():
        assert types[name] == info.cls, name
