"""The KITTI odometry layout: ``<root>/sequences/XX/{velodyne/*.bin, calib.txt, times.txt}``, ``<root>/poses/XX.txt``.

The shared scan-file pieces live in :mod:`vcr_odom.data.scans`. pykitti's ``odometry`` class is
not used: it requires ``times.txt`` and the four camera matrices, and prints instead of raising when
poses are missing, while this loader must work without them and fail with messages that name files.
"""

from __future__ import annotations

import os
import re
import secrets
from pathlib import Path

from vcr_odom.data.bin_scans import DEFAULT_BIN_COLUMNS, check_bin_size, check_columns, decode_bin
from vcr_odom.data.scans import (
    TIMES_FILE,
    ScanFileSequence,
    check_pose_count,
    describe_other_entries,
    list_scan_entries,
    natural_sort_key,
    path_label,
    read_tr,
)
from vcr_odom.errors import ConfigError, DataError
from vcr_odom.io import read_kitti_poses

DATA_ROOT_ENV = "VCR_ODOM_DATA_ROOT"
"""Environment variable read by :func:`resolve_data_root` when ``--data-root`` is not given."""


def resolve_data_root(option: str | os.PathLike[str] | None) -> Path:
    """The KITTI data root: the ``--data-root`` value if given, else ``$VCR_ODOM_DATA_ROOT``.

    The root is the folder that holds ``sequences/`` (and ``poses/``). An explicit option always
    wins over the environment so that one command line never depends on a stale shell variable.
    Raises ConfigError naming both ``--data-root`` and ``VCR_ODOM_DATA_ROOT`` when neither is set,
    and naming the path and where it came from when it does not exist.
    """
    if option is not None and str(option) != "":
        source, value = "--data-root", str(option)
        if os.environ.get(DATA_ROOT_ENV) == value:  # a CLI that fills the option from the variable
            source = f"--data-root or ${DATA_ROOT_ENV} (both {value})"
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


STAGING_SUFFIXES = (".writing", ".old")
"""``vcr-odom synth`` writes a sequence in ``sequences/.<seq>.<pid>.<token>.writing`` and renames the old
one to ``.<seq>.<pid>.<token>.old`` (:func:`vcr_odom.synth.kitti_layout.write_sequence`): a killed synth
leaves one behind, half written. Such folders are never sequences."""


def staging_name(seq: str, suffix: str) -> str:
    """The hidden name under which synth writes (``.writing``) or sets aside (``.old``) ``seq``."""
    return f".{seq}.{os.getpid()}.{secrets.token_hex(4)}{suffix}"


_STAGING = re.compile(r"^\.[A-Za-z0-9_-]+\.\d+\.[0-9a-f]{8}(\.writing|\.old)$")


def is_staging(path: Path) -> bool:
    """True for a synth staging folder (named by :func:`staging_name`) or anything inside one."""
    return any(_STAGING.match(part) for part in Path(os.path.abspath(path)).parts)


def refuse_staging(path: Path) -> None:
    """DataError when ``path`` is (in) a synth staging folder: its scans may be half written."""
    if is_staging(path):
        raise DataError(
            f"{path} is in a folder synth was writing (or setting aside) when it stopped, not a "
            "sequence: its scans may be half written. Run synth again, or remove it"
        )


def list_sequences(root: Path) -> list[str]:
    """Names under ``<root>/sequences``, naturally sorted, for error messages that say what exists.
    Hidden folders are not listed: synth's staging folders (:data:`STAGING_SUFFIXES`) are hidden."""
    sequences = root / "sequences"
    if not sequences.is_dir():
        return []
    names = (p.name for p in sequences.iterdir() if p.is_dir() and not p.name.startswith("."))
    return sorted(names, key=natural_sort_key)


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
    refuse_staging(folder)
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
    ``Tr``'s rotation is projected onto the nearest exact rotation (a change below the file's printed
    precision) when read. ``bin_columns`` is the float32 columns per point of the scans (4 in KITTI;
    5 for x, y, z, intensity, ring exports); hidden files (``._*`` resource forks) are not scans.
    """

    def __init__(
        self, root: str | os.PathLike[str], seq: str | int, *, bin_columns: int = DEFAULT_BIN_COLUMNS
    ) -> None:
        self.bin_columns = check_columns(bin_columns)
        self.root = Path(root).expanduser()
        self.seq, self.sequence_path = _sequence_folder(self.root, seq)
        self.name = f"kitti/{self.seq}"
        self.label = f"{path_label(self.root) or 'kitti'}-{self.seq}"
        self.velodyne_path = self.sequence_path / "velodyne"
        self.files = self._list_scans()

        calib_path = self.sequence_path / "calib.txt"
        poses_path = self.root / "poses" / f"{self.seq}.txt"
        times_path = self.sequence_path / TIMES_FILE
        self.calib_path = calib_path if calib_path.is_file() else None
        self.poses_path = poses_path if poses_path.is_file() else None
        self.times_path = times_path if times_path.is_file() else None

        tr = read_tr(self.calib_path, required=False) if self.calib_path else None
        poses = None
        if self.poses_path is not None:
            poses = read_kitti_poses(self.poses_path)
            check_pose_count(poses, len(self.files), self.poses_path, self.velodyne_path, self._uncounted())
            if tr is None:
                raise DataError(
                    f"{self.poses_path} holds camera-frame poses but {calib_path} "
                    f"{'has no Tr line' if self.calib_path else 'is missing'}, so they cannot be "
                    "converted to the LiDAR frame; add the sequence's calib.txt, or move the poses file "
                    "away to run without ground truth"
                )
        self._set_poses(poses, tr, camera_frame=True)

        remedy = (
            f"add the sequence's {TIMES_FILE} to {self.sequence_path}, or open {self.velodyne_path} "
            "with --folder and --times FILE"
        )
        self._set_times(self.times_path, len(self.files), self.sequence_path, remedy)

    def _list_scans(self) -> list[Path]:
        """The ``.bin`` scans in frame order; every size checked, and the first and last scans' layout and
        values (:func:`~vcr_odom.data.bin_scans.decode_bin`): a wrong layout fails before a long run."""
        if not self.velodyne_path.is_dir():
            raise DataError(f"{self.sequence_path} has no velodyne/ folder of .bin scans")
        files = list_scan_entries(self.velodyne_path, (".bin",))
        if not files:
            raise DataError(f"no .bin scans in {self.velodyne_path}")
        for path in files:  # stat only: catches a truncated file before a long run
            check_bin_size(path, self.bin_columns)
        for path in dict.fromkeys((files[0], files[-1])):
            decode_bin(path, self.bin_columns)
        return files

    def _uncounted(self) -> str:
        return describe_other_entries(self.velodyne_path, (".bin",))
