"""Recordings in the formats kiss-icp reads (ROS 1/2 bags, MCAP, Ouster pcap, nuScenes, KITTI raw,
Apollo, HeLiPR, generic folders), behind this tool's :class:`~vcr_odom.data.base.LidarSequence`.

Why reuse kiss-icp's loaders: it is already a dependency, and its loaders know each format (split ROS 1
bags, topic discovery, nuScenes' token chains, HeLiPR's per-sensor records). What they lack is what the
rest of vcr-odom expects of a sequence, added here:

- **Errors that say what to do.** The loaders ``print`` and ``sys.exit`` on a missing package or an
  ambiguous topic; here a missing package is a ConfigError naming the pip extra to install (checked
  before the loader is imported), and anything a loader prints before failing ends up in one DataError
  or ConfigError that names the recording (and, for topics, lists the point-cloud topics to choose from).
- **Livox scans.** Topics of ``livox_ros_driver(2)/CustomMsg`` are read as well as PointCloud2 ones
  (see :mod:`~vcr_odom.data.livox`): the loaders' topic check is replaced by one that knows both, and a
  CustomMsg topic's frames are converted from the message bytes. Their stamps are the header stamps
  (the drivers set them to the scan's ``timebase``, the sensor clock), in ROS bags too.
- **Random access.** The ROS bag and MCAP loaders only stream (``dataset[i]`` returns the *next*
  message whatever ``i`` is); frames are read forward here, skipping undecoded messages for a stride and
  re-opening the recording to go back.
- **Timestamps up front.** Odometry and the result files need every stamp before the first frame is
  read, while the streaming loaders record a stamp only as they read each frame. One pass over the
  recording collects the same stamps they would (bag record times for ROS bags, header stamps for MCAP)
  without decoding a cloud. nuScenes and HeLiPR stamps come from their index; the other loaders give
  none, so 10 Hz is assumed with a warning (``timestamps_assumed``), unless ``--times FILE`` gives them.
- **Frames and ground truth as everywhere else.** float32 ``(N, 4)`` x, y, z, reflectance (intensity
  from ROS clouds, see :mod:`~vcr_odom.data.pointcloud2`; 0 for the loaders that keep xyz only); a
  loader's ground truth (nuScenes, KITTI raw, Apollo, HeLiPR) re-anchored to frame 0, or the user's
  ``--poses``.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import io
import os
import struct
import threading
import warnings
import weakref
from collections.abc import Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vcr_odom.data.base import Points
from vcr_odom.data.livox import is_custom_msg, points_from_custom_msg
from vcr_odom.data.pointcloud2 import points_from_pointcloud2
from vcr_odom.data.scans import SequenceBase, clean_points, folder_times_remedy, path_label
from vcr_odom.errors import ConfigError, DataError, DataWarning, VcrOdomError
from vcr_odom.geometry import project_to_se3


@dataclass(frozen=True)
class LoaderInfo:
    """One kiss-icp loader: its class in ``kiss_icp.datasets.<name>``, what it reads, the modules it
    imports, and the vcr-odom extra that installs them (``pip install 'vcr-odom[EXTRA]'``)."""

    cls: str
    summary: str
    needs: tuple[str, ...] = ()
    extra: str | None = None
    topic: bool = False
    sequence: bool = False
    streaming: bool = False


LOADERS: dict[str, LoaderInfo] = {
    "rosbag": LoaderInfo(
        "RosbagDataset",
        "a ROS 1 .bag, a folder of split .bag files, or a ROS 2 bag folder",
        needs=("rosbags",),
        extra="rosbag",
        topic=True,
        streaming=True,
    ),
    "mcap": LoaderInfo(
        "McapDataloader",
        "a ROS 2 .mcap file",
        needs=("mcap", "mcap_ros2"),
        extra="mcap",
        topic=True,
        streaming=True,
    ),
    "ouster": LoaderInfo(
        "OusterDataloader", "an Ouster .pcap with its metadata .json beside it", ("ouster.sdk",), "ouster"
    ),
    "nuscenes": LoaderInfo(
        "NuScenesDataset",
        "nuScenes v1.0-mini root, scene number as --seq",
        ("nuscenes", "pyquaternion"),
        "nuscenes",
        sequence=True,
    ),
    "kitti_raw": LoaderInfo(
        "KITTIRawDataset", "KITTI raw root, odometry sequence 00-10 but 03 as --seq", sequence=True
    ),
    "apollo": LoaderInfo("ApolloDataset", "an Apollo-SouthBay drive folder", ("pyquaternion",), "apollo"),
    "helipr": LoaderInfo(
        "HeLiPRDataset",
        "HeLiPR root, sensor name as --seq: Avia, Aeva, Ouster or Velodyne",
        ("pyquaternion",),
        "helipr",
        sequence=True,
    ),
    "generic": LoaderInfo("GenericDataset", "a folder of .bin, .pcd, .ply, .xyz, .obj, ... scans"),
}
"""Every loader ``--dataloader`` accepts, by kiss-icp's module name."""


