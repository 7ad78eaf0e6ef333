"""The street's plan: which kind of zone each stretch passes through, its cross-section (lanes,
parking, sidewalks), where cross streets are, and for any point how far it is from a carriageway.

Four kinds of zone (urban, residential, industrial, open) alternate at intersections, so that a
network trained on the scene sees the variety of KITTI's drives rather than one repeated corridor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from enum import IntEnum
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from vcr_odom.synth.courtyard import FOOTPATH_SETBACK, FOOTPATH_SIDEWALK, FOOTPATH_WIDTH, Courtyard
from vcr_odom.synth.mesh import FloatArray
from vcr_odom.synth.road import PREROLL, ROAD_STEP, Road, Terrain

if TYPE_CHECKING:
    from vcr_odom.synth.styles import SceneStyle


class ZoneKind(IntEnum):
    URBAN = 0
    RESIDENTIAL = 1
    INDUSTRIAL = 2
    OPEN = 3


@dataclass(frozen=True)
class Profile:
    """Cross-section of one stretch of street; offsets are metres from the driven path, per side.

    Side 0 is the right (negative offsets), side 1 the left. The car drives in the centre of the
    rightmost lane; ``lanes_left`` lanes (oncoming or not) lie to its left.
    """

    kind: ZoneKind
    lane_width: float
    lanes_left: int
    parking: tuple[float, float]
    sidewalk: tuple[float, float]
    curb_height: float
    road_albedo: float
    frontage: tuple[str, str]
    street_trees: tuple[float, float]
    lamp_spacing: float
    setback: tuple[float, float]
    power_line: int = -1
    """Side (0 right, 1 left) with a line of wooden utility poles, or -1."""
    median: float = 0.0
    """Width of a raised median between the two directions (avenues, highways), 0 for none."""
    median_kind: str = "planted"
    """``planted`` (grass and trees) or ``barrier`` (a concrete wall)."""

    def lane_edge(self, side: int) -> float:
        return self.lane_width / 2.0 + (self.lanes_left * self.lane_width + self.median if side else 0.0)

    @property
    def lanes_ahead(self) -> int:
        """Lanes in the car's direction when there is a median (the oncoming ones lie beyond it)."""
        return (self.lanes_left + 1) // 2 if self.median > 0.0 else self.lanes_left + 1

    def median_span(self) -> tuple[float, float]:
        """Left offsets (m) of the median's inner and outer edges."""
        inner = self.lane_width / 2.0 + (self.lanes_ahead - 1) * self.lane_width
        return inner, inner + self.median

    def lane_lines(self) -> list[float]:
        """Left offsets of the dashed lines between lanes (none where the median separates them)."""
        lines = []
        for lane in range(self.lanes_left):
            d = self.lane_width / 2.0 + lane * self.lane_width
            if self.median > 0.0 and lane >= self.lanes_ahead - 1:
                if lane == self.lanes_ahead - 1:
                    continue
                d += self.median
            lines.append(d)
        return lines

    def curb(self, side: int) -> float:
        return self.lane_edge(side) + self.parking[side]

    def outer(self, side: int) -> float:
        return self.curb(side) + self.sidewalk[side]

    def footpath(self, building_side: int) -> Profile:
        """This zone's cross-section narrowed to a paved path round a building on ``building_side``
        (:mod:`~vcr_odom.synth.courtyard`): no lanes beside it, no parking, nothing between the path
        and the building's walls, and on the other side a sidewalk and yards of a few metres."""
        inner, outer = building_side, 1 - building_side
        return replace(
            self,
            lane_width=FOOTPATH_WIDTH,
            lanes_left=0,
            parking=(0.0, 0.0),
            median=0.0,
            power_line=-1,
            sidewalk=_sides(inner, 0.0, outer, min(self.sidewalk[outer], FOOTPATH_SIDEWALK)),
            frontage=_sides(inner, "none", outer, self.frontage[outer]),
            street_trees=_sides(inner, 0.0, outer, self.street_trees[outer]),
            setback=_sides(inner, 0.0, outer, min(self.setback[outer], FOOTPATH_SETBACK)),
        )


