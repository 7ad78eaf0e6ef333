"""Where frames come from: the KITTI odometry layout, a plain folder of scans, or a recording read by one
of kiss-icp's loaders (ROS bags, MCAP, ...), behind one Protocol."""

from __future__ import annotations

import os
from pathlib import Path

from vcr_odom.data.base import LidarSequence, Points
from vcr_odom.data.bin_scans import DEFAULT_BIN_COLUMNS, read_bin_scan
from vcr_odom.data.folder import FolderSequence, read_scan
from vcr_odom.data.kiss_loaders import LOADERS, KissLoaderSequence, installed_loaders
from vcr_odom.data.kitti import DATA_ROOT_ENV, KittiSequence, normalise_seq, resolve_data_root
from vcr_odom.errors import ConfigError

__all__ = [
    "DATA_ROOT_ENV",
    "DEFAULT_BIN_COLUMNS",
    "LOADERS",
    "FolderSequence",
    "KissLoaderSequence",
    "KittiSequence",
    "LidarSequence",
    "Points",
    "installed_loaders",
    "normalise_seq",
    "open_sequence",
    "read_bin_scan",
    "read_scan",
    "resolve_data_root",
]

PathLike = str | os.PathLike[str]


def _is_kitti_sequence_folder(folder: Path) -> bool:
    return (folder / "velodyne").is_dir() and folder.parent.name == "sequences"


def open_sequence(
    seq: str | int | None = None,
    *,
    data_root: PathLike | None = None,
    folder: PathLike | None = None,
    poses: PathLike | None = None,
    calib: PathLike | None = None,
    times: PathLike | None = None,
    bin_columns: int = DEFAULT_BIN_COLUMNS,
) -> KittiSequence | FolderSequence:
    """One entry point for the CLI: ``seq`` opens a KITTI sequence, ``folder`` a folder of scans.

    - ``seq`` (with ``data_root`` or ``$VCR_ODOM_DATA_ROOT``, see :func:`resolve_data_root`) opens
      ``<root>/sequences/<seq>``; ``poses``/``calib``/``times`` are not accepted there (the layout fixes them).
    - ``folder`` opens a :class:`FolderSequence` with the optional ``poses``/``calib``/``times`` files
      (a ``times.txt`` inside the folder is found by itself); a KITTI sequence folder
      (``.../sequences/XX`` with ``velodyne/``) given without those files is opened as that KITTI
      sequence, so its calibration and poses are found.
    - ``bin_columns`` is the float32 columns per point of ``.bin`` scans (4: KITTI; 5: x, y, z,
      intensity, ring), for both.
    Exactly one of ``seq`` and ``folder`` is required (ConfigError otherwise). Recordings in other
    formats open with :class:`KissLoaderSequence`.
    """
    if (seq is None) == (folder is None):
        raise ConfigError("give exactly one of --seq (a KITTI sequence) and a scan folder")
    if seq is not None:
        extras = [name for name, value in (("poses", poses), ("calib", calib), ("times", times)) if value]
        if extras:
            raise ConfigError(
                f"--{'/--'.join(extras)} only apply to a scan folder; a KITTI sequence reads "
                "poses/XX.txt, calib.txt and times.txt from the data root"
            )
        return KittiSequence(resolve_data_root(data_root), seq, bin_columns=bin_columns)
    path = Path(folder).expanduser()  # type: ignore[arg-type]
    if poses is None and calib is None and times is None and _is_kitti_sequence_folder(path):
        return KittiSequence(path.parent.parent, path.name, bin_columns=bin_columns)
    return FolderSequence(path, poses=poses, calib=calib, times=times, bin_columns=bin_columns)