def missing_modules(loader: str) -> list[str]:
    """The modules ``loader`` imports that are not installed (found without importing them)."""
    missing = []
    for module in LOADERS[loader].needs:
        try:
            found = importlib.util.find_spec(module) is not None
        except ImportError:  # the parent package of a dotted name is missing
            found = False
        if not found:
            missing.append(module)
    return missing


def installed_loaders() -> list[str]:
    """Loaders whose dependencies are installed, in :data:`LOADERS` order."""
    return [name for name in LOADERS if not missing_modules(name)]


def install_hint(loader: str) -> str:
    """``pip install 'vcr-odom[EXTRA]'`` for ``loader``."""
    return f"pip install 'vcr-odom[{LOADERS[loader].extra}]'"


def check_loader(loader: str) -> str:
    """``loader`` if it is known and installed, else ConfigError naming ``--dataloader`` or the extra."""
    if loader not in LOADERS:
        raise ConfigError(f"--dataloader {loader!r} is not a loader; choose one of {', '.join(LOADERS)}")
    missing = missing_modules(loader)
    if missing:
        raise ConfigError(
            f"--dataloader {loader} needs {', '.join(missing)}, which {'is' if len(missing) == 1 else 'are'} "
            f"not installed: {install_hint(loader)}"
        )
    return loader


POINT_CLOUD2 = "sensor_msgs/msg/PointCloud2"


def _listed(topics: dict[str, str]) -> str:
    """``/a, /b`` when all are one type, else ``/a (type), /b (type)``."""
    if len(set(topics.values())) == 1:
        return ", ".join(topics)
    return ", ".join(f"{name} ({msgtype})" for name, msgtype in topics.items())


def choose_topic(found: dict[str, str], topic: str | None, path: Path, loader: str) -> str:
    """The topic to read among ``found`` (topic -> message type): ``topic`` if given, else the only
    PointCloud2 or Livox CustomMsg topic; ConfigError or DataError listing the candidates otherwise."""
    clouds = {
        name: kind for name, kind in sorted(found.items()) if kind == POINT_CLOUD2 or is_custom_msg(kind)
    }
    if topic:
        if topic in clouds:
            return topic
        what = f"a {found[topic]} topic, not" if topic in found else "not"
        raise ConfigError(
            f"--topic {topic} is {what} a PointCloud2 or Livox CustomMsg topic of {path}; "
            f"its point-cloud topics: {_listed(clouds) or 'none'}"
        )
    if len(clouds) == 1:
        return next(iter(clouds))
    if not clouds:
        others = f"; its topics: {_listed(dict(sorted(found.items())))}" if found else ""
        raise DataError(
            f"{path}: no sensor_msgs/msg/PointCloud2 or Livox CustomMsg topic "
            f"(the {loader} loader reads point clouds){others}"
        )
    kinds = {"PointCloud2" if kind == POINT_CLOUD2 else "Livox CustomMsg" for kind in clouds.values()}
    what = kinds.pop() if len(kinds) == 1 else "point-cloud"
    raise ConfigError(f"{path} has several {what} topics ({_listed(clouds)}); choose one with --topic")


class _QuietDel:
    """kiss-icp's ``__del__`` closes ``self.bag`` even when a failed ``__init__`` never opened it (a broken
    bag), and Python prints that error as an "Exception ignored in __del__" traceback after the one-line
    error; what was opened is closed by :func:`_release`, so nothing here may raise."""

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            super().__del__()  # type: ignore[misc]