def _sides(a: int, a_value: Any, b: int, b_value: Any) -> tuple[Any, Any]:
    """A (right, left) pair from the values of sides ``a`` and ``b`` (one 0, the other 1)."""
    return (a_value, b_value) if a == 0 else (b_value, a_value)


def random_profile(rng: np.random.Generator, kind: ZoneKind) -> Profile:
    """Street cross-sections typical of each kind of zone (KITTI's Karlsruhe: towns, suburbs, roads)."""
    u = rng.uniform
    if kind == ZoneKind.URBAN:
        lanes, lane_w = int(rng.choice([1, 1, 2, 3])), u(3.1, 3.6)
        parking = tuple(float(rng.random() < 0.85) * u(2.0, 2.5) for _ in range(2))
        sidewalk = (u(2.5, 5.0), u(2.5, 5.0))
        frontage = ("none", "none")
        trees = tuple(u(7.0, 14.0) if rng.random() < 0.6 else 0.0 for _ in range(2))
        lamp, setback = u(22.0, 35.0), (u(0.0, 2.5), u(0.0, 2.5))
    elif kind == ZoneKind.RESIDENTIAL:
        lanes, lane_w = 1, u(3.0, 3.5)
        parking = tuple(float(rng.random() < 0.8) * u(2.0, 2.4) for _ in range(2))
        sidewalk = (u(1.5, 3.0), u(1.5, 3.0))
        frontage = tuple(str(rng.choice(["hedge", "wall", "fence", "none"])) for _ in range(2))
        trees = tuple(u(9.0, 18.0) if rng.random() < 0.4 else 0.0 for _ in range(2))
        lamp, setback = u(28.0, 40.0), (u(3.0, 10.0), u(3.0, 10.0))
    elif kind == ZoneKind.INDUSTRIAL:
        lanes, lane_w = int(rng.choice([1, 1, 2])), u(3.2, 3.7)
        parking = tuple(float(rng.random() < 0.4) * u(2.2, 2.8) for _ in range(2))
        sidewalk = tuple(u(1.5, 3.0) if rng.random() < 0.6 else 0.0 for _ in range(2))
        frontage = tuple(str(rng.choice(["fence", "fence", "wall", "none"])) for _ in range(2))
        trees = tuple(u(12.0, 25.0) if rng.random() < 0.3 else 0.0 for _ in range(2))
        lamp, setback = u(30.0, 45.0), (u(4.0, 18.0), u(4.0, 18.0))
    else:
        lanes, lane_w = 1, u(3.0, 3.6)
        parking = (u(0.3, 1.0), u(0.3, 1.0))
        sidewalk = tuple(u(1.5, 2.5) if rng.random() < 0.25 else 0.0 for _ in range(2))
        frontage = tuple(str(rng.choice(["guardrail", "none", "none", "hedge"])) for _ in range(2))
        trees = tuple(u(8.0, 16.0) if rng.random() < 0.6 else 0.0 for _ in range(2))
        lamp, setback = (u(35.0, 50.0) if rng.random() < 0.5 else 0.0), (0.0, 0.0)
    power_line = (
        int(rng.integers(0, 2))
        if kind in (ZoneKind.OPEN, ZoneKind.RESIDENTIAL) and rng.random() < 0.4
        else -1
    )
    return Profile(
        kind=kind,
        lane_width=lane_w,
        lanes_left=lanes,
        parking=parking,  # type: ignore[arg-type]
        sidewalk=sidewalk,  # type: ignore[arg-type]
        curb_height=u(0.1, 0.16),
        road_albedo=u(0.32, 0.52),
        frontage=frontage,  # type: ignore[arg-type]
        street_trees=trees,  # type: ignore[arg-type]
        lamp_spacing=lamp,
        setback=setback,
        power_line=power_line,
    )


