"""The kiss-icp polish's voxel size, from the first frame's density.

kiss-icp derives its voxel from the maximum range (``max_range / 100``: 1 m at 100 m), a rule made for
spinning scans, where a 1 m grid still leaves its registration about 2,000 points. A solid-state scan
or a keyframe cloud voxel-thinned by a SLAM system leaves it 500-1,300, and the polish then registers
few, coarse points: there a finer grid cuts the polish's error (docs/benchmarks.md, "The polish
voxel"). A sparse spinning scan (16 beams) keeps kiss-icp's voxel (:func:`ring_structured`). The
configured range also says nothing of the scene: indoors, where the scan reaches 10 m, a 1 m grid leaves
a corridor two cells wide, so the voxel also shrinks with the range the scan actually reaches
(:func:`reach_voxel`). The voxel is chosen once, on the first frame, because kiss-icp's local map needs
one grid for the whole run.
"""

from __future__ import annotations

import copy

import numpy as np
from kiss_icp.config import KISSConfig
from kiss_icp.kiss_icp import get_preprocessor
from scipy.spatial import cKDTree

from vcr_odom.odometry.guided_kiss import voxelize_at

SPARSE_SOURCE_POINTS = 1400
"""A first frame that leaves kiss-icp's registration fewer points than this at its own voxel is sparse.
The sparsest of the 60 real HDL-64E scans of the KITTI sample leaves 1,556, so 64-beam scans keep
kiss-icp's voxel (and the polish its speed)."""

TARGET_SOURCE_POINTS = 2000
"""A sparse frame gets the largest voxel that leaves at least this many: about what a 64-beam scan
leaves at 1 m (the KITTI sample's median: 1,918), so the polish registers as much as on such a scan."""

VOXEL_STEP = 0.7
"""Each smaller candidate voxel is this fraction of the one before (about half the grid cells' area)."""

MIN_VOXEL_FRACTION = 0.25
"""Never finer than this fraction of kiss-icp's voxel (0.25 m at 100 m): the polish only gets slower."""

SPACING_FACTOR = 2.0
"""Nor finer than this many times the cloud's own median point spacing: the map keeps points on half a
voxel, and a map grid finer than the points themselves (a keyframe cloud thinned to 0.7 m by its SLAM
system) has nothing more to give; on such a cloud a finer grid made the polish worse, not better."""


def source_points(frame: np.ndarray, voxel_size: float) -> int:
    """How many points kiss-icp's registration gets from ``frame`` (already cropped) at ``voxel_size``."""
    source, _ = voxelize_at(frame, voxel_size)
    return len(source)


RING_SHARE = 0.8
"""A frame whose points fall this much or more into 128 elevation rows of 0.1 deg is a spinning scan's
rings (synthetic 16- to 128-beam scans: 0.997-1.0; rosettes and thinned keyframes: 0.28-0.63)."""


def ring_structured(points: np.ndarray) -> bool:
    """Whether the frame is a spinning sensor's rings: sparse between rings, dense along them. A finer
    grid there fits the rings rather than the scene: on 16-beam drives it cut the per-pair error and
    doubled the drift (docs/benchmarks.md, "The polish voxel"), so such scans keep kiss-icp's voxel."""
    elevation = np.degrees(np.arctan2(points[:, 2], np.hypot(points[:, 0], points[:, 1])))
    rows = np.bincount(np.floor((elevation + 90.0) / 0.1).astype(np.int64))
    return float(np.sort(rows)[::-1][:128].sum()) >= RING_SHARE * len(points)


def median_spacing(points: np.ndarray) -> float:
    """Median distance from a point to its nearest neighbour."""
    return float(np.median(_neighbour_distances(points))) if len(points) >= 2 else 0.0


THINNED_SHARE = 0.4
"""A cloud whose closest tenth of nearest-neighbour distances lies at this share of their median or more
was thinned on a grid, which keeps no two points much closer than its cells (synthetic keyframes
voxel-thinned to 0.15-0.3 m: 0.48-0.52); a raw scan's points bunch where its pattern crosses itself
(33 solid-state first frames: 0.17-0.34)."""


def thinned(points: np.ndarray) -> bool:
    """Whether ``points`` were thinned on a grid (a SLAM system's keyframe cloud), not a raw scan."""
    if len(points) < 10:
        return False
    closest_tenth, median = np.percentile(_neighbour_distances(points), [10, 50])
    return bool(closest_tenth >= THINNED_SHARE * median)


def _neighbour_distances(points: np.ndarray) -> np.ndarray:
    distances, _ = cKDTree(points).query(points, k=2)
    return distances[:, 1]


