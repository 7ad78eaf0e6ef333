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

The plan (:mod:`~vcr_odom.synth.floorplan`) and its meshes (:mod:`~vcr_odom.synth.fittings`) are
built from the ring. The walker keeps to the corridors: everything against a corridor wall is at most
the corridor's half-width less :data:`~vcr_odom.synth.floorplan.OBJECT_SETBACK` deep, nothing hangs
below :data:`~vcr_odom.synth.floorplan.HUNG_CLEARANCE`, and the corners are rounded
(:func:`~vcr_odom.synth.corridors.corner_radius`) so that the walker stays at least about 0.6 m from
every wall and object. Routes: ``loop`` goes round the ring about
:data:`~vcr_odom.synth.routes.LAPS` times (same-direction revisits); ``return`` walks out along the
corridors, turns round in a hall and walks back past the start (opposite-direction revisits, a
corridor's keep-right apart).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vcr_odom.errors import ConfigError
from vcr_odom.synth.corridors import TURN_RADIUS, Ring, Stray, Track, Walkway, make_ring, ring_track, u_turn
from vcr_odom.synth.fittings import fit_out
from vcr_odom.synth.floorplan import FloorPlan
from vcr_odom.synth.mesh import FloatArray, MeshPart
from vcr_odom.synth.routes import LAPS, PAST_START

INDOOR_SCENE = "indoor"
"""The ``--scene`` name of the indoor floor."""
INDOOR_ROUTES = ("loop", "return")
"""Routes the indoor scene is walked on."""
LAP_LENGTH = (40.0, 250.0)
"""Bounds (m) on the walker's lap of the corridor ring: the distance walked / LAPS within them."""
RETURN_LAP = 60.0
"""A ``return`` walk's ring is at least this long round (m): its longest side holds the turning hall."""
MAX_HAND_HEIGHT = 1.8
"""Highest sensor (m) the indoor scene allows: under the lowest beam by more than half a metre."""


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
        self.plan = FloorPlan(self.ring, seed, turnaround=route == "return")
        self._parts = fit_out(self.plan, seed)
        self._boxes = np.array(
            [np.concatenate([p.vertices[:, :2].min(0), p.vertices[:, :2].max(0)]) for p in self._parts]
        )
        self.track = _track(self.ring, self.plan, np.random.default_rng([seed, 41]), route, travel)
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


def _track(ring: Ring, plan: FloorPlan, rng: np.random.Generator, route: str, travel: float) -> Track:
    """The walker's track: round the ring from the middle of a side (``loop``), or out to the turning
    hall, round in it and back past the start (``return``)."""
    lap = ring.lap()
    length = 1.05 * travel + 30.0
    starts = lap.starts
    if route == "loop":
        side = int(rng.integers(ring.n))
        start = starts[2 * side] + lap.pieces[2 * side, 3] * rng.uniform(0.3, 0.7)
        return ring_track(lap, start, length)
    hall = next(h for h in plan.halls if h.turn)
    radius = rng.uniform(*TURN_RADIUS)
    probe = u_turn(np.zeros(2), 0.0, radius)  # its length, and how far on it rejoins the centre line
    advance = float(probe.end()[0][0])
    # It starts 0.6 m into the hall's opening, on the side's straight (which starts at corner radius).
    turn_at = starts[2 * hall.side] + (hall.u0 + 0.6 - ring.radii[hall.side])
    margin = float(np.clip(0.1 * travel, *PAST_START))
    out = max(10.0, 0.5 * (travel - probe.length - margin))
    way_out = ring_track(lap, turn_at - out, out)
    turn = u_turn(*way_out.end(), radius)
    way_back = ring_track(lap, turn_at + advance, max(length - out - turn.length, 10.0), backward=True)
    joined = float(np.linalg.norm(turn.end()[0] - way_back.evaluate([0.0])[0][0]))
    if joined > 1e-6:
        raise AssertionError(f"the U-turn misses the way back by {joined:.3g} m")  # cannot happen
    return Track.chain([way_out, turn, way_back])
