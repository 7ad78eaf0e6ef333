"""The corridor ring of the indoor scene (``--scene indoor``) and the track a walker follows through it.

The ring is a closed, axis-aligned (rectilinear) polygon of corridor centre lines: a rectangle, or an
L where the floor is large enough, each side its own width. A :class:`Track` is a chain of straights
and circular arcs evaluated exactly at any station (no sampling: a walk sampled at 50 Hz stays smooth
through a 1 m corner), built by following the ring's centre line with its corners rounded
(:func:`ring_track`), forwards or backwards from any station and for any length (a walk that goes
round many times repeats the same lap).

Corner radii are chosen so that a walker up to :data:`LATERAL_MAX` to either side of the track keeps
:data:`CORNER_CLEARANCE` from the inner corner of the walls.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vcr_odom.synth.mesh import FloatArray

CORRIDOR_WIDTH = (2.0, 3.5)
"""Corridor widths (m), drawn per side of the ring."""
LATERAL_MAX = 0.25
"""Most a walker strays (m) to either side of the track: a keep-right offset plus a slow wander."""
CORNER_CLEARANCE = 0.6
"""Least distance (m) from a walker within :data:`LATERAL_MAX` of the track to a corner's inner edge."""
MAX_RADIUS = 2.5
"""Largest corner radius (m) of the track, however wide the corridors."""
MIN_SIDE = 7.0
"""Shortest side (m) of the ring's centre line: room for two rounded corners and a straight."""
TURN_RADIUS = (1.3, 1.6)
"""Radius (m) of the half turn a walk makes to turn round (:func:`u_turn`)."""
ASIDE_RADIUS = 2.5
"""Radius (m) of the two arcs that take a turning walker aside first (:func:`u_turn`)."""


@dataclass(frozen=True)
class Ring:
    """The corridors' centre line: corners ``(n, 2)`` counter-clockwise (the core is on the left),
    side ``i`` running from corner ``i`` to corner ``i + 1`` with half-width ``half_widths[i]``, and
    the track's radius at each corner."""

    corners: FloatArray
    half_widths: FloatArray
    radii: FloatArray

    @property
    def n(self) -> int:
        return len(self.corners)

    def side(self, i: int) -> tuple[FloatArray, FloatArray, FloatArray, float]:
        """Start, unit direction, unit left normal (towards the core) and length of side ``i``."""
        start, end = self.corners[i % self.n], self.corners[(i + 1) % self.n]
        length = float(np.linalg.norm(end - start))
        direction = (end - start) / length
        return start, direction, np.array([-direction[1], direction[0]]), length

    def turns_left(self, k: int) -> bool:
        """Whether the centre line turns left (round the core) at corner ``k``."""
        _, d0, _, _ = self.side(k - 1)
        _, d1, _, _ = self.side(k)
        return bool(d0[0] * d1[1] - d0[1] * d1[0] > 0.0)

    def wall_corners(self, side: float) -> FloatArray:
        """Corners ``(n, 2)`` of the walls' faces: ``side`` +1 the inner walls (facing the core side
        of the corridors), -1 the outer ones; corner ``k`` is where side ``k - 1``'s face meets side
        ``k``'s."""
        out = np.empty((self.n, 2))
        for k in range(self.n):
            p0, _, n0, _ = self.side(k - 1)
            p1, _, n1, _ = self.side(k)
            a = np.stack([n0, n1])
            b = np.array([n0 @ p0 + side * self.half_widths[k - 1], n1 @ p1 + side * self.half_widths[k]])
            out[k] = np.linalg.solve(a, b)
        return out

    def corridor_rects(self) -> FloatArray:
        """Each side's corridor as an axis-aligned rectangle ``(n, 4)`` (xmin, ymin, xmax, ymax),
        corners included."""
        rects = []
        for i in range(self.n):
            start, d, normal, length = self.side(i)
            a0, a, a1 = self.half_widths[i - 1], self.half_widths[i], self.half_widths[(i + 1) % self.n]
            corners = [start + u * d + v * normal for u in (-a0, length + a1) for v in (-a, a)]
            rects.append(np.concatenate([np.min(corners, axis=0), np.max(corners, axis=0)]))
        return np.array(rects)

    @property
    def perimeter(self) -> float:
        return float(sum(self.side(i)[3] for i in range(self.n)))

    def lap(self) -> Track:
        """One lap of the rounded centre line, from the end of corner 0's arc on side 0."""
        pieces = []
        heading = math.atan2(*self.side(0)[1][::-1])
        for i in range(self.n):
            start, d, _, length = self.side(i)
            r0, r1 = self.radii[i], self.radii[(i + 1) % self.n]
            pieces.append((*(start + r0 * d), heading, length - r0 - r1, 0.0))
            turn = 1.0 if self.turns_left(i + 1) else -1.0
            pieces.append((*(start + (length - r1) * d), heading, 0.5 * math.pi * r1, turn / r1))
            heading += turn * 0.5 * math.pi
        return Track(np.array(pieces))


