"""Result folders: one timestamped folder per command, a ``latest`` link, and the provenance to redo it.

A result folder is a transaction. What a command writes about its trajectory (the trajectory files,
``frames.json``, the scores) is published as one *unit*: written into a fresh hidden folder
``.unit-NNNNNN`` with the marker :data:`MARKER` last, then made current by swapping one symlink,
``.unit``, which the folder's visible files (``trajectory_kitti.txt -> .unit/trajectory_kitti.txt``,
...) point through. Swapping a symlink is one atomic rename, so a reader, or a folder left behind by a
SIGKILL at any moment, sees either the previous unit or the new one, never trajectory files of one
and ``frames.json`` of the other. Where the file system has no symlinks, each file is replaced
atomically and the marker last: still never half a file, but no longer one unit.

The marker says whether the unit is ``complete`` or ``partial`` (a checkpoint, Ctrl-C, an error
part-way), with how many frames it holds and why. A folder is itself made in a hidden staging folder
and renamed into place with its first marker, so no folder without a marker ever appears, and
``latest`` only moves to a folder that holds a trajectory. Interrupting signals (Ctrl-C, SIGTERM,
SIGHUP) that arrive while a unit or a folder is being put in place wait until it is
(:func:`deferred_interrupts`), so an interrupt never leaves one half-made.
"""

from __future__ import annotations

import json
import os
import platform
import re
import secrets
import shutil
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import datetime
from importlib import metadata
from pathlib import Path
from typing import Any, Literal

from vcr_odom.errors import ConfigError, DataError, Interrupted
from vcr_odom.io import atomic_write_text
from vcr_odom.jsonsafe import json_safe
from vcr_odom.stop_signals import STOP_SIGNALS

TRACKED_DISTRIBUTIONS = (
    "vcr-odom",
    "numpy",
    "torch",
    "open3d",
    "kiss-icp",
    "evo",
    "click",
    "rich",
)

MARKER = "result.json"
"""Written last into every unit: ``{"status", "frames_done", "frames_selected", "reason"}``."""

Status = Literal["complete", "partial"]
_UNIT_LINK = ".unit"
_UNIT_PREFIX = ".unit-"


# -- checking where results go, before any work ------------------------------------------------------


def check_output_folder(path: str | os.PathLike[str], option: str) -> Path:
    """``path`` is, or can be made as, a writable folder; else a ConfigError naming ``option``.

    Why before the work: a run that finds out at its end that it cannot write has wasted the run.
    """
    path = Path(path).expanduser()
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{option} {path}: exists and is not a folder")
    _check_creatable(path, option)
    return path


def check_output_file(
    path: str | os.PathLike[str], option: str, suffixes: tuple[str, ...] | None = None
) -> Path:
    """``path`` can be written as a file (with one of ``suffixes``, when given); else a ConfigError."""
    path = Path(path).expanduser()
    if suffixes is not None and path.suffix.lower() not in suffixes:
        raise ConfigError(
            f"{option} {path}: expected a file ending in {' or '.join(suffixes)}, "
            f"not {path.suffix or 'no extension'!r}"
        )
    if path.is_dir():
        raise ConfigError(f"{option} {path}: is a folder; give a file name")
    _check_creatable(path.parent, option, for_file=path)
    return path


def _check_creatable(folder: Path, option: str, for_file: Path | None = None) -> None:
    """The nearest existing ancestor of ``folder`` must be a writable folder (it is where the rest of
    the path will be made)."""
    named = for_file if for_file is not None else folder
    existing = folder.absolute()
    while not existing.exists():
        if existing.parent == existing:
            break
        existing = existing.parent
    if not existing.is_dir():
        raise ConfigError(f"{option} {named}: {existing} is a file, not a folder")
    if existing.exists() and not os.access(existing, os.W_OK | os.X_OK):
        raise ConfigError(f"{option} {named}: {existing} is not writable")
    if folder.exists() and not os.access(folder, os.W_OK | os.X_OK):
        raise ConfigError(f"{option} {named}: {folder} is not writable")


# -- folders --------------------------------------------------------------------------------------


