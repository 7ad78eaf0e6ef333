"""KITTI-style ``.bin`` scans: headerless little-endian records of ``columns`` float32 values each.

A ``.bin`` has no header, so nothing in the file says how to read it; two mistakes are common enough
to handle here rather than leave to odometry that silently diverges:

- **Other column layouts.** Many exporters write x, y, z, intensity, ring (5 floats): ``columns``
  (``--bin-columns``) says how many; columns past the 4th are dropped, 3 columns mean no reflectance.
- **float64 records.** ``numpy.ndarray.tofile`` writes whatever dtype the array has, and numpy's default
  is float64, so a scan prepared in numpy often lands on disk as float64. Such a file is a whole number of
  float32 records too, and read that way it gives points scattered over 10^-30..10^30 metres. Each file
  is checked (:func:`bin_dtype`): when its float32 reading is implausible and its float64 one is not,
  the file **is read as float64, with a DataWarning** (once per folder) rather than refused, because
  the values are unambiguous once detected and a refusal would only make the user convert every file.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from vcr_odom.data.base import Points
from vcr_odom.errors import ConfigError, DataError, DataWarning

DEFAULT_BIN_COLUMNS = 4
"""KITTI's layout: x, y, z, reflectance."""

MAX_BIN_COLUMNS = 16
FLOAT32_BYTES = 4

PLAUSIBLE_COORDINATE_M = 1e5
"""A LiDAR coordinate above this (100 km, generous even for millimetre units) is not a measurement."""

TINY_COORDINATE_M = 1e-6
"""A non-zero coordinate below a micrometre is not a measurement either: random bits read as float32."""

_SAMPLE_ROWS = 8192
_float64_warned: set[Path] = set()


def describe_columns(columns: int) -> str:
    """What ``columns`` floats a record mean, for messages: ``x, y, z, intensity, ring``."""
    if columns == 5:
        return "x, y, z, intensity, ring"
    names = ["x", "y", "z", "reflectance"][:columns]
    extra = columns - len(names)
    return ", ".join(names) + (f" + {extra} more" if extra > 0 else "")


def check_columns(columns: int) -> int:
    """``columns`` as an int in 3..16, or ConfigError naming ``--bin-columns``."""
    if isinstance(columns, bool) or not isinstance(columns, int | np.integer):
        raise ConfigError(f"--bin-columns must be an integer 3..{MAX_BIN_COLUMNS}; got {columns!r}")
    if not 3 <= columns <= MAX_BIN_COLUMNS:
        raise ConfigError(f"--bin-columns must be 3..{MAX_BIN_COLUMNS} (x, y, z at least); got {columns}")
    return int(columns)


def check_bin_size(path: Path, columns: int = DEFAULT_BIN_COLUMNS) -> int:
    """The file's size in bytes, or DataError when it is not whole ``columns`` x float32 records.

    A stat only (no read), so a whole folder is checked before a long run. The message says which other
    ``--bin-columns`` would give whole records, since a wrong layout is the usual cause.
    """
    record = FLOAT32_BYTES * columns
    try:
        size = path.stat().st_size
    except OSError as error:
        raise DataError(f"cannot read scan file {path}: {error}") from error
    if size % record:
        fits = [c for c in range(3, 9) if c != columns and size % (FLOAT32_BYTES * c) == 0]
        hint = f"; whole records with --bin-columns {' or '.join(map(str, fits))}" if fits else ""
        raise DataError(
            f"{path}: size {size} bytes is not a multiple of {record} "
            f"(.bin scans read as float32 {describe_columns(columns)} records, --bin-columns {columns})"
            f"{hint}; otherwise the file is truncated or not a scan"
        )
    return size


def plausible_fraction(xyz: NDArray[np.floating]) -> float:
    """Share of the finite rows whose coordinates all look like LiDAR measurements (0 with no finite row).

    Finite rows only: organised clouds mark missing returns with NaN, which says nothing about the dtype.
    """
    finite = np.isfinite(xyz).all(axis=1)
    if not finite.any():
        return 0.0
    magnitude = np.abs(xyz[finite].astype(np.float64))
    ok = (magnitude == 0) | ((magnitude >= TINY_COORDINATE_M) & (magnitude <= PLAUSIBLE_COORDINATE_M))
    return float(ok.all(axis=1).mean())


def bin_dtype(data: bytes, columns: int = DEFAULT_BIN_COLUMNS) -> np.dtype:
    """``<f4`` or ``<f8``: how the records of ``data`` (a whole ``.bin`` file) are written.

    float32 unless all of: the size is whole float64 records, float64 coordinates look like measurements
    (>= 90 % of rows), and float32 ones do not (< 50 %), or the file has the fingerprint of float32 values
    stored as float64 (``astype(np.float64)`` leaves the low 29 mantissa bits zero, so every other
    32-bit word is 0 or one of a few constants). Ties stay float32, KITTI's layout, so a valid float32
    file is never re-read; the checks look at up to 8192 evenly spaced records.
    """
    float32 = np.dtype("<f4")
    record64 = 2 * FLOAT32_BYTES * columns
    if len(data) < record64 or len(data) % record64:
        return float32
    as32 = np.frombuffer(data, dtype=float32).reshape(-1, columns)
    as64 = np.frombuffer(data, dtype="<f8").reshape(-1, columns)
    step32 = max(1, len(as32) // _SAMPLE_ROWS)
    step64 = max(1, len(as64) // _SAMPLE_ROWS)
    p64 = plausible_fraction(as64[::step64, :3])
    if p64 < 0.9:
        return float32
    p32 = plausible_fraction(as32[::step32, :3])
    words = np.frombuffer(data, dtype="<u4")[: 2 * _SAMPLE_ROWS * columns]
    low, high = words[0::2], words[1::2]
    upcast = np.count_nonzero(high) > len(high) / 2 and np.mean((low & 0x1FFFFFFF) == 0) > 0.99
    return np.dtype("<f8") if (p32 < 0.5 or upcast) else float32


def read_bin_scan(path: str | os.PathLike[str], columns: int = DEFAULT_BIN_COLUMNS) -> Points:
    """Read one ``.bin`` scan as float32 ``(N, 4)``: x, y, z, reflectance (0 when ``columns`` is 3).

    Bad sizes raise DataError naming the file; float64 files are read as float64 with a DataWarning
    (see the module docstring). Points are cleaned by :func:`vcr_odom.data.scans.clean_points`.
    """
    from vcr_odom.data.scans import clean_points  # scans imports this module

    path = Path(path)
    check_bin_size(path, columns)
    try:
        data = path.read_bytes()
    except OSError as error:
        raise DataError(f"cannot read scan file {path}: {error}") from error
    dtype = bin_dtype(data, columns)
    if dtype.itemsize == 8:
        _warn_float64(path)
    records = np.frombuffer(data, dtype=dtype).reshape(-1, columns)
    points = np.zeros((len(records), 4), dtype=np.float32)
    points[:, : min(columns, 4)] = records[:, :4]
    return clean_points(points, path)


def _warn_float64(path: Path) -> None:
    folder = path.parent.resolve()
    if folder in _float64_warned:
        return
    _float64_warned.add(folder)
    warnings.warn(
        f"{path}: the .bin holds float64 records (numpy's default dtype), not KITTI's float32; reading "
        f"them as float64 (this folder's other such files too). Write scans with "
        f"points.astype(np.float32).tofile(...) to silence this",
        DataWarning,
        stacklevel=4,
    )
