"""The plan of the indoor floor (:mod:`~vcr_odom.synth.indoor`): where its corridor walls run, how
high its ceilings are, and where its halls and rooms are (:class:`FloorPlan`).

Plan coordinates along a wall are a :class:`Frame`: ``u`` along the wall's face, ``d`` behind it.
Every wall of the ring is axis-aligned, so rooms, halls and corridors are axis-aligned rectangles, and
a room is placed only where its footprint overlaps no corridor, hall or other room (rooms in a row
share their partition walls).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from vcr_odom.errors import ConfigError
from vcr_odom.synth.corridors import Ring
from vcr_odom.synth.mesh import FloatArray, MeshBuilder, Surface

CEILING_HEIGHT = (2.6, 3.5)
"""Ceiling heights (m) of corridors and rooms."""
TOP = 4.4
"""Height (m) of the slab over everything: walls rise to it, above the highest ceiling (a hall's)."""
HUNG_CLEARANCE = 2.4
"""Nothing hangs lower than this (m) over a corridor (beams, ducts)."""
OBJECT_SETBACK = 0.85
"""Anything against a corridor wall is at most the corridor's half-width less this deep (m): a
walker :data:`~vcr_odom.synth.corridors.LATERAL_MAX` off the track keeps 0.6 m from it."""
ROOM_WIDTH = (2.5, 8.0)
ROOM_MIN_DEPTH = 2.2
"""Rooms' widths along the corridor and least depth (m); a room with less space is left out."""
HALL_LENGTH, HALL_DEPTH = (7.0, 14.0), (3.0, 6.0)
"""A hall's opening along the corridor and its depth beyond the corridor's wall (m)."""
_OVERLAP = 0.15
"""Footprints overlapping by less than this (m) do not clash (rooms sharing a partition wall)."""

Rect = tuple[float, float, float, float]
"""An axis-aligned plan rectangle (xmin, ymin, xmax, ymax)."""


@dataclass(frozen=True)
class Frame:
    """Plan coordinates along a wall face: ``u`` metres along it from ``origin``, ``d`` metres
    behind it (into the wall and beyond; negative: in front of it, in the corridor)."""

    origin: FloatArray
    along: FloatArray
    back: FloatArray

    def at(self, u: float, d: float) -> FloatArray:
        return self.origin + u * self.along + d * self.back

    def rect(self, u0: float, u1: float, d0: float, d1: float) -> Rect:
        corners = np.array([self.at(u, d) for u in (u0, u1) for d in (d0, d1)])
        lo, hi = corners.min(axis=0), corners.max(axis=0)
        return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])

    def local(self, rect: Rect) -> tuple[float, float, float, float]:
        """``rect`` as (u0, u1, d0, d1) in this frame (walls are axis-aligned, so it is exact)."""
        corners = np.array([(x, y) for x in (rect[0], rect[2]) for y in (rect[1], rect[3])]) - self.origin
        u, d = corners @ self.along, corners @ self.back
        return float(u.min()), float(u.max()), float(d.min()), float(d.max())

    def box(
        self,
        mesh: MeshBuilder,
        u: tuple[float, float],
        d: tuple[float, float],
        z: tuple[float, float],
        surface: int,
        albedo: float,
    ) -> None:
        if u[1] - u[0] <= 1e-6 or d[1] - d[0] <= 1e-6 or z[1] - z[0] <= 1e-6:
            return
        plan = [self.at(u[0], d[0]), self.at(u[1], d[0]), self.at(u[1], d[1]), self.at(u[0], d[1])]
        corners = [(*p, z[0]) for p in plan] + [(*p, z[1]) for p in plan]
        mesh.hexahedron(corners, surface, albedo)

    def floor(
        self, mesh: MeshBuilder, u: tuple[float, float], d: tuple[float, float], z: float, albedo: float
    ) -> None:
        """A horizontal quad (a floor or a ceiling) over ``u`` x ``d`` at height ``z``."""
        plan = [self.at(u[0], d[0]), self.at(u[1], d[0]), self.at(u[1], d[1]), self.at(u[0], d[1])]
        surface = Surface.SIDEWALK if z <= 0.0 else Surface.WALL
        mesh.quad([(*p, z) for p in plan], surface, albedo)