def create_result_folder(
    root: str | os.PathLike[str],
    label: str,
    config: dict[str, Any] | None = None,
    frames_selected: int = 0,
) -> Path:
    """Make ``<root>/<YYYYmmdd-HHMMSS>_<label>`` (suffixed if taken) holding ``config.json`` (the
    :func:`provenance` of ``config``, when given) and a first ``partial`` marker with no frames.

    The folder is filled in a hidden staging folder and renamed into place, so it never exists without
    its marker. ``latest`` is not moved: see :func:`point_latest_at`.
    """
    root = check_output_folder(root, "--results-dir")
    root.mkdir(parents=True, exist_ok=True)
    _remove_abandoned_staging(root)
    stem = f"{datetime.now().strftime('%Y%m%d-%H%M%S')}_{_safe(label)}"
    folder: Path | None = None
    try:
        with deferred_interrupts():  # held until the folder is whole; acts when the block ends
            staging = _staged_folder(root, stem, config, frames_selected)
            try:
                folder = _rename_to_free_name(staging, root / stem)
            except BaseException:
                shutil.rmtree(staging, ignore_errors=True)
                raise
    except BaseException as error:  # stopped while it was made: the caller never saw it, so nobody would
        if folder is not None:  # remove it (a stray folder that says "started" forever)
            remove_result_folder(folder)
        note_kept(error, "no result folder was kept")
        raise
    return folder


def note_kept(error: BaseException, note: str) -> None:
    """Tell an interrupt what its command kept (``"the partial result is kept in ..."``), for the one
    line the command line prints; the innermost note, which knows most, wins."""
    if isinstance(error, KeyboardInterrupt) and not hasattr(error, "kept_note"):
        error.kept_note = note  # type: ignore[attr-defined]


def _rename_to_free_name(staging: Path, folder: Path) -> Path:
    """Rename ``staging`` to ``folder``, or ``folder-2``, ``-3``, ... where taken."""
    stem, suffix = folder.name, 1
    while True:
        if not folder.exists():
            try:
                os.rename(staging, folder)
                return folder
            except OSError:
                if not folder.exists():  # not taken between the check and the rename: a real error
                    raise
        suffix += 1
        folder = folder.parent / f"{stem}-{suffix}"


def create_marked_folder(folder: str | os.PathLike[str], frames_selected: int = 0) -> Path:
    """Make ``folder`` (a comparison's folder for one method) with a first ``partial`` marker, in one
    rename as :func:`create_result_folder` does, so that even a folder left by a SIGKILL before the
    method's first frame says what it is. An existing ``folder`` is left as it is."""
    folder = Path(folder)
    if folder.exists():
        return folder
    with deferred_interrupts():
        staging = _staged_folder(folder.parent, folder.name, None, frames_selected)
        try:
            os.rename(staging, folder)
        except OSError:  # made meanwhile by someone else: theirs stands
            shutil.rmtree(staging, ignore_errors=True)
    return folder


def _staged_folder(parent: Path, stem: str, config: dict[str, Any] | None, frames_selected: int) -> Path:
    """A hidden folder in ``parent`` holding ``config.json`` (when given) and a first marker, to be
    renamed into place (:func:`_remove_abandoned_staging` clears those of a killed process)."""
    staging = parent / f".{stem}.{os.getpid()}.{secrets.token_hex(4)}.creating"
    staging.mkdir()
    try:
        if config is not None:
            write_json(staging / "config.json", provenance(config))
        with result_unit(staging) as unit:
            write_marker(unit, "partial", 0, frames_selected, "started: no frame finished yet")
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return staging


def _remove_abandoned_staging(root: Path) -> None:
    """Staging folders whose process is gone (killed while making its folder): hidden, but litter."""
    for staging in root.glob(".*.creating"):
        try:
            pid = int(staging.name.split(".")[-3])
            os.kill(pid, 0)
        except ProcessLookupError:
            shutil.rmtree(staging, ignore_errors=True)
        except (ValueError, IndexError, OSError):
            continue


def remove_result_folder(folder: str | os.PathLike[str]) -> None:
    """Delete a result folder that holds nothing worth keeping (a run that failed before its first
    frame); ``latest`` never pointed at it."""
    shutil.rmtree(folder, ignore_errors=True)


_LABEL_CHARS = 100
"""Longest label kept in a folder name: with the time stamp and the staging suffix it stays far below
the 255 bytes most file systems allow in a name."""


def _safe(label: str) -> str:
    """``label`` in ASCII letters, digits and ``-_.`` only (every other run of characters becomes one
    ``-``), so the folder name needs no quoting in a shell and means the same on every file system."""
    safe = re.sub(r"[^A-Za-z0-9_.-]+", "-", label)[:_LABEL_CHARS]
    return safe.strip("-.") or "run"


def holds_trajectory(folder: str | os.PathLike[str]) -> bool:
    """A trajectory with at least one pose in ``folder`` or one of its sub-folders (a comparison)."""
    folder = Path(folder)
    candidates = [folder / "trajectory_kitti.txt", *folder.glob("*/trajectory_kitti.txt")]
    return any(path.is_file() and path.stat().st_size > 0 for path in candidates)