@dataclass(frozen=True, eq=False)
class RouteFeatures:
    """What a route other than the open street adds to the street's plan (``None``, the open street,
    keeps the plan exactly as it always was, random draws included).

    ``closed``: the road is one lap of a closed street; its last zone continues into its first, so
    the cross-section does not jump where the lap's stations start again. ``self_crossings``: (station,
    station, angle in deg) where the road crosses itself; nothing is built there. ``turning_loop``:
    the centre line ``(N, 2)`` of a turning loop beyond the road's end, kept clear like a carriageway.
    ``single_zone``: one cross-section all along and no cross streets (repeated blocks).
    ``courtyard``: the buildings a short walked loop goes round and between; the road is then a
    footpath (:meth:`Profile.footpath`) in a single zone.
    """

    closed: bool = False
    self_crossings: tuple[tuple[float, float, float], ...] = ()
    turning_loop: FloatArray | None = field(default=None, repr=False)
    single_zone: bool = False
    courtyard: Courtyard | None = None


TURNING_LOOP_HALF_WIDTH = 3.5
"""Half width (m) of a turning loop's carriageway (one lane and a shoulder)."""
JUNCTION_MARGIN = 3.0
"""Metres kept free beyond the other branch's outer edge where a road crosses itself."""
FLAT_RAMP = 15.0
"""Metres over which the camber fades out towards a junction of a road with itself or its turning loop."""
CAMBER = 0.015
"""Cross-fall of the carriageway from its crown to the curbs (1.5 %, a typical road design value)."""
ROUGHNESS = np.array([0.3, 0.5, 0.4, 1.0])
"""Scale of the off-road bumps per :class:`ZoneKind` (yards are flatter than fields)."""


