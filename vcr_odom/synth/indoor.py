"""The indoor scene (``--scene indoor``): one floor of a building, walked with a handheld scanner.

A closed ring of corridors (:mod:`~vcr_odom.synth.corridors`: 2-3.5 m wide, each side its own width
and ceiling height, 2.6-3.5 m) runs round a core of rooms, with more rooms on its outer side behind
the exterior wall's windows. Along the corridors: doorways open into furnished rooms the sensor sees
into, closed doors as recessed panels, wall niches, pilasters, radiators, notice boards, cabinets,
benches, plants and bins against the walls; light panels, beams and ducts under the ceiling; one or
two wider halls open off the corridor, with columns. A bare corridor fixes no motion along its axis;
this clutter, every few metres and never repeating, is what does, as in a real building.

Everything is a pure function of the seed, the route and the walk's length (:class:`IndoorScene`):
the same seed gives the same floor, byte for byte. The floor is bounded (its ring is at most
:data:`LAP_LENGTH` round; a longer walk goes round more often), so it is built whole, in one chunk
per side of the ring, and handed to the ray caster like a street's chunks (:meth:`mesh_near`).

The walker keeps to the corridors: everything against a corridor wall is at most the corridor's
half-width less :data:`OBJECT_SETBACK` deep, nothing hangs below :data:`HUNG_CLEARANCE`, and the
corners are rounded (:func:`~vcr_odom.synth.corridors.corner_radius`) so that the walker stays at
least about 0.6 m from every wall and object. Routes: ``loop`` goes round the ring about
:data:`~vcr_odom.synth.routes.LAPS` times (same-direction revisits); ``return`` walks out along the
corridors, turns round in a hall and walks back past the start (opposite-direction revisits, a
corridor's keep-right apart).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vcr_odom.errors import ConfigError
from vcr_odom.synth.corridors import (
    LATERAL_MAX,
    Ring,
    Stray,
    Track,
    Walkway,
    make_ring,
    ring_track,
)
from vcr_odom.synth.mesh import FloatArray, MeshBuilder, MeshPart, Surface
from vcr_odom.synth.routes import LAPS, PAST_START

INDOOR_SCENE = "indoor"
"""The ``--scene`` name of the indoor floor."""
INDOOR_ROUTES = ("loop", "return")
"""Routes the indoor scene is walked on."""
LAP_LENGTH = (40.0, 250.0)
"""Bounds (m) on the walker's lap of the corridor ring: the distance walked / :data:`LAPS` within them."""
RETURN_LAP = 60.0
"""A ``return`` walk's ring is at least this long round (m): its longest side holds the turning hall."""
CEILING_HEIGHT = (2.6, 3.5)
"""Ceiling heights (m) of corridors and rooms."""
TOP = 4.4
"""Height (m) of the slab over everything: walls rise to it, above the highest ceiling (a hall's)."""
MAX_HAND_HEIGHT = 1.8
"""Highest sensor (m) the indoor scene allows: under the lowest beam by more than half a metre."""
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
TURN_RADIUS = (1.3, 1.6)
"""Radius (m) of the U-turn a ``return`` walk makes in its hall."""
_S_RADIUS = 2.5
"""Radius (m) of the two arcs that take the walker aside into the hall before the U-turn."""
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


