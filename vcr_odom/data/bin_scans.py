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
- **A layout the size does not reveal.** Five floats a point is also a whole number of 4-float records
  whenever the point count divides by 4, and three floats whenever it divides by 4 too; read as KITTI's
  four columns, such a file gives points that mix coordinates, intensities and ring numbers, and odometry
  runs on them without a complaint. The values of a ``.bin`` repeat their kind with the record length
  (x and y signed and metres wide, z mostly below the sensor, intensity in 0..1 or 0..255, ring a small
  integer), so :func:`likely_columns` measures, on a sample, how much the columns differ when the file is
  read with each record length: the right one (and its multiples) separates them best, a wrong one
  blends them. A file whose given layout blends what another separates is refused, naming the layout
  that fits (:func:`check_bin_values`).
- **Not a scan at all.** Random bytes or another format saved as ``.bin`` read as float32 give
  coordinates over 10^-38..10^38 m; a file where fewer than 90 % of the sampled points look like
  measurements is refused rather than run with its NaNs dropped.
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

PLAUSIBLE_SHARE = 0.9
"""A scan whose sampled points look like measurements less often than this is not a scan (real KITTI
scans and synthetic ones: over 99.99 %; random bytes read as float32: about 0.3 %)."""

LAYOUT_CANDIDATES = range(3, 9)
"""Record lengths (floats a point) compared by :func:`likely_columns`, besides the one given."""

STRUCTURE_FLOOR = 0.2
"""Below this column-to-column contrast the values say nothing about their layout (noise: about 0.05)."""

_SAMPLE_ROWS = 8192
_PLAUSIBLE_ROWS = 2048
_LAYOUT_CHUNKS, _LAYOUT_CHUNK = 32, 384
_MIN_LAYOUT_VALUES = 2048
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

    Bad sizes, another column layout and files that hold no LiDAR points raise DataError naming the
    file (:func:`check_bin_values`); float64 files are read as float64 with a DataWarning (see the module
    docstring). Points are cleaned by :func:`vcr_odom.data.scans.clean_points`.
    """
    from vcr_odom.data.scans import clean_points  # scans imports this module

    path = Path(path)
    records, dtype = decode_bin(path, columns)
    if dtype.itemsize == 8:
        _warn_float64(path)
    points = np.zeros((len(records), 4), dtype=np.float32)
    points[:, : min(columns, 4)] = records[:, :4]
    return clean_points(points, path)


def decode_bin(path: Path, columns: int = DEFAULT_BIN_COLUMNS) -> tuple[NDArray[np.floating], np.dtype]:
    """The checked ``(N, columns)`` records of ``path`` and their dtype; nothing is warned here, so the
    loaders can check a folder's first scan when it is opened (before a run) without a second warning."""
    check_bin_size(path, columns)
    try:
        data = path.read_bytes()
    except OSError as error:
        raise DataError(f"cannot read scan file {path}: {error}") from error
    dtype = bin_dtype(data, columns)
    values = np.frombuffer(data, dtype=dtype)
    check_bin_values(path, values, columns, dtype)
    return values.reshape(-1, columns), dtype


def check_bin_values(path: Path, values: NDArray[np.floating], columns: int, dtype: np.dtype) -> None:
    """DataError naming ``path`` when its values are not ``columns`` floats a point (another layout fits
    clearly better, :func:`likely_columns`) or are not LiDAR points at all (:data:`PLAUSIBLE_SHARE`)."""
    kind = "float64" if dtype.itemsize == 8 else "float32"
    fits = likely_columns(values, columns)
    if fits is not None:
        raise DataError(
            f"{path}: not {columns} {kind} values a point (--bin-columns {columns}: "
            f"{describe_columns(columns)}): its values repeat their kinds every {fits} floats, as "
            f"{fits}-value records ({describe_columns(fits)}) do, and read as {columns} they would mix "
            f"coordinates with other fields; pass --bin-columns {fits} if the file was written so"
        )
    rows = values[: len(values) // columns * columns].reshape(-1, columns)
    sample = rows[:: max(1, len(rows) // _PLAUSIBLE_ROWS), :3]
    share = plausible_fraction(sample)
    if np.isfinite(sample).all(axis=1).any() and share < PLAUSIBLE_SHARE:
        raise DataError(
            f"{path}: not a LiDAR scan: read as {kind} records of {describe_columns(columns)}, only "
            f"{share:.1%} of the sampled points have coordinates between {TINY_COORDINATE_M:g} and "
            f"{PLAUSIBLE_COORDINATE_M:g} m (a scan has nearly all); expected headerless float32 records "
            "(KITTI's x, y, z, reflectance): the file is corrupt or in another format"
        )


def column_contrast(values: NDArray[np.floating], lengths: list[int]) -> dict[int, float]:
    """For each record length, how much the columns differ when ``values`` are read with it: the largest
    spread, over the columns, of the share of negative values, of values within +-1, of whole numbers,
    and of the mean log magnitude. Evenly spread runs of consecutive values are sampled (every column
    is seen equally in a run), so it is cheap and does not depend on the points' order."""
    if len(values) <= 2 * _LAYOUT_CHUNKS * _LAYOUT_CHUNK:  # small: all of it
        index = np.arange(len(values))
    else:  # runs far enough apart not to overlap
        starts = np.linspace(0, len(values) - _LAYOUT_CHUNK, _LAYOUT_CHUNKS).astype(np.int64)
        index = (starts[:, None] + np.arange(_LAYOUT_CHUNK)[None, :]).ravel()
    with np.errstate(invalid="ignore"):  # random bits hold signalling NaNs
        sample = values[index].astype(np.float64)
    finite = np.isfinite(sample)
    index, sample = index[finite], sample[finite]
    magnitude = np.abs(sample)
    features = np.stack(
        [
            sample < 0,
            magnitude <= 1.0,
            sample == np.round(sample),
            np.clip(np.log10(magnitude + 1e-12), -3.0, 3.0) / 6.0,
        ]
    )
    rows = np.arange(len(features))[:, None]
    contrast = {}
    for length in lengths:
        column = index % length
        counts = np.maximum(np.bincount(column, minlength=length), 1)
        slots = (rows * length + column).ravel()
        sums = np.bincount(slots, weights=features.ravel(), minlength=len(features) * length)
        means = sums.reshape(len(features), length) / counts
        contrast[length] = float(np.ptp(means, axis=1).max())
    return contrast


def likely_columns(values: NDArray[np.floating], columns: int) -> int | None:
    """The record length the values were written with, when it is clearly not ``columns``; else None.

    The right length separates the columns' kinds best (so does any multiple of it); a wrong one blends
    them, so its contrast is at most the right one's. ``columns`` is kept unless its contrast is under
    60 % of the best and 0.15 below it, with the best over :data:`STRUCTURE_FLOOR` (values without any
    structure, too few values, say nothing either way). The answer is the shortest length near the best,
    one that gives whole records if there is such.
    """
    if len(values) < _MIN_LAYOUT_VALUES:
        return None
    lengths = sorted({*LAYOUT_CANDIDATES, columns})
    contrast = column_contrast(values, lengths)
    best = max(contrast.values())
    given = contrast[columns]
    if best < STRUCTURE_FLOOR or given >= 0.6 * best or best - given < 0.15:
        return None
    near = [n for n in lengths if contrast[n] >= 0.8 * best and n != columns]
    whole = [n for n in near if len(values) % n == 0]
    return (whole or near)[0]


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
