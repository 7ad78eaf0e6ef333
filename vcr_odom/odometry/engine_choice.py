"""``--polish-engine auto``: the polish's registration engine chosen for a run by how far apart in time
its frames are.

Why: kiss-icp's registration is made for consecutive scans, where its constant-velocity prediction
errs by centimetres. Frames further apart than a scan period (keyframes, a low rate, a stride) start
it a metre and more off, where its point-to-point search crawls for a hundred iterations and falls
into other minima; small_gicp's VGICP converges from there in a few (docs/benchmarks.md, "The engine
chosen by the frames' spacing in time"). At a sensor's rate kiss-icp's own engine stays.
"""

from __future__ import annotations

from typing import Literal, cast

import numpy as np
from numpy.typing import NDArray

from vcr_odom.errors import ConfigError
from vcr_odom.odometry.guided_kiss import ENGINES, PolishEngine

AUTO = "auto"
SCAN_PERIOD_S = 0.1
"""A 10 Hz sensor's scan period: the usual rate of spinning and solid-state LiDARs, and the rate
assumed where a recording has no times."""
APART_PERIODS = 1.5
"""Frames whose median spacing exceeds this many scan periods are not consecutive scans (a jitter
of half a period still is)."""

EngineChoice = Literal["kiss-icp", "vgicp", "vgicp-start", "auto"]
ENGINE_CHOICES: dict[str, str] = {
    **ENGINES,
    AUTO: f"vgicp where the run's frames are more than {APART_PERIODS:g} scan periods of a "
    f"{1 / SCAN_PERIOD_S:g} Hz sensor apart in time (median; keyframes, low rates, strides), else "
    "kiss-icp (times.txt, or 10 Hz assumed)",
}
"""``--polish-engine``'s choices: the engines and ``auto``."""


def engine_for(choice: str, timestamps: NDArray[np.float64] | None) -> PolishEngine:
    """The engine ``choice`` names; for ``auto`` the one the frames' spacing in time calls for
    (``timestamps``: the run's frames, in order; fewer than two frames: kiss-icp's, nothing to space)."""
    if choice not in ENGINE_CHOICES:
        raise ConfigError(f"unknown polish engine {choice!r}; valid choices: {', '.join(ENGINE_CHOICES)}")
    if choice != AUTO:
        return cast(PolishEngine, choice)
    if timestamps is None:
        raise ConfigError("--polish-engine auto needs the run's frame times to choose an engine")
    gaps = np.diff(np.asarray(timestamps, dtype=np.float64))
    apart = len(gaps) > 0 and float(np.median(gaps)) > APART_PERIODS * SCAN_PERIOD_S
    return "vgicp" if apart else "kiss-icp"
