"""KISS-SLAM (PRBonn) as a baseline: kiss-icp odometry, loop closures between its local maps found by
map_closures, and a pose graph optimised over them.

It is the loop-closing peer users compare LiDAR mapping against. Optional (``pip install
'vcr-odom[slam]'``), so it is imported only when built; without it building fails with a
:class:`~vcr_odom.errors.MissingExtraError` that ``compare`` shows as a "not installed" row.

KISS-SLAM's own default configuration, except its odometry: that is our kiss-icp row's configuration
(:func:`~vcr_odom.registration.kiss.kiss_config`, no deskewing), so the two rows differ only by what
KISS-SLAM adds (local maps, closures, the pose graph).
"""

from __future__ import annotations

import contextlib
import functools
import io
import os
import sys
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from vcr_odom.data.base import Points
from vcr_odom.errors import ConfigError, DataWarning, MissingExtraError
from vcr_odom.geometry import Transform, normalise_to_first
from vcr_odom.registration.base import FinishedTrajectory
from vcr_odom.registration.kiss import kiss_config, kiss_input

EXTRA = "slam"
"""The vcr-odom extra that installs kiss-slam."""


def require_kiss_slam() -> None:
    """Import kiss-slam, or raise MissingExtraError naming the extra. Not cached: a test (or a user
    who installs it mid-session) sees the import as it is now."""
    try:
        import kiss_slam.config
        import kiss_slam.slam  # noqa: F401
    except ImportError as error:
        raise MissingExtraError("kiss-slam", EXTRA, str(error)) from error


def kiss_slam_config(
    max_range: float = 100.0,
    min_range: float = 0.0,
    voxel_size: float | None = None,
    deskew: bool = False,
    max_num_threads: int = 0,
) -> Any:
    """KISS-SLAM's defaults (``kiss_slam.config.load_config(None)``: local maps split every 100 m,
    0.5 m local-map voxels, map_closures' thresholds, 10 pose-graph iterations) with the odometry of
    our kiss-icp row. Returns a ``kiss_slam.config.KissSLAMConfig``."""
    require_kiss_slam()
    from kiss_slam.config import load_config

    odometry = kiss_config(max_range, min_range, voxel_size, deskew, max_num_threads)
    config = load_config(None)
    config.odometry.preprocessing = odometry.data
    config.odometry.registration = odometry.registration
    config.odometry.mapping = odometry.mapping
    config.odometry.adaptive_threshold = odometry.adaptive_threshold
    config.occupancy_mapper.max_range = float(max_range)  # unused here (no occupancy grid), kept consistent
    return config


@contextlib.contextmanager
def quiet_output() -> Iterator[io.StringIO]:
    """Python prints into the yielded buffer, and file descriptors 1 and 2 to /dev/null, for the moment
    KISS-SLAM checks a closure or solves its graph: it prints each step and g2o logs every iteration to
    stderr, which would break the progress bar and the tables. Kept brief, so anything another thread
    writes meanwhile is at most one progress redraw."""
    text = io.StringIO()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    saved: list[int] = []
    try:
        with contextlib.suppress(OSError):
            saved = [os.dup(1), os.dup(2)]
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, 1)
            os.dup2(null, 2)
            os.close(null)
        with contextlib.redirect_stdout(text):
            yield text
    finally:
        for fd, copy in zip((1, 2), saved, strict=False):
            os.dup2(copy, fd)
            os.close(copy)


@functools.cache
def _quiet_kiss_slam_class() -> type:
    """``kiss_slam.slam.KissSLAM`` whose closure checks run inside :func:`quiet_output`, keeping what
    they printed (the count of rejected candidates is only printed)."""
    from kiss_slam.slam import KissSLAM

    class QuietKissSLAM(KissSLAM):  # type: ignore[misc, valid-type]
        def __init__(self, config: Any) -> None:
            super().__init__(config)
            self.printed: list[str] = []

        def compute_closures(self, query_id: int, query: Any) -> None:
            with quiet_output() as text:
                super().compute_closures(query_id, query)
            self.printed.append(text.getvalue())

    return QuietKissSLAM


@dataclass(frozen=True)
class LoopClosure:
    """One accepted closure: KISS-SLAM constrains the poses of two local maps' first frames.

    ``local_maps`` are KISS-SLAM's ids (reference, query); ``frames`` the sequence's indices of the
    frames those maps start at (their key poses).
    """

    local_maps: tuple[int, int]
    frames: tuple[int, int]


