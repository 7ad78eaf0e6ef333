"""Writing a synthetic sequence in the KITTI odometry layout (``sequences/<seq>/velodyne/*.bin``,
``calib.txt``, ``times.txt`` and camera-frame ``poses/<seq>.txt``), so every tool that reads KITTI
reads it too."""

from __future__ import annotations

import json
import os
import re
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vcr_odom.data.kitti import staging_name
from vcr_odom.errors import ConfigError, DataError
from vcr_odom.geometry import lidar_to_camera_poses
from vcr_odom.io import (
    atomic_write_bytes,
    atomic_write_text,
    check_free_space,
    describe_os_error,
    temporary_sibling,
    write_kitti_calib,
    write_kitti_poses,
    write_times,
)
from vcr_odom.jsonsafe import json_safe
from vcr_odom.synth.calibration import KITTI_TR, kitti_calib
from vcr_odom.synth.sequence import SynthConfig, SynthSequence

SEQUENCE_NAME = re.compile(r"^[A-Za-z0-9_-]+$")
"""What ``seq`` may be: it becomes a folder and a file name."""


@dataclass(frozen=True)
class WrittenSequence:
    """What :func:`write_sequence` wrote: where, and a summary of the drive for the user."""

    seq_dir: Path
    poses_file: Path
    frames: int
    """Frames written (the keyframes, with ``keyframes``)."""
    length: float
    """Distance driven (m)."""
    duration: float
    """Time of the last frame (s)."""
    seconds: float
    """Wall-clock time the generation took (s)."""
    sensor: str
    height: float
    """Sensor mounting height (m)."""
    scene: str
    generated: int
    """Frames generated, of which ``frames`` were written."""
    motion: str
    """``car`` or ``handheld``."""
    route: str = "street"
    """Which route (:data:`~vcr_odom.synth.routes.ROUTES`) was driven."""


def write_bin(path: Path, points: NDArray[np.float32]) -> Path:
    """Write a KITTI ``.bin`` atomically: never a half-written frame."""
    return atomic_write_bytes(path, np.ascontiguousarray(points, dtype=np.float32).tobytes())


MANIFEST = "synth.json"
"""Written into every sequence folder synth makes: what it made (its configuration, frame count and
poses file). Why: a real download holds the same names synth writes (``velodyne/``, ``calib.txt``,
``poses/<seq>.txt``), so only this file tells a sequence synth may replace from one it must not."""
MANIFEST_MADE_BY = "vcr-odom synth"


