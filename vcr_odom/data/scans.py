"""What every scan loader shares: point clean-up, timestamps, ``Tr``, and the lazy sequence bases that
:mod:`~vcr_odom.data.kitti`, :mod:`~vcr_odom.data.folder` and :mod:`~vcr_odom.data.kiss_loaders` extend.

``.bin`` decoding lives in :mod:`~vcr_odom.data.bin_scans` (re-exported here): pykitti's reader fixed
four float32 columns, and users' files come with five, or as float64.
"""

from __future__ import annotations

import contextlib
import errno
import itertools
import operator
import os
import re
import stat
import warnings
from collections.abc import Iterator
from decimal import Decimal
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from vcr_odom.data.base import Points
from vcr_odom.data.bin_scans import DEFAULT_BIN_COLUMNS, read_bin_scan
from vcr_odom.errors import DataError, DataWarning
from vcr_odom.geometry import camera_to_lidar_poses, lidar_to_camera_poses, normalise_to_first, project_to_se3
from vcr_odom.io import read_kitti_calib, read_kitti_poses, read_times

DEFAULT_RATE_HZ = 10.0
"""KITTI's Velodyne spins at about 10 Hz: the assumed rate where a source has no timestamps."""

TIMES_FILE = "times.txt"
"""The timestamps file KITTI keeps beside a sequence's scans; a scan folder's own is found too."""

SECONDS_STEP_LIMIT = 1e3
"""A median frame step above this many seconds means the file is not in seconds (ns or us epochs)."""


_NUMBER = re.compile(r"(\d+(?:\.\d+)?)")


def natural_sort_key(path: str | os.PathLike[str]) -> tuple[tuple[int, Decimal | str], ...]:
    """Sort ``2.bin`` before ``10.bin`` and ``1700000000.05.bin`` before ``1700000000.4.bin``.

    The rule: numbers in a name compare by value, the text between them as text. A number is a run of
    digits, with its decimals when a dot and digits follow (timestamps: seconds.fraction), so names
    that are all numbers sort as numbers, and ``scan_2``, ``scan_10`` by their numbers. A dot followed
    by a letter (``.bin``) is text. Two names equal by this rule (``5.bin``, ``05.bin``) have no order:
    :func:`sort_scan_files` refuses them.
    """
    parts = _NUMBER.split(Path(path).name)
    return tuple((0, Decimal(part)) if part[0].isdigit() else (1, part) for part in parts if part)


def sort_scan_files(files: list[Path]) -> list[Path]:
    """``files`` by :func:`natural_sort_key`, or DataError naming two whose order would be a guess."""
    ordered = sorted(files, key=lambda path: (natural_sort_key(path), path.name))
    for first, second in itertools.pairwise(ordered):
        if natural_sort_key(first) == natural_sort_key(second):
            raise DataError(
                f"{first} and {second}: two scans with the same number, so their frame order is a "
                "guess; rename or remove one (names sort by the value of their numbers)"
            )
    return ordered


_NO_SKIP = (
    "frames are never skipped (every later frame would take the wrong pose and time): repair or remove it"
)


def check_scan_entry(entry: Path) -> None:
    """DataError naming ``entry`` (named like a scan) when it is not a readable file: a broken symbolic
    link, a link loop, a folder. Skipping it would shift every later frame's number, and so its pose
    and timestamp, by one."""
    try:
        mode = entry.stat().st_mode
    except OSError as error:
        if error.errno == errno.ELOOP:
            what = "a symbolic link loop"
        elif entry.is_symlink():
            what = f"a broken symbolic link (to {os.readlink(entry)}, which does not exist)"
        else:
            what = f"unreadable ({error.strerror})"
        raise DataError(f"{entry}: named like a scan but {what}; {_NO_SKIP}") from error
    if stat.S_ISDIR(mode):
        raise DataError(f"{entry}: named like a scan but a folder, not a scan file; {_NO_SKIP}")
    if not stat.S_ISREG(mode):
        raise DataError(f"{entry}: named like a scan but not a regular file; {_NO_SKIP}")