class _RosbagTopics(_QuietDel):
    """Over kiss-icp's RosbagDataset: :func:`choose_topic`, and CustomMsg frames from the raw bytes."""

    recording: Path
    msgtype: str

    def check_topic(self, topic: str | None) -> str:
        found = {name: info.msgtype for name, info in self.bag.topics.items()}
        chosen = choose_topic(found, topic, self.recording, "rosbag")
        self.msgtype = found[chosen]
        return chosen

    def __getitem__(self, idx: int) -> Any:
        if not is_custom_msg(self.msgtype):
            return super().__getitem__(idx)
        _, _, rawdata = next(self.msgs)
        return self.read_point_cloud(rawdata)


class _McapTopics(_QuietDel):
    """Over kiss-icp's McapDataloader: :func:`choose_topic`, and CustomMsg frames from the raw CDR bytes
    (read with ``mcap`` alone, so they need no schema that ``mcap_ros2`` could decode)."""

    recording: Path
    msgtype: str

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if is_custom_msg(self.msgtype):
            self.reset()

    def check_topic(self, topic: str | None) -> str:
        schemas = self.summary.schemas
        found = {
            channel.topic: schemas[channel.schema_id].name if channel.schema_id in schemas else ""
            for channel in self.summary.channels.values()
        }
        chosen = choose_topic(found, topic, self.recording, "mcap")
        self.msgtype = found[chosen]
        return chosen

    def reset(self) -> None:
        if not is_custom_msg(self.msgtype):
            return super().reset()
        self.timestamps = []
        self.msgs = _mcap_payloads(self.mcap_file, self.topic)

    def __getitem__(self, idx: int) -> Any:
        if not is_custom_msg(self.msgtype):
            return super().__getitem__(idx)
        return self.read_point_cloud(next(self.msgs))


def _mcap_payloads(path: str, topic: str) -> Iterator[bytes]:
    """The serialized messages of ``topic``, in log-time order; the file closes with the generator."""
    from mcap.reader import make_reader

    with open(path, "rb") as handle:
        for _, _, message in make_reader(handle).iter_messages(topics=[topic]):
            yield message.data


_TOPIC_CHOICE = {"rosbag": _RosbagTopics, "mcap": _McapTopics}


def _open_error(loader: str, path: Path, printed: str, error: BaseException | None) -> Exception:
    """One clear error from what a loader printed before it exited or raised."""
    said = " ".join(
        line.strip() for line in printed.splitlines() if line.strip() and not line.startswith("-")
    )
    detail = "; ".join(part for part in (said, f"{type(error).__name__}: {error}" if error else "") if part)
    return DataError(f"the {loader} loader could not open {path}: {detail or 'it exited without a message'}")


def _ros2_header_stamp(data: bytes) -> float:
    """``header.stamp`` of a CDR-encoded ROS 2 message, in seconds, without decoding the rest: the
    header is a message's first field and the stamp its first, right after the 4-byte encapsulation."""
    order = "<" if data[1] & 1 else ">"
    sec, nanosec = struct.unpack_from(f"{order}iI", data, 4)
    return sec + float(nanosec) / 1e9  # as kiss-icp's McapDataloader.stamp_to_sec


def _ros1_header_stamp(data: bytes) -> float:
    """``header.stamp`` of a ROS 1 message, in seconds: after the header's ``uint32 seq``, little-endian."""
    sec, nsec = struct.unpack_from("<II", data, 4)
    return sec + float(nsec) / 1e9


def _release(dataset: Any) -> None:
    """Close what a loader holds open: the pending message generator first (an open SQLite cursor makes
    closing a ROS 2 bag fail with "database is locked"), then the bag, once, so that kiss-icp's own
    ``__del__`` does not close it again while the interpreter shuts down."""
    messages = getattr(dataset, "msgs", None)
    if hasattr(messages, "close"):
        with contextlib.suppress(Exception):
            messages.close()
    bag = dataset.__dict__.pop("bag", None)
    if hasattr(bag, "close"):
        with contextlib.suppress(Exception):
            bag.close()


