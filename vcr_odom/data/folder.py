"""A plain folder of scans (``.bin``, ``.pcd`` or ``.ply``), for data that is not in the KITTI layout.

Users bring recordings exported by other tools; this takes them as they are: files sorted by the
numbers in their names (timestamps with decimals too), hidden files (macOS ``._*`` resource forks)
skipped but nothing else (a broken link or a folder named like a scan is an error), an optional
KITTI-format poses file, and timestamps from a given ``times.txt``-style file or the folder's own
``times.txt`` (10 Hz assumed, with a warning, when there is neither).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from vcr_odom.data.base import Points
from vcr_odom.data.bin_scans import (
    DEFAULT_BIN_COLUMNS,
    check_bin_size,
    check_columns,
    decode_bin,
    read_bin_scan,
)
from vcr_odom.data.cloud_files import check_cloud_file
from vcr_odom.data.kitti import refuse_staging
from vcr_odom.data.scans import (
    TIMES_FILE,
    ScanFileSequence,
    clean_points,
    describe_other_entries,
    folder_times_remedy,
    list_scan_entries,
    path_label,
)
from vcr_odom.errors import DataError

SCAN_EXTENSIONS = (".bin", ".pcd", ".ply")

_EMPTY_HEADER = re.compile(rb"^\s*(POINTS\s+0|element\s+vertex\s+0)\s*$", re.MULTILINE)


def _reflectance(cloud: object, count: int) -> NDArray[np.float32]:
    """Intensity if the file has it, else the first colour channel scaled to [0, 1], else zeros."""
    attributes = cloud.point  # type: ignore[attr-defined]
    for key in ("intensity", "reflectance", "remission"):
        if key in attributes:
            return attributes[key].numpy().reshape(count, -1)[:, 0].astype(np.float32)
    if "colors" in attributes:
        colours = attributes["colors"].numpy().reshape(count, -1)[:, 0]
        if np.issubdtype(colours.dtype, np.integer):
            return (colours / np.iinfo(colours.dtype).max).astype(np.float32)
        return colours.astype(np.float32)
    return np.zeros(count, dtype=np.float32)


def read_open3d_scan(path: str | os.PathLike[str]) -> Points:
    """Read a ``.pcd``/``.ply`` with open3d's tensor API (which keeps custom fields like intensity).

    open3d only logs when it cannot parse a file, and fills a truncated PLY's missing points with
    garbage; so a file whose data is shorter than its header declares raises DataError first
    (:func:`~vcr_odom.data.cloud_files.check_cloud_file`), an unreadable file raises DataError, and a
    file whose header declares zero points is an empty frame (a warning), as for ``.bin`` scans.
    """
    import open3d as o3d  # heavy import, only when such files are used

    path = Path(path)
    if not path.is_file():
        raise DataError(f"scan file not found: {path}")
    try:
        check_cloud_file(path, path.read_bytes())
    except OSError as error:
        raise DataError(f"cannot read scan file {path}: {error}") from error
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        cloud = o3d.t.io.read_point_cloud(str(path))
    if "positions" not in cloud.point or cloud.point.positions.shape[0] == 0:
        with path.open("rb") as handle:
            header = handle.read(4096)
        if not _EMPTY_HEADER.search(header):
            raise DataError(f"open3d could not read a point cloud from {path} (corrupt or unsupported file)")
        return clean_points(np.zeros((0, 4), dtype=np.float32), path)
    xyz = cloud.point.positions.numpy().astype(np.float32).reshape(-1, 3)
    points = np.column_stack([xyz, _reflectance(cloud, len(xyz))])
    return clean_points(points, path)


def read_scan(path: str | os.PathLike[str], bin_columns: int = DEFAULT_BIN_COLUMNS) -> Points:
    """Read any supported scan file by its extension (``bin_columns``: float32 columns of a ``.bin``)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".bin":
        return read_bin_scan(path, bin_columns)
    if suffix in (".pcd", ".ply"):
        return read_open3d_scan(path)
    raise DataError(
        f"{path}: unsupported scan format {suffix!r}; expected one of {', '.join(SCAN_EXTENSIONS)}"
    )