class IndoorScene:
    """The indoor floor for one seed, sized to the walk; hands out the geometry near given positions
    and the walker's line (see the module doc)."""

    style_name = INDOOR_SCENE

    def __init__(self, seed: int, route: str, travel: float) -> None:
        if route not in INDOOR_ROUTES:
            raise ConfigError(
                f"route: the indoor scene is walked on {' or '.join(INDOOR_ROUTES)}, got {route!r}"
            )
        self.seed = seed
        self.route = route
        shortest = LAP_LENGTH[0] if route == "loop" else RETURN_LAP
        lap = float(np.clip(travel / LAPS, shortest, LAP_LENGTH[1]))
        self.ring = make_ring(np.random.default_rng([seed, 40]), lap)
        floor = _Floor(self.ring, seed, turnaround=route == "return")
        self.halls = floor.halls
        self.rooms = floor.rooms
        self._parts = floor.parts
        self._boxes = np.array(
            [np.concatenate([p.vertices[:, :2].min(0), p.vertices[:, :2].max(0)]) for p in self._parts]
        )
        self.track = _track(self.ring, floor, np.random.default_rng([seed, 41]), route, travel)
        self.walkway = Walkway(self.track, Stray.random(np.random.default_rng([seed, 44])))

    def chunks_near(self, centres: ArrayLike, radius: float) -> list[tuple[int, int, int]]:
        """Keys of the chunks (the shell, then one per side of the ring) within ``radius`` in plan."""
        centres = np.atleast_2d(np.asarray(centres, dtype=np.float64))[:, :2]
        boxes = self._boxes
        dx = np.maximum(
            np.maximum(boxes[:, None, 0] - centres[None, :, 0], centres[None, :, 0] - boxes[:, None, 2]), 0
        )
        dy = np.maximum(
            np.maximum(boxes[:, None, 1] - centres[None, :, 1], centres[None, :, 1] - boxes[:, None, 3]), 0
        )
        near = np.sqrt(dx * dx + dy * dy).min(axis=1) <= radius
        return [(2, int(k), 0) for k in np.flatnonzero(near)]

    def chunk(self, key: tuple[int, int, int]) -> MeshPart:
        return self._parts[key[1]]

    @property
    def cached_chunks(self) -> int:
        """Chunks held in memory: all of them (the floor is bounded, :data:`LAP_LENGTH`)."""
        return len(self._parts)

    def mesh_near(self, centres: ArrayLike, radius: float) -> MeshPart:
        """Everything within ``radius`` of the centres as one mesh, in a fixed chunk order."""
        return MeshPart.concatenate([self.chunk(key) for key in self.chunks_near(centres, radius)])

    def ground_height(self, xy: ArrayLike) -> FloatArray:
        """The floor is level, at height 0."""
        return np.zeros(len(np.atleast_2d(np.asarray(xy, dtype=np.float64))))

    def walk(self, distance: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Track stations, positions ``(N, 2)`` and headings of the walker after ``distance`` metres."""
        distance = np.asarray(distance, dtype=np.float64)
        if len(distance) and float(distance.max()) > self.walkway.length:
            raise ConfigError("track too short for the walk")  # cannot happen: it is sized for it
        return self.walkway.at(distance)

    def turning(self, distance: ArrayLike) -> NDArray[np.bool_]:
        """Whether the walker is rounding a corner or turning round after ``distance`` metres."""
        return self.walkway.turning(distance)


def _track(ring: Ring, floor: _Floor, rng: np.random.Generator, route: str, travel: float) -> Track:
    """The walker's track: round the ring from the middle of a side (``loop``), or out to the turning
    hall, round in it and back past the start (``return``)."""
    lap = ring.lap()
    length = 1.05 * travel + 30.0
    starts = lap.starts
    if route == "loop":
        side = int(rng.integers(ring.n))
        start = starts[2 * side] + lap.pieces[2 * side, 3] * rng.uniform(0.3, 0.7)
        return ring_track(lap, start, length)
    hall = next(h for h in floor.halls if h.turn)
    radius = rng.uniform(*TURN_RADIUS)
    # Aside by 2 radius (two arcs of _S_RADIUS), then a U-turn of radius back onto the centre line.
    theta = math.acos(1.0 - radius / _S_RADIUS)
    advance = 2.0 * _S_RADIUS * math.sin(theta)
    turn_at = starts[2 * hall.side] + (hall.u0 + 0.6 - ring.radii[hall.side])
    bulb = 2.0 * _S_RADIUS * theta + math.pi * radius
    margin = float(np.clip(0.1 * travel, *PAST_START))
    out = max(10.0, 0.5 * (travel - bulb - margin))
    way_out = ring_track(lap, turn_at - out, out)
    (x, y), heading = way_out.end()
    pieces = [(x, y, heading, _S_RADIUS * theta, -1.0 / _S_RADIUS)]
    for length_k, kappa in ((_S_RADIUS * theta, 1.0 / _S_RADIUS), (math.pi * radius, 1.0 / radius)):
        pieces.append((*_end(pieces[-1]), length_k, kappa))
    way_back = ring_track(lap, turn_at + advance, max(length - out - bulb, 10.0), backward=True)
    track = Track.chain([way_out, Track(np.array(pieces)), way_back])
    joined = np.linalg.norm(_end(pieces[-1])[:2] - way_back.evaluate([0.0])[0][0])
    assert joined < 1e-6, f"the U-turn misses the way back by {joined:.3g} m"
    return track


def _end(piece: tuple[float, ...]) -> NDArray[np.float64]:
    x0, y0, h0, length, kappa = piece
    h1 = h0 + kappa * length
    if kappa == 0.0:
        return np.array([x0 + length * math.cos(h0), y0 + length * math.sin(h0), h1])
    return np.array(
        [x0 + (math.sin(h1) - math.sin(h0)) / kappa, y0 + (math.cos(h0) - math.cos(h1)) / kappa, h1]
    )


def _overlaps(a: Rect, b: Rect) -> bool:
    return min(a[2], b[2]) - max(a[0], b[0]) > _OVERLAP and min(a[3], b[3]) - max(a[1], b[1]) > _OVERLAP


def _grow(rect: ArrayLike, by: float) -> Rect:
    x0, y0, x1, y1 = (float(v) for v in np.asarray(rect, dtype=np.float64))
    return x0 - by, y0 - by, x1 + by, y1 + by


class _Floor:
    """Builds the floor plan and its meshes: halls first (rooms keep clear of them), then rooms behind
    both walls of every side, then each side's corridor, walls, doors and furniture."""

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
        self.parts = [self._shell()] + [self._side(i) for i in range(ring.n)]

    # -- the plan ----------------------------------------------------------------------------------

    def _object_zone(self, side: int) -> tuple[float, float]:
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
            lo, hi = self._object_zone(int(side))
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

    # -- meshes ------------------------------------------------------------------------------------

    def _shell(self) -> MeshPart:
        """A slab under and over everything: no ray leaves the building, whatever it slips through."""
        rects = np.array(self.obstacles)
        lo, hi = rects[:, :2].min(axis=0) - 1.0, rects[:, 2:].max(axis=0) + 1.0
        mesh = MeshBuilder()
        plan = [(lo[0], lo[1]), (hi[0], lo[1]), (hi[0], hi[1]), (lo[0], hi[1])]
        mesh.quad([(x, y, -0.3) for x, y in plan], Surface.SIDEWALK, 0.3)
        mesh.quad([(x, y, TOP) for x, y in plan], Surface.WALL, 0.5)
        return mesh.build()

    def _side(self, i: int) -> MeshPart:
        """Side ``i`` of the ring: its corridor, both walls and what stands at them, its halls and the
        rooms behind its walls."""
        rng = np.random.default_rng([self.seed, 46, i])
        mesh = MeshBuilder()
        self._corridor(rng, mesh, i)
        for hall in self.halls:
            if hall.side == i:
                self._hall(rng, mesh, hall)
        for w in (2 * i, 2 * i + 1):
            for room in (r for r in self.rooms if r.wall == w):
                self._room(rng, mesh, room)
        for w in (2 * i, 2 * i + 1):
            self._wall_features(rng, mesh, w)
            self.walls[w].build(mesh)
        return mesh.build()

    def _corridor(self, rng: np.random.Generator, mesh: MeshBuilder, i: int) -> None:
        """Floor, ceiling (a step down or up where the last side's differs), lights, beams and ducts."""
        ring = self.ring
        start, d, normal, length = ring.side(i)
        a_prev, a, a_next = ring.half_widths[i - 1], ring.half_widths[i], ring.half_widths[(i + 1) % ring.n]
        h, h_prev = float(self.ceilings[i]), float(self.ceilings[i - 1])
        centre = Frame(start, d, normal)  # d: across, + towards the core
        u0, u1 = a_prev, length + a_next
        centre.floor(mesh, (u0, u1), (-a, a), 0.0, rng.uniform(0.2, 0.45))
        centre.floor(mesh, (u0, u1), (-a, a), h, rng.uniform(0.6, 0.85))
        if abs(h - h_prev) > 1e-6:
            centre.box(mesh, (u0 - 0.03, u0), (-a, a), (min(h, h_prev), max(h, h_prev)), Surface.WALL, 0.7)
        # Lights flush with the ceiling, every 2.2-4 m, in the middle or staggered.
        u = u0 + rng.uniform(0.5, 2.0)
        square = rng.random() < 0.5
        while u < u1 - 1.0:
            size = (0.6, 0.6) if square else (1.2, 0.25)
            v = rng.choice([0.0, 0.0, -0.35 * a, 0.35 * a])
            centre.box(
                mesh, (u, u + size[0]), (v - size[1] / 2, v + size[1] / 2), (h - 0.06, h), Surface.METAL, 0.8
            )
            u += rng.uniform(2.2, 4.0)
        if rng.random() < 0.5 and h - HUNG_CLEARANCE >= 0.15:  # beams across
            depth = min(0.45, h - HUNG_CLEARANCE)
            u = u0 + rng.uniform(1.0, 4.0)
            while u < u1 - 1.0:
                centre.box(mesh, (u, u + rng.uniform(0.3, 0.5)), (-a, a), (h - depth, h), Surface.WALL, 0.65)
                u += rng.uniform(4.0, 9.0)
        if rng.random() < 0.35 and h - 0.45 >= HUNG_CLEARANCE:  # a duct along one wall
            side = rng.choice([-1.0, 1.0])
            width = rng.uniform(0.3, 0.5)
            v = side * (a - 0.05 - width / 2)
            stop = u0 + (u1 - u0) * rng.uniform(0.5, 1.0)
            centre.box(
                mesh, (u0, stop), (v - width / 2, v + width / 2), (h - 0.45, h - 0.2), Surface.METAL, 0.55
            )

    def _hall(self, rng: np.random.Generator, mesh: MeshBuilder, hall: Hall) -> None:
        """The hall's opening, walls (a glazed back wall now and then), floor, ceiling, columns
        (not in a turning hall) and furniture at its back."""
        wall = self.walls[2 * hall.side + 1]
        frame, t = wall.frame, wall.thickness
        h = float(self.ceilings[hall.side])
        u0, u1, depth = hall.u0, hall.u1, hall.depth
        wall.cuts.append((u0, u1, 0.0, h))
        albedo = rng.uniform(0.5, 0.85)
        frame.box(mesh, (u0 - 0.15, u0), (t, depth), (0.0, TOP), Surface.WALL, albedo)
        frame.box(mesh, (u1, u1 + 0.15), (t, depth), (0.0, TOP), Surface.WALL, albedo)
        back = (depth, depth + 0.3)
        if rng.random() < 0.5:  # a glass front: mullions, a spandrel, panes
            frame.box(mesh, (u0 - 0.15, u1 + 0.15), back, (0.0, 0.4), Surface.WALL, albedo)
            frame.box(mesh, (u0 - 0.15, u1 + 0.15), back, (2.6, TOP), Surface.WALL, albedo)
            frame.box(mesh, (u0, u1), (depth + 0.14, depth + 0.16), (0.4, 2.6), Surface.GLASS, 0.2)
            for u in np.arange(u0, u1 + 1e-6, (u1 - u0) / max(1, round((u1 - u0) / 1.5))):
                frame.box(mesh, (u - 0.04, u + 0.04), back, (0.4, 2.6), Surface.METAL, 0.5)
        else:
            frame.box(mesh, (u0 - 0.15, u1 + 0.15), back, (0.0, TOP), Surface.WALL, albedo)
        frame.floor(mesh, (u0, u1), (0.0, depth), 0.0, rng.uniform(0.2, 0.5))
        frame.floor(mesh, (u0, u1), (0.0, depth), hall.ceiling, rng.uniform(0.6, 0.85))
        if hall.turn:
            # The walker swings up to 2 turn radii + LATERAL_MAX aside of the centre line: its back
            # keeps 0.6 m clear.
            a = self.ring.half_widths[hall.side]
            room = depth - (2.0 * TURN_RADIUS[1] + LATERAL_MAX - a) - 0.7
            if room >= 0.4:
                for u in np.arange(u0 + 0.5, u1 - 1.5, rng.uniform(2.5, 4.0)):
                    self._bench(rng, mesh, frame, u, rng.uniform(1.2, 2.0), (depth - min(room, 0.5), depth))
            return
        # Columns: a row just beyond the corridor's wall line, another in the middle of deep halls.
        rows = [0.6] + ([depth / 2 + 0.3] if depth > 4.5 else [])
        round_columns, size = rng.random() < 0.5, rng.uniform(0.35, 0.6)
        for d in rows:
            count = max(1, round((u1 - u0) / rng.uniform(3.5, 5.0)))
            for u in u0 + (np.arange(count) + 0.5) * (u1 - u0) / count:
                if round_columns:
                    mesh.cylinder(
                        (*frame.at(u, d + size / 2), 0.0), (0, 0, 1), size / 2, TOP, Surface.WALL, albedo, 12
                    )
                else:
                    frame.box(
                        mesh, (u - size / 2, u + size / 2), (d, d + size), (0.0, TOP), Surface.WALL, albedo
                    )
        for u in np.arange(u0 + 0.5, u1 - 1.5, rng.uniform(2.5, 4.5)):
            kind = rng.random()
            if kind < 0.5:
                self._bench(rng, mesh, frame, u, rng.uniform(1.2, 2.0), (depth - 0.45, depth))
            elif kind < 0.8:
                self._plant(rng, mesh, frame, u + 0.4, depth - 0.45)
            else:
                frame.box(mesh, (u, u + 1.6), (depth - 0.9, depth - 0.2), (0.0, 1.05), Surface.WOOD, 0.4)

    def _room(self, rng: np.random.Generator, mesh: MeshBuilder, room: Room) -> None:
        """A room's walls (windows in an exterior one), floor, ceiling, door and furniture."""
        wall = self.walls[room.wall]
        frame = wall.frame
        d0, d1 = room.d0, room.d0 + room.depth
        albedo = rng.uniform(0.45, 0.85)
        frame.box(mesh, (room.u0 - 0.05, room.u0 + 0.05), (d0, d1), (0.0, TOP), Surface.WALL, albedo)
        if not any(r.wall == room.wall and abs(r.u0 - room.u1) < 1e-9 for r in self.rooms):
            frame.box(mesh, (room.u1 - 0.05, room.u1 + 0.05), (d0, d1), (0.0, TOP), Surface.WALL, albedo)
        back = (d1, d1 + (0.3 if room.exterior else 0.1))
        if room.exterior:
            sill, head = rng.uniform(0.8, 1.0), rng.uniform(2.1, 2.4)
            count = max(1, int((room.u1 - room.u0) / 2.5))
            width = min(1.6, (room.u1 - room.u0) / count - 0.6)
            edges = [room.u0 - 0.05]
            for k in range(count):
                centre = room.u0 + (k + 0.5) * (room.u1 - room.u0) / count
                edges += [centre - width / 2, centre + width / 2]
                frame.box(
                    mesh,
                    (centre - width / 2, centre + width / 2),
                    (d1 + 0.14, d1 + 0.16),
                    (sill, head),
                    Surface.GLASS,
                    0.2,
                )
                frame.box(
                    mesh, (centre - width / 2, centre + width / 2), back, (0.0, sill), Surface.WALL, albedo
                )
                frame.box(
                    mesh, (centre - width / 2, centre + width / 2), back, (head, TOP), Surface.WALL, albedo
                )
            edges.append(room.u1 + 0.05)
            for a, b in zip(edges[0::2], edges[1::2], strict=True):
                frame.box(mesh, (a, b), back, (0.0, TOP), Surface.WALL, albedo)
        else:
            frame.box(mesh, (room.u0 - 0.05, room.u1 + 0.05), back, (0.0, TOP), Surface.WALL, albedo)
        frame.floor(mesh, (room.u0, room.u1), (d0, d1), 0.0, rng.uniform(0.15, 0.5))
        frame.floor(mesh, (room.u0, room.u1), (d0, d1), rng.uniform(*CEILING_HEIGHT), rng.uniform(0.6, 0.85))
        # The door: open into the room (a leaf swung 70-115 deg) or shut, a panel set into the wall.
        width = (
            rng.uniform(1.6, 1.9)
            if room.u1 - room.u0 > 5.0 and rng.random() < 0.2
            else rng.uniform(0.85, 1.0)
        )
        u = rng.uniform(room.u0 + 0.3, max(room.u0 + 0.3, room.u1 - 0.3 - width))
        height = rng.uniform(2.0, 2.3)
        opened = rng.random() < 0.55
        self._door(rng, mesh, wall, u, width, height, opened)
        if opened:
            hinge_left = rng.random() < 0.5
            angle = math.radians(rng.uniform(70.0, 115.0))
            leaf = width if width < 1.2 else width / 2
            hinge = np.array([u if hinge_left else u + width, d0])
            along = np.array([math.cos(angle) * (1 if hinge_left else -1), math.sin(angle)])
            across = np.array([-along[1], along[0]]) * 0.04
            plan = [hinge, hinge + leaf * along, hinge + leaf * along + across, hinge + across]
            world = [frame.at(*p) for p in plan]
            corners = [(*p, 0.01) for p in world] + [(*p, height - 0.01) for p in world]
            mesh.hexahedron(corners, Surface.WOOD, rng.uniform(0.3, 0.5))
        self._furnish(rng, mesh, frame, room)

    def _door(
        self,
        rng: np.random.Generator,
        mesh: MeshBuilder,
        wall: Wall,
        u: float,
        width: float,
        height: float,
        opened: bool,
    ) -> None:
        """A doorway cut into a corridor wall with its casing; shut, a panel recessed into the wall."""
        frame, t = wall.frame, wall.thickness
        wall.cuts.append((u, u + width, 0.0, height))
        wall.taken.append((u - 0.1, u + width + 0.1))
        casing = rng.uniform(0.2, 0.6)
        frame.box(mesh, (u - 0.07, u), (-0.02, 0.0), (0.0, height + 0.07), Surface.WOOD, casing)
        frame.box(
            mesh, (u + width, u + width + 0.07), (-0.02, 0.0), (0.0, height + 0.07), Surface.WOOD, casing
        )
        frame.box(mesh, (u, u + width), (-0.02, 0.0), (height, height + 0.07), Surface.WOOD, casing)
        if opened:
            frame.floor(mesh, (u, u + width), (0.0, t), 0.0, rng.uniform(0.2, 0.45))
            return
        recess = rng.uniform(0.04, max(0.05, t - 0.06))
        surface = Surface.METAL if rng.random() < 0.3 else Surface.WOOD
        frame.box(
            mesh, (u, u + width), (recess, recess + 0.045), (0.0, height), surface, rng.uniform(0.25, 0.6)
        )

    def _furnish(self, rng: np.random.Generator, mesh: MeshBuilder, frame: Frame, room: Room) -> None:
        """Desks and tables (a top on legs), shelves and cabinets against the walls, chairs, sofas."""
        ua, ub = room.u0 + 0.1, room.u1 - 0.1
        da, db = room.d0 + 0.6, room.d0 + room.depth - 0.1  # the door's swing stays clear-ish
        for _ in range(int(rng.integers(2, 8))):
            kind = rng.random()
            if kind < 0.3:  # a table or desk
                w, dep, top = rng.uniform(1.0, 1.8), rng.uniform(0.6, 0.9), rng.uniform(0.72, 0.76)
                u, d = rng.uniform(ua, max(ua, ub - w)), rng.uniform(da, max(da, db - dep))
                frame.box(
                    mesh, (u, u + w), (d, d + dep), (top - 0.03, top), Surface.WOOD, rng.uniform(0.3, 0.6)
                )
                for lu in (u, u + w - 0.05):
                    for ld in (d, d + dep - 0.05):
                        frame.box(
                            mesh, (lu, lu + 0.05), (ld, ld + 0.05), (0.0, top - 0.03), Surface.METAL, 0.4
                        )
            elif kind < 0.55:  # shelves or a cabinet against the back wall
                w, dep = rng.uniform(0.6, 2.0), rng.uniform(0.3, 0.5)
                height = rng.uniform(1.8, 2.2) if rng.random() < 0.6 else rng.uniform(0.8, 1.3)
                u = rng.uniform(ua, max(ua, ub - w))
                frame.box(
                    mesh, (u, u + w), (db - dep, db), (0.0, height), Surface.WOOD, rng.uniform(0.25, 0.6)
                )
            elif kind < 0.75:  # a cabinet against a side wall
                w, dep, height = rng.uniform(0.5, 1.2), rng.uniform(0.4, 0.6), rng.uniform(0.8, 2.0)
                d = rng.uniform(da, max(da, db - w))
                u = (ua, ua + dep) if rng.random() < 0.5 else (ub - dep, ub)
                frame.box(mesh, u, (d, d + w), (0.0, height), Surface.METAL, rng.uniform(0.3, 0.6))
            elif kind < 0.92:  # a chair: seat and back
                u, d = rng.uniform(ua, max(ua, ub - 0.45)), rng.uniform(da, max(da, db - 0.45))
                frame.box(
                    mesh, (u, u + 0.45), (d, d + 0.45), (0.0, 0.46), Surface.RUBBER, rng.uniform(0.1, 0.4)
                )
                frame.box(mesh, (u, u + 0.45), (d + 0.4, d + 0.45), (0.46, 0.9), Surface.RUBBER, 0.3)
            else:  # a sofa
                w = rng.uniform(1.4, 2.0)
                u, d = rng.uniform(ua, max(ua, ub - w)), rng.uniform(da, max(da, db - 0.85))
                frame.box(mesh, (u, u + w), (d, d + 0.85), (0.0, 0.45), Surface.RUBBER, rng.uniform(0.1, 0.4))
                frame.box(mesh, (u, u + w), (d + 0.65, d + 0.85), (0.45, 0.85), Surface.RUBBER, 0.3)

    def _wall_features(self, rng: np.random.Generator, mesh: MeshBuilder, w: int) -> None:
        """What a corridor wall carries between its doors, every 0.3-3.5 m: closed doors, niches,
        pilasters, boards, radiators, extinguishers, cabinets, benches, plants, bins, machines; each
        at most the corridor's half-width less :data:`OBJECT_SETBACK` deep."""
        wall = self.walls[w]
        side = w // 2
        allowance = min(0.75, self.ring.half_widths[side] - OBJECT_SETBACK)
        lo, hi = self._object_zone(side)
        lo, hi = max(lo, wall.u0 + 0.2), min(hi, wall.u1 - 0.2)
        kinds = {"board": 2.0, "radiator": 1.5, "niche": 1.2, "door": 1.5, "pilaster": 1.0}
        needs = {"extinguisher": (0.18, 0.6), "cabinet": (0.4, 1.5), "bench": (0.38, 1.0), "plant": (0.55, 1.0),
                 "bin": (0.35, 0.7), "machine": (0.72, 0.4)}  # fmt: skip
        kinds |= {kind: weight for kind, (depth, weight) in needs.items() if allowance >= depth}
        names = sorted(kinds)
        weights = np.array([kinds[n] for n in names])
        u = lo + rng.uniform(0.0, 1.5)
        while u < hi:
            kind = names[int(rng.choice(len(names), p=weights / weights.sum()))]
            width = {"pilaster": rng.uniform(0.3, 0.6), "extinguisher": 0.3, "plant": 0.6, "bin": 0.45,
                     "machine": rng.uniform(0.8, 1.0), "door": rng.uniform(0.85, 1.0)}.get(kind, rng.uniform(0.6, 2.2))  # fmt: skip
            if u + width <= hi and wall.free(u, u + width):
                self._feature(rng, mesh, wall, kind, u, width, allowance)
                if kind != "door":  # a door takes its own stretch
                    wall.taken.append((u, u + width))
            u += width + rng.uniform(0.3, 3.5)

    def _feature(
        self,
        rng: np.random.Generator,
        mesh: MeshBuilder,
        wall: Wall,
        kind: str,
        u: float,
        width: float,
        allowance: float,
    ) -> None:
        frame, t = wall.frame, wall.thickness
        span = (u, u + width)
        if kind == "door":
            self._door(rng, mesh, wall, u, width, rng.uniform(2.0, 2.3), opened=False)
        elif kind == "niche":  # recessed into the wall: from the floor, or a wall niche above a sill
            depth = rng.uniform(0.15, 0.45)
            z0, z1 = (
                (0.0, rng.uniform(2.0, 2.4))
                if rng.random() < 0.5
                else (rng.uniform(0.7, 1.0), rng.uniform(1.8, 2.2))
            )
            wall.cuts.append((u, u + width, z0, z1))
            albedo = rng.uniform(0.4, 0.8)
            frame.box(mesh, span, (depth, max(depth + 0.05, t)), (z0, z1), Surface.WALL, albedo)
            if depth > t:
                frame.box(mesh, (u - 0.05, u), (t, depth + 0.05), (z0, z1), Surface.WALL, albedo)
                frame.box(
                    mesh, (u + width, u + width + 0.05), (t, depth + 0.05), (z0, z1), Surface.WALL, albedo
                )
                frame.box(mesh, span, (t, depth), (z1, z1 + 0.05), Surface.WALL, albedo)
                if z0 > 0.0:
                    frame.box(mesh, span, (t, depth), (z0 - 0.05, z0), Surface.WALL, albedo)
        elif kind == "pilaster":
            depth = min(allowance, rng.uniform(0.12, 0.3)) if allowance > 0.12 else 0.08
            frame.box(mesh, span, (-depth, 0.0), (0.0, TOP), Surface.WALL, self.wall_albedo)
        elif kind == "board":
            z0 = rng.uniform(0.9, 1.3)
            frame.box(
                mesh,
                span,
                (-0.03, 0.0),
                (z0, z0 + rng.uniform(0.5, 1.0)),
                Surface.SIGN,
                rng.uniform(0.3, 0.9),
            )
        elif kind == "radiator":
            frame.box(
                mesh, span, (-0.1, 0.0), (0.15, rng.uniform(0.6, 0.8)), Surface.METAL, rng.uniform(0.5, 0.8)
            )
        elif kind == "extinguisher":
            z0 = rng.uniform(0.1, 0.9)
            base = (*frame.at(u + 0.15, -0.09), z0)
            mesh.cylinder(base, (0, 0, 1), 0.08, 0.55, Surface.METAL, 0.5, 10)
        elif kind == "cabinet":
            depth = rng.uniform(0.4, min(0.6, allowance))
            frame.box(
                mesh, span, (-depth, 0.0), (0.0, rng.uniform(0.9, 2.0)), Surface.METAL, rng.uniform(0.3, 0.7)
            )
        elif kind == "bench":
            self._bench(rng, mesh, frame, u, width, (-min(0.45, allowance), 0.0))
        elif kind == "plant":
            self._plant(rng, mesh, frame, u + 0.3, -0.27)
        elif kind == "bin":
            radius = rng.uniform(0.14, 0.16)
            mesh.cylinder((*frame.at(u + 0.22, -radius - 0.01), 0.0), (0, 0, 1), radius, rng.uniform(0.5, 0.8),
                          Surface.METAL, rng.uniform(0.3, 0.6), 10)  # fmt: skip
        else:  # a vending machine or a copier
            depth = rng.uniform(0.7, allowance)
            frame.box(
                mesh, span, (-depth, 0.0), (0.0, rng.uniform(1.1, 1.85)), Surface.METAL, rng.uniform(0.3, 0.7)
            )

    def _bench(
        self,
        rng: np.random.Generator,
        mesh: MeshBuilder,
        frame: Frame,
        u: float,
        width: float,
        d: tuple[float, float],
    ) -> None:
        """A bench ``width`` long from ``u``, its seat over ``d`` (across the frame), on two legs."""
        albedo = rng.uniform(0.3, 0.6)
        frame.box(mesh, (u, u + width), d, (0.4, 0.46), Surface.WOOD, albedo)
        for lu in (u + 0.05, u + width - 0.1):
            frame.box(mesh, (lu, lu + 0.05), d, (0.0, 0.4), Surface.METAL, 0.4)

    def _plant(self, rng: np.random.Generator, mesh: MeshBuilder, frame: Frame, u: float, d: float) -> None:
        """A pot with a leafy crown, centred at ``(u, d)``; at most 0.27 m from there in plan."""
        pot, crown = rng.uniform(0.15, 0.2), rng.uniform(0.16, 0.22)
        height = rng.uniform(0.35, 0.5)
        centre = frame.at(u, d)
        mesh.cylinder((*centre, 0.0), (0, 0, 1), pot, height, Surface.WOOD, rng.uniform(0.2, 0.5), 10)
        radii = (crown, crown, rng.uniform(0.3, 0.6))
        mesh.blob((*centre, height + radii[2]), radii, rng, Surface.VEGETATION, rng.uniform(0.3, 0.5), 0.15)