class KissSlamOdometry:
    """``kiss_slam.slam.KissSLAM`` fed frame by frame, as KISS-SLAM's own pipeline feeds it.

    ``step`` returns KISS-SLAM's current estimate of the frame's pose (its odometry in the current
    local map, placed by that map's key pose as last optimised); :meth:`finish` closes the last local
    map, looks for a closure once more and returns the pose graph's final trajectory, the one
    KISS-SLAM's pipeline writes (``fine_grained_optimization``).
    """

    name = "kiss-slam"

    def __init__(
        self,
        max_range: float = 100.0,
        min_range: float = 0.0,
        voxel_size: float | None = None,
        deskew: bool = False,
        max_num_threads: int = 0,
    ) -> None:
        self.config = kiss_slam_config(max_range, min_range, voxel_size, deskew, max_num_threads)
        self.reset()

    def reset(self) -> None:
        """A fresh KISS-SLAM: the next frame is frame 0 (identity)."""
        self._slam = _quiet_kiss_slam_class()(self.config.model_copy(deep=True))
        self._map_starts = [0]  # position (among the frames stepped) of each local map's first frame
        self._stepped = 0
        self._finished = False

    def step(self, points: Points, timestamp: float = 0.0) -> Transform:
        """Register one raw frame. ``timestamp`` is unused: KISS-SLAM takes per-point times only (for
        deskewing, off here as in the kiss-icp row), never frame times."""
        del timestamp
        if self._finished:
            raise ConfigError("kiss-slam: finish() was called; reset() before stepping again")
        frame = kiss_input(points)
        if len(frame) == 0:
            warnings.warn(
                "kiss-slam: empty frame, pose extrapolated by the motion model", DataWarning, stacklevel=2
            )
        graph = self._slam.local_map_graph
        last_map = graph.last_id
        self._slam.process_scan(frame, np.array([]))
        if graph.last_id != last_map:  # this frame ended a local map and starts the next
            self._map_starts.append(self._stepped)
        self._stepped += 1
        return np.asarray(graph.last_local_map.endpose, dtype=np.float64).copy()

    def finish(self, frame_indices: Sequence[int]) -> FinishedTrajectory:
        """The optimised poses of the frames stepped (``frame_indices``: their indices in the sequence,
        to name the closures' frames) and a summary of the loop closures, as KISS-SLAM's pipeline
        ends a run. Called once; :meth:`reset` starts again."""
        indices = [int(i) for i in frame_indices]
        if len(indices) != self._stepped:
            raise ConfigError(f"kiss-slam: {self._stepped} frames stepped, {len(indices)} indices given")
        if self._finished:
            raise ConfigError("kiss-slam: finish() was already called; reset() to run again")
        self._finished = True
        slam = self._slam
        if self._stepped < 2:  # no odometry edge: the pose graph would have nothing to hold
            return FinishedTrajectory(np.tile(np.eye(4), (self._stepped, 1, 1)), self._summary(indices))
        with quiet_output() as text:
            slam.generate_new_node()
            slam.local_map_graph.erase_last_local_map()
            poses, _ = slam.fine_grained_optimization()
        slam.printed.append(text.getvalue())
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
        if len(poses) != self._stepped:
            raise RuntimeError(f"kiss-slam returned {len(poses)} poses for {self._stepped} frames")
        return FinishedTrajectory(normalise_to_first(poses), self._summary(indices))

    def closures(self, frame_indices: Sequence[int]) -> list[LoopClosure]:
        """The accepted closures so far, their frames named by ``frame_indices`` (those stepped)."""
        indices = list(frame_indices)
        return [
            LoopClosure(
                (int(ref), int(query)),
                (int(indices[self._map_starts[ref]]), int(indices[self._map_starts[query]])),
            )
            for ref, query in self._slam.closures
        ]

    def _summary(self, indices: list[int]) -> dict[str, Any]:
        closures = self.closures(indices)
        printed = "".join(self._slam.printed)
        return {
            "loop_closures": len(closures),
            "closure_frames": [list(c.frames) for c in closures],
            "closure_local_maps": [list(c.local_maps) for c in closures],
            "closure_candidates": printed.count("Closure Detected"),
            "local_maps": len(self._map_starts),
            "local_map_first_frames": [indices[p] for p in self._map_starts],
            "config": self.config.model_dump(mode="json"),
        }
