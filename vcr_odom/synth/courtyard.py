"""The courtyard a short walked loop goes round: a walk (``--motion handheld --route loop``) whose loop
is shorter than a city block follows a footpath round one building, a couple of metres from its
walls, with more buildings facing it across a lawn, as the campus loops people record with a
handheld scanner do.

Why: a street's cross-section (carriageway, parking, sidewalks: 10-18 m) bent into a ~55 m loop
leaves nothing inside it, and lots laid along so tight a curve leave wide gaps: a forward-looking
scanner would face bare ground round every corner, a scene no odometry can follow and no recording
holds.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from vcr_odom.synth.mesh import FloatArray
from vcr_odom.synth.road import Road

FOOTPATH_WIDTH = 2.5
"""Width (m) of the paved path round the building (what the walk keeps to)."""
FOOTPATH_SIDEWALK, FOOTPATH_SETBACK = 2.0, 3.0
"""Most metres of sidewalk, and of yard beyond it, on the path's outer side."""
INNER_GAP = (1.0, 2.5)
"""Metres of verge between the path's edge and the building it goes round, drawn per seed."""
OUTER_GAP = (1.0, 5.0)
"""Metres of lawn between the outer side's yards and the buildings facing the path, drawn per seed."""
SMALLEST_SCALE = 0.25
"""The building inside is the loop's polygon shrunk about its centre until its walls clear the path;
a loop so tight that it would have to shrink below this gets no courtyard."""
SCALE_STEP = 0.02
"""Step (of the polygon's size) in which the walls are moved in or out until they clear the path."""
WALL_STEP = 0.25
"""Metres between the wall samples checked against the path."""
OUTER_TRIM = 0.1
"""Share of a side's length left open at each of its ends (passages between the buildings round the
courtyard)."""


@dataclass(frozen=True, eq=False)
class Courtyard:
    """The plan: the building inside (``inner``, corners ``(K, 2)`` counter-clockwise), the facades
    that face the path from outside (``outer``: ``(2, 2)`` start and end, the courtyard on their
    left), and the road side (0 right, 1 left) the building inside stands on."""

    inner: FloatArray
    outer: tuple[FloatArray, ...]
    side: int


def fit_courtyard(corners: FloatArray, road: Road, rng: np.random.Generator) -> Courtyard | None:
    """The loop's polygon (``corners``, counter-clockwise round the origin, as the road rounds it
    off) shrunk until every wall is :data:`INNER_GAP` clear of the path; and each of its sides moved
    out, parallel to itself, until it is beyond the outer side's sidewalk, yards and
    :data:`OUTER_GAP`. None when the loop is too tight for a building inside (:data:`SMALLEST_SCALE`).

    Every side has its building: beyond them the world is empty, and a view out through a missing
    one saw bare ground to the horizon, which no campus shows."""
    inner_clearance = FOOTPATH_WIDTH / 2.0 + rng.uniform(*INNER_GAP)
    outer_clearance = FOOTPATH_WIDTH / 2.0 + FOOTPATH_SIDEWALK + FOOTPATH_SETBACK + rng.uniform(*OUTER_GAP)
    path = cKDTree(road.xy)

    def clear(samples: FloatArray, clearance: float) -> bool:
        return bool(path.query(samples)[0].min() >= clearance)

    walls = wall_samples(corners)
    inner = next((s for s in _scales(1.0, -SCALE_STEP) if clear(walls * s, inner_clearance)), None)
    if inner is None:
        return None
    outer = []
    for a, b in itertools.pairwise(np.vstack([corners, corners[:1]])):
        samples = wall_samples(np.array([a, b]), closed=False)
        scale = next(s for s in _scales(1.0, SCALE_STEP) if clear(samples * s, outer_clearance))
        trim = OUTER_TRIM * (b - a)
        outer.append(np.array([a + trim, b - trim]) * scale)
    side = 1 if _signed_area(road.xy) > 0.0 else 0
    return Courtyard(corners * inner, tuple(outer), side)


def _scales(start: float, step: float) -> Iterator[float]:
    """``start``, ``start + step``, ... (shrinking: no further than :data:`SMALLEST_SCALE`; growing:
    until a polygon round the path clears it, which it always does)."""
    for k in itertools.count():
        scale = start + k * step
        if scale < SMALLEST_SCALE - 1e-9:
            return
        yield scale


def wall_samples(corners: FloatArray, closed: bool = True) -> FloatArray:
    """Points every :data:`WALL_STEP` metres along a polygon's edges (``closed``) or a polyline's."""
    ring = np.vstack([corners, corners[:1]]) if closed else corners
    points = []
    for a, b in itertools.pairwise(ring):
        count = max(2, int(np.ceil(np.linalg.norm(b - a) / WALL_STEP)))
        points.append(a + np.linspace(0.0, 1.0, count, endpoint=closed)[:, None] * (b - a))
    return np.concatenate(points)


def _signed_area(xy: FloatArray) -> float:
    """Shoelace area of a closed polyline: positive when it runs counter-clockwise."""
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