def corner_radius(half_in: float, half_out: float) -> float:
    """The largest radius (within [min half-width, :data:`MAX_RADIUS`], 5 cm steps) of a 90 deg
    corner between corridors of these half-widths that keeps a walker :data:`LATERAL_MAX` inside the
    track :data:`CORNER_CLEARANCE` from the walls' inner corner (the smallest half-width when none
    does: it keeps about that half-width, less the stray)."""
    smallest = min(half_in, half_out)
    best = smallest
    for radius in np.arange(smallest, MAX_RADIUS + 1e-9, 0.05):
        if _inner_corner_gap(half_in, half_out, float(radius)) >= CORNER_CLEARANCE:
            best = float(radius)
    return best


def _inner_corner_gap(half_in: float, half_out: float, radius: float) -> float:
    """Distance from the walls' inner corner to the walker's arc, the walker :data:`LATERAL_MAX`
    inside the track. Frame: in along +x to the corner at the origin, out along +y."""
    centre = np.array([-radius, radius])
    corner = np.array([-half_out, half_in])
    rho = radius - LATERAL_MAX
    offset = corner - centre
    angle = math.atan2(offset[1], offset[0])
    if -0.5 * math.pi <= angle <= 0.0:
        return abs(float(np.linalg.norm(offset)) - rho)
    ends = centre + rho * np.array([[0.0, -1.0], [1.0, 0.0]])
    return float(np.linalg.norm(ends - corner, axis=1).min())


def make_ring(rng: np.random.Generator, lap: float) -> Ring:
    """A ring whose rounded lap (:meth:`Ring.lap`) is ``lap`` metres long: a rectangle with sides
    1:1 to 2.2:1, or (from about 110 m round) an L with a notch of 30-45 % of each side; corridor
    widths from :data:`CORRIDOR_WIDTH`, drawn per side.

    Rounding a 90 deg corner of radius r shortens the lap by (2 - pi/2) r; the radii depend on the
    widths only, so a few rounds of sizing settle the centre line's perimeter."""
    aspect = rng.uniform(1.0, 2.2)
    notch = rng.uniform(0.3, 0.45, 2) if rng.random() < 0.65 else None
    widths = rng.uniform(*CORRIDOR_WIDTH, 6)
    ring = _shaped_ring(lap, aspect, notch, widths)
    for _ in range(4):
        ring = _shaped_ring(lap + (2.0 - 0.5 * math.pi) * float(ring.radii.sum()), aspect, notch, widths)
    return ring


