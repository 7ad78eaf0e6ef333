"""File formats shared by data, odometry and evaluation: KITTI poses, KITTI calib, TUM trajectories.

Every writer goes through :func:`atomic_write_text` so an interrupted run never leaves a half-written file.
"""

from __future__ import annotations

import os
import secrets
import shutil
import stat
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
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


@contextmanager
def replacing(path: str | os.PathLike[str], suffix: str = "") -> Iterator[Path]:
    """A temporary file (name ending in ``suffix``) to write ``path``'s new content into, put in place
    when the block succeeds and removed either way, so ``path`` is never left half-written.

    In place means: renamed onto ``path``; onto what ``path`` points at if it is a symbolic link (the
    link stays a link, as ``>`` in a shell keeps it); copied into it if it is a FIFO or a device such
    as ``/dev/stdout``, which a rename would replace by a regular file that no reader sees."""
    path = Path(path)
    stream = _is_stream(path)
    target = Path(os.path.realpath(path)) if path.is_symlink() and not stream else path
    temporary = temporary_sibling(Path(tempfile.gettempdir()) / path.name if stream else target)
    temporary = temporary.with_name(temporary.name + suffix)
    try:
        yield temporary
        if stream:
            with open(temporary, "rb") as source, open(path, "wb") as sink:
                shutil.copyfileobj(source, sink)
        else:
            os.replace(temporary, target)
    finally:
        temporary.unlink(missing_ok=True)


def _is_stream(path: Path) -> bool:
    try:
        mode = os.stat(path).st_mode  # follows links: /dev/stdout -> the pipe or terminal behind it
    except OSError:
        return False
    return stat.S_ISFIFO(mode) or stat.S_ISCHR(mode) or stat.S_ISSOCK(mode)


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to ``path`` through :func:`replacing` (never half-written)."""
    path = Path(path)
    try:
        with replacing(path) as temporary, open(temporary, "xb") as handle:
            handle.write(data)
    except OSError as error:  # a full disk, a quota, a read-only mount: one line naming the file
        raise DataError(f"{path}: could not write: {describe_os_error(error)}") from error
    return path


def describe_os_error(error: OSError) -> str:
    """``No space left on device`` (the reason alone: the caller names the file it was writing)."""
    return error.strerror or str(error)


def check_free_space(
    path: str | os.PathLike[str], needed: int, what: str, *, named: str | os.PathLike[str] | None = None
) -> None:
    """DataError, before writing ``what`` (about ``needed`` bytes) at ``path``, where its file system
    has less free space: a full disk found after the work would waste it, or cut a file short.
    ``named``: the file the message names where ``path`` is a temporary stand-in for it."""
    folder = Path(path).absolute().parent
    while not folder.exists() and folder.parent != folder:
        folder = folder.parent
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        return  # nothing to measure with (an odd file system): the write itself still checks
    if free < needed:
        raise DataError(
            f"{named or path}: not enough free space for {what} (needs about {_megabytes(needed)}, "
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


POSE_ROTATION_TOLERANCE = 1e-4
"""Largest ``|R^T R - I|`` entry a pose file may hold: 7 printed digits (KITTI's files) leave about
2e-7 and even 4 decimals stay under it, while a scaled or sheared block (which projection would quietly
turn into some rotation) is over it."""

POSE_TRANSLATION_LIMIT_M = 1e8
"""Largest ``|x|``, ``|y|``, ``|z|`` a pose file may hold: UTM northings and Earth-centred coordinates
stay under 1e7 m, so anything beyond is a broken file, refused before it overflows the metrics."""


def read_kitti_poses(path: str | os.PathLike[str]) -> NDArray[np.float64]:
    """Read a KITTI pose file (12 numbers a line, row-major 3x4) into ``(M, 4, 4)``.

    Rotations are projected onto SO(3): the files' 7 printed digits otherwise show up as false
    rotation in relative poses (see :func:`vcr_odom.geometry.project_to_se3`). A block that printing
    cannot explain (scaled, sheared, mirrored) and a non-finite or absurdly far position are refused
    with the file and line, rather than projected or scored.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"poses file not found: {path}")
    rows: list[list[float]] = []
    line_numbers: list[int] = []
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
        line_numbers.append(line_number)
    if not rows:
        raise DataError(f"poses file is empty: {path}")
    blocks = np.asarray(rows).reshape(-1, 3, 4)
    _check_pose_blocks(path, blocks, line_numbers)
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :4] = blocks
    return project_to_se3(poses)


