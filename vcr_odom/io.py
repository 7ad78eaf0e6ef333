"""File formats shared by data, odometry and evaluation: KITTI poses, KITTI calib, TUM trajectories.

Every writer goes through :func:`atomic_write_text` so an interrupted run never leaves a half-written file.
"""

from __future__ import annotations

import os
import secrets
import shutil
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vcr_odom.errors import DataError
from vcr_odom.geometry import project_to_se3


def temporary_sibling(path: str | os.PathLike[str]) -> Path:
    """A fresh hidden name beside ``path`` for write-then-rename (created by the caller, so the
    umask applies: ``mkstemp`` would leave result files readable by their owner only)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to a temporary file beside ``path``, then rename it into place."""
    path = Path(path)
    try:
        temporary = temporary_sibling(path)
        try:
            with open(temporary, "xb") as handle:
                handle.write(data)
            os.replace(temporary, path)
        finally:
            temporary.unlink(missing_ok=True)
    except OSError as error:  # a full disk, a quota, a read-only mount: one line naming the file
        raise DataError(f"{path}: could not write: {describe_os_error(error)}") from error
    return path


def describe_os_error(error: OSError) -> str:
    """``No space left on device`` (the reason alone: the caller names the file it was writing)."""
    return error.strerror or str(error)


def check_free_space(path: str | os.PathLike[str], needed: int, what: str) -> None:
    """DataError, before writing ``what`` (about ``needed`` bytes) at ``path``, where its file system
    has less free space: a full disk found after the work would waste it, or cut a file short."""
    folder = Path(path).absolute().parent
    while not folder.exists() and folder.parent != folder:
        folder = folder.parent
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        return  # nothing to measure with (an odd file system): the write itself still checks
    if free < needed:
        raise DataError(
            f"{path}: not enough free space for {what} (needs about {_megabytes(needed)}, "
            f"{_megabytes(free)} free on {folder})"
        )


def _megabytes(size: int) -> str:
    return f"{size / 1e6:.1f} MB"


def atomic_write_text(path: str | os.PathLike[str], text: str) -> Path:
    """:func:`atomic_write_bytes` for text (UTF-8)."""
    return atomic_write_bytes(path, text.encode())


EXPECTED_POSES = "a KITTI poses file holds 12 numbers (a 3x4 matrix, row-major) per line"
EXPECTED_CALIB = "a KITTI calib.txt holds lines 'NAME: numbers'"


def read_text(path: Path, expected: str) -> str:
    """The file as UTF-8 text, or a DataError naming the file, the line and what it should hold: a
    binary or mis-encoded file would otherwise surface as a UnicodeDecodeError traceback."""
    raw = path.read_bytes()
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        line = raw[: error.start].count(b"\n") + 1
        raise DataError(
            f"{path}:{line}: not UTF-8 text (byte 0x{raw[error.start]:02x}); {expected}"
        ) from None


def read_kitti_poses(path: str | os.PathLike[str]) -> NDArray[np.float64]:
    """Read a KITTI pose file (12 numbers a line, row-major 3x4) into ``(M, 4, 4)``.

    Rotations are projected onto SO(3): the files' 7 printed digits otherwise show up as false
    rotation in relative poses (see :func:`vcr_odom.geometry.project_to_se3`). A block too far from a
    rotation for printing to explain is refused rather than projected.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"poses file not found: {path}")
    rows = []
    for line_number, line in enumerate(read_text(path, EXPECTED_POSES).splitlines(), start=1):
        if not line.strip():
            continue
        try:
            values = [float(v) for v in line.split()]
        except ValueError as error:
            raise DataError(f"{path}:{line_number}: expected 12 numbers, got {line!r}") from error
        if len(values) != 12:
            raise DataError(f"{path}:{line_number}: expected 12 numbers (a 3x4 pose), got {len(values)}")
        rows.append(values)
    if not rows:
        raise DataError(f"poses file is empty: {path}")
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :4] = np.asarray(rows).reshape(-1, 3, 4)
    if not np.all(np.isfinite(poses)):
        raise DataError(f"{path}: poses contain NaN or inf")
    rotations = poses[:, :3, :3]
    deviation = np.abs(np.swapaxes(rotations, 1, 2) @ rotations - np.eye(3)).max(axis=(1, 2))
    if deviation.max() > 1e-3:
        bad = int(np.argmax(deviation)) + 1
        raise DataError(f"{path}: pose {bad} has a rotation block that is not a rotation matrix")
    return project_to_se3(poses)


def format_kitti_poses(poses: ArrayLike) -> str:
    """KITTI text for ``(M, 4, 4)`` poses: the top 3x4 block of each, row-major, one pose a line."""
    poses = np.asarray(poses, dtype=np.float64)
    return "".join(" ".join(f"{v:.9e}" for v in pose[:3, :4].ravel()) + "\n" for pose in poses)


def write_kitti_poses(path: str | os.PathLike[str], poses: ArrayLike) -> Path:
    """Write :func:`format_kitti_poses` atomically."""
    return atomic_write_text(path, format_kitti_poses(poses))


def read_kitti_calib(path: str | os.PathLike[str]) -> dict[str, NDArray[np.float64]]:
    """Parse a KITTI ``calib.txt`` (``KEY: v1 v2 ...``); ``Tr`` comes back as a 4x4 matrix."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"calibration file not found: {path}")
    calib: dict[str, NDArray[np.float64]] = {}
    for line_number, line in enumerate(read_text(path, EXPECTED_CALIB).splitlines(), start=1):
        if not line.strip():
            continue
        key, sep, rest = line.partition(":")
        if not sep:
            raise DataError(f"{path}:{line_number}: expected 'KEY: numbers', got {line!r}")
        try:
            calib[key.strip()] = np.array([float(v) for v in rest.split()])
        except ValueError as error:
            raise DataError(f"{path}:{line_number}: non-numeric value in {line!r}") from error
    if "Tr" in calib:
        if calib["Tr"].size != 12:
            raise DataError(f"{path}: 'Tr' must have 12 numbers (3x4), got {calib['Tr'].size}")
        tr = np.eye(4)
        tr[:3, :4] = calib["Tr"].reshape(3, 4)
        calib["Tr"] = tr
    return calib


