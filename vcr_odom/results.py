"""Result folders: one timestamped folder per command, a ``latest`` link, and the provenance to redo it.

Every file is written atomically, so a folder interrupted by Ctrl-C holds only complete files.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from datetime import datetime
from importlib import metadata
from pathlib import Path
from typing import Any

from vcr_odom.io import atomic_write_text
from vcr_odom.jsonsafe import json_safe

TRACKED_DISTRIBUTIONS = (
    "vcr-odom",
    "numpy",
    "torch",
    "open3d",
    "kiss-icp",
    "evo",
    "pykitti",
    "click",
    "rich",
)


def create_result_folder(root: str | os.PathLike[str], label: str) -> Path:
    """Make ``<root>/<YYYYmmdd-HHMMSS>_<label>`` (suffixed if taken) and point ``<root>/latest`` at it."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    stem = f"{datetime.now().strftime('%Y%m%d-%H%M%S')}_{_safe(label)}"
    folder = root / stem
    suffix = 1
    while True:
        try:
            folder.mkdir()
            break
        except FileExistsError:
            suffix += 1
            folder = root / f"{stem}-{suffix}"
    _point_latest_at(root, folder)
    return folder


def _safe(label: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "-" for c in label).strip("-") or "run"


def _point_latest_at(root: Path, folder: Path) -> None:
    """Swap the ``latest`` symlink atomically (make a new link, then rename over the old one)."""
    link = root / "latest"
    temporary = root / f".latest.{os.getpid()}"
    try:
        temporary.unlink(missing_ok=True)
        temporary.symlink_to(folder.name, target_is_directory=True)
        os.replace(temporary, link)
    except OSError:  # file systems without symlinks: the folder itself is still complete
        temporary.unlink(missing_ok=True)


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
