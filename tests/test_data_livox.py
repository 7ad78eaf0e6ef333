"""Livox ``CustomMsg`` recordings: ROS 1 and ROS 2 bags and MCAP written here with rosbags (the Livox
types registered in its typestore) from the synthetic drive of test_data_recordings, read back point for
point, and run end to end through ``vcr-odom run --dataloader rosbag``."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
import test_data_recordings as recordings
from test_data_recordings import CLOUD, EXIT_USAGE, START, cloud_message, result_folder, run_cli

from vcr_odom.data import KissLoaderSequence
from vcr_odom.data.livox import (
    CUSTOM_MSG_TYPES,
    is_custom_msg,
    livox_types,
    points_from_custom_msg,
    register_livox_types,
)
from vcr_odom.errors import DataError, DataWarning
from vcr_odom.io import read_kitti_poses

rosbags = pytest.importorskip("rosbags")
from rosbags.rosbag1 import Writer as Ros1Writer  # noqa: E402
from rosbags.rosbag2 import StoragePlugin  # noqa: E402
from rosbags.rosbag2 import Writer as Ros2Writer  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

drive, frames = recordings.drive, recordings.frames  # its synthetic drive's fixtures, shared

STEP = 8  # every 8th synthetic point: ~14 000 a scan, a Livox Mid-360's count
TOPIC = "/livox/lidar"
RECORD_DELAY = 0.003  # record time after the header stamp, so the two cannot be mistaken
ROS1 = ("livox_ros_driver/msg/CustomMsg", Stores.ROS1_NOETIC)
ROS2 = ("livox_ros_driver2/msg/CustomMsg", Stores.ROS2_HUMBLE)


def scan(points: np.ndarray) -> np.ndarray:
    """A subsampled frame with a missing return (0, 0, 0) and a NaN point, which the reader drops."""
    kept = points[::STEP].copy()
    return np.concatenate([kept[:5], [[0, 0, 0, 0.5], [np.nan, 1, 2, 0.5]], kept[5:]]).astype(np.float32)


def expected(points: np.ndarray) -> np.ndarray:
    """What the reader gives for ``points``: valid returns, reflectivity quantised to uint8 over 255."""
    valid = np.isfinite(points[:, :3]).all(axis=1) & (points[:, :3] != 0).any(axis=1)
    out = points[valid].copy()
    out[:, 3] = reflectivity(out).astype(np.float32) / np.float32(255)
    return out


def reflectivity(points: np.ndarray) -> np.ndarray:
    return np.clip(np.round(points[:, 3] * 255), 0, 255).astype(np.uint8)


def livox_message(store, msgtype: str, points: np.ndarray, stamp: float, *, point_num: int | None = None):
    types = store.types
    package = msgtype.split("/")[0]
    point, header, time = (
        types[f"{package}/msg/CustomPoint"],
        types["std_msgs/msg/Header"],
        types["builtin_interfaces/msg/Time"],
    )
    nanoseconds = round(stamp * 1e9)
    stamp_msg = time(sec=nanoseconds // 10**9, nanosec=nanoseconds % 10**9)
    ros1 = "seq" in header.__dataclass_fields__
    header_msg = header(seq=0, stamp=stamp_msg, frame_id="livox_frame") if ros1 else header(stamp=stamp_msg, frame_id="livox_frame")  # fmt: skip
    values = reflectivity(np.nan_to_num(points))
    custom_points = [
        point(offset_time=10 * k, x=float(p[0]), y=float(p[1]), z=float(p[2]), reflectivity=int(r), tag=16, line=k % 4)
        for k, (p, r) in enumerate(zip(points, values, strict=True))
    ]  # fmt: skip
    return types[msgtype](
        header=header_msg, timebase=nanoseconds, point_num=len(points) if point_num is None else point_num,
        lidar_id=1, rsvd=np.zeros(3, dtype=np.uint8), points=custom_points,
    )  # fmt: skip


def write_livox(
    path: Path,
    scans: list[np.ndarray],
    *,
    kind: tuple[str, Stores] = ROS2,
    storage: StoragePlugin | None = StoragePlugin.SQLITE3,
    cloud_topic: str | None = None,
    point_num: int | None = None,
) -> Path:
    """A bag of ``scans`` on :data:`TOPIC` (ROS 1 ``.bag`` for ``ROS1``, else a ROS 2 folder in
    ``storage``), optionally with the same scans as PointCloud2 on ``cloud_topic``."""
    msgtype, store_name = kind
    store = register_livox_types(get_typestore(store_name))
    ros1 = store_name == Stores.ROS1_NOETIC
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    writer = Ros1Writer(path) if ros1 else Ros2Writer(path, version=9, storage_plugin=storage)
    with writer:
        livox = writer.add_connection(TOPIC, msgtype, typestore=store)
        cloud = writer.add_connection(cloud_topic, CLOUD, typestore=store) if cloud_topic else None
        for index, points in enumerate(scans):
            stamp = START + 0.1 * index
            message = livox_message(store, msgtype, points, stamp, point_num=point_num)
            writer.write(livox, round((stamp + RECORD_DELAY) * 1e9), serialize(message, msgtype))
            if cloud is not None:
                data = serialize(cloud_message(store, points, stamp), CLOUD)
                writer.write(cloud, round((stamp + RECORD_DELAY) * 1e9), data)
    return path


@pytest.fixture(scope="module")
def scans(frames) -> list[np.ndarray]:
    return [scan(points) for points in frames]


@pytest.fixture(scope="module")
def ros1_bag(tmp_path_factory, scans) -> Path:
    return write_livox(tmp_path_factory.mktemp("livox1") / "avia.bag", scans, kind=ROS1)


# --- reading ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("layout", ["ros1", "ros2", "mcap"])
def test_livox_bags_give_back_the_points_and_header_stamps(layout, ros1_bag, scans, tmp_path):
    if layout == "ros1":
        loader, data, count = "rosbag", ros1_bag, len(scans)
    else:
        count = 3
        storage = StoragePlugin.MCAP if layout == "mcap" else StoragePlugin.SQLITE3
        data = write_livox(tmp_path / "drive", scans[:count], storage=storage)
        loader = "rosbag"
        if layout == "mcap":
            pytest.importorskip("mcap")
            loader, (data,) = "mcap", data.glob("*.mcap")
    with KissLoaderSequence(loader, data) as sequence:
        assert len(sequence) == count and sequence.topic == TOPIC and not sequence.timestamps_assumed
        # header stamps (the scan's timebase), not the bag's record times
        np.testing.assert_allclose(sequence.timestamps, START + 0.1 * np.arange(count), atol=1e-6)
        for index in (2, 0, 1, 1):  # forward, back, repeat
            np.testing.assert_array_equal(sequence.frame(index), expected(scans[index]))


def test_a_livox_bag_runs_end_to_end(ros1_bag, drive, tmp_path):
    results = tmp_path / "results"
    result = run_cli(
        "run", "--dataloader", "rosbag", "--data", str(ros1_bag), "--method", "icp", "--results-dir", str(results)
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    folder = result_folder(results)
    poses = read_kitti_poses(folder / "trajectory_kitti.txt")
    assert len(poses) == len(drive.gt_poses)
    # ICP on ~14 000 points a scan: each ~1 m step to a few cm, the 5 m drive's end to within 4 %
    steps, gt_steps = (np.linalg.norm(np.diff(p[:, :3, 3], axis=0), axis=1) for p in (poses, drive.gt_poses))
    np.testing.assert_allclose(steps, gt_steps, atol=0.05)
    end_error = np.linalg.norm(poses[-1, :3, 3] - drive.gt_poses[-1, :3, 3])
    assert end_error < 0.04 * gt_steps.sum(), end_error
    stamps = [float(line.split()[0]) for line in (folder / "trajectory_tum.txt").read_text().splitlines()]
    np.testing.assert_allclose(stamps, START + 0.1 * np.arange(len(poses)), atol=1e-6)


def test_the_reader_matches_rosbags_deserializer_in_both_byte_orders(scans):
    for msgtype, store_name in (ROS1, ROS2):
        store = register_livox_types(get_typestore(store_name))
        message = livox_message(store, msgtype, scans[0][:200], START)
        encodings = (
            [(store.serialize_ros1(message, msgtype), False)]
            if store_name == Stores.ROS1_NOETIC
            else [(store.serialize_cdr(message, msgtype, little_endian=le), True) for le in (True, False)]
        )
        for data, cdr in encodings:
            decoded = store.deserialize_cdr(data, msgtype) if cdr else store.deserialize_ros1(data, msgtype)
            by_rosbags = np.array([[p.x, p.y, p.z, p.reflectivity] for p in decoded.points], dtype=np.float32)
            by_rosbags[:, 3] /= np.float32(255)
            keep = np.isfinite(by_rosbags[:, :3]).all(axis=1) & (by_rosbags[:, :3] != 0).any(axis=1)
            np.testing.assert_array_equal(points_from_custom_msg(data, cdr=cdr), by_rosbags[keep])


def test_livox_type_names():
    assert all(is_custom_msg(name) for name in CUSTOM_MSG_TYPES)
    assert is_custom_msg("livox_ros_driver/CustomMsg") and not is_custom_msg(CLOUD)
    assert set(livox_types("livox_ros_driver")) == {
        "livox_ros_driver/msg/CustomMsg",
        "livox_ros_driver/msg/CustomPoint",
    }


# --- topics and bad data ----------------------------------------------------------------------------


def test_a_bag_with_livox_and_pointcloud2_topics_asks_which(scans, tmp_path):
    bag = write_livox(tmp_path / "both", [points[:300] for points in scans[:2]], cloud_topic="/points")
    result = run_cli("run", "--dataloader", "rosbag", "--data", str(bag), "--method", "icp")
    text = " ".join(result.output.split())
    assert result.exit_code == EXIT_USAGE, result.output
    assert "several point-cloud topics" in text and "--topic" in text
    assert "/livox/lidar (livox_ros_driver2/msg/CustomMsg)" in text
    assert "/points (sensor_msgs/msg/PointCloud2)" in text
    result = run_cli(
        "run", "--dataloader", "rosbag", "--data", str(bag), "--topic", "/nope", "--method", "icp"
    )
    assert result.exit_code == EXIT_USAGE and "--topic /nope" in result.output and TOPIC in result.output
    with KissLoaderSequence("rosbag", bag, topic=TOPIC) as sequence:
        np.testing.assert_array_equal(sequence.frame(1), expected(scans[1][:300]))
    with KissLoaderSequence("rosbag", bag, topic="/points") as sequence:  # keeps (0, 0, 0), as before
        cloud = scans[1][:300]
        np.testing.assert_array_equal(sequence.frame(1), cloud[np.isfinite(cloud).all(axis=1)])


def test_a_point_num_that_disagrees_is_a_warning_and_the_points_are_read(scans, tmp_path):
    bag = write_livox(tmp_path / "odd", [points[:100] for points in scans[:2]], point_num=7)
    warning = r"odd \(/livox/lidar\): CustomMsg point_num 7 but it holds 100"
    with KissLoaderSequence("rosbag", bag) as sequence, pytest.warns(DataWarning, match=warning):
        frame = sequence.frame(0)
    np.testing.assert_array_equal(frame, expected(scans[0][:100]))


def test_a_truncated_message_is_a_data_error_naming_its_source(scans):
    msgtype, store_name = ROS1
    store = register_livox_types(get_typestore(store_name))
    data = store.serialize_ros1(livox_message(store, msgtype, scans[0][:50], START), msgtype)
    with pytest.raises(DataError, match=r"scan\.bag: CustomMsg of \d+ bytes for 50 points"):
        points_from_custom_msg(data[:-7], cdr=False, source="scan.bag")
    with pytest.raises(DataError, match="ends inside its header"):
        points_from_custom_msg(data[:20], cdr=False, source="scan.bag")
    cdr = struct.pack("<4B", 0, 0x0A, 0, 0) + bytes(40)  # XCDR2: another encoding
    with pytest.raises(DataError, match="not plain CDR"):
        points_from_custom_msg(cdr, cdr=True)


def test_an_empty_livox_topic_or_no_point_cloud_topic_is_a_data_error(tmp_path):
    bag = write_livox(tmp_path / "empty", [])
    with pytest.raises(
        DataError, match=r"empty: no messages on /livox/lidar \(livox_ros_driver2/msg/CustomMsg\)"
    ):
        KissLoaderSequence("rosbag", bag)
    store = get_typestore(Stores.ROS2_HUMBLE)
    with Ros2Writer(tmp_path / "chatter", version=9) as writer:
        connection = writer.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
        data = store.serialize_cdr(store.types["std_msgs/msg/String"](data="hi"), "std_msgs/msg/String")
        writer.write(connection, 1, data)
    result = run_cli("run", "--dataloader", "rosbag", "--data", str(tmp_path / "chatter"), "--method", "icp")
    assert (
        result.exit_code == 1 and "no sensor_msgs/msg/PointCloud2 or Livox CustomMsg topic" in result.output
    )
    assert "/chatter" in result.output and "Traceback" not in result.output