def _shaped_ring(perimeter: float, aspect: float, notch: FloatArray | None, widths: FloatArray) -> Ring:
    """The ring of :func:`make_ring` with this centre-line perimeter."""
    half = perimeter / 2.0
    height = max(half / (1.0 + aspect), 9.0)
    width = half - height
    corners = [(0.0, 0.0), (width, 0.0), (width, height), (0.0, height)]
    if notch is not None and perimeter >= 110.0:
        nx, ny = notch[0] * width, notch[1] * height
        if min(width - nx, height - ny) >= 14.0 and min(nx, ny) >= MIN_SIDE:
            corners[2:3] = [(width, height - ny), (width - nx, height - ny), (width - nx, height)]
    half_widths = widths[: len(corners)] / 2.0
    radii = np.array([corner_radius(half_widths[k - 1], half_widths[k]) for k in range(len(corners))])
    return Ring(np.array(corners, dtype=np.float64), half_widths, radii)


@dataclass(frozen=True)
class Track:
    """A chain of pieces ``(K, 5)``: start x, start y, start heading (rad), length (m), curvature
    (1/m; 0 for a straight, > 0 turning left). Headings run on continuously (no 2 pi jumps)."""

    pieces: FloatArray

    @property
    def starts(self) -> FloatArray:
        return np.concatenate([[0.0], np.cumsum(self.pieces[:, 3])])

    @property
    def length(self) -> float:
        return float(self.pieces[:, 3].sum())

    def evaluate(self, stations: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Position ``(N, 2)``, heading and curvature at ``stations`` (clipped to the track)."""
        s = np.clip(np.atleast_1d(np.asarray(stations, dtype=np.float64)), 0.0, self.length)
        starts = self.starts
        k = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(self.pieces) - 1)
        x0, y0, h0, _, kappa = self.pieces[k].T
        t = s - starts[k]
        heading = h0 + kappa * t
        bent = kappa != 0.0
        safe = np.where(bent, kappa, 1.0)
        dx = np.where(bent, (np.sin(heading) - np.sin(h0)) / safe, t * np.cos(h0))
        dy = np.where(bent, (np.cos(h0) - np.cos(heading)) / safe, t * np.sin(h0))
        return np.column_stack([x0 + dx, y0 + dy]), heading, kappa

    def end(self) -> tuple[FloatArray, float]:
        """Position and heading at the end."""
        xy, heading, _ = self.evaluate([self.length])
        return xy[0], float(heading[0])

    def reversed(self) -> Track:
        """The same track driven from its end to its start."""
        ends = [_piece_end(p) for p in self.pieces]
        flipped = [(e[0], e[1], e[2] + math.pi, p[3], -p[4]) for p, e in zip(self.pieces, ends, strict=True)]
        return Track(np.array(flipped[::-1]))

    def cut(self, start: float, stop: float) -> Track:
        """The part from station ``start`` to ``stop`` (within the track)."""
        starts = self.starts
        pieces = []
        for k, piece in enumerate(self.pieces):
            lo, hi = max(start, starts[k]), min(stop, starts[k + 1])
            if hi - lo <= 1e-9:
                continue
            xy, heading, _ = self.evaluate([lo])
            pieces.append((xy[0, 0], xy[0, 1], heading[0], hi - lo, piece[4]))
        return Track(np.array(pieces))

    @staticmethod
    def chain(tracks: list[Track]) -> Track:
        """Tracks one after another, each turned by whole turns to continue the last's heading."""
        pieces = []
        for track in tracks:
            part = track.pieces.copy()
            if pieces:
                end = _piece_end(pieces[-1])[2]
                part[:, 2] += 2.0 * math.pi * round((end - part[0, 2]) / (2.0 * math.pi))
            pieces.extend(part)
        return Track(np.array(pieces))


def u_turn(start: ArrayLike, heading: float, radius: float) -> Track:
    """Turning round from ``start``, heading ``heading``: aside to the right by two radii over two
    arcs of :data:`ASIDE_RADIUS`, then a half turn left of ``radius`` that ends on the line it left,
    heading the other way, a few metres further on (a walker turning round in a hall)."""
    theta = math.acos(1.0 - radius / ASIDE_RADIUS)
    pieces = [(*np.asarray(start, dtype=np.float64), heading, ASIDE_RADIUS * theta, -1.0 / ASIDE_RADIUS)]
    for length, kappa in ((ASIDE_RADIUS * theta, 1.0 / ASIDE_RADIUS), (math.pi * radius, 1.0 / radius)):
        pieces.append((*_piece_end(np.array(pieces[-1])), length, kappa))
    return Track(np.array(pieces))


def _piece_end(piece: FloatArray) -> tuple[float, float, float]:
    x0, y0, h0, length, kappa = (float(v) for v in piece)
    h1 = h0 + kappa * length
    if kappa == 0.0:
        return x0 + length * math.cos(h0), y0 + length * math.sin(h0), h1
    return x0 + (math.sin(h1) - math.sin(h0)) / kappa, y0 + (math.cos(h0) - math.cos(h1)) / kappa, h1


def ring_track(lap: Track, start: float, length: float, backward: bool = False) -> Track:
    """Round and round ``lap`` from its station ``start`` (taken modulo the lap) for ``length``
    metres, forwards or (``backward``) against the lap's direction."""
    total = lap.length
    start = start % total
    if backward:
        lap = lap.reversed()
        start = (total - start) % total
    laps = math.ceil((start + length) / total) + 1
    unrolled = Track.chain([lap] * laps)
    return unrolled.cut(start, start + length)


WALK_STEP = 0.2
"""Spacing (m) of the table from the walker's distance to the track's station."""


@dataclass(frozen=True)
class Stray:
    """Where the walker keeps across the track: ``keep`` metres right of it, wandering ``amplitude``
    metres either side over ``wavelength`` metres (at most :data:`LATERAL_MAX` in all)."""

    keep: float
    amplitude: float
    wavelength: float
    phase: float

    @staticmethod
    def random(rng: np.random.Generator) -> Stray:
        return Stray(
            rng.uniform(0.03, 0.15), rng.uniform(0.03, 0.1), rng.uniform(12.0, 30.0), rng.uniform(0, 6.3)
        )

    def offset(self, stations: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Offset (m, left of the track) and its slope along the track at ``stations``."""
        omega = 2.0 * math.pi / self.wavelength
        angle = omega * stations + self.phase
        return -self.keep + self.amplitude * np.sin(angle), self.amplitude * omega * np.cos(angle)


class Walkway:
    """The walker's line: ``track`` offset by ``stray``, looked up by distance walked along it."""

    def __init__(self, track: Track, stray: Stray) -> None:
        self.track = track
        self.stray = stray
        grid = np.append(np.arange(0.0, track.length, WALK_STEP), track.length)
        _, _, kappa = track.evaluate(grid)
        lateral, slope = stray.offset(grid)
        rate = np.hypot(1.0 - kappa * lateral, slope)
        self._stations = grid
        self._walked = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(grid))])

    @property
    def length(self) -> float:
        return float(self._walked[-1])

    def stations(self, distance: ArrayLike) -> FloatArray:
        """Track stations where the walker is after walking ``distance`` metres."""
        return np.interp(np.asarray(distance, dtype=np.float64), self._walked, self._stations)

    def at(self, distance: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Track stations, positions ``(N, 2)`` and headings of the walker after ``distance`` metres."""
        stations = self.stations(distance)
        centre, heading, kappa = self.track.evaluate(stations)
        lateral, slope = self.stray.offset(stations)
        normal = np.column_stack([-np.sin(heading), np.cos(heading)])
        return (
            stations,
            centre + lateral[:, None] * normal,
            heading + np.arctan2(slope, 1.0 - kappa * lateral),
        )

    def turning(self, distance: ArrayLike) -> NDArray[np.bool_]:
        """Whether the walker is rounding a corner (on an arc of the track) after ``distance`` metres."""
        _, _, kappa = self.track.evaluate(self.stations(distance))
        return kappa != 0.0
