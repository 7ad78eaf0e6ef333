"""Livox ``CustomMsg`` scans (livox_ros_driver, livox_ros_driver2) to frames: x, y, z and reflectivity.

Livox drivers publish their own message rather than ``sensor_msgs/PointCloud2`` by default (the
``xfer_format`` that FAST-LIO and most Livox pipelines use), so bags of Livox sensors often hold nothing
else. The definitions are the same in both drivers, ROS 1 and ROS 2; only the package name differs.

Messages are read from their serialized bytes (ROS 1 or CDR) with one numpy view, not through a
message deserializer: rosbags builds one Python object per point, about 60 ms for a 20 000-point scan,
which alone would use most of a 10 Hz frame's budget. The byte layout is checked against the message's
length, so a recording whose CustomMsg differs from these definitions fails with a DataError instead of
giving wrong points. :func:`livox_types` gives the definitions to rosbags' typestore, to write such
bags (as the tests do) or to read one with rosbags itself.

What a frame keeps: x, y, z in the sensor frame, ``reflectivity / 255`` as reflectance (0..1). Points
with a non-finite coordinate or exactly at (0, 0, 0) (how the drivers mark a missing return) are
dropped. ``offset_time`` (per-point time since ``timebase``) is not used, since frames are not de-skewed,
and neither are ``tag`` (return and noise flags) and ``line`` (laser id).
"""

from __future__ import annotations

import struct
import warnings
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from vcr_odom.errors import DataError, DataWarning

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

PACKAGES = ("livox_ros_driver", "livox_ros_driver2")
"""The drivers whose ``CustomMsg`` is read: livox_ros_driver (ROS 1), livox_ros_driver2 (ROS 1 and 2)."""

CUSTOM_MSG_TYPES = frozenset(f"{package}/msg/CustomMsg" for package in PACKAGES)
"""Message type names as rosbags and ROS 2 spell them (rosbags writes ROS 1's ``pkg/Type`` this way)."""

CUSTOM_MSG = """\
std_msgs/Header header
uint64 timebase
uint32 point_num
uint8 lidar_id
uint8[3] rsvd
CustomPoint[] points
"""

CUSTOM_POINT = """\
uint32 offset_time
float32 x
float32 y
float32 z
uint8 reflectivity
uint8 tag
uint8 line
"""

_POINT_BYTES = 19  # offset_time, x, y, z (4 bytes each), reflectivity, tag, line (1 byte each)
_AFTER_FRAME_ID = 8 + 4 + 1 + 3  # timebase, point_num, lidar_id, rsvd


def is_custom_msg(msgtype: str) -> bool:
    """Whether ``msgtype`` (``pkg/msg/Type`` or ROS 1's ``pkg/Type``) is a Livox CustomMsg."""
    return msgtype.replace("/msg/", "/") in {name.replace("/msg/", "/") for name in CUSTOM_MSG_TYPES}


def livox_types(package: str = "livox_ros_driver2") -> dict:
    """``package``'s CustomMsg and CustomPoint as rosbags type definitions, for ``Typestore.register``."""
    from rosbags.typesys import get_types_from_msg

    if package not in PACKAGES:
        raise ValueError(f"unknown Livox driver package {package!r}; known: {', '.join(PACKAGES)}")
    types = dict(get_types_from_msg(CUSTOM_MSG, f"{package}/msg/CustomMsg"))
    types.update(get_types_from_msg(CUSTOM_POINT, f"{package}/msg/CustomPoint"))
    return types


def register_livox_types(typestore: Typestore) -> Typestore:
    """Add both drivers' CustomMsg and CustomPoint to ``typestore`` (in place) and return it."""
    for package in PACKAGES:
        typestore.register(livox_types(package))
    return typestore


def _point_dtype(order: str) -> np.dtype:
    return np.dtype(
        {
            "names": ["x", "y", "z", "reflectivity"],
            "formats": [f"{order}f4", f"{order}f4", f"{order}f4", "u1"],
            "offsets": [4, 8, 12, 16],
            "itemsize": _POINT_BYTES,
        }
    )