@dataclass
class Wall:
    """A corridor wall: its face's frame, where the face runs (``u0`` to ``u1``), how thick it is,
    and the openings cut into it ``(u0, u1, z0, z1)``, never overlapping."""

    frame: Frame
    u0: float
    u1: float
    thickness: float
    albedo: float
    cuts: list[tuple[float, float, float, float]]
    taken: list[tuple[float, float]]
    """Stretches of the face already used (doors, niches, objects, halls)."""

    def free(self, a: float, b: float, gap: float = 0.15) -> bool:
        return a >= self.u0 and b <= self.u1 and all(b + gap <= lo or a - gap >= hi for lo, hi in self.taken)

    def build(self, mesh: MeshBuilder) -> None:
        """Boxes for the wall, full height but where cut."""
        cuts = sorted(self.cuts)
        edges = sorted({self.u0, self.u1, *(c[0] for c in cuts), *(c[1] for c in cuts)})
        depth = (0.0, self.thickness)
        for a, b in itertools.pairwise(edges):
            cut = next((c for c in cuts if c[0] <= a + 1e-9 and b <= c[1] + 1e-9), None)
            spans = [(0.0, TOP)] if cut is None else [(0.0, cut[2]), (cut[3], TOP)]
            for z in spans:
                self.frame.box(mesh, (a, b), depth, z, Surface.WALL, self.albedo)


@dataclass(frozen=True)
class Room:
    """A room behind a corridor wall: ``u0``-``u1`` along the wall's frame, from the wall's back face
    (``d0``) ``depth`` metres deep; ``exterior`` rooms have the building's outer wall at their back."""

    wall: int
    u0: float
    u1: float
    d0: float
    depth: float
    exterior: bool

    def footprint(self, frame: Frame) -> Rect:
        back = 0.3 if self.exterior else 0.1
        return frame.rect(self.u0 - 0.05, self.u1 + 0.05, self.d0, self.d0 + self.depth + back)


@dataclass(frozen=True)
class Hall:
    """A hall opening off a corridor's outer wall over ``u0``-``u1``, ``depth`` metres deep, with its
    own ceiling height; ``turn`` is where a ``return`` walk turns round (kept clear)."""

    side: int
    u0: float
    u1: float
    depth: float
    ceiling: float
    turn: bool


def _overlaps(a: Rect, b: Rect) -> bool:
    return min(a[2], b[2]) - max(a[0], b[0]) > _OVERLAP and min(a[3], b[3]) - max(a[1], b[1]) > _OVERLAP


def _grow(rect: ArrayLike, by: float) -> Rect:
    x0, y0, x1, y1 = (float(v) for v in np.asarray(rect, dtype=np.float64))
    return x0 - by, y0 - by, x1 + by, y1 + by