def write_kitti_calib(path: str | os.PathLike[str], entries: dict[str, ArrayLike]) -> Path:
    """Write ``KEY: numbers`` lines; a 4x4 ``Tr`` is written as its 3x4 block, as KITTI does."""
    lines = []
    for key, value in entries.items():
        array = np.asarray(value, dtype=np.float64)
        if array.shape == (4, 4):
            array = array[:3, :4]
        lines.append(f"{key}: " + " ".join(f"{v:.12e}" for v in array.ravel()))
    return atomic_write_text(path, "\n".join(lines) + "\n")


def read_times(path: str | os.PathLike[str]) -> NDArray[np.float64]:
    """Read a KITTI ``times.txt``: one timestamp in seconds a line, strictly increasing.

    Odometry turns frame gaps into speeds, so a wrong stamp is a wrong velocity rather than a cosmetic
    problem: every rule is checked here and a broken file raises :class:`DataError` naming the file, the
    line and what was expected. Blank lines are skipped (line numbers still count them); a second column,
    a header word, NaN/inf, a repeated or decreasing stamp (an all-zero file included) and bytes that are
    not UTF-8 text are all errors. Whether there is one line per frame is the caller's check (it knows
    the frame count): see :func:`vcr_odom.data.scans.load_times`.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"timestamps file not found: {path}")
    text = read_text(path, "a times.txt holds one number (seconds) per line")
    expected = "one number (seconds) per line, strictly increasing"
    stamps: list[float] = []
    previous_line = 0
    for number, line in enumerate(text.splitlines(), start=1):
        fields = line.split()
        if not fields:
            continue
        if len(fields) != 1:
            raise DataError(
                f"{path}:{number}: expected {expected}; got {len(fields)} columns: {line.strip()!r}"
            )
        try:
            value = float(fields[0])
        except ValueError:
            raise DataError(f"{path}:{number}: expected {expected}; got {fields[0]!r}") from None
        if not np.isfinite(value):
            raise DataError(f"{path}:{number}: expected {expected}; got {fields[0]!r}")
        if stamps and value <= stamps[-1]:
            how = "repeats" if value == stamps[-1] else "goes back from"
            raise DataError(
                f"{path}:{number}: timestamps must be strictly increasing; {value!r} {how} "
                f"{stamps[-1]!r} on line {previous_line}"
            )
        stamps.append(value)
        previous_line = number
    if not stamps:
        raise DataError(f"{path}: no timestamps (expected {expected})")
    return np.asarray(stamps, dtype=np.float64)


def write_times(path: str | os.PathLike[str], times: ArrayLike) -> Path:
    """Write a KITTI ``times.txt`` (one timestamp in seconds a line) atomically.

    Each stamp is written in full (the shortest text that reads back to the same float): KITTI's own
    ``%e`` keeps 7 digits, which is fine from 0 but rounds Unix-epoch stamps (1.7e9 s) to 1000 s.
    """
    return atomic_write_text(path, "".join(f"{float(t)!r}\n" for t in np.asarray(times, dtype=np.float64)))


def format_tum_trajectory(poses: ArrayLike, timestamps: ArrayLike) -> str:
    """TUM text (``t x y z qx qy qz qw``) through evo's own quaternion conversion."""
    from evo.core.transformations import quaternion_from_matrix

    lines = []
    for pose, stamp in zip(np.asarray(poses, dtype=np.float64), np.asarray(timestamps), strict=True):
        qw, qx, qy, qz = quaternion_from_matrix(pose)
        x, y, z = pose[:3, 3]
        lines.append(f"{stamp:.6f} {x:.9f} {y:.9f} {z:.9f} {qx:.9f} {qy:.9f} {qz:.9f} {qw:.9f}\n")
    return "".join(lines)


def write_tum_trajectory(path: str | os.PathLike[str], poses: ArrayLike, timestamps: ArrayLike) -> Path:
    """Write :func:`format_tum_trajectory` atomically."""
    return atomic_write_text(path, format_tum_trajectory(poses, timestamps))