def latest_trajectory(root: str | os.PathLike[str]) -> Path:
    """The trajectory of the run ``<root>/latest`` points at, for ``eval`` without ``--est``: the
    folder it resolves to, so that the user is told which run was scored. A comparison holds one
    trajectory per row: the user must choose, so it is an error naming them."""
    link = Path(root) / "latest"
    if not link.is_dir():
        raise ConfigError(
            f"--est not given and {link} does not exist: run `vcr-odom run` first, or give --est FILE "
            "(a KITTI-format trajectory)"
        )
    folder = link.resolve()
    own = folder / "trajectory_kitti.txt"
    if own.is_file():
        return own
    rows = sorted(str(path) for path in folder.glob("*/trajectory_kitti.txt"))
    raise ConfigError(
        f"--est not given and the latest result {folder} holds "
        + (
            f"{len(rows)} trajectories (a comparison): give --est one of {', '.join(rows)}"
            if rows
            else "no trajectory_kitti.txt: give --est FILE"
        )
    )


def recorded_config(folder: str | os.PathLike[str]) -> dict[str, Any]:
    """The settings a result folder's ``config.json`` records (``{}`` where it is missing or
    unreadable: what reads it, ``eval`` and ``view``, then asks the user instead)."""
    try:
        config = json.loads((Path(folder) / "config.json").read_text(encoding="utf-8"))["config"]
    except (OSError, ValueError, KeyError, TypeError):
        return {}
    return config if isinstance(config, dict) else {}


def recorded_calibration(folder: str | os.PathLike[str]) -> Path | None:
    """The calib.txt the run in ``folder`` read (its ``config.json``: ``--calib``, else the KITTI
    layout's ``sequences/SEQ/calib.txt``) where it still exists: scoring that run as it scored itself
    takes the same frame."""
    selection = recorded_config(folder).get("selection")
    if not isinstance(selection, dict):
        return None
    calib = selection.get("calib")
    if not calib and selection.get("data_root") and selection.get("seq"):
        calib = Path(selection["data_root"]) / "sequences" / str(selection["seq"]) / "calib.txt"
    return Path(calib) if calib and Path(calib).is_file() else None


def point_latest_at(root: str | os.PathLike[str], folder: str | os.PathLike[str]) -> bool:
    """Swap ``<root>/latest`` atomically to ``folder`` (a new link renamed over the old one), but only
    once ``folder`` holds a trajectory: ``latest`` is what a user scores next. Returns whether it moved."""
    root, folder = Path(root), Path(folder)
    if not holds_trajectory(folder):
        return False
    link = root / "latest"
    temporary = root / f".latest.{os.getpid()}.{secrets.token_hex(4)}"
    try:
        temporary.symlink_to(folder.name, target_is_directory=True)
        os.replace(temporary, link)
    except OSError:  # file systems without symlinks: the folder itself is still complete
        temporary.unlink(missing_ok=True)
        return False
    return True


# -- units and markers ------------------------------------------------------------------------------


@contextmanager
def result_unit(folder: str | os.PathLike[str]) -> Iterator[Path]:
    """Yields an empty hidden folder for the files of one unit; on leaving without an error they are
    published together (see the module's docstring). Write the marker (:func:`write_marker`) last.

    On an error (or Ctrl-C) inside, nothing is published and the folder keeps its previous unit; once
    published, the unit stays whatever comes after.
    """
    folder = Path(folder)
    staging = _new_unit_folder(folder)
    published = False
    try:
        yield staging
        if not (staging / MARKER).is_file():
            raise RuntimeError(f"a result unit is published with its marker ({MARKER}) written last")
        with deferred_interrupts():
            _publish(folder, staging)
            published = True
    except BaseException as error:
        if not published:
            shutil.rmtree(staging, ignore_errors=True)
        if isinstance(error, DataError) and str(staging) in str(error):  # name the result folder,
            raise DataError(str(error).replace(str(staging), str(folder))) from error  # not its staging
        raise


def _new_unit_folder(folder: Path) -> Path:
    suffixes = [p.name[len(_UNIT_PREFIX) :] for p in folder.glob(f"{_UNIT_PREFIX}*")]
    number = max((int(s) for s in suffixes if s.isdigit()), default=0) + 1
    while True:
        staging = folder / f"{_UNIT_PREFIX}{number:06d}"
        try:
            staging.mkdir()
            return staging
        except FileExistsError:
            number += 1