def made_by_synth(seq_dir: Path) -> bool:
    """Whether ``seq_dir`` holds synth's manifest (:data:`MANIFEST`): a sequence synth wrote itself."""
    try:
        manifest = json.loads((seq_dir / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(manifest, dict) and manifest.get("made_by") == MANIFEST_MADE_BY


def write_sequence(
    sequence: SynthSequence,
    out_root: str | os.PathLike[str],
    seq: str = "00",
    progress: Callable[[int], None] | None = None,
    *,
    force: bool = False,
) -> WrittenSequence:
    """Write ``sequence`` under ``out_root`` in the KITTI odometry layout.

    The sequence folder is written in full beside its place (a hidden ``sequences/.<seq>.*.writing``)
    and renamed into place; the poses file is written beside its place too and renamed in last. So an
    interrupted or killed synth over an existing sequence leaves the old one or the new one, never
    frames of both: at worst a sequence without its poses file, which is how an incomplete sequence
    shows. A write that fails (a full disk) leaves the old sequence whole and raises a DataError
    naming the sequence; the free space is checked after the first frame.

    What synth may replace (:func:`check_replaceable`, before any work): nothing, an empty sequence
    folder, or one it made itself (its :data:`MANIFEST`); anything else (a real dataset's scans, its
    ground-truth poses) only with ``force``. ``progress`` is called with the number of frames written
    so far. Only the sequence's frames are written: with keyframes, the kept ones, numbered from 0,
    with their own times and poses.
    """
    if not SEQUENCE_NAME.match(seq):
        raise ConfigError(f"seq must be letters, digits, '-' or '_', got {seq!r}")
    start = time.perf_counter()
    root = Path(out_root)
    seq_dir = root / "sequences" / seq
    poses_file = root / "poses" / f"{seq}.txt"
    check_replaceable(seq_dir, poses_file, force=force)
    seq_dir.parent.mkdir(parents=True, exist_ok=True)
    poses_file.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale(seq_dir, poses_file)
    staging = seq_dir.with_name(staging_name(seq, ".writing"))
    poses_pending = temporary_sibling(poses_file)
    existed = seq_dir.is_dir()
    try:
        try:
            _write_staging(sequence, staging, seq_dir, progress)
            _write_manifest(staging / MANIFEST, sequence, seq, poses_file)
            write_kitti_poses(poses_pending, lidar_to_camera_poses(sequence.gt_poses, KITTI_TR))
        except (OSError, DataError) as error:
            failure = _not_written(error, seq_dir, existed)
            if failure is None:
                raise
            raise failure from error
        poses_file.unlink(missing_ok=True)  # from here the old sequence shows as incomplete
        _replace_folder(staging, seq_dir)
        os.replace(poses_pending, poses_file)  # a rename: needs no space, so it cannot run out of it
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        poses_pending.unlink(missing_ok=True)
        raise
    return WrittenSequence(
        seq_dir=seq_dir,
        poses_file=poses_file,
        frames=len(sequence),
        length=sequence.length,
        duration=float(sequence.timestamps[-1]),
        seconds=time.perf_counter() - start,
        sensor=sequence.sensor.name,
        height=sequence.sensor.height,
        scene=sequence.scene_style,
        generated=sequence.frames,
        motion=sequence.motion,
        route=sequence.route,
    )


def _write_staging(
    sequence: SynthSequence, staging: Path, seq_dir: Path, progress: Callable[[int], None] | None
) -> None:
    """Frames, calibration and times into ``staging``; after the first frame, a DataError if the
    disk cannot hold about as many frames again (found at frame 1, not at frame 900)."""
    velodyne = staging / "velodyne"
    velodyne.mkdir(parents=True)
    for index in range(len(sequence)):
        points = sequence.frame(index)
        if index == 0:
            needed = np.asarray(points, dtype=np.float32).nbytes * len(sequence)
            check_free_space(seq_dir, needed, f"{len(sequence)} frames")
        write_bin(velodyne / f"{index:06d}.bin", points)
        if progress is not None:
            progress(index + 1)
    write_kitti_calib(staging / "calib.txt", kitti_calib())
    write_times(staging / "times.txt", sequence.timestamps)


def _not_written(error: OSError | DataError, seq_dir: Path, existed: bool) -> DataError | None:
    """One line for a write that failed (a full disk, a quota, a read-only mount): which sequence,
    why, and that the sequence already there, if any, is untouched. None for any other error."""
    cause = error if isinstance(error, OSError) else error.__cause__
    if not isinstance(cause, OSError):
        return None
    kept = "the sequence already there is kept" if existed else "nothing was written"
    return DataError(f"{seq_dir}: could not write the sequence: {describe_os_error(cause)}; {kept}")


def _remove_stale(seq_dir: Path, poses_file: Path) -> None:
    """What a killed synth left beside the sequence and its poses file."""
    for pattern in (f".{seq_dir.name}.*.writing", f".{seq_dir.name}.*.old"):
        for stale in seq_dir.parent.glob(pattern):
            shutil.rmtree(stale, ignore_errors=True)
    for stale in poses_file.parent.glob(f".{poses_file.name}.*.tmp"):
        stale.unlink(missing_ok=True)


def check_replaceable(seq_dir: Path, poses_file: Path, *, force: bool = False) -> None:
    """A ConfigError, before any work, where writing ``seq_dir`` and ``poses_file`` would replace what
    synth did not make: one rule, whatever the folder holds. Free to write: nothing there yet, an
    empty sequence folder (with no poses file), or a folder with synth's :data:`MANIFEST` (its poses
    file is synth's too). ``force`` replaces anything but a file where the folder goes."""
    if seq_dir.exists() and not seq_dir.is_dir():
        raise ConfigError(f"--out: {seq_dir} exists and is not a folder")
    if force or (seq_dir.is_dir() and made_by_synth(seq_dir)):
        return
    held = sorted(p.name for p in seq_dir.iterdir())[:5] if seq_dir.is_dir() else []
    if held:
        what = f"{seq_dir} holds {', '.join(held)}, and synth did not make it (it has no {MANIFEST})"
    elif poses_file.exists():
        what = f"{poses_file} exists, and synth did not write it (no {seq_dir / MANIFEST} beside it)"
    else:
        return
    raise ConfigError(
        f"--out: {what}: refusing to replace it; choose another --out or --seq, or give --force to replace it"
    )


def _write_manifest(path: Path, sequence: SynthSequence, seq: str, poses_file: Path) -> None:
    """Synth's :data:`MANIFEST`: it made this folder (so a later synth may replace it), and how."""
    manifest = {
        "made_by": MANIFEST_MADE_BY,
        "seq": seq,
        "frames": len(sequence),
        "poses_file": f"{poses_file.parent.name}/{poses_file.name}",
        "config": sequence.config.to_dict(),
    }  # no time stamp: the same seed writes byte-identical files
    atomic_write_text(path, json.dumps(json_safe(manifest), indent=2) + "\n")


def _replace_folder(new: Path, target: Path) -> None:
    """Put ``new`` where ``target`` is: the old folder is renamed aside, then removed."""
    old = None
    if target.exists():
        old = target.with_name(staging_name(target.name, ".old"))
        os.rename(target, old)
    os.rename(new, target)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def generate_sequence(
    out_root: str | os.PathLike[str],
    seq: str = "00",
    config: SynthConfig | None = None,
    progress: Callable[[int], None] | None = None,
    *,
    force: bool = False,
    **options: Any,
) -> WrittenSequence:
    """Generate a synthetic sequence and write it in the KITTI layout (``<out_root>/sequences/<seq>``).

    ``options`` are :class:`SynthConfig` fields (``frames``, ``seed``, ``speed``, ``sensor``,
    ``height``, ``scene``, ``stops``, ``frame_period``, ``motion``, ``keyframes``, ``keyframe_angle``,
    ``thin``, ``route``), applied on top of ``config`` when one is given. ``force``: see
    :func:`write_sequence`.
    """
    return write_sequence(SynthSequence(config, **options), out_root, seq, progress, force=force)