def list_scan_entries(folder: Path, suffixes: tuple[str, ...]) -> list[Path]:
    """The scan files of ``folder`` (by suffix, any case; hidden files are not scans), in frame order;
    DataError naming any entry named like a scan that is not a readable file (:func:`check_scan_entry`)
    or two whose order is a guess (:func:`sort_scan_files`)."""
    entries = [p for p in folder.iterdir() if p.suffix.lower() in suffixes and not is_hidden(p)]
    for entry in entries:
        check_scan_entry(entry)
    return sort_scan_files(entries)


def describe_other_entries(folder: Path, suffixes: tuple[str, ...]) -> str:
    """``; not counted as scans there: a.txt, ._0.bin`` (what is not a frame, the times and calibration
    files that live beside scans aside), for count mismatches."""
    companions = {TIMES_FILE, "calib.txt"}
    names = (p.name for p in folder.iterdir() if p.suffix.lower() not in suffixes or is_hidden(p))
    others = sorted((name for name in names if name not in companions), key=natural_sort_key)
    if not others:
        return ""
    shown = ", ".join(others[:5]) + (f" and {len(others) - 5} more" if len(others) > 5 else "")
    return f"; not counted as scans there: {shown}"


def is_hidden(path: Path) -> bool:
    """Dot-files are never scans: macOS writes ``._name`` resource forks beside every file it copies to
    a foreign disk, and they carry a scan's extension but not its data."""
    return path.name.startswith(".")


def clean_points(points: NDArray[np.floating], source: str | os.PathLike[str]) -> Points:
    """Drop points with NaN/inf in any column (counted in a warning) and warn on an empty frame.

    Downstream stages assume finite float32 ``(N, 4)`` data; doing this once here keeps them simple.
    """
    points = np.asarray(points, dtype=np.float32).reshape(-1, 4)
    finite = np.isfinite(points).all(axis=1)
    dropped = int(len(points) - finite.sum())
    if dropped:
        warnings.warn(
            f"{source}: dropped {dropped} of {len(points)} points with NaN or inf values",
            DataWarning,
            stacklevel=3,
        )
        points = points[finite]
    if len(points) == 0:
        warnings.warn(f"{source}: empty frame (no valid points)", DataWarning, stacklevel=3)
    elif not points[:, :3].any():  # organised clouds write a missing return as (0, 0, 0)
        warnings.warn(
            f"{source}: no returns: all {len(points)} points are at the sensor (0, 0, 0)",
            DataWarning,
            stacklevel=3,
        )
    return np.ascontiguousarray(points, dtype=np.float32)


def assumed_timestamps(count: int, where: str | os.PathLike[str], remedy: str) -> NDArray[np.float64]:
    """10 Hz timestamps from 0, with one DataWarning that names the source and says how to give the real
    ones (``remedy``), so nobody mistakes guessed stamps for measured ones."""
    warnings.warn(
        f"{where}: no timestamps (no {TIMES_FILE}), assuming {DEFAULT_RATE_HZ:g} Hz; {remedy}",
        DataWarning,
        stacklevel=3,
    )
    return np.arange(count, dtype=np.float64) / DEFAULT_RATE_HZ


def folder_times_remedy() -> str:
    """How a user of a scan folder (or a loader) gives real timestamps."""
    return (
        f"give the real ones with --times FILE (seconds, one line per frame) or put a {TIMES_FILE} "
        "beside the scans"
    )


def load_times(path: Path, count: int) -> NDArray[np.float64]:
    """Read ``times.txt`` (checked by :func:`vcr_odom.io.read_times`) and insist on one line per frame:
    a mismatch would misalign every stamp. A median step over 1000 s warns: the file is likely in
    nanoseconds or microseconds, and odometry reads seconds."""
    times = read_times(path)
    if len(times) != count:
        raise DataError(
            f"{path}: {len(times)} timestamps but {count} frames; the times file needs one line per frame"
        )
    if count > 1 and float(np.median(np.diff(times))) > SECONDS_STEP_LIMIT:
        warnings.warn(
            f"{path}: the median step between frames is {float(np.median(np.diff(times))):.3g} s; "
            "timestamps must be in seconds (this looks like nanoseconds or microseconds)",
            DataWarning,
            stacklevel=3,
        )
    return times