class StreetLayout:
    """Where the street changes character, where cross streets are, and what is road where.

    Every road (the driven one and the cross-street arms) is a set of samples carrying its
    cross-section; the nearest sample tells for any point how far it is from a carriageway, which is
    how objects keep off the road even where the road turns sharply or passes itself again.
    """

    def __init__(
        self,
        road: Road,
        terrain: Terrain,
        rng: np.random.Generator,
        style: SceneStyle,
        features: RouteFeatures | None = None,
    ) -> None:
        self.road = road
        self.terrain = terrain
        self.style = style
        self.features = features
        self.junctions: list[tuple[float, float]] = []
        """(station, half length) of stretches where the road crosses itself: nothing is built there."""
        self._flat_spots: list[tuple[FloatArray, float]] = []
        self._road_tree: cKDTree | None = None
        if features is None:
            self._make_zones(rng)
        else:
            self._make_route_zones(rng, features)
        self._make_samples()

    # -- zones and intersections
    def _make_zones(self, rng: np.random.Generator) -> None:
        style = self.style
        kinds = list(style.zone_weights)
        weights = np.array(list(style.zone_weights.values()))

        def draw_profile() -> Profile:
            kind = ZoneKind(kinds[int(rng.choice(len(kinds), p=weights))])
            profile = random_profile(rng, kind)
            return style.adjust(rng, profile) if style.adjust else profile

        starts, profiles = [0.0], [draw_profile()]
        crossings, half_widths = [], []
        s = PREROLL + rng.uniform(30.0, 120.0)
        while s < self.road.length - 60.0:
            _, _, curvature = self.road.sample(np.arange(s - 25.0, s + 25.0, 5.0))
            if np.max(np.abs(curvature)) < 1.0 / 80.0:
                if style.crossings:
                    crossings.append(s)
                    half_widths.append(rng.uniform(*style.crossing_half_width))
                if rng.random() < 0.6:
                    starts.append(s)
                    profiles.append(draw_profile())
            s += rng.uniform(*style.crossing_gap)
        self.zone_starts = np.array(starts)
        self.profiles = profiles
        self.crossings = np.array(crossings)
        self.crossing_half_widths = np.array(half_widths)

    def _draw_profile(self, rng: np.random.Generator, with_buildings: bool = False) -> Profile:
        """A profile of a zone kind drawn by the style's weights (``with_buildings``: not open land,
        where the style has any other kind)."""
        kinds = list(self.style.zone_weights)
        weights = np.array(list(self.style.zone_weights.values()))
        if with_buildings and weights[[k != ZoneKind.OPEN for k in kinds]].sum() > 0:
            weights = np.where([k == ZoneKind.OPEN for k in kinds], 0.0, weights)
        kind = ZoneKind(kinds[int(rng.choice(len(kinds), p=weights / weights.sum()))])
        profile = random_profile(rng, kind)
        return self.style.adjust(rng, profile) if self.style.adjust else profile

    def _make_route_zones(self, rng: np.random.Generator, features: RouteFeatures) -> None:
        """Zones and cross streets for a route's road: as on the open street, but on a lap from its
        first metres on and continuous across its seam, none within 60 m of where the road crosses
        itself, and a single zone without cross streets for repeated blocks."""
        style = self.style
        courtyard = features.courtyard
        first = self._draw_profile(rng, with_buildings=features.single_zone or courtyard is not None)
        starts, profiles = [0.0], [first if courtyard is None else first.footpath(courtyard.side)]
        crossings: list[float] = []
        half_widths: list[float] = []
        own = [station for crossing in features.self_crossings for station in crossing[:2]]
        s = (0.0 if features.closed else PREROLL) + rng.uniform(30.0, 120.0)
        single_zone = features.single_zone or courtyard is not None
        while not single_zone and s < self.road.length - 60.0:
            _, _, curvature = self.road.sample(np.arange(s - 25.0, s + 25.0, 5.0))
            clear = all(self._apart(s, station) >= 60.0 for station in own)
            if clear and np.max(np.abs(curvature)) < 1.0 / 80.0:
                if style.crossings:
                    crossings.append(s)
                    half_widths.append(rng.uniform(*style.crossing_half_width))
                if rng.random() < 0.6:
                    starts.append(s)
                    profiles.append(self._draw_profile(rng))
            s += rng.uniform(*style.crossing_gap)
        if features.closed and len(profiles) > 1:
            profiles[-1] = profiles[0]
        self.zone_starts = np.array(starts)
        self.profiles = profiles
        self.crossings = np.array(crossings)
        self.crossing_half_widths = np.array(half_widths)
        for first, second, angle in features.self_crossings:
            self._add_junction(first, second, math.radians(angle))

    def _apart(self, a: float, b: float) -> float:
        """Distance between two stations along the road (round the lap when it is closed)."""
        gap = abs(a - b)
        return min(gap, self.road.length - gap) if self.features and self.features.closed else gap

    def _add_junction(self, first: float, second: float, angle: float) -> None:
        """Keep both branches of a self-crossing free over the other branch's full width."""
        width = [max(self.profile_at(s).outer(0), self.profile_at(s).outer(1)) for s in (first, second)]
        sin, cos = max(abs(math.sin(angle)), 0.3), abs(math.cos(angle))
        for station, own, other in ((first, width[0], width[1]), (second, width[1], width[0])):
            self.junctions.append((station, (other + own * cos) / sin + JUNCTION_MARGIN))
        xy, _, _ = self.road.sample([first])
        self._flat_spots.append((xy[0], max(half for _, half in self.junctions[-2:])))

    def profile_at(self, station: float) -> Profile:
        return self.profiles[int(np.searchsorted(self.zone_starts, station, side="right")) - 1]

    def gaps(self, s0: float, s1: float, margin: float) -> list[tuple[float, float]]:
        """Station intervals around cross streets in [s0, s1) where road-side objects must not stand."""
        out = []
        for s, hw in zip(self.crossings, self.crossing_half_widths, strict=True):
            lo, hi = s - hw - margin - 3.0, s + hw + margin + 3.0
            if hi > s0 and lo < s1:
                out.append((lo, hi))
        for s, half in self.junctions:
            lo, hi = s - half - margin, s + half + margin
            if hi > s0 and lo < s1:
                out.append((lo, hi))
        return out

    def free_intervals(self, s0: float, s1: float, margin: float = 0.0) -> list[tuple[float, float]]:
        """The parts of [s0, s1) between cross streets: each lies within one zone."""
        intervals, cursor = [], s0
        for lo, hi in sorted(self.gaps(s0, s1, margin)):
            if lo > cursor:
                intervals.append((cursor, min(lo, s1)))
            cursor = max(cursor, hi)
        if cursor < s1:
            intervals.append((cursor, s1))
        return intervals

    # -- the nearest-road lookup
    def _make_samples(self) -> None:
        stations = np.arange(len(self.road.xy)) * ROAD_STEP
        zone = np.searchsorted(self.zone_starts, stations, side="right") - 1
        edges_by_zone = np.array(
            [[[p.lane_edge(side), p.curb(side), p.outer(side)] for side in (0, 1)] for p in self.profiles]
        )
        xy = [self.road.xy]
        tangent = [np.stack([np.cos(self.road.heading), np.sin(self.road.heading)], 1)]
        edges = [edges_by_zone[zone]]
        kinds = [np.array([p.kind for p in self.profiles])[zone]]
        albedo = [np.array([p.road_albedo for p in self.profiles])[zone]]
        for s, hw in zip(self.crossings, self.crossing_half_widths, strict=True):
            profile = self.profile_at(s)
            centre, heading, _ = self.road.sample([s])
            normal = np.array([-math.sin(heading[0]), math.cos(heading[0])])
            for side, sign in ((0, -1.0), (1, 1.0)):
                dist = np.arange(profile.curb(side), 110.0, ROAD_STEP)
                if self.features is not None:
                    dist = self._clip_arm(s, centre[0], sign * normal, dist, hw)
                xy.append(centre + sign * dist[:, None] * normal)
                tangent.append(np.tile(sign * normal, (len(dist), 1)))
                sidewalk = hw + 2.5
                edges.append(np.tile([[hw, hw, sidewalk], [hw, hw, sidewalk]], (len(dist), 1, 1)))
                kinds.append(np.full(len(dist), profile.kind))
                albedo.append(np.full(len(dist), profile.road_albedo))
        rounded = sum(len(part) for part in xy)
        if self.features is not None and self.features.turning_loop is not None:
            self._add_turning_loop(self.features.turning_loop, xy, tangent, edges, kinds, albedo)
        self.sample_xy = np.concatenate(xy)
        self._rounded_end = np.arange(len(self.sample_xy)) < rounded
        self.sample_tangent = np.concatenate(tangent)
        self.sample_edges = np.concatenate(edges)
        self.sample_kind = np.concatenate(kinds)
        self.sample_albedo = np.concatenate(albedo)
        self._tree = cKDTree(self.sample_xy)

    def _clip_arm(
        self, station: float, centre: FloatArray, direction: FloatArray, dist: FloatArray, half_width: float
    ) -> FloatArray:
        """A cross-street arm's distances up to where it would come near another part of the road
        (a loop's far side, the other lobe of a figure eight): arms end before they run into it."""
        if self._road_tree is None:
            self._road_tree = cKDTree(self.road.xy)
        widest = max(max(p.outer(0), p.outer(1)) for p in self.profiles)
        reach = half_width + widest + JUNCTION_MARGIN
        points = centre + dist[:, None] * direction
        for k, near in enumerate(self._road_tree.query_ball_point(points, reach)):
            if any(self._apart(i * ROAD_STEP, station) > reach + 30.0 for i in near):
                return dist[:k]
        return dist

    def _add_turning_loop(
        self,
        loop: FloatArray,
        xy: list[FloatArray],
        tangent: list[FloatArray],
        edges: list[FloatArray],
        kinds: list[NDArray[np.int64]],
        albedo: list[FloatArray],
    ) -> None:
        """Samples of a turning loop beyond the road's end (every ROAD_STEP metres of its centre
        line), as a carriageway of its own; its camber fades out where it meets the road."""
        along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(loop, axis=0), axis=1))])
        at = np.arange(0.0, along[-1], ROAD_STEP)
        points = np.column_stack([np.interp(at, along, loop[:, 0]), np.interp(at, along, loop[:, 1])])
        step = np.gradient(points, axis=0)
        profile = self.profile_at(self.road.length)
        hw = TURNING_LOOP_HALF_WIDTH
        xy.append(points)
        tangent.append(step / np.linalg.norm(step, axis=1, keepdims=True))
        edges.append(np.tile([[hw, hw, hw + 1.0], [hw, hw, hw + 1.0]], (len(points), 1, 1)))
        kinds.append(np.full(len(points), profile.kind))
        albedo.append(np.full(len(points), profile.road_albedo))
        mouth = 0.5 * (loop[0] + loop[-1])
        self._flat_spots.append((mouth, 0.5 * float(np.linalg.norm(loop[-1] - loop[0])) + FLAT_RAMP + hw))

    def nearest(self, xy: ArrayLike) -> tuple[FloatArray, NDArray[np.int64]]:
        """Signed offset (left positive) from the nearest road's centre line, and that sample's index.

        On a route's plan the street's and its cross streets' ends are rounded off: beyond the last
        sample the distance is to that sample, not to the line through it (the open street keeps its
        original lookup). A turning loop's ends are not: they lie on the street's lanes, and the lane
        beyond them is carriageway."""
        xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        _, index = self._tree.query(xy)
        rel = xy - self.sample_xy[index]
        t = self.sample_tangent[index]
        signed = t[:, 0] * rel[:, 1] - t[:, 1] * rel[:, 0]
        if self.features is not None:
            along = np.abs(t[:, 0] * rel[:, 0] + t[:, 1] * rel[:, 1])
            beyond = np.where(self._rounded_end[index], np.maximum(along - ROAD_STEP, 0.0), 0.0)
            signed = np.where(signed < 0.0, -1.0, 1.0) * np.hypot(signed, beyond)
        return signed, index

    def lateral(self, xy: ArrayLike) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
        """Distance from the nearest road's centre line, that road's (lane edge, curb, outer) on
        the point's side ``(N, 3)``, and the index of the nearest sample."""
        signed, index = self.nearest(xy)
        side = (signed > 0).astype(np.int64)
        return np.abs(signed), self.sample_edges[index, side], index

    def is_clear(self, xy: ArrayLike, level: int, tolerance: float = 0.25) -> bool:
        """True when no point is inside a road's lane (level 0), carriageway (1) or sidewalk (2)."""
        distance, edges, _ = self.lateral(xy)
        return bool(np.all(distance >= edges[:, level] - tolerance))

    def ground_height(self, xy: ArrayLike) -> FloatArray:
        """Terrain height: hills and ripples everywhere, the road's camber (its crown is higher, so
        rain runs to the curbs), and bumps that fade in away from the road."""
        xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        signed, index = self.nearest(xy)
        curbs = self.sample_edges[index, :, 1]  # right, left
        crown, half_width = 0.5 * (curbs[:, 1] - curbs[:, 0]), 0.5 * (curbs[:, 1] + curbs[:, 0])
        camber = -CAMBER * np.minimum(np.abs(signed - crown), half_width)
        for centre, radius in self._flat_spots:
            fade = np.clip((np.linalg.norm(xy - centre, axis=1) - radius) / FLAT_RAMP, 0.0, 1.0)
            camber = camber * fade * fade * (3.0 - 2.0 * fade)
        outer = self.sample_edges[index, (signed > 0).astype(np.int64), 2]
        weight = np.clip((np.abs(signed) - outer - 3.0) / 12.0, 0.0, 1.0)
        weight = weight * weight * (3.0 - 2.0 * weight)
        bumps = weight * ROUGHNESS[self.sample_kind[index]] * self.terrain.bumps(xy)
        return self.terrain.base_height(xy) + self.terrain.ripples(xy) + camber + bumps