def _publish(folder: Path, staging: Path) -> None:
    """Point every visible name at ``.unit/<name>``, then swap ``.unit`` to ``staging`` in one rename."""
    names = sorted(p.name for p in staging.iterdir())
    token = f"{os.getpid()}.{secrets.token_hex(4)}"
    try:
        for name in names:
            visible = folder / name
            if not visible.is_symlink():
                temporary = folder / f".{name}.{token}.link"
                temporary.symlink_to(Path(_UNIT_LINK) / name)
                os.replace(temporary, visible)
        temporary = folder / f"{_UNIT_LINK}.{token}.link"
        temporary.symlink_to(staging.name, target_is_directory=True)
        os.replace(temporary, folder / _UNIT_LINK)
    except OSError:  # no symlinks here: each file atomically, the marker last
        for link in folder.glob(f".*.{token}.link"):
            link.unlink(missing_ok=True)
        for name in [n for n in names if n != MARKER] + [MARKER]:
            os.replace(staging / name, folder / name)
        shutil.rmtree(staging, ignore_errors=True)
        return
    for old in folder.glob(f"{_UNIT_PREFIX}*"):
        if old != staging:
            shutil.rmtree(old, ignore_errors=True)


def write_marker(
    folder: str | os.PathLike[str],
    status: Status,
    frames_done: int,
    frames_selected: int,
    reason: str = "",
    **extra: Any,
) -> Path:
    """The marker: ``complete`` when every selected frame was done and everything written, else
    ``partial`` with the ``reason`` (a checkpoint of a run still going, Ctrl-C, an error)."""
    payload = {
        "status": status,
        "frames_done": int(frames_done),
        "frames_selected": int(frames_selected),
        "reason": reason,
        **extra,
        "written": datetime.now().isoformat(timespec="seconds"),
    }
    return write_json(Path(folder) / MARKER, payload)


def read_marker(folder: str | os.PathLike[str]) -> dict[str, Any] | None:
    """The folder's marker, or None where it has none (not a vcr-odom result, or an older one)."""
    path = Path(folder) / MARKER
    if not path.is_file():
        return None
    try:
        marker = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as error:
        raise DataError(f"{path}: unreadable result marker: {error}") from error
    if not isinstance(marker, dict) or marker.get("status") not in ("complete", "partial"):
        raise DataError(f"{path}: not a result marker (no 'status': 'complete' or 'partial')")
    return marker


def interruption_reason(error: BaseException) -> str:
    """What a ``partial`` marker says about why a command stopped: ``interrupted (SIGTERM)``, ..."""
    if isinstance(error, Interrupted):
        return f"interrupted ({error.label})"
    if isinstance(error, KeyboardInterrupt):
        return "interrupted (Ctrl-C)"
    return f"stopped by an error: {type(error).__name__}: {error}".strip()


@contextmanager
def deferred_interrupts() -> Iterator[None]:
    """Hold Ctrl-C, SIGTERM and SIGHUP until the block is done, then let them act as they would have.

    Why: an interrupt in the middle of putting a unit in place, or of writing the partial result of a
    command already stopping, would leave it half-made or lose it. Outside the main thread (where
    Python runs signal handlers) it holds nothing, and needs not.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []
    previous = {}
    for signum in STOP_SIGNALS:
        handler = signal.getsignal(signum)
        if handler is not None:  # None: set outside Python, which it cannot restore
            previous[signum] = signal.signal(signum, lambda number, _frame: held.append(number))
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        for signum in dict.fromkeys(held):
            signal.raise_signal(signum)


# -- provenance -------------------------------------------------------------------------------------


def git_revision() -> str:
    """The checkout's commit (with ``-dirty`` when it has changes), or ``unknown`` outside git."""
    source = Path(__file__).resolve().parent.parent
    try:
        revision = subprocess.run(
            ["git", "-C", str(source), "rev-parse", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(source), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return f"{revision}-dirty" if dirty else revision


def versions() -> dict[str, str]:
    found = {"python": sys.version.split()[0], "platform": platform.platform()}
    for name in TRACKED_DISTRIBUTIONS:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = "not installed"
    return found


def provenance(config: dict[str, Any]) -> dict[str, Any]:
    """Config plus what it ran on: enough to reproduce the folder's figures."""
    return {
        "config": config,
        "command_line": sys.argv,
        "git_revision": git_revision(),
        "versions": versions(),
        "created": datetime.now().isoformat(timespec="seconds"),
    }


def write_json(path: str | os.PathLike[str], payload: Any) -> Path:
    return atomic_write_text(path, json.dumps(json_safe(payload), indent=2, allow_nan=False) + "\n")