def read_tr(calib_path: Path, *, required: bool) -> NDArray[np.float64] | None:
    """``Tr`` (LiDAR -> left camera) from a KITTI ``calib.txt``: checked, then made exactly rigid.

    A missing ``Tr:`` line is an error only when ``required`` (camera-frame poses need it).
    """
    calib = read_kitti_calib(calib_path)
    if "Tr" not in calib:
        if required:
            raise DataError(f"{calib_path}: no 'Tr:' line (the velodyne -> camera transform)")
        return None
    tr = calib["Tr"].copy()
    if not np.isfinite(tr).all():
        raise DataError(
            f"{calib_path}:{_line_of(calib_path, 'Tr')}: 'Tr' holds a NaN or infinite value; expected "
            "12 finite numbers (the velodyne -> camera transform, 3x4)"
        )
    rotation = tr[:3, :3]
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-4) or np.linalg.det(rotation) < 0:
        raise DataError(f"{calib_path}: 'Tr' rotation is not orthonormal (not a rigid transform)")
    # KITTI prints Tr to ~1e-7; the nearest exact rotation keeps the closed-form inverse exact,
    # so converted poses stay rigid and frame 0 stays the identity to machine precision.
    return project_to_se3(tr)


def _line_of(path: Path, key: str) -> int | str:
    """The line number of ``key:`` in a ``KEY: numbers`` file (for messages), or ``?``."""
    with contextlib.suppress(OSError, UnicodeDecodeError):
        for number, line in enumerate(path.read_text().splitlines(), start=1):
            if line.partition(":")[0].strip() == key:
                return number
    return "?"


def check_pose_count(
    poses: NDArray[np.float64], count: int, poses_path: Path, scans: Path, others: str = ""
) -> None:
    """One pose per scan file, or a DataError naming both counts (a mismatch would misalign them all)
    and ``others``, the folder's entries that were not counted (:func:`describe_other_entries`): a scan
    saved under another name is the usual cause."""
    if len(poses) != count:
        raise DataError(
            f"{poses_path}: {len(poses)} poses but {count} scan files in {scans}; "
            f"the poses file must have one line per scan{others}"
        )


def path_label(path: Path) -> str:
    """The last component of ``path`` as typed, made absolute (so "." and ".." name a folder) without
    following links (a link's own name is the one the user knows)."""
    return Path(os.path.abspath(path)).name