class FloorPlan:
    """The floor's plan for a ring and a seed: its corridor walls (side ``i``: inner wall ``2 i``,
    outer wall ``2 i + 1``), ceiling heights, halls (placed first: rooms keep clear of them) and the
    rooms in a row behind every wall, each as deep as the space behind allows. What stands at the
    walls, and every mesh, comes with the fitting out (:mod:`~vcr_odom.synth.fittings`)."""

    def __init__(self, ring: Ring, seed: int, turnaround: bool) -> None:
        self.ring = ring
        self.seed = seed
        rng = np.random.default_rng([seed, 42])
        self.thickness = rng.uniform(0.12, 0.25)
        base = rng.uniform(*CEILING_HEIGHT)
        self.ceilings = np.clip(
            base + np.where(rng.random(ring.n) < 0.4, rng.uniform(-0.4, 0.4, ring.n), 0.0), *CEILING_HEIGHT
        )
        self.wall_albedo = rng.uniform(0.45, 0.8)
        self.walls: list[Wall] = []  # side i: inner wall 2i, outer wall 2i + 1
        inner, outer = ring.wall_corners(1.0), ring.wall_corners(-1.0)
        for i in range(ring.n):
            start, d, normal, _ = ring.side(i)
            for sign, corners in ((1.0, inner), (-1.0, outer)):
                frame = Frame(start + sign * ring.half_widths[i] * normal, d, sign * normal)
                u = [float((corners[k % ring.n] - frame.origin) @ d) for k in (i, i + 1)]
                self.walls.append(Wall(frame, u[0], u[1], self.thickness, self.wall_albedo, [], []))
        self.obstacles: list[Rect] = [_grow(r, 0.25) for r in ring.corridor_rects()]
        self.halls = self._halls(np.random.default_rng([seed, 43]), turnaround)
        self.rooms: list[Room] = []
        for w in range(len(self.walls)):
            self._rooms(np.random.default_rng([seed, 45, w]), w)

    def object_zone(self, side: int) -> tuple[float, float]:
        """Where along side ``side`` (u from its start corner) things may stand against its walls:
        clear of the corners' arcs."""
        _, _, _, length = self.ring.side(side)
        return self.ring.radii[side] + 0.4, length - self.ring.radii[(side + 1) % self.ring.n] - 0.4

    def _halls(self, rng: np.random.Generator, turnaround: bool) -> list[Hall]:
        """One or two halls off outer walls (the first the turning hall of a return)."""
        count = 1 + int(self.ring.perimeter > 120.0 and rng.random() < 0.5)
        halls: list[Hall] = []
        order = rng.permutation(self.ring.n)
        if turnaround:  # the turning hall goes on the longest side, where it surely fits
            longest = int(np.argmax([self.ring.side(i)[3] for i in range(self.ring.n)]))
            order = np.concatenate([[longest], order[order != longest]])
        for side in order:
            if len(halls) == count:
                break
            turn = turnaround and not halls
            lo, hi = self.object_zone(int(side))
            length = rng.uniform(8.5, 12.0) if turn else rng.uniform(*HALL_LENGTH)
            depth = rng.uniform(4.0, 6.0) if turn else rng.uniform(*HALL_DEPTH)
            if hi - lo < length + 1.0:
                if turn:
                    length = hi - lo - 0.2
                    if length < 8.0:
                        raise ConfigError("the indoor floor has no side long enough to turn round in")
                else:
                    continue
            u0 = lo + rng.uniform(0.0, hi - lo - length)
            wall = self.walls[2 * int(side) + 1]
            rect = wall.frame.rect(u0 - 0.2, u0 + length + 0.2, 0.0, depth + 0.2)
            clash = [r for k, r in enumerate(self.obstacles) if k != side and _overlaps(rect, r)]
            if clash:
                if turn:
                    raise ConfigError("the indoor floor's turning hall does not fit")
                continue
            ceiling = min(self.ceilings[side] + rng.uniform(0.0, 0.6), TOP - 0.2)
            halls.append(Hall(int(side), u0, u0 + length, depth, ceiling, turn))
            self.obstacles.append(rect)
            wall.taken.append((u0, u0 + length))
        return halls

    def _rooms(self, rng: np.random.Generator, w: int) -> None:
        """Rooms in a row behind wall ``w``, each as deep as drawn or as the space behind allows."""
        wall = self.walls[w]
        exterior = w % 2 == 1
        own = w // 2
        lo, hi = wall.u0 + 0.3, wall.u1 - 0.3
        stretches = [(lo, hi)]
        for a, b in sorted(wall.taken):  # around the halls
            stretches = [
                piece for s in stretches for piece in ((s[0], min(s[1], a - 0.3)), (max(s[0], b + 0.3), s[1]))
            ]
        for a, b in stretches:
            u = a
            while b - u >= ROOM_WIDTH[0]:
                width = rng.uniform(*ROOM_WIDTH)
                if b - (u + width) < ROOM_WIDTH[0]:
                    width = b - u
                depth = rng.uniform(3.5, 7.0) if exterior else rng.uniform(3.0, 6.5)
                room = Room(w, u, u + width, wall.thickness, depth, exterior)
                depth = min(depth, self._space_behind(room, own))
                u += width
                if depth >= ROOM_MIN_DEPTH:
                    room = Room(w, room.u0, room.u1, room.d0, depth, exterior)
                    self.rooms.append(room)
                    self.obstacles.append(room.footprint(wall.frame))

    def _space_behind(self, room: Room, own: int) -> float:
        """How deep ``room`` may be without entering another corridor, hall or room."""
        frame = self.walls[room.wall].frame
        back = 0.3 if room.exterior else 0.1
        limit = math.inf
        for k, rect in enumerate(self.obstacles):
            if k == own:
                continue
            u0, u1, d0, d1 = frame.local(rect)
            if min(u1, room.u1 + 0.05) - max(u0, room.u0 - 0.05) <= _OVERLAP or d1 <= room.d0 + _OVERLAP:
                continue
            limit = min(limit, d0 + _OVERLAP - room.d0 - back - 0.05)
        return limit
