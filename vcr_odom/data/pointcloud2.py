"""``sensor_msgs/PointCloud2`` messages to frames: x, y, z and reflectance as float32 ``(N, 4)``.

kiss-icp's own converter (``kiss_icp.tools.point_cloud2``) keeps x, y, z only, and finds a field's type
by scanning the message object's attributes for the type constants, which messages decoded by
``mcap_ros2`` (0.5 and later) do not carry as attributes, so every MCAP recording fails with "Unknown
datatype code 7" (kiss-icp pull request #498). This reads the documented datatype codes directly and
keeps intensity, for the ROS bag and MCAP loaders of :mod:`~vcr_odom.data.kiss_loaders`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from vcr_odom.errors import DataError

POINTFIELD_TYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
"""``sensor_msgs/PointField`` datatype codes (INT8 .. FLOAT64) as numpy type codes."""

REFLECTANCE_FIELDS = ("intensity", "reflectivity", "reflectance", "remission", "i")
"""Field names taken as column 3, first match wins; raw values, not rescaled (drivers differ: Velodyne
gives 0..255 floats, Ouster 16-bit counts), and 0 where a cloud has none."""


def points_from_pointcloud2(msg: Any, source: str = "PointCloud2") -> NDArray[np.float32]:
    """x, y, z, reflectance of every finite point of ``msg``, in the sensor frame.

    Organised clouds mark missing returns with NaN; those rows are dropped here, silently, as every ROS
    consumer does (they are not a data problem). Row padding (``row_step`` beyond ``width * point_step``)
    and big-endian clouds are handled. A cloud without x, y or z, or with a field type outside the
    PointField codes, raises DataError naming ``source``.
    """
    fields = {field.name: field for field in msg.fields}
    missing = [name for name in ("x", "y", "z") if name not in fields]
    if missing:
        raise DataError(
            f"{source}: PointCloud2 without field(s) {', '.join(missing)}; fields: {', '.join(fields)}"
        )
    reflectance = next((name for name in REFLECTANCE_FIELDS if name in fields), None)
    names = ["x", "y", "z"] + ([reflectance] if reflectance else [])
    order = ">" if msg.is_bigendian else "<"
    formats = []
    for name in names:
        code = POINTFIELD_TYPES.get(int(fields[name].datatype))
        if code is None:
            raise DataError(
                f"{source}: field {name!r} has unknown PointField datatype {fields[name].datatype}"
            )
        formats.append(order + code)
    point_step, width, height = int(msg.point_step), int(msg.width), int(msg.height)
    dtype = np.dtype(
        {
            "names": names,
            "formats": formats,
            "offsets": [int(fields[name].offset) for name in names],
            "itemsize": point_step,
        }
    )
    raw = np.frombuffer(bytes(msg.data), dtype=np.uint8) if not isinstance(msg.data, np.ndarray) else msg.data
    raw = raw.astype(np.uint8, copy=False).ravel()
    row_bytes = width * point_step
    row_step = int(msg.row_step) or row_bytes
    if len(raw) < (height - 1) * row_step + row_bytes:
        raise DataError(
            f"{source}: PointCloud2 data holds {len(raw)} bytes, fewer than its {width}x{height} points"
        )
    if row_step != row_bytes:
        raw = np.concatenate([raw[row * row_step : row * row_step + row_bytes] for row in range(height)])
    records = np.ndarray(
        (width * height,), dtype=dtype, buffer=np.ascontiguousarray(raw[: width * height * point_step])
    )
    points = np.zeros((len(records), 4), dtype=np.float32)
    for column, name in enumerate(names):
        points[:, column] = records[name]
    return points[np.isfinite(points[:, :3]).all(axis=1)]