def list_scan_files(folder: Path) -> list[Path]:
    """Scan files of one kind, in frame order (:func:`~vcr_odom.data.scans.natural_sort_key`); mixed
    kinds are an error (frame order would be a guess), and so is an entry named like a scan that is not
    a readable file (:func:`~vcr_odom.data.scans.check_scan_entry`): it is never skipped. Hidden files
    are not scans (see :func:`~vcr_odom.data.scans.is_hidden`)."""
    if not folder.is_dir():
        raise DataError(f"scan folder does not exist: {folder}")
    refuse_staging(folder)
    files = list_scan_entries(folder, SCAN_EXTENSIONS)
    if not files:
        hint = f" (did you mean {folder / 'velodyne'}?)" if (folder / "velodyne").is_dir() else ""
        raise DataError(f"no scans ({', '.join(SCAN_EXTENSIONS)}) in {folder}{hint}")
    kinds = sorted({p.suffix.lower() for p in files})
    if len(kinds) > 1:
        raise DataError(f"{folder} mixes scan formats ({', '.join(kinds)}); keep one kind of file per folder")
    return files


class FolderSequence(ScanFileSequence):
    """A folder of ``.bin`` (float32 records, ``bin_columns`` a point), ``.pcd`` or ``.ply`` scans, read lazily.

    ``poses`` is a KITTI-format poses file (one 3x4 pose a line, one line per scan). With a ``calib``
    holding ``Tr`` the poses are taken as KITTI camera-frame poses and converted to the LiDAR frame;
    without one they are taken as LiDAR-frame poses. ``times`` is a ``times.txt``-style file; without it
    the folder's own ``times.txt`` is used if there is one (it is where KITTI keeps it, and users copy
    the layout), else 10 Hz is assumed with one warning and :attr:`timestamps_assumed` is True.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        poses: str | os.PathLike[str] | None = None,
        calib: str | os.PathLike[str] | None = None,
        *,
        times: str | os.PathLike[str] | None = None,
        bin_columns: int = DEFAULT_BIN_COLUMNS,
    ) -> None:
        self.bin_columns = check_columns(bin_columns)
        self.path = Path(path).expanduser()
        self.sequence_path = self.path
        self.name = f"folder/{self.path.resolve().name}"
        self.label = path_label(self.path) or "folder"
        self.files = list_scan_files(self.path)
        self.kind = self.files[0].suffix.lower()
        if self.kind == ".bin":
            for file in self.files:  # stat only, as for KITTI: fail before a long run
                check_bin_size(file, self.bin_columns)
            for file in dict.fromkeys((self.files[0], self.files[-1])):  # before a long run too:
                decode_bin(file, self.bin_columns)  # the layout and values of the first and last scan

        self.poses_path = Path(poses).expanduser() if poses is not None else None
        self.calib_path = Path(calib).expanduser() if calib is not None else None
        self.times_path = Path(times).expanduser() if times is not None else None
        if self.times_path is None and (self.path / TIMES_FILE).is_file():
            self.times_path = self.path / TIMES_FILE
        self._set_user_poses(self.poses_path, self.calib_path, self.path)
        remedy = folder_times_remedy()
        if (self.path.parent / TIMES_FILE).is_file():  # KITTI keeps it beside velodyne/, not in it
            remedy += f" ({self.path.parent / TIMES_FILE} may be it: pass it with --times)"
        self._set_times(self.times_path, len(self.files), self.path, remedy)

    def _read(self, path: Path) -> Points:
        return read_scan(path, self.bin_columns)

    def _uncounted(self) -> str:
        return describe_other_entries(self.path, SCAN_EXTENSIONS)