class SequenceBase:
    """What every :class:`~vcr_odom.data.base.LidarSequence` here shares: index checks, ground truth in
    both frames, timestamps and whether they were assumed. Subclasses set ``name`` and ``label``,
    implement ``__len__`` and ``_load(position)``, and call :meth:`_set_poses` and :meth:`_set_times`."""

    name: str
    label: str
    """What result folders are named after: the data itself (a KITTI root's folder and the sequence, a
    scan folder's name, a recording's stem), where ``name`` only says the kind ("kitti/00" for any root)."""
    gt_poses_camera: NDArray[np.float64] | None
    """Ground truth in KITTI's left-camera frame (frame 0 = identity), or None when no calibration."""

    _gt_poses: NDArray[np.float64] | None
    _timestamps: NDArray[np.float64]
    _timestamps_assumed: bool
    _tr: NDArray[np.float64] | None

    def __len__(self) -> int:
        raise NotImplementedError

    def _load(self, position: int) -> Points:
        raise NotImplementedError

    def _uncounted(self) -> str:
        """The source's entries not counted as frames, for count mismatches ("" where it has none)."""
        return ""

    def __iter__(self) -> Iterator[Points]:
        for index in range(len(self)):
            yield self.frame(index)

    def __repr__(self) -> str:
        gt = "with" if self._gt_poses is not None else "without"
        return f"<{type(self).__name__} {self.name}: {len(self)} frames, {gt} ground truth>"

    def frame(self, index: int) -> Points:
        """Frame ``index`` (negative counts from the end) as float32 ``(N, 4)``: x, y, z, reflectance."""
        return self._load(self._check_index(index))

    def _check_index(self, index: int) -> int:
        position = operator.index(index)  # TypeError for floats, as for lists
        count = len(self)
        if not -count <= position < count:
            raise IndexError(
                f"frame {position} out of range: {self.name} has {count} frames (0..{count - 1})"
            )
        return position % count

    @property
    def gt_poses(self) -> NDArray[np.float64] | None:
        """``(len, 4, 4)`` ground truth in the LiDAR frame, frame 0 = identity, or None."""
        return self._gt_poses

    @property
    def timestamps(self) -> NDArray[np.float64]:
        """Seconds per frame (10 Hz assumed, with a warning at construction, where none are known)."""
        return self._timestamps

    @property
    def timestamps_assumed(self) -> bool:
        """True when no timestamps were given and :data:`DEFAULT_RATE_HZ` was assumed: odometry should
        then not trust speeds derived from frame gaps."""
        return self._timestamps_assumed

    @property
    def tr_velo_to_cam(self) -> NDArray[np.float64] | None:
        """KITTI's 4x4 ``Tr`` (LiDAR -> left camera), or None when no calibration is known."""
        return self._tr

    def _set_times(
        self,
        times_path: Path | None,
        count: int,
        where: str | os.PathLike[str],
        remedy: str,
        given: NDArray[np.float64] | None = None,
    ) -> None:
        """Timestamps from ``times_path``, else ``given`` (a loader's own), else assumed with a warning."""
        self._timestamps_assumed = times_path is None and given is None
        if times_path is not None:
            self._timestamps = load_times(times_path, count)
        elif given is not None:
            self._timestamps = np.asarray(given, dtype=np.float64)
        else:
            self._timestamps = assumed_timestamps(count, where, remedy)

    def _set_user_poses(self, poses_path: Path | None, calib_path: Path | None, where: Path) -> None:
        """Ground truth from a user's KITTI-format poses file: camera-frame poses when ``calib_path``
        holds ``Tr`` (converted to the LiDAR frame), LiDAR-frame poses without one."""
        tr = read_tr(calib_path, required=True) if calib_path is not None else None
        pose_array = None
        if poses_path is not None:
            pose_array = read_kitti_poses(poses_path)
            check_pose_count(pose_array, len(self), poses_path, where, self._uncounted())
        self._set_poses(pose_array, tr, camera_frame=tr is not None)

    def _set_poses(
        self, poses: NDArray[np.float64] | None, tr: NDArray[np.float64] | None, camera_frame: bool
    ) -> None:
        """Store ground truth in both frames, re-anchored so frame 0 = identity: every trajectory in the
        library starts there, so estimates and ground truth compare without an alignment step."""
        self._tr = tr
        self._gt_poses = None
        self.gt_poses_camera = None
        if poses is None:
            return
        if camera_frame:
            assert tr is not None
            self.gt_poses_camera = normalise_to_first(poses)
            self._gt_poses = normalise_to_first(camera_to_lidar_poses(poses, tr))
        else:
            self._gt_poses = normalise_to_first(poses)
            if tr is not None:
                self.gt_poses_camera = lidar_to_camera_poses(self._gt_poses, tr)


class ScanFileSequence(SequenceBase):
    """Lazy sequence over a sorted list of scan files: nothing is read until :meth:`frame` is called.

    Subclasses fill ``files``, ``name``, ``bin_columns`` and the pose/time/calibration attributes.
    """

    files: list[Path]
    bin_columns: int = DEFAULT_BIN_COLUMNS

    def __len__(self) -> int:
        return len(self.files)

    def _load(self, position: int) -> Points:
        return self._read(self.files[position])

    def _read(self, path: Path) -> Points:
        return read_bin_scan(path, self.bin_columns)