class KissLoaderSequence(SequenceBase):
    """One recording read through kiss-icp's ``loader`` (see :data:`LOADERS`), loaded lazily.

    ``data`` is what the loader opens (a bag, a file, a dataset root); ``sequence`` is passed to the
    loaders that take one (``kitti_raw``, ``nuscenes``, ``helipr``), ``topic`` to the ROS ones.
    ``poses``/``calib``/``times`` are the user's files, as for :class:`~vcr_odom.data.FolderSequence`,
    and win over what the loader gives. :meth:`close` (or a ``with`` block) releases the recording;
    otherwise it is released when the sequence is collected or at exit.
    """

    def __init__(
        self,
        loader: str,
        data: str | os.PathLike[str],
        *,
        sequence: str | None = None,
        topic: str | None = None,
        poses: str | os.PathLike[str] | None = None,
        calib: str | os.PathLike[str] | None = None,
        times: str | os.PathLike[str] | None = None,
    ) -> None:
        self.loader = check_loader(loader)
        self.info = LOADERS[loader]
        self.path = Path(data).expanduser()
        if not self.path.exists():
            raise DataError(f"--data {self.path} does not exist")
        if topic and not self.info.topic:
            raise ConfigError(f"--topic only applies to the rosbag and mcap loaders, not {loader}")
        self._lock = threading.Lock()
        self._cursor = 0
        self.dataset = self._open(sequence, topic)
        self._finalizer = weakref.finalize(self, _release, self.dataset)
        try:
            stamps = self._recorded_stamps()
        except Exception as error:
            raise DataError(f"{self.path}: cannot read the recording's timestamps: {error}") from error
        self._count = len(stamps) if stamps is not None and self.info.streaming else len(self.dataset)
        label = getattr(self.dataset, "sequence_id", None) or self.path.stem
        self.name = f"{loader}/{label}"
        stem = self.path.stem if self.path.is_file() else path_label(self.path)
        self.label = stem if stem == str(label) or stem.startswith(f"{label}.") else f"{stem}-{label}"
        self.sequence_path = self.path
        self.topic = getattr(self.dataset, "topic", None)
        if self._count == 0:
            raise DataError(self._no_frames())
        if self.info.streaming:
            self.dataset.read_point_cloud = self._converter()

        self.poses_path = Path(poses).expanduser() if poses is not None else None
        self.calib_path = Path(calib).expanduser() if calib is not None else None
        self.times_path = Path(times).expanduser() if times is not None else None
        if self.poses_path is not None or self.calib_path is not None:
            self._set_user_poses(self.poses_path, self.calib_path, self.path)
        else:
            self._set_poses(self._loader_poses(), None, camera_frame=False)
        if stamps is not None and self.times_path is None:
            self._check_stamps(stamps)
        self._set_times(self.times_path, self._count, self.path, folder_times_remedy(), given=stamps)

    def __len__(self) -> int:
        return self._count

    def _no_frames(self) -> str:
        """Why a recording with no frames is refused, naming the file (and the topic it read)."""
        if self.topic:
            kind = getattr(self.dataset, "msgtype", "point cloud")
            return f"{self.path}: no messages on {self.topic} ({kind}): the recording holds no point clouds"
        return f"{self.path}: no point clouds: the {self.loader} loader found no frames in it"

    def close(self) -> None:
        """Release the recording (open files, a bag's database); frames cannot be read afterwards."""
        self._finalizer()

    def __enter__(self) -> KissLoaderSequence:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    def _converter(self) -> Any:
        """The loaders' own hook for message -> points (not bound to self: see close)."""
        source = f"{self.path} ({self.topic})"
        if is_custom_msg(self.dataset.msgtype):
            cdr = self.loader == "mcap" or self.dataset.bag.is2
            return partial(points_from_custom_msg, cdr=cdr, source=source)
        return partial(points_from_pointcloud2, source=source)

    def _open(self, sequence: str | None, topic: str | None) -> Any:
        """The loader, built as kiss-icp's ``dataset_factory`` builds it, without that function's parse
        of every loader's source (which only finds the class name, and warns about kiss-icp's regexes)."""
        printed = io.StringIO()
        options = {"sequence": sequence if self.info.sequence else None, "topic": topic or None, "meta": None}
        try:
            with contextlib.redirect_stdout(printed):
                module = importlib.import_module(f"kiss_icp.datasets.{self.loader}")
                loader = getattr(module, self.info.cls)
                if self.loader in _TOPIC_CHOICE:
                    fields = {"recording": self.path}
                    loader = type(loader.__name__, (_TOPIC_CHOICE[self.loader], loader), fields)
                return loader(data_dir=self.path, **options)
        except VcrOdomError:
            raise
        except SystemExit as error:  # the loaders exit after printing what went wrong
            raise _open_error(self.loader, self.path, printed.getvalue(), None) from error
        except Exception as error:
            raise _open_error(self.loader, self.path, printed.getvalue(), error) from error

    def _recorded_stamps(self) -> NDArray[np.float64] | None:
        """Every frame's stamp in seconds, as the loader would report it, or None where it gives none."""
        dataset = self.dataset
        if self.loader == "rosbag":
            messages = dataset.bag.messages(connections=dataset.connections)
            if is_custom_msg(dataset.msgtype):  # header stamps: see the module's docstring
                header_stamp = _ros2_header_stamp if dataset.bag.is2 else _ros1_header_stamp
                return np.array([header_stamp(data) for _, _, data in messages], dtype=np.float64)
            return np.array([dataset.to_sec(stamp) for _, stamp, _ in messages], dtype=np.float64)
        if self.loader == "mcap":
            from mcap.reader import make_reader

            with open(dataset.mcap_file, "rb") as handle:
                messages = make_reader(handle).iter_messages(topics=[dataset.topic])
                return np.array([_ros2_header_stamp(m.data) for _, _, m in messages], dtype=np.float64)
        if self.loader == "nuscenes":
            records = (dataset.nusc.get("sample_data", token) for token in dataset.lidar_tokens)
            return np.array([record["timestamp"] * 1e-6 for record in records], dtype=np.float64)
        if self.loader == "helipr":
            return np.asarray(dataset.scan_timestamps, dtype=np.float64) * 1e-9
        return None

    def _check_stamps(self, stamps: NDArray[np.float64]) -> None:
        if len(stamps) != self._count:
            raise DataError(f"{self.path}: {len(stamps)} timestamps for {self._count} frames")
        steps = np.diff(stamps)
        if not np.all(np.isfinite(stamps)) or np.any(steps <= 0):
            first = int(np.argmax(~(steps > 0))) + 1 if len(steps) else 0
            warnings.warn(
                f"{self.path}: the recording's timestamps are not strictly increasing (frame {first}); "
                "speeds derived from them will be wrong there",
                DataWarning,
                stacklevel=3,
            )

    def _loader_poses(self) -> NDArray[np.float64] | None:
        gt = getattr(self.dataset, "gt_poses", None)
        if gt is None:
            return None
        poses = np.asarray(gt, dtype=np.float64)
        if poses.shape != (self._count, 4, 4) or not np.all(np.isfinite(poses)):
            warnings.warn(
                f"{self.path}: the {self.loader} loader's ground truth has shape {poses.shape} for "
                f"{self._count} frames; running without ground truth",
                DataWarning,
                stacklevel=3,
            )
            return None
        return project_to_se3(poses)  # some loaders keep float32 rotations

    def _load(self, position: int) -> Points:
        item = self._stream(position) if self.info.streaming else self.dataset[position]
        points = np.asarray(item[0] if isinstance(item, tuple) else item)
        if points.ndim != 2 or points.shape[1] < 3:
            raise DataError(f"{self.name}: frame {position} is not an (N, 3) point array: {points.shape}")
        frame = np.zeros((len(points), 4), dtype=np.float32)
        frame[:, : min(points.shape[1], 4)] = points[:, :4]
        return clean_points(frame, f"{self.name} frame {position}")

    def _stream(self, position: int) -> Any:
        """Frame ``position`` of a loader that only reads forward: re-open to go back, skip messages
        (undecoded) to go forward."""
        with self._lock:
            if position < self._cursor:
                self.dataset.msgs.close()  # an open cursor would keep the bag from closing
                with contextlib.redirect_stdout(io.StringIO()):
                    self.dataset.reset()
                self._cursor = 0
            try:
                while self._cursor < position:
                    next(self.dataset.msgs)
                    self._cursor += 1
                self._cursor += 1
                return self.dataset[position]
            except StopIteration:
                raise DataError(f"{self.path}: the recording ended before frame {position}") from None
