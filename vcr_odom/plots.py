"""Matplotlib figures written to PNG (headless backend; no display needed)."""

from __future__ import annotations

import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from numpy.typing import NDArray

from vcr_odom.errors import DataError
from vcr_odom.io import describe_os_error, replacing

_SURROGATES = re.compile("[\ud800-\udfff]")


def printable(text: object) -> str:
    """``text`` as matplotlib can draw it: a path whose name is not valid UTF-8 (``b"scans\\xff"``,
    which Python holds as a lone surrogate, ``"scans\\udcff"``) would otherwise fail in the font code,
    after every frame of a run was done. Each surrogate becomes U+FFFD, as a file manager shows it."""
    return _SURROGATES.sub("\ufffd", str(text))


def _save(figure: plt.Figure, path: str | os.PathLike[str]) -> Path:
    """Save through a temporary file so an interrupted run never leaves a truncated PNG; a failed
    write (a full disk) is a DataError naming the file, not a traceback from deep in PIL."""
    path = Path(path)
    try:
        with replacing(path) as temporary:
            figure.savefig(temporary, dpi=130, bbox_inches="tight", format="png")
    except OSError as error:
        raise DataError(f"{path}: could not write: {describe_os_error(error)}") from error
    finally:
        plt.close(figure)
    return path


def plot_trajectories(
    path: str | os.PathLike[str],
    trajectories: Mapping[str, NDArray[np.float64]],
    ground_truth: NDArray[np.float64] | None = None,
    *,
    title: str = "",
    background_xy: NDArray[np.float64] | None = None,
    links: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]] = (),
) -> Path:
    """Top-down (x-y, LiDAR frame: x forward, y left) view of one or more trajectories over ground truth;
    ``links`` are pairs of poses drawn as lines (loop closures)."""
    figure, axes = plt.subplots(figsize=(7, 7))
    if background_xy is not None and len(background_xy):
        axes.scatter(background_xy[:, 0], background_xy[:, 1], s=0.2, c="0.75", linewidths=0, label="map")
    if ground_truth is not None:
        axes.plot(ground_truth[:, 0, 3], ground_truth[:, 1, 3], "k--", lw=2, label="ground truth")
    for name, poses in trajectories.items():
        axes.plot(poses[:, 0, 3], poses[:, 1, 3], lw=1.5, label=printable(name))
    for number, (a, b) in enumerate(links):
        label = f"loops ({len(links)})" if number == 0 else None
        axes.plot([a[0, 3], b[0, 3]], [a[1, 3], b[1, 3]], "m-", lw=0.8, alpha=0.8, label=label)
    first = next(iter(trajectories.values()), ground_truth)
    if first is not None and len(first):
        axes.plot(first[0, 0, 3], first[0, 1, 3], "ko", ms=5)
    axes.set_xlabel("x [m]")
    axes.set_ylabel("y [m]")
    axes.set_aspect("equal", adjustable="datalim")
    axes.grid(True, alpha=0.3)
    axes.legend(loc="best", fontsize=8)
    axes.set_title(printable(title))
    return _save(figure, path)


def plot_pair_errors(
    path: str | os.PathLike[str],
    rotation_errors_deg: Mapping[str, NDArray[np.float64]],
    translation_errors_m: Mapping[str, NDArray[np.float64]],
    *,
    title: str = "",
) -> Path:
    """Per-pair rotation and translation errors along the sequence, one line per method."""
    figure, (top, bottom) = plt.subplots(2, 1, figsize=(8, 5), sharex=True)
    for name, errors in rotation_errors_deg.items():
        top.plot(errors, lw=1, label=printable(name))
    for name, errors in translation_errors_m.items():
        bottom.plot(errors, lw=1, label=printable(name))
    top.set_ylabel("rotation error [deg]")
    bottom.set_ylabel("translation error [m]")
    bottom.set_xlabel("pair")
    for axes in (top, bottom):
        axes.grid(True, alpha=0.3)
        axes.set_yscale("symlog", linthresh=1e-2)
    top.legend(loc="best", fontsize=8)
    top.set_title(printable(title))
    return _save(figure, path)


def plot_grouped_bars(
    path: str | os.PathLike[str],
    panels: Mapping[str, tuple[Sequence[str], Mapping[str, Sequence[float]]]],
    *,
    ylabel: str,
) -> Path:
    """One panel per key: a group of bars per label, a bar per series (NaN: no bar), e.g. a suite's
    drift per dataset (groups) and method (series), one panel per stride."""
    figure, axes = plt.subplots(len(panels), 1, figsize=(8, 3.5 * len(panels)), squeeze=False)
    for axis, (title, (groups, series)) in zip(axes[:, 0], panels.items(), strict=True):
        width = 0.8 / max(1, len(series))
        positions = np.arange(len(groups))
        for k, (name, values) in enumerate(series.items()):
            axis.bar(positions + k * width, values, width, label=printable(name))
        axis.set_xticks(positions + 0.4 - width / 2, [printable(g) for g in groups])
        axis.set_ylabel(ylabel)
        axis.set_title(printable(title))
        axis.legend(fontsize=8)
    figure.tight_layout()
    return _save(figure, path)