REACH_PERCENTILE = 99.0
"""The scan's reach: this percentile of its points' ranges (the farthest few are stray returns)."""

ROOM_REACH = 15.0
"""A scan reaching this far or less (m) was taken in rooms and corridors (the synthetic OS0 floor's first
frames: 10.6-11.7 m, at least 7.4 m on any frame); its voxel is the reach over :data:`ROOM_CELLS`."""

ROOM_CELLS = 60.0
"""Cells across a room-scale reach (0.2 m at 12 m): the coarsest grid at which the path through rooms
stops improving; a finer one costs time for the same accuracy, a 1 m grid overestimates the path
(the measurements: docs/benchmarks.md, "The polish voxel indoors")."""

STREET_REACH = 30.0
"""A scan reaching this far or more (m) keeps kiss-icp's voxel: the KITTI sample's first frame reaches
57 m, the synthetic street drives' 34 m or more, but the OS0's (a 50 m indoor sensor) in narrow old-town
lanes, 26-29 m (``benchmarks/polish_voxel_survey.py``). Between the two reaches the voxel is blended
linearly, so a scene near either bound gets nearly the same grid."""

MIN_REACH_VOXEL = 0.1
"""Never finer than this (m), however close the walls: the polish's cost grows with the points a finer
grid keeps (docs/benchmarks.md, "The polish voxel indoors")."""


def reach(points: np.ndarray) -> float:
    """How far the scan reaches: :data:`REACH_PERCENTILE` of its points' ranges from the sensor."""
    return float(np.percentile(np.linalg.norm(points, axis=1), REACH_PERCENTILE))


def reach_voxel(points: np.ndarray, voxel: float) -> float:
    """``voxel`` (kiss-icp's) for a scan reaching a street's distance, reach / :data:`ROOM_CELLS` for
    one in rooms, blended between; never coarser than ``voxel`` nor finer than :data:`MIN_REACH_VOXEL`."""
    knots = [ROOM_REACH, STREET_REACH]
    scaled = float(np.interp(reach(points), [0.0, *knots], [0.0, ROOM_REACH / ROOM_CELLS, voxel]))
    return min(voxel, max(MIN_REACH_VOXEL, scaled))


def density_voxel(frame: np.ndarray, config: KISSConfig) -> float:
    """kiss-icp's own voxel, made finer for a scan of a small scene (:func:`reach_voxel`), for a frame
    dense enough for it or a spinning scan's rings; for another sparse one (solid-state, thinned
    keyframes) the largest voxel on the ladder (``VOXEL_STEP``) that leaves :data:`TARGET_SOURCE_POINTS`,
    no finer than the floors (:data:`MIN_VOXEL_FRACTION`, :data:`SPACING_FACTOR`), nor coarser than
    the small scene's."""
    voxel = float(config.mapping.voxel_size)
    cropped = get_preprocessor(config).preprocess(frame, np.array([]), np.eye(4))
    if len(cropped) == 0:
        return voxel
    scene_voxel = reach_voxel(cropped, voxel)
    if not _sparse(cropped, voxel):
        return scene_voxel
    return min(scene_voxel, _sparse_voxel(cropped, voxel))


def raw_sparse_scan(frame: np.ndarray, config: KISSConfig) -> bool:
    """Whether ``frame`` leaves kiss-icp's registration few points at ``config``'s voxel and is neither a
    spinning scan's rings nor a cloud thinned on a grid: a raw solid-state scan, whose point-to-point
    fit slides (:mod:`~vcr_odom.odometry.plane_refinement`)."""
    cropped = get_preprocessor(config).preprocess(frame, np.array([]), np.eye(4))
    return len(cropped) > 0 and _sparse(cropped, float(config.mapping.voxel_size)) and not thinned(cropped)


def _sparse(cropped: np.ndarray, voxel: float) -> bool:
    return source_points(cropped, voxel) < SPARSE_SOURCE_POINTS and not ring_structured(cropped)


def _sparse_voxel(cropped: np.ndarray, voxel: float) -> float:
    """The largest voxel on the ladder from ``voxel`` that leaves :data:`TARGET_SOURCE_POINTS`."""
    floor = max(voxel * MIN_VOXEL_FRACTION, SPACING_FACTOR * median_spacing(cropped))
    while voxel * VOXEL_STEP >= floor:
        voxel *= VOXEL_STEP
        if source_points(cropped, voxel) >= TARGET_SOURCE_POINTS:
            break
    return voxel


def with_voxel(config: KISSConfig, voxel_size: float) -> KISSConfig:
    """A copy of ``config`` with another map voxel (the caller's configuration is left as it is)."""
    changed = copy.deepcopy(config)
    changed.mapping.voxel_size = float(voxel_size)
    return changed
