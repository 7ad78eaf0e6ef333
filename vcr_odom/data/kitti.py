"""The KITTI odometry layout: ``<root>/sequences/XX/{velodyne/*.bin, calib.txt, times.txt}``, ``<root>/poses/XX.txt``.

Also home to the pieces every scan loader shares (the ``.bin`` reader, point clean-up, the lazy
file-backed sequence base), so that :mod:`vcr_odom.data.folder` reuses them instead of copying them.

pykitti decodes the ``.bin`` scans (:func:`pykitti.utils.load_velo_scan`). Its ``odometry`` class is
not used: it requires ``times.txt`` and the four camera matrices, and prints instead of raising when
poses are missing, while this loader must work without them and fail with messages that name files.
"""

from __future__ import annotations

import operator
import os
import re
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from vcr_odom.data.base import Points
from vcr_odom.errors import ConfigError, DataError, DataWarning
from vcr_odom.geometry import camera_to_lidar_poses, lidar_to_camera_poses, normalise_to_first
from vcr_odom.io import read_kitti_calib, read_kitti_poses, read_times

DATA_ROOT_ENV = "VCR_ODOM_DATA_ROOT"
"""Environment variable read by :func:`resolve_data_root` when ``--data-root`` is not given."""

DEFAULT_RATE_HZ = 10.0
"""KITTI's Velodyne spins at about 10 Hz: the assumed rate where a source has no timestamps."""

BIN_POINT_BYTES = 16  # float32 x, y, z, reflectance


def resolve_data_root(option: str | os.PathLike[str] | None) -> Path:
    """The KITTI data root: the ``--data-root`` value if given, else ``$VCR_ODOM_DATA_ROOT``.

    The root is the folder that holds ``sequences/`` (and ``poses/``). An explicit option always
    wins over the environment so that one command line never depends on a stale shell variable.
    Raises ConfigError naming both ``--data-root`` and ``VCR_ODOM_DATA_ROOT`` when neither is set,
    and naming the path and where it came from when it does not exist.
    """
    if option is not None and str(option) != "":
        source, value = "--data-root", str(option)
    elif os.environ.get(DATA_ROOT_ENV):
        source, value = f"${DATA_ROOT_ENV}", os.environ[DATA_ROOT_ENV]
    else:
        raise ConfigError(
            f"no KITTI data root: pass --data-root PATH or set the environment variable {DATA_ROOT_ENV} "
            "to the folder that holds sequences/ and poses/"
        )
    root = Path(value).expanduser()
    if not root.is_dir():
        raise ConfigError(f"KITTI data root from {source} does not exist or is not a folder: {root}")
    return root


def normalise_seq(seq: str | int) -> str:
    """``3``, ``"3"`` and ``"03"`` all name sequence ``"03"``; non-numeric names are kept as given."""
    text = str(seq).strip()
    if not text:
        raise ConfigError("sequence id (--seq) is empty")
    return f"{int(text):02d}" if text.isdigit() else text


def natural_sort_key(path: str | os.PathLike[str]) -> tuple[tuple[int, int | str], ...]:
    """Sort ``2.bin`` before ``10.bin``: digit runs compare as numbers, the rest as text."""
    parts = re.split(r"(\d+)", Path(path).name)
    return tuple((0, int(part)) if part.isdigit() else (1, part) for part in parts if part)


def check_bin_size(path: Path) -> None:
    """A KITTI scan is whole float32x4 records; any other size means a truncated or foreign file."""
    try:
        size = path.stat().st_size
    except OSError as error:
        raise DataError(f"cannot read scan file {path}: {error}") from error
    if size % BIN_POINT_BYTES:
        raise DataError(
            f"{path}: size {size} bytes is not a multiple of {BIN_POINT_BYTES} "
            "(KITTI .bin scans are float32 x, y, z, reflectance records); the file is truncated or not a scan"
        )


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
    return np.ascontiguousarray(points, dtype=np.float32)


