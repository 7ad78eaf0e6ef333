"""Out and back along one street (``--route return``): the street ends in a turning loop, the car
drives out in its direction's inner lane, round the loop, and back in the other direction's inner
lane (the same lane where the street has only one).

Why a turning loop rather than a U-turn on the carriageway: a car cannot turn within the few metres
between two lanes, and on avenues and highways a median stands between them. The loop lies beyond
the street's end, where nothing else stands, and is part of the street's plan (nothing is built on it).

The turn is made of arcs (a swing to the right, a wide left turn, a swing back) whose curvature is
smoothed as on the street itself; its swing angle is solved so that it ends in the other lane.
"""

from __future__ import annotations

import math

import numpy as np

from vcr_odom.synth.mesh import FloatArray
from vcr_odom.synth.paths import DrivePath, resample
from vcr_odom.synth.road import ROAD_STEP, Road, smooth

TURN_RADIUS = 8.0
"""Radius (m) of the loop's main turn: a car's turning circle with room to spare."""
SWING_RADIUS = 12.0
"""Radius (m) of the swing out to the right before the turn and back after it."""
LOOP_HALF_WIDTH = 3.5
"""Half width (m) of the turning loop's carriageway."""
_SMOOTH = 3.0
_DU = 0.02


def _turn(alpha: float, radius: float) -> FloatArray:
    """The turn in its own frame (x ahead, y left) from (0, 0) heading +x: a lead-in, a swing right
    by ``alpha``, a left turn by pi + 2 ``alpha``, a swing right by ``alpha`` and a lead-out."""
    lead = 3.0 * _SMOOTH
    swing = SWING_RADIUS * alpha
    main = radius * (math.pi + 2.0 * alpha)
    total = 2.0 * (lead + swing) + main
    u = np.arange(0.0, total + 0.5 * _DU, _DU)
    kappa = np.zeros_like(u)
    kappa[(u >= lead) & (u < lead + swing)] = -1.0 / SWING_RADIUS
    kappa[(u >= lead + swing) & (u < lead + swing + main)] = 1.0 / radius
    kappa[(u >= lead + swing + main) & (u < total - lead)] = -1.0 / SWING_RADIUS
    kappa = smooth(kappa, _SMOOTH / _DU)
    kappa *= math.pi / (kappa.sum() * _DU)  # exactly half a turn in all
    heading = np.concatenate([[0.0], np.cumsum(0.5 * (kappa[1:] + kappa[:-1]) * _DU)])
    mid = heading[:-1] + 0.5 * np.diff(heading)
    steps = np.column_stack([np.cos(mid), np.sin(mid)]) * _DU
    return np.vstack([np.zeros((1, 2)), np.cumsum(steps, axis=0)])


def u_turn(offset: float) -> FloatArray:
    """A turn from (0, 0) heading +x to (about) (0, ``offset``) heading -x, in its own frame.

    The end's lateral position falls as the swing angle grows (from twice the turn radius with no
    swing), so the angle is found by bisection."""
    radius = max(TURN_RADIUS, 0.5 * offset + 1.0)
    lo, hi = 0.0, 0.5 * math.pi
    for _ in range(40):
        alpha = 0.5 * (lo + hi)
        if _turn(alpha, radius)[-1, 1] > offset:
            lo = alpha
        else:
            hi = alpha
    turn = _turn(0.5 * (lo + hi), radius)
    # The bisection leaves the end within a centimetre or two of (0, offset): share the miss out
    # along the turn, so the way back joins it without a kink.
    along = np.linspace(0.0, 1.0, len(turn))[:, None]
    return turn + along * (np.array([0.0, offset]) - turn[-1])


def turn_length(offset: float) -> float:
    """Length (m) of :func:`u_turn` for ``offset``."""
    xy = u_turn(offset)
    return float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum())


def to_world(road: Road, station: float, local: FloatArray) -> FloatArray:
    """Points given in the road's frame at ``station`` (x along the road, y to its left) in the world."""
    xy, heading, _ = road.sample([station])
    forward = np.array([math.cos(heading[0]), math.sin(heading[0])])
    left = np.array([-forward[1], forward[0]])
    return xy[0] + local[:, :1] * forward + local[:, 1:] * left


def return_path(road: Road, out_offset: FloatArray, back_offset: FloatArray) -> tuple[DrivePath, FloatArray]:
    """Out along ``road`` ``out_offset`` metres left of its centre line, round the turning loop
    beyond its end, and back ``back_offset`` metres left of it (one value per road sample each).
    Also the loop's centre line in the world (the turn itself), which the street's plan keeps clear."""
    end = road.length
    local = u_turn(float(back_offset[-1] - out_offset[-1])) + np.array([0.0, out_offset[-1]])
    turn = to_world(road, end, local)
    stations = np.arange(len(road.xy)) * ROAD_STEP
    out = road.offset(stations, out_offset)
    back = road.offset(stations[::-1], back_offset[::-1])
    polyline = np.vstack([out, turn[1:-1], back])
    road_station = np.concatenate([stations, np.full(len(turn) - 2, end), stations[::-1]])
    line, at = resample(polyline)
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(polyline, axis=0), axis=1))])
    return DrivePath(line, np.interp(at, along, road_station)), turn