def _points_start_ros1(data: bytes, source: str) -> tuple[int, int, str, int]:
    """(point_num, point count, byte order, offset of the first point) of a ROS 1 message: fields are
    packed, little-endian, with no alignment."""
    (frame_id_bytes,) = struct.unpack_from("<I", data, 12)  # after seq, stamp.sec, stamp.nsec
    position = 16 + frame_id_bytes
    if position + _AFTER_FRAME_ID + 4 > len(data):
        raise DataError(f"{source}: CustomMsg of {len(data)} bytes ends inside its header")
    (point_num,) = struct.unpack_from("<I", data, position + 8)
    (count,) = struct.unpack_from("<I", data, position + _AFTER_FRAME_ID)
    return point_num, count, "<", position + _AFTER_FRAME_ID + 4


def _points_start_cdr(data: bytes, source: str) -> tuple[int, int, str, int]:
    """The same for CDR (ROS 2): a 4-byte encapsulation header, then fields aligned to their size,
    relative to the end of that header."""
    if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
        raise DataError(f"{source}: CustomMsg is not plain CDR (encapsulation {bytes(data[:4]).hex()})")
    order = "<" if data[1] == 1 else ">"
    (frame_id_bytes,) = struct.unpack_from(f"{order}I", data, 4 + 8)  # after stamp.sec, stamp.nanosec
    position = 12 + frame_id_bytes  # relative to the end of the encapsulation header
    position += -position % 8  # timebase is a uint64
    if 4 + position + _AFTER_FRAME_ID + 4 > len(data):
        raise DataError(f"{source}: CustomMsg of {len(data)} bytes ends inside its header")
    (point_num,) = struct.unpack_from(f"{order}I", data, 4 + position + 8)
    (count,) = struct.unpack_from(f"{order}I", data, 4 + position + _AFTER_FRAME_ID)
    return point_num, count, order, 4 + position + _AFTER_FRAME_ID + 4


def points_from_custom_msg(
    data: bytes | bytearray | memoryview, *, cdr: bool, source: str = "CustomMsg"
) -> NDArray[np.float32]:
    """x, y, z, reflectivity / 255 of the returns in one serialized CustomMsg, float32 ``(N, 4)``.

    ``cdr``: ROS 2 (CDR) rather than ROS 1 serialization. Points at (0, 0, 0) or non-finite are dropped
    (no return). A ``point_num`` that disagrees with the points the message holds is a DataWarning (the
    points are what the message carries; ``point_num`` only repeats their count); a message whose
    length does not match its point count (a truncated message, or a CustomMsg defined otherwise) is a
    DataError naming ``source``.
    """
    data = bytes(data)
    try:
        start = _points_start_cdr if cdr else _points_start_ros1
        point_num, count, order, offset = start(data, source)
    except struct.error as error:
        raise DataError(f"{source}: CustomMsg of {len(data)} bytes ends inside its header") from error
    stride = _POINT_BYTES + (1 if cdr else 0)  # CDR aligns each point to 4 bytes
    needed = offset + (count - 1) * stride + _POINT_BYTES if count else offset
    # CDR writers may pad the end of a message to 4 bytes; anything else means another layout
    if not needed <= len(data) <= needed + (3 if cdr else 0):
        raise DataError(
            f"{source}: CustomMsg of {len(data)} bytes for {count} points, expected {needed}: "
            f"truncated, or not the livox_ros_driver(2) CustomMsg layout"
        )
    if point_num != count:
        warnings.warn(
            f"{source}: CustomMsg point_num {point_num} but it holds {count} points; reading the {count}",
            DataWarning,
            stacklevel=2,
        )
    records = np.ndarray((count,), dtype=_point_dtype(order), buffer=data, offset=offset, strides=(stride,))
    points = np.empty((count, 4), dtype=np.float32)
    for column, name in enumerate(("x", "y", "z")):
        points[:, column] = records[name]
    points[:, 3] = records["reflectivity"].astype(np.float32) / np.float32(255)
    xyz = points[:, :3]
    return points[np.isfinite(xyz).all(axis=1) & (xyz != 0).any(axis=1)]