def read_bin_scan(path: str | os.PathLike[str]) -> Points:
    """Read one KITTI ``.bin`` scan as float32 ``(N, 4)``; bad sizes raise DataError naming the file."""
    from pykitti.utils import load_velo_scan  # imported here: pykitti pulls in PIL, only needed to read

    path = Path(path)
    check_bin_size(path)
    return clean_points(load_velo_scan(str(path)), path)


def assumed_timestamps(count: int, where: str | os.PathLike[str]) -> NDArray[np.float64]:
    """10 Hz timestamps from 0, with one DataWarning naming the source so the user knows they are guessed."""
    warnings.warn(
        f"{where}: no timestamps (times.txt), assuming {DEFAULT_RATE_HZ:g} Hz",
        DataWarning,
        stacklevel=3,
    )
    return np.arange(count, dtype=np.float64) / DEFAULT_RATE_HZ


def load_times(path: Path, count: int) -> NDArray[np.float64]:
    """Read ``times.txt`` and insist on one line per frame (a mismatch would misalign every stamp)."""
    if not path.is_file():
        raise DataError(f"timestamps file not found: {path}")
    times = read_times(path)
    if len(times) != count:
        raise DataError(f"{path}: {len(times)} timestamps but {count} scan files")
    if not np.all(np.isfinite(times)):
        raise DataError(f"{path}: timestamps contain NaN or inf")
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
    rotation = tr[:3, :3]
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-4) or np.linalg.det(rotation) < 0:
        raise DataError(f"{calib_path}: 'Tr' rotation is not orthonormal (not a rigid transform)")
    # KITTI prints Tr to ~1e-7; the nearest exact rotation keeps the closed-form inverse exact,
    # so converted poses stay rigid and frame 0 stays the identity to machine precision.
    u, _, vt = np.linalg.svd(rotation)
    tr[:3, :3] = u @ vt
    return tr


def check_pose_count(poses: NDArray[np.float64], count: int, poses_path: Path, scans: Path) -> None:
    if len(poses) != count:
        raise DataError(
            f"{poses_path}: {len(poses)} poses but {count} scan files in {scans}; "
            "the poses file must have one line per scan"
        )


class ScanFileSequence:
    """Lazy sequence over a sorted list of scan files: nothing is read until :meth:`frame` is called.

    Subclasses fill ``files``, ``name`` and the private pose/time/calibration attributes.
    """

    name: str
    files: list[Path]
    gt_poses_camera: NDArray[np.float64] | None
    """Ground truth in KITTI's left-camera frame (frame 0 = identity), or None when no calibration."""

    _gt_poses: NDArray[np.float64] | None
    _timestamps: NDArray[np.float64]
    _tr: NDArray[np.float64] | None

    def __len__(self) -> int:
        return len(self.files)

    def __iter__(self) -> Iterator[Points]:
        for index in range(len(self)):
            yield self.frame(index)

    def __repr__(self) -> str:
        gt = "with" if self._gt_poses is not None else "without"
        return f"<{type(self).__name__} {self.name}: {len(self)} frames, {gt} ground truth>"

    def frame(self, index: int) -> Points:
        """Frame ``index`` (negative counts from the end) as float32 ``(N, 4)``: x, y, z, reflectance."""
        return self._read(self.files[self._check_index(index)])

    def _read(self, path: Path) -> Points:
        return read_bin_scan(path)

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
    def tr_velo_to_cam(self) -> NDArray[np.float64] | None:
        """KITTI's 4x4 ``Tr`` (LiDAR -> left camera), or None when no calibration is known."""
        return self._tr

    def _set_poses(
        self, poses: NDArray[np.float64] | None, tr: NDArray[np.float64] | None, camera_frame: bool
    ) -> None:
        """Store ground truth in both frames, re-anchored so frame 0 = identity (DESIGN conventions)."""
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


