"""Routes (``--route``): which street is built and how it is driven, for drives that come back to
places they have seen (loop-closure tests) and one that only seems to.

- ``street``: the open street driven once (the original sequences, byte for byte; built by
  :class:`~vcr_odom.synth.scene.StreetScene` itself).
- ``loop``: a closed, rounded, irregular street driven about 1.25 times round: same-direction revisits.
- ``figure8``: a street that crosses itself, driven about 1.25 times round: the crossing is passed in
  two directions 90-110 deg apart.
- ``return``: out along the street, round a turning loop at its end and back in the other
  direction's lane, past the start: opposite-direction revisits a lane apart (and a median, where
  there is one).
- ``blocks``: a straight street whose roadside repeats exactly every 30-60 m, driven once: places
  that look the same and are not.

Closed routes and the return are sized to the motion (``travel``: how far a path takes the car or
walker in its frames), so the revisit happens whatever the frame count and speed: a lap is the
distance travelled / 1.25 (within :data:`LOOP_PERIMETER`, :data:`WALK_LOOP_PERIMETER` for a walk, or
:data:`FIGURE8_PERIMETER`), and the turn comes where the way back passes the start by
:data:`PAST_START`. The street is a function of the seed, the route and that size only: a place
revisited is the same geometry every time.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Literal, get_args

import numpy as np

from vcr_odom.synth.closed_roads import Lap, figure8_lap, loop_lap
from vcr_odom.synth.courtyard import fit_courtyard
from vcr_odom.synth.layout import Profile, RouteFeatures, StreetLayout
from vcr_odom.synth.paths import DrivePath, unroll
from vcr_odom.synth.repeating import block_period, periodic_terrain, straight_road
from vcr_odom.synth.road import PREROLL, ROAD_CHUNK, ROAD_STEP, Road, Terrain, make_road
from vcr_odom.synth.scene import RouteWorld
from vcr_odom.synth.styles import SceneStyle
from vcr_odom.synth.turnaround import return_path

Route = Literal["street", "loop", "figure8", "return", "blocks"]
ROUTES: tuple[str, ...] = get_args(Route)

LAPS = 1.25
"""Laps of a loop or figure eight the drive covers (when the perimeter's bounds allow)."""
LOOP_PERIMETER = (250.0, 1500.0)
"""Bounds (m) on a loop's perimeter: a city block at least, and longer drives go round more often."""
WALK_LOOP_PERIMETER = (50.0, 1500.0)
"""The same for a walk (``--motion handheld``): a loop round one building, the scale of the campus loops
people record with a handheld scanner (~60 m), where a car's city block would leave a short walk
without any revisit. A walked loop shorter than a car's is a footpath round a building in a courtyard
(:mod:`~vcr_odom.synth.courtyard`), not a street."""
FIGURE8_PERIMETER = (400.0, 2000.0)
"""Bounds (m) on a figure eight's length (both lobes)."""
PAST_START = (5.0, 40.0)
"""A return passes its start by 10 % of the distance travelled, within these bounds (m)."""
MIN_OUT = 20.0
"""Shortest way out (m) before a return turns."""
SIZING_ROUNDS = 8
"""Rounds of sizing: size the route to the travel, measure the travel on it, again."""

Travel = Callable[[Road], float]
"""How far (m) along a path the motion takes the sensor from its first frame to its last."""


def build_route(
    route: str, seed: int, style: SceneStyle, length: float, travel: Travel, walked: bool = False
) -> RouteWorld:
    """The street and path of a route other than ``street``, for a motion that needs at most
    ``length`` metres of path after its preroll (as the open street is sized) and travels
    ``travel(path)`` metres along a given path; ``walked``: a walker's, whose loops may be short."""
    terrain = Terrain.random(np.random.default_rng([seed, 2]))
    if route in ("loop", "figure8"):
        return _closed(route, seed, style, terrain, length, travel, walked)
    if route == "return":
        return _out_and_back(seed, style, terrain, length, travel)
    if route == "blocks":
        return _blocks(seed, style, terrain, length)
    raise ValueError(f"route must be one of {', '.join(ROUTES[1:])} here, got {route!r}")


def _closed(
    route: str, seed: int, style: SceneStyle, terrain: Terrain, length: float, travel: Travel, walked: bool
) -> RouteWorld:
    """A loop or figure eight with a perimeter of the travel / :data:`LAPS`, driven round and round."""
    if route == "loop":
        make, bounds = loop_lap, WALK_LOOP_PERIMETER if walked else LOOP_PERIMETER
    else:
        make, bounds = figure8_lap, FIGURE8_PERIMETER

    def build(perimeter: float) -> tuple[Lap, DrivePath]:
        lap = make(np.random.default_rng([seed, 30]), perimeter)
        return lap, unroll(lap.road, lap.start - PREROLL, PREROLL + length)

    perimeter = bounds[1]
    lap, path = build(perimeter)
    for _ in range(SIZING_ROUNDS):
        wanted = float(np.clip(travel(path.line) / LAPS, *bounds))
        if abs(wanted - perimeter) < 2.0 * ROAD_STEP:
            break
        perimeter = wanted
        lap, path = build(perimeter)
    crossings = tuple((c.first, c.second, c.angle_deg) for c in lap.crossings)
    courtyard = None
    if walked and lap.corners is not None and perimeter < LOOP_PERIMETER[0]:
        courtyard = fit_courtyard(lap.corners, lap.road, np.random.default_rng([seed, 31]))
    features = RouteFeatures(closed=True, self_crossings=crossings, courtyard=courtyard)
    layout = StreetLayout(lap.road, terrain, np.random.default_rng([seed, 3]), style, features)
    return RouteWorld(lap.road, terrain, layout, path)


def _out_and_back(
    seed: int, style: SceneStyle, terrain: Terrain, length: float, travel: Travel
) -> RouteWorld:
    """The open street cut where the way back will pass the start by :data:`PAST_START`, a turning
    loop beyond its end, and the path out, round and back in the other direction's lane."""
    full = make_road(
        np.random.default_rng([seed, 1]),
        PREROLL + math.ceil(max(length, 1.0) / ROAD_CHUNK) * ROAD_CHUNK,
        style.road,
    )

    def build(out: float) -> tuple[Road, StreetLayout, DrivePath, np.ndarray]:
        end = min(round((PREROLL + out) / ROAD_STEP), len(full.xy) - 1)
        road = Road(full.xy[: end + 1], full.heading[: end + 1], full.curvature[: end + 1])
        zones = StreetLayout(road, terrain, np.random.default_rng([seed, 3]), style, RouteFeatures())
        path, turn = return_path(road, *lanes(zones))
        return road, zones, path, turn

    def wanted(path: DrivePath, road: Road) -> float:
        travelled = travel(path.line)
        turn = path.line.length - 2.0 * road.length
        margin = float(np.clip(0.1 * travelled, *PAST_START))
        return max(MIN_OUT, 0.5 * (travelled - turn - margin))

    straight_on = travel(full)
    out = max(MIN_OUT, 0.5 * (straight_on - float(np.clip(0.1 * straight_on, *PAST_START))))
    road, _, path, turn = build(out)
    for _ in range(SIZING_ROUNDS):
        new = wanted(path, road)
        if abs(new - out) < ROAD_STEP:
            break
        out = new
        road, _, path, turn = build(out)
    layout = StreetLayout(
        road, terrain, np.random.default_rng([seed, 3]), style, RouteFeatures(turning_loop=turn)
    )
    return RouteWorld(road, terrain, layout, path)


def lanes(layout: StreetLayout) -> tuple[np.ndarray, np.ndarray]:
    """Offsets (m, left of the centre line) at every road sample of the lanes a return drives: its
    direction's inner lane out, the other direction's inner lane back (the one lane both ways where
    there is only one), eased over about 10 m where the cross-section changes."""
    stations = np.arange(len(layout.road.xy)) * ROAD_STEP
    offsets = np.array([_inner_lanes(layout.profile_at(float(s))) for s in stations])
    sigma = round(5.0 / ROAD_STEP)
    kernel = np.exp(-0.5 * (np.arange(-3 * sigma, 3 * sigma + 1) / sigma) ** 2)
    padded = np.pad(offsets, ((3 * sigma, 3 * sigma), (0, 0)), mode="edge")
    eased = [np.convolve(padded[:, k], kernel / kernel.sum(), mode="valid") for k in (0, 1)]
    return eased[0], eased[1]


def _inner_lanes(profile: Profile) -> tuple[float, float]:
    """Centres of the innermost lane each way: the car's own lanes are the right half (those before
    the median, where there is one), the rest go the other way."""
    if profile.lanes_left == 0:
        return 0.0, 0.0
    if profile.median > 0.0:
        out = (profile.lanes_ahead - 1) * profile.lane_width
        return out, out + profile.lane_width + profile.median
    out = ((profile.lanes_left + 2) // 2 - 1) * profile.lane_width
    return out, out + profile.lane_width


def _blocks(seed: int, style: SceneStyle, terrain: Terrain, length: float) -> RouteWorld:
    """A straight street of one zone over periodic ground, its roadside repeating every B metres."""
    period = block_period(np.random.default_rng([seed, 31]))
    road = straight_road(PREROLL + math.ceil(max(length, 1.0) / ROAD_CHUNK) * ROAD_CHUNK)
    ground = periodic_terrain(terrain, period)
    features = RouteFeatures(single_zone=True)
    layout = StreetLayout(road, ground, np.random.default_rng([seed, 3]), style, features)
    return RouteWorld(road, ground, layout, DrivePath.along(road), repeat=period)