def _check_pose_blocks(path: Path, blocks: NDArray[np.float64], line_numbers: list[int]) -> None:
    """Refuse the first line whose 3x4 block is not a pose, naming the file, the line and why."""

    def refuse(index: int, why: str) -> None:
        raise DataError(f"{path}: pose {index + 1} (line {line_numbers[index]}) {why}")

    finite = np.all(np.isfinite(blocks), axis=(1, 2))
    if not finite.all():
        refuse(int(np.argmin(finite)), "contains NaN or inf; expected 12 finite numbers")
    far = np.abs(blocks[:, :, 3]).max(axis=1) > POSE_TRANSLATION_LIMIT_M
    if far.any():
        index = int(np.argmax(far))
        refuse(
            index,
            f"has a position {np.abs(blocks[index, :, 3]).max():.3g} m from the origin; expected "
            f"metres, under {POSE_TRANSLATION_LIMIT_M:.0e} m",
        )
    rotations = blocks[:, :, :3]
    expected = f"expected a rotation (R^T R = I to {POSE_ROTATION_TOLERANCE:g}, determinant +1)"
    # A rotation's entries lie in [-1, 1]: larger ones are refused before their products overflow.
    oversized = np.abs(rotations).max(axis=(1, 2)) > 1.0 + POSE_ROTATION_TOLERANCE
    safe = np.where(oversized[:, None, None], 0.0, rotations)
    deviation = np.abs(np.swapaxes(safe, 1, 2) @ safe - np.eye(3)).max(axis=(1, 2))
    not_rotation = oversized | (deviation > POSE_ROTATION_TOLERANCE)
    if not_rotation.any():
        refuse(
            int(np.argmax(not_rotation)), f"has a rotation block that is not a rotation matrix; {expected}"
        )
    mirrored = np.linalg.det(rotations) < 0
    if mirrored.any():
        refuse(
            int(np.argmax(mirrored)),
            f"has a rotation block that is not a rotation matrix (a mirror, determinant -1); {expected}",
        )


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
    a header word, NaN/inf, a repeated or decreasing stamp (an all-zero file included), bytes that are
    not UTF-8 text and steps that no sensor's frame period explains (under 0.1 ms, or a median over
    10 s: milliseconds or nanoseconds read as seconds) are all errors. Whether there is one line per
    frame is the caller's check (it knows the frame count): see :func:`vcr_odom.data.scans.load_times`.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"timestamps file not found: {path}")
    text = read_text(path, "a times.txt holds one number (seconds) per line")
    expected = "one number (seconds) per line, strictly increasing"
    stamps: list[float] = []
    line_numbers: list[int] = []
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
        line_numbers.append(number)
        previous_line = number
    if not stamps:
        raise DataError(f"{path}: no timestamps (expected {expected})")
    _check_frame_steps(path, np.asarray(stamps, dtype=np.float64), line_numbers)
    return np.asarray(stamps, dtype=np.float64)


MIN_FRAME_STEP_S = 1e-4
"""Shortest step between two frames a times file may hold: no LiDAR sweeps at 10 kHz, so a shorter
step is two stamps for one frame or a wrong unit, and odometry would read it as an impossible speed."""

MAX_MEDIAN_FRAME_STEP_S = 10.0
"""Longest typical (median) step: scanners sweep at 1-100 Hz, so a median over 10 s is a file in
milliseconds (10 Hz gives 100), microseconds or nanoseconds, not a sensor read in seconds."""


def _check_frame_steps(path: Path, stamps: NDArray[np.float64], line_numbers: list[int]) -> None:
    """Refuse steps no sensor's frame period explains, saying that seconds are expected."""
    if len(stamps) < 2:
        return
    steps = np.diff(stamps)
    too_short = steps < MIN_FRAME_STEP_S
    if too_short.any():
        first = int(np.argmax(too_short))
        raise DataError(
            f"{path}:{line_numbers[first + 1]}: {steps[first]:.3g} s after the stamp on line "
            f"{line_numbers[first]} cannot be a frame period; expected seconds, at least "
            f"{MIN_FRAME_STEP_S:g} s between frames"
        )
    median = float(np.median(steps))
    if median > MAX_MEDIAN_FRAME_STEP_S:
        raise DataError(
            f"{path}: the median step between frames is {median:.3g}, which as seconds would be a "
            f"{1 / median:.2g} Hz sensor; expected seconds (this looks like {_likely_unit(median)})"
        )


def _likely_unit(median_step: float) -> str:
    """The unit a scanner's 0.01-1 s frame period takes to print as ``median_step``."""
    if median_step < 1e4:
        return "milliseconds"
    return "microseconds" if median_step < 1e7 else "nanoseconds"


def write_times(path: str | os.PathLike[str], times: ArrayLike) -> Path:
    """Write a KITTI ``times.txt`` (one timestamp in seconds a line) atomically.

    Each stamp is written in full (the shortest text that reads back to the same float): KITTI's own
    ``%e`` keeps 7 digits, which is fine from 0 but rounds Unix-epoch stamps (1.7e9 s) to 1000 s.
    """
    return atomic_write_text(path, "".join(f"{float(t)!r}\n" for t in np.asarray(times, dtype=np.float64)))


def format_tum_trajectory(poses: ArrayLike, timestamps: ArrayLike) -> str:
    """TUM text (``t x y z qx qy qz qw``) through evo's own quaternion conversion."""
    from evo.core.transformations import quaternion_from_matrix

    stamps = np.asarray(timestamps, dtype=np.float64)
    decimals = tum_stamp_decimals(stamps)
    lines = []
    for pose, stamp in zip(np.asarray(poses, dtype=np.float64), stamps, strict=True):
        qw, qx, qy, qz = quaternion_from_matrix(pose)
        x, y, z = pose[:3, 3]
        lines.append(f"{stamp:.{decimals}f} {x:.9f} {y:.9f} {z:.9f} {qx:.9f} {qy:.9f} {qz:.9f} {qw:.9f}\n")
    return "".join(lines)


def tum_stamp_decimals(stamps: NDArray[np.float64]) -> int:
    """Decimals that keep distinct stamps distinct: microseconds (TUM's usual 6) unless the shortest
    step needs more, so sub-microsecond steps never print as one repeated stamp."""
    steps = np.diff(stamps)
    steps = steps[steps > 0]
    if not len(steps):
        return 6
    return int(np.clip(np.ceil(-np.log10(steps.min())) + 2, 6, 15))


def write_tum_trajectory(path: str | os.PathLike[str], poses: ArrayLike, timestamps: ArrayLike) -> Path:
    """Write :func:`format_tum_trajectory` atomically."""
    return atomic_write_text(path, format_tum_trajectory(poses, timestamps))