def list_sequences(root: Path) -> list[str]:
    sequences = root / "sequences"
    if not sequences.is_dir():
        return []
    return sorted((p.name for p in sequences.iterdir() if p.is_dir()), key=natural_sort_key)


def _sequence_folder(root: Path, seq: str | int) -> tuple[str, Path]:
    """Find ``sequences/<seq>``; the error says what exists so a typo is obvious."""
    if not root.is_dir():
        raise DataError(f"KITTI data root does not exist: {root}")
    if not (root / "sequences").is_dir():
        raise DataError(
            f"{root} has no sequences/ folder; the KITTI odometry layout is <root>/sequences/XX/velodyne/*.bin"
        )
    name = normalise_seq(seq)
    literal = str(seq).strip()
    if not (root / "sequences" / name).is_dir() and (root / "sequences" / literal).is_dir():
        name = literal  # e.g. a folder really called "003"
    folder = root / "sequences" / name
    if not folder.is_dir():
        found = list_sequences(root)
        listing = ", ".join(found) if found else "none"
        raise DataError(f"sequence {name!r} not found under {root / 'sequences'}; sequences found: {listing}")
    return name, folder


class KittiSequence(ScanFileSequence):
    """One sequence of the KITTI odometry layout, loaded lazily.

    Attributes: ``root``, ``seq`` (two-digit id), ``sequence_path``, ``velodyne_path``, ``files``,
    ``calib_path``/``poses_path``/``times_path`` (None where absent), ``gt_poses`` (LiDAR frame),
    ``gt_poses_camera`` (camera frame, as KITTI writes it), ``tr_velo_to_cam``, ``timestamps``.

    A poses file without ``calib.txt`` (or without its ``Tr`` line) raises DataError: KITTI poses are
    in the camera frame, and using them as LiDAR-frame poses would give silently wrong metrics.
    ``Tr``'s rotation is projected onto the nearest exact rotation (a ~1e-7 change) when read.
    """

    def __init__(self, root: str | os.PathLike[str], seq: str | int) -> None:
        self.root = Path(root).expanduser()
        self.seq, self.sequence_path = _sequence_folder(self.root, seq)
        self.name = f"kitti/{self.seq}"
        self.velodyne_path = self.sequence_path / "velodyne"
        self.files = self._list_scans()

        calib_path = self.sequence_path / "calib.txt"
        poses_path = self.root / "poses" / f"{self.seq}.txt"
        times_path = self.sequence_path / "times.txt"
        self.calib_path = calib_path if calib_path.is_file() else None
        self.poses_path = poses_path if poses_path.is_file() else None
        self.times_path = times_path if times_path.is_file() else None

        tr = read_tr(self.calib_path, required=False) if self.calib_path else None
        poses = None
        if self.poses_path is not None:
            poses = read_kitti_poses(self.poses_path)
            check_pose_count(poses, len(self.files), self.poses_path, self.velodyne_path)
            if tr is None:
                raise DataError(
                    f"{self.poses_path} holds camera-frame poses but {calib_path} "
                    f"{'has no Tr line' if self.calib_path else 'is missing'}, so they cannot be "
                    "converted to the LiDAR frame; add the sequence's calib.txt, or move the poses file "
                    "away to run without ground truth"
                )
        self._set_poses(poses, tr, camera_frame=True)

        if self.times_path is not None:
            self._timestamps = load_times(self.times_path, len(self.files))
        else:
            self._timestamps = assumed_timestamps(len(self.files), self.sequence_path)

    def _list_scans(self) -> list[Path]:
        if not self.velodyne_path.is_dir():
            raise DataError(f"{self.sequence_path} has no velodyne/ folder of .bin scans")
        files = sorted(self.velodyne_path.glob("*.bin"), key=natural_sort_key)
        if not files:
            raise DataError(f"no .bin scans in {self.velodyne_path}")
        for path in files:  # stat only: catches a truncated file before a long run, reads nothing
            check_bin_size(path)
        return files
