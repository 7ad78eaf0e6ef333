"""Procedural street scene for the synthetic LiDAR (``vcr-odom synth``).

The scene is laid out around a road: a smooth centre line (the path the car drives), a hilly ground
heightfield, and the things that make real streets registrable: facades with recesses, windows and
balconies, poles and signs, parked cars, trees, hedges, walls and fences. Four kinds of street
(urban, residential, industrial, open) alternate at intersections so that a network trained on it
sees the variety of KITTI's drives rather than one repeated corridor. A scene style (:data:`SCENES`:
suburban, avenue, highway, oldtown) changes the mix, the cross-sections and how the road bends.

Everything is a pure function of the seed. Geometry is generated lazily in chunks (50 m blocks of
road-side objects, 64 m squares of ground) so that a long drive only ever holds what the sensor can
reach; a chunk's content never depends on which other chunks were built before it.
"""

from __future__ import annotations

import itertools
import math
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from enum import IntEnum
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from vcr_odom.errors import ConfigError

FloatArray = NDArray[np.float64]

ROAD_STEP = 0.5
"""Spacing (m) of the road's centre-line samples: fine enough that nearest-sample offsets are exact to mm."""
BLOCK_LENGTH = 50.0
"""Road-side objects are generated per 50 m of road: small enough to load only what is in range."""
TILE_SIZE = 64.0
GROUND_STEP = 2.0
"""Ground grid spacing (m): the hills are smooth (wavelengths >= 120 m), so 2 m facets are exact to mm."""
REACH = 90.0
"""Furthest any road-side object reaches from the road centre line (m); bounds each block's extent."""
ROAD_CHUNK = 1000.0
"""The road is generated in whole kilometres, so a short sequence is a prefix of a longer one."""
PREROLL = 150.0
"""Road before the first frame, so the sensor sees a street behind it too."""


class Surface(IntEnum):
    """What a triangle is made of: it sets reflectance and how the sensor sees it (glass, leaves)."""

    ROAD = 0
    PAINT = 1
    SIDEWALK = 2
    TERRAIN = 3
    WALL = 4
    GLASS = 5
    ROOF = 6
    VEGETATION = 7
    WOOD = 8
    METAL = 9
    SIGN = 10
    CAR = 11
    CAR_GLASS = 12
    RUBBER = 13


class ZoneKind(IntEnum):
    URBAN = 0
    RESIDENTIAL = 1
    INDUSTRIAL = 2
    OPEN = 3


# ----------------------------------------------------------------------------------------------
# Meshes


@dataclass
class MeshPart:
    """Triangles with a surface kind and an albedo per triangle (what the sensor needs per hit)."""

    vertices: FloatArray
    triangles: NDArray[np.int64]
    surface: NDArray[np.uint8]
    albedo: NDArray[np.float32]

    @staticmethod
    def empty() -> MeshPart:
        return MeshPart(
            np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.uint8), np.zeros(0, np.float32)
        )

    @staticmethod
    def concatenate(parts: list[MeshPart]) -> MeshPart:
        """One mesh from several, in the given order (so the result is deterministic)."""
        parts = [p for p in parts if len(p.triangles)]
        if not parts:
            return MeshPart.empty()
        offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
        return MeshPart(
            np.concatenate([p.vertices for p in parts]),
            np.concatenate([p.triangles + o for p, o in zip(parts, offsets, strict=True)]),
            np.concatenate([p.surface for p in parts]),
            np.concatenate([p.albedo for p in parts]),
        )

    def __len__(self) -> int:
        return len(self.triangles)


# Hexahedron corners: bottom face 0-3 counter-clockwise seen from above, top face 4-7 above them.
_HEX_FACES = np.array(
    [[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7]]
    + [[i, (i + 1) % 4, 4 + (i + 1) % 4] for i in range(4)]
    + [[i, 4 + (i + 1) % 4, 4 + i] for i in range(4)],
    dtype=np.int64,
)


@lru_cache(maxsize=4)
def _icosphere(subdivisions: int) -> tuple[FloatArray, NDArray[np.int64]]:
    """Unit icosphere (vertices, faces); the base of blobby crowns and bushes."""
    phi = (1.0 + math.sqrt(5.0)) / 2.0
    verts = [
        (-1, phi, 0), (1, phi, 0), (-1, -phi, 0), (1, -phi, 0),
        (0, -1, phi), (0, 1, phi), (0, -1, -phi), (0, 1, -phi),
        (phi, 0, -1), (phi, 0, 1), (-phi, 0, -1), (-phi, 0, 1),
    ]  # fmt: skip
    faces = [
        (0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11),
        (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6), (7, 1, 8),
        (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9),
        (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1),
    ]  # fmt: skip
    vertices = [np.array(v, dtype=np.float64) / np.linalg.norm(v) for v in verts]
    for _ in range(subdivisions):
        midpoints: dict[tuple[int, int], int] = {}
        new_faces = []
        for a, b, c in faces:
            ab, bc, ca = (_midpoint(vertices, midpoints, x, y) for x, y in ((a, b), (b, c), (c, a)))
            new_faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new_faces
    return np.array(vertices), np.array(faces, dtype=np.int64)


def _midpoint(vertices: list[FloatArray], cache: dict[tuple[int, int], int], a: int, b: int) -> int:
    """Index of the unit-sphere midpoint of edge (a, b), shared by the two faces that use it."""
    key = (min(a, b), max(a, b))
    if key not in cache:
        m = vertices[a] + vertices[b]
        vertices.append(m / np.linalg.norm(m))
        cache[key] = len(vertices) - 1
    return cache[key]


class MeshBuilder:
    """Collects primitives (boxes, cylinders, blobs) into one :class:`MeshPart`."""

    def __init__(self) -> None:
        self._parts: list[MeshPart] = []

    def add(self, vertices: ArrayLike, triangles: ArrayLike, surface: int, albedo: float) -> None:
        tris = np.asarray(triangles, dtype=np.int64)
        self._parts.append(
            MeshPart(
                np.asarray(vertices, dtype=np.float64),
                tris,
                np.full(len(tris), surface, np.uint8),
                np.full(len(tris), albedo, np.float32),
            )
        )

    def add_part(self, part: MeshPart) -> None:
        self._parts.append(part)

    def hexahedron(self, corners: ArrayLike, surface: int, albedo: float) -> None:
        """Eight corners (bottom 4 then top 4): boxes, slabs, sloped car cabins, curved wall pieces."""
        self.add(corners, _HEX_FACES, surface, albedo)

    def quad(self, corners: ArrayLike, surface: int, albedo: float) -> None:
        self.add(corners, [[0, 1, 2], [0, 2, 3]], surface, albedo)

    def cylinder(
        self,
        base: ArrayLike,
        axis: ArrayLike,
        radius: float,
        length: float,
        surface: int,
        albedo: float,
        sides: int = 8,
        top_radius: float | None = None,
    ) -> None:
        """A capped cylinder or cone (``top_radius=0``) along ``axis``: poles, trunks, wheels, conifers."""
        axis = np.asarray(axis, dtype=np.float64)
        axis = axis / np.linalg.norm(axis)
        helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = np.cross(axis, helper)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis, e1)
        angles = np.arange(sides) * (2.0 * math.pi / sides)
        ring = np.outer(np.cos(angles), e1) + np.outer(np.sin(angles), e2)
        top_r = radius if top_radius is None else top_radius
        base = np.asarray(base, dtype=np.float64)
        bottom = base + radius * ring
        top = base + axis * length + top_r * ring
        centres = np.stack([base, base + axis * length])
        vertices = np.concatenate([bottom, top, centres])
        i = np.arange(sides)
        j = (i + 1) % sides
        tris = np.concatenate(
            [
                np.stack([i, j, sides + j], 1),
                np.stack([i, sides + j, sides + i], 1),
                np.stack([np.full(sides, 2 * sides), j, i], 1),
                np.stack([np.full(sides, 2 * sides + 1), sides + i, sides + j], 1),
            ]
        )
        self.add(vertices, tris, surface, albedo)

    def blob(
        self,
        centre: ArrayLike,
        radii: ArrayLike,
        rng: np.random.Generator,
        surface: int,
        albedo: float,
        roughness: float = 0.25,
        subdivisions: int = 1,
    ) -> None:
        """A lumpy ellipsoid: tree crowns and bushes are irregular, never spheres."""
        unit, faces = _icosphere(subdivisions)
        directions = rng.normal(size=(4, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        freq = rng.uniform(1.5, 4.0, 4)
        phase = rng.uniform(0.0, 2.0 * math.pi, 4)
        lumps = np.sin((unit @ directions.T) * freq + phase).mean(axis=1)
        scale = 1.0 + roughness * lumps + rng.uniform(-0.3, 0.3, len(unit)) * roughness * 0.3
        vertices = np.asarray(centre) + unit * scale[:, None] * np.asarray(radii)
        self.add(vertices, faces, surface, albedo)

    def build(self) -> MeshPart:
        return MeshPart.concatenate(self._parts)


# ----------------------------------------------------------------------------------------------
# Terrain and road


@dataclass(frozen=True)
class Terrain:
    """Smooth hills (a tilt plus long plane waves), centimetre ripples, and rougher ground off the road.

    Roads follow :meth:`base_height` plus :meth:`ripples` (an uneven surface that makes the car pitch
    and roll a little, as on real roads); yards, fields and verges add :meth:`bumps`.
    """

    tilt: FloatArray
    wave_vectors: FloatArray
    wave_amplitudes: FloatArray
    wave_phases: FloatArray
    bump_vectors: FloatArray
    bump_amplitudes: FloatArray
    bump_phases: FloatArray
    ripple_vectors: FloatArray
    ripple_amplitudes: FloatArray
    ripple_phases: FloatArray

    @staticmethod
    def random(rng: np.random.Generator) -> Terrain:
        """Grades up to about 6 %: a 0-2 % tilt plus four waves of 120-600 m wavelength."""
        tilt_angle = rng.uniform(0.0, 2.0 * math.pi)
        tilt = rng.uniform(0.0, 0.02) * np.array([math.cos(tilt_angle), math.sin(tilt_angle)])

        def waves(count: int, wavelengths: tuple[float, float], grade: tuple[float, float]):
            angle = rng.uniform(0.0, 2.0 * math.pi, count)
            wavelength = rng.uniform(*wavelengths, count)
            k = (2.0 * math.pi / wavelength)[:, None] * np.stack([np.cos(angle), np.sin(angle)], 1)
            amplitude = rng.uniform(*grade, count) * wavelength / (2.0 * math.pi)
            return k, amplitude, rng.uniform(0.0, 2.0 * math.pi, count)

        wk, wa, wp = waves(4, (120.0, 600.0), (0.004, 0.012))
        bk, ba, bp = waves(4, (12.0, 45.0), (0.03, 0.08))
        rk, ra, rp = waves(3, (5.0, 16.0), (0.003, 0.007))
        return Terrain(tilt, wk, wa, wp, bk, ba, bp, rk, ra, rp)

    def base_height(self, xy: ArrayLike) -> FloatArray:
        xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        return xy @ self.tilt + np.sin(xy @ self.wave_vectors.T + self.wave_phases) @ self.wave_amplitudes

    def bumps(self, xy: ArrayLike) -> FloatArray:
        xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        return np.sin(xy @ self.bump_vectors.T + self.bump_phases) @ self.bump_amplitudes

    def ripples(self, xy: ArrayLike) -> FloatArray:
        xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        return np.sin(xy @ self.ripple_vectors.T + self.ripple_phases) @ self.ripple_amplitudes


@dataclass(frozen=True)
class Road:
    """The driven centre line, sampled every :data:`ROAD_STEP` metres from station 0."""

    xy: FloatArray
    heading: FloatArray
    curvature: FloatArray

    @property
    def length(self) -> float:
        return (len(self.xy) - 1) * ROAD_STEP

    def sample(self, stations: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Position ``(N, 2)``, heading and curvature at arbitrary stations (linear interpolation)."""
        s = np.clip(np.atleast_1d(np.asarray(stations, dtype=np.float64)), 0.0, self.length) / ROAD_STEP
        i = np.minimum(s.astype(np.int64), len(self.xy) - 2)
        f = s - i
        xy = self.xy[i] * (1.0 - f)[:, None] + self.xy[i + 1] * f[:, None]
        heading = self.heading[i] * (1.0 - f) + self.heading[i + 1] * f
        curvature = self.curvature[i] * (1.0 - f) + self.curvature[i + 1] * f
        return xy, heading, curvature

    def offset(self, stations: ArrayLike, lateral: ArrayLike) -> FloatArray:
        """Points ``lateral`` metres left (negative: right) of the centre line at ``stations``."""
        xy, heading, _ = self.sample(stations)
        normal = np.stack([-np.sin(heading), np.cos(heading)], 1)
        return xy + normal * np.asarray(lateral, dtype=np.float64).reshape(-1, 1)


def _smooth(values: FloatArray, sigma_samples: float) -> FloatArray:
    """Gaussian smoothing with edge padding: turns piecewise curvature into clothoid-like transitions."""
    half = int(3 * sigma_samples)
    kernel = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma_samples) ** 2)
    kernel /= kernel.sum()
    padded = np.pad(values, half, mode="edge")
    return np.convolve(padded, kernel, mode="valid")


@dataclass(frozen=True)
class RoadShape:
    """How a road bends (metres, degrees): straights, then either a sharp (intersection-like) turn
    with probability ``sharp_prob`` or a gentle bend. The defaults are the suburban street."""

    straight: tuple[float, float] = (40.0, 220.0)
    sharp_prob: float = 0.45
    sharp_angle: tuple[float, float] = (60.0, 100.0)
    sharp_radius: tuple[float, float] = (16.0, 35.0)
    gentle_angle: tuple[float, float] = (10.0, 45.0)
    gentle_radius: tuple[float, float] = (60.0, 300.0)


def make_road(rng: np.random.Generator, length: float, shape: RoadShape = RoadShape()) -> Road:
    """Straights with slight drift, gentle bends and sharp (intersection-like) turns, smoothly joined.

    Segments are drawn one after another, so a longer road starts exactly like a shorter one.
    """
    n = math.ceil(length / ROAD_STEP) + 1
    pieces: list[FloatArray] = [np.zeros(int(PREROLL / ROAD_STEP) + 60)]
    total = len(pieces[0])
    while total < n + 100:
        straight = rng.uniform(*shape.straight)
        pieces.append(np.full(int(straight / ROAD_STEP), rng.normal(0.0, 1.0 / 1500.0)))
        if rng.random() < shape.sharp_prob:
            angle, radius = math.radians(rng.uniform(*shape.sharp_angle)), rng.uniform(*shape.sharp_radius)
        else:
            angle, radius = math.radians(rng.uniform(*shape.gentle_angle)), rng.uniform(*shape.gentle_radius)
        sign = 1.0 if rng.random() < 0.5 else -1.0
        pieces.append(np.full(max(1, int(radius * angle / ROAD_STEP)), sign / radius))
        total = sum(len(p) for p in pieces)
    curvature = _smooth(np.concatenate(pieces), sigma_samples=6.0 / ROAD_STEP)[:n]
    heading = np.concatenate([[0.0], np.cumsum(0.5 * (curvature[1:] + curvature[:-1]) * ROAD_STEP)])
    mid = heading[:-1] + 0.5 * np.diff(heading)
    steps = np.stack([np.cos(mid), np.sin(mid)], 1) * ROAD_STEP
    xy = np.concatenate([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    return Road(xy, heading, curvature)


# ----------------------------------------------------------------------------------------------
# Street layout: zones, cross-sections, intersections


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


def _random_profile(rng: np.random.Generator, kind: ZoneKind) -> Profile:
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


ZONE_WEIGHTS = {
    ZoneKind.URBAN: 0.35,
    ZoneKind.RESIDENTIAL: 0.35,
    ZoneKind.INDUSTRIAL: 0.15,
    ZoneKind.OPEN: 0.15,
}
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
        self, road: Road, terrain: Terrain, rng: np.random.Generator, style: SceneStyle | None = None
    ) -> None:
        self.road = road
        self.terrain = terrain
        self.style = style or SCENES["suburban"]
        self._make_zones(rng)
        self._make_samples()

    # -- zones and intersections
    def _make_zones(self, rng: np.random.Generator) -> None:
        style = self.style
        kinds = list(style.zone_weights)
        weights = np.array(list(style.zone_weights.values()))

        def draw_profile() -> Profile:
            kind = ZoneKind(kinds[int(rng.choice(len(kinds), p=weights))])
            profile = _random_profile(rng, kind)
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

    def profile_at(self, station: float) -> Profile:
        return self.profiles[int(np.searchsorted(self.zone_starts, station, side="right")) - 1]

    def gaps(self, s0: float, s1: float, margin: float) -> list[tuple[float, float]]:
        """Station intervals around cross streets in [s0, s1) where road-side objects must not stand."""
        out = []
        for s, hw in zip(self.crossings, self.crossing_half_widths, strict=True):
            lo, hi = s - hw - margin - 3.0, s + hw + margin + 3.0
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
                xy.append(centre + sign * dist[:, None] * normal)
                tangent.append(np.tile(sign * normal, (len(dist), 1)))
                sidewalk = hw + 2.5
                edges.append(np.tile([[hw, hw, sidewalk], [hw, hw, sidewalk]], (len(dist), 1, 1)))
                kinds.append(np.full(len(dist), profile.kind))
                albedo.append(np.full(len(dist), profile.road_albedo))
        self.sample_xy = np.concatenate(xy)
        self.sample_tangent = np.concatenate(tangent)
        self.sample_edges = np.concatenate(edges)
        self.sample_kind = np.concatenate(kinds)
        self.sample_albedo = np.concatenate(albedo)
        self._tree = cKDTree(self.sample_xy)

    def nearest(self, xy: ArrayLike) -> tuple[FloatArray, NDArray[np.int64]]:
        """Signed offset (left positive) from the nearest road's centre line, and that sample's index."""
        xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        _, index = self._tree.query(xy)
        rel = xy - self.sample_xy[index]
        t = self.sample_tangent[index]
        return t[:, 0] * rel[:, 1] - t[:, 1] * rel[:, 0], index

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
        outer = self.sample_edges[index, (signed > 0).astype(np.int64), 2]
        weight = np.clip((np.abs(signed) - outer - 3.0) / 12.0, 0.0, 1.0)
        weight = weight * weight * (3.0 - 2.0 * weight)
        bumps = weight * ROUGHNESS[self.sample_kind[index]] * self.terrain.bumps(xy)
        return self.terrain.base_height(xy) + self.terrain.ripples(xy) + camber + bumps


# ----------------------------------------------------------------------------------------------
# Road-side objects, one block of road at a time


class _Block:
    """Builds the road-side content of one block of road (both sides) into a mesh."""

    def __init__(self, layout: StreetLayout, index: int, rng: np.random.Generator) -> None:
        self.layout = layout
        self.road = layout.road
        self.rng = rng
        self.mesh = MeshBuilder()
        self.s0 = index * BLOCK_LENGTH
        self.s1 = min(self.s0 + BLOCK_LENGTH, self.road.length)

    # -- helpers
    def ground(self, xy: ArrayLike) -> FloatArray:
        return self.layout.ground_height(xy)

    def frame(self, station: float, lateral: float, yaw_offset: float = 0.0) -> _Frame:
        xy, heading, _ = self.road.sample([station])
        normal = np.array([-math.sin(heading[0]), math.cos(heading[0])])
        return _Frame(xy[0] + lateral * normal, float(heading[0]) + yaw_offset)

    def strip(
        self,
        sa: float,
        sb: float,
        d_in: float,
        d_out: float,
        z_lo: float,
        z_hi: float,
        surface: Surface,
        albedo: float,
    ) -> None:
        """A slab following the road's curve between two stations (sidewalks, walls, hedges, rails)."""
        stations = np.array([sa, sb, sb, sa])
        lateral = np.array([d_in, d_in, d_out, d_out])
        xy = self.road.offset(stations, lateral)
        g = self.ground(xy)
        corners = np.concatenate([np.column_stack([xy, g + z_lo]), np.column_stack([xy, g + z_hi])], axis=0)
        self.mesh.hexahedron(corners, surface, albedo)

    def along(
        self, step: float, lo: float, hi: float, jitter: float = 0.0, offset: float = 0.0
    ) -> list[float]:
        """Stations in [lo, hi) every ``step`` metres on a grid fixed to the road (so spacing continues
        across blocks), each moved by up to ``jitter``."""
        first = math.ceil((lo - offset) / step) * step + offset
        return [
            float(s + self.rng.uniform(-jitter, jitter)) if jitter else float(s)
            for s in np.arange(first, hi, step)
        ]

    # -- the whole block
    def build(self) -> MeshPart:
        for lo, hi in self.layout.free_intervals(self.s0, self.s1):
            profile = self.layout.profile_at(0.5 * (lo + hi))
            self.lane_markings(lo, hi, profile)
            if profile.median > 0.0:
                self.median(lo, hi, profile)
            for side in (0, 1):
                self.sidewalk(lo, hi, side, profile)
                self.frontage(lo, hi, side, profile)
                self.parked_cars(lo, hi, side, profile)
                self.buildings(lo, hi, side, profile)
                self.yards(lo, hi, side, profile)
                self.street_furniture(lo, hi, side, profile)
        self.intersection_furniture()
        return self.mesh.build()

    # -- road surface details
    def lane_markings(self, lo: float, hi: float, profile: Profile) -> None:
        """Dashed lines between lanes and solid edge lines: bright paint the sensor sees in reflectance."""
        albedo = float(self.rng.uniform(0.6, 0.85))
        for d in profile.lane_lines():
            for s in np.arange(math.ceil(lo / 9.0) * 9.0, hi - 3.0, 9.0):
                self.strip(s, s + 3.0, d - 0.06, d + 0.06, -0.05, 0.012, Surface.PAINT, albedo)
        if profile.kind in (ZoneKind.OPEN, ZoneKind.INDUSTRIAL):
            for side, sign in ((0, -1.0), (1, 1.0)):
                d = sign * (profile.curb(side) - 0.35)
                for s in np.arange(lo, hi - 0.5, 6.0):
                    self.strip(s, min(s + 6.0, hi), d - 0.07, d + 0.07, -0.05, 0.012, Surface.PAINT, albedo)

    def median(self, lo: float, hi: float, profile: Profile) -> None:
        """The strip between the two directions: a concrete barrier, or a raised lawn with trees."""
        rng = self.rng
        a, b = profile.median_span()
        centre = 0.5 * (a + b)
        if profile.median_kind == "barrier":
            albedo = float(rng.uniform(0.3, 0.5))
            for s in np.arange(lo, hi - 0.2, 4.0):
                self.strip(s, min(s + 4.0, hi), centre - 0.3, centre + 0.3, -0.2, 0.85, Surface.WALL, albedo)
            return
        albedo = float(rng.uniform(0.35, 0.5))
        for s in np.arange(lo, hi - 0.2, 4.0):
            self.strip(s, min(s + 4.0, hi), a, b, -0.3, profile.curb_height, Surface.TERRAIN, albedo)
        for s in self.along(float(rng.uniform(7.0, 12.0)), lo, hi, jitter=1.0):
            _tree(self, self.road.offset([s], [centre])[0], rng.uniform(0.8, 1.1))

    def sidewalk(self, lo: float, hi: float, side: int, profile: Profile) -> None:
        """Raised sidewalk with its curb face, in 4 m pieces that follow the road's curve."""
        width = profile.sidewalk[side]
        if width <= 0.0:
            return
        sign = 1.0 if side else -1.0
        d_in, d_out = sign * profile.curb(side), sign * profile.outer(side)
        albedo = float(self.rng.uniform(0.25, 0.4))
        for s in np.arange(lo, hi - 0.2, 4.0):
            sb = min(s + 4.0, hi)
            probe = self.road.offset([s, sb, s, sb], [d_in, d_in, d_out, d_out])
            if self.layout.is_clear(probe, level=1, tolerance=0.3):
                self.strip(s, sb, d_in, d_out, -0.3, profile.curb_height, Surface.SIDEWALK, albedo)

    def frontage(self, lo: float, hi: float, side: int, profile: Profile) -> None:
        """What lines the outer edge of the sidewalk: hedges, low walls, fences, guard rails."""
        kind = profile.frontage[side]
        if kind == "none":
            return
        sign = 1.0 if side else -1.0
        rng = self.rng
        if kind == "guardrail":
            d = sign * (profile.curb(side) + 0.4)
            for s in np.arange(lo, hi - 0.5, 4.0):
                sb = min(s + 4.0, hi)
                if not self.layout.is_clear(self.road.offset([s, sb], [d, d]), level=1, tolerance=0.2):
                    continue
                self.strip(s, sb, d, d + sign * 0.05, 0.45, 0.75, Surface.METAL, 0.55)
                post = self.road.offset([s], [d + sign * 0.1])[0]
                z = self.ground(post)[0]
                self.mesh.cylinder([*post, z - 0.2], [0, 0, 1], 0.06, 0.95, Surface.METAL, 0.45, sides=4)
            return
        d = sign * (profile.outer(side) + rng.uniform(0.2, 1.0))
        height = {
            "hedge": rng.uniform(0.9, 1.9),
            "wall": rng.uniform(0.4, 1.3),
            "fence": rng.uniform(1.0, 2.0),
        }[kind]
        thick = {"hedge": rng.uniform(0.6, 1.1), "wall": rng.uniform(0.2, 0.35), "fence": 0.04}[kind]
        albedo = float(rng.uniform(0.35, 0.55) if kind == "hedge" else rng.uniform(0.2, 0.5))
        for s in np.arange(lo, hi - 0.5, 2.5):
            sb = min(s + 2.5, hi)
            if rng.random() < 0.08:  # gates and driveways
                continue
            probe = self.road.offset([s, sb], [d, d + sign * thick])
            if not self.layout.is_clear(probe, level=2, tolerance=0.3):
                continue
            if kind == "hedge":
                top = height + rng.uniform(-0.15, 0.15)
                self.strip(s, sb, d, d + sign * thick, -0.2, top, Surface.VEGETATION, albedo)
            elif kind == "wall":
                self.strip(s, sb, d, d + sign * thick, -0.2, height, Surface.WALL, albedo)
            else:
                post = self.road.offset([s], [d])[0]
                z = self.ground(post)[0]
                self.mesh.cylinder([*post, z - 0.2], [0, 0, 1], 0.05, height + 0.2, Surface.METAL, albedo, 4)
                for rail in (0.35 * height, 0.9 * height):
                    self.strip(s, sb, d, d + sign * thick, rail - 0.04, rail + 0.04, Surface.METAL, albedo)

    # -- cars
    def parked_cars(self, lo: float, hi: float, side: int, profile: Profile) -> None:
        """Cars parked along the curb, with gaps, in both directions on the left."""
        if profile.parking[side] < 1.8:
            return
        rng = self.rng
        sign = 1.0 if side else -1.0
        s = lo + rng.uniform(0.0, 4.0)
        while s < hi - 3.5:
            if rng.random() < 0.15:  # an empty stretch: driveway, hydrant, loading zone
                s += rng.uniform(4.0, 15.0)
                continue
            dims = _car_dimensions(rng)
            length = dims[0]
            if s + length > hi:
                break
            lateral = sign * (profile.curb(side) - dims[1] / 2.0 - rng.uniform(0.1, 0.3))
            flip = side == 1 and rng.random() < 0.7
            frame = self.frame(s + length / 2.0, lateral, math.pi if flip else 0.0)
            footprint = frame.to_world(_box_outline(length, dims[1]))
            if self.layout.is_clear(footprint, level=0, tolerance=0.0):
                _car(self, frame, dims)
            s += length + rng.uniform(0.6, 3.5)

    # -- buildings
    def buildings(self, lo: float, hi: float, side: int, profile: Profile) -> None:
        """Rows of buildings on lots along the street, in the style of the zone."""
        if profile.kind == ZoneKind.OPEN:
            return
        rng = self.rng
        style = self.layout.style.buildings.get(profile.kind, _BUILDING_STYLES[profile.kind])
        s = lo
        while s < hi - 5.0:
            if rng.random() < style.gap_prob:
                s += rng.uniform(*style.gap)
                continue
            width = rng.uniform(*style.width)
            if hi - (s + width) < 5.0:  # no sliver lot at the end of the block: the last lot takes the rest
                width = hi - s
            front = profile.outer(side) + profile.setback[side] + rng.uniform(0.0, style.setback_jitter)
            _building(self, side, s + width / 2.0, width, front, style)
            s += width + rng.uniform(*style.spacing)

    def yards(self, lo: float, hi: float, side: int, profile: Profile) -> None:
        """Trees and bushes behind the sidewalk: front yards, verges, fields."""
        rng = self.rng
        sign = 1.0 if side else -1.0
        per_100m = {ZoneKind.URBAN: 3, ZoneKind.RESIDENTIAL: 18, ZoneKind.INDUSTRIAL: 6, ZoneKind.OPEN: 25}
        count = rng.poisson(per_100m[profile.kind] * (hi - lo) / 100.0)
        near = profile.outer(side) + 0.8
        far = near + (profile.setback[side] if profile.kind != ZoneKind.OPEN else rng.uniform(10.0, 45.0))
        for _ in range(count):
            s = rng.uniform(lo, hi)
            d = sign * rng.uniform(near, max(near + 0.5, far))
            xy = self.road.offset([s], [d])
            if rng.random() < 0.45:
                radius = rng.uniform(0.4, 1.5)
                if self.layout.is_clear(xy, level=2, tolerance=-radius):
                    _bush(self, xy[0], radius)
            elif self.layout.is_clear(xy, level=2, tolerance=-1.0):
                _tree(self, xy[0], rng.uniform(0.7, 1.3))
        if profile.kind == ZoneKind.OPEN and profile.street_trees[side] > 0.0:
            d = sign * (profile.outer(side) + rng.uniform(1.5, 4.0))
            for s in self.along(profile.street_trees[side], lo, hi, jitter=1.5):
                xy = self.road.offset([s], [d])
                if self.layout.is_clear(xy, level=1, tolerance=-1.0):
                    _tree(self, xy[0], rng.uniform(0.9, 1.3))

    # -- poles, signs, clutter
    def street_furniture(self, lo: float, hi: float, side: int, profile: Profile) -> None:
        """Lamp posts on a regular spacing, street trees in the sidewalk, signs and clutter."""
        rng = self.rng
        sign = 1.0 if side else -1.0
        curb = profile.curb(side)
        walk = profile.sidewalk[side]
        if profile.lamp_spacing > 0.0:
            offset = 0.0 if side == 0 else profile.lamp_spacing / 2.0  # staggered across the street
            for s in self.along(profile.lamp_spacing, lo, hi, offset=offset):
                self._place(s, sign * (curb + (0.5 if walk else 1.2)), lambda xy, h: _lamp(self, xy, h, sign))
        spacing = profile.street_trees[side]
        if spacing > 0.0 and profile.kind != ZoneKind.OPEN and walk > 2.0:
            for s in self.along(spacing, lo, hi, jitter=1.0):
                self._place(s, sign * (curb + 1.0), lambda xy, h: _tree(self, xy, rng.uniform(0.7, 1.1)))
        if profile.power_line == side:
            d = sign * (profile.outer(side) + 3.0)
            for s in self.along(40.0, lo, hi, jitter=3.0):
                self._place(s, d, lambda xy, h: _power_pole(self, xy, h))
        clutter = {ZoneKind.URBAN: 10, ZoneKind.RESIDENTIAL: 4, ZoneKind.INDUSTRIAL: 3, ZoneKind.OPEN: 1}
        for _ in range(rng.poisson(clutter[profile.kind] * (hi - lo) / 50.0)):
            s = rng.uniform(lo, hi)
            d = curb + (rng.uniform(0.3, max(0.4, walk - 0.3)) if walk else rng.uniform(0.8, 2.5))
            kind = str(rng.choice(["sign", "sign", "bin", "bollard", "cabinet", "bench", "column", "bike"]))
            if kind == "column" and profile.kind != ZoneKind.URBAN:
                kind = "sign"
            self._place(s, sign * d, lambda xy, h, k=kind: _clutter(self, xy, h, k))

    def intersection_furniture(self) -> None:
        """Traffic lights and signs at the corners of cross streets in this block."""
        for s, hw in zip(self.layout.crossings, self.layout.crossing_half_widths, strict=True):
            if not (self.s0 <= s < self.s1):
                continue
            profile = self.layout.profile_at(s)
            for side, sign in ((0, -1.0), (1, 1.0)):
                d = sign * (profile.curb(side) + 0.6)
                for ds in (-hw - 1.5, hw + 1.5):
                    if self.rng.random() < 0.7:
                        self._place(s + ds, d, lambda xy, h, g=sign: _traffic_light(self, xy, h, g))
                    else:
                        self._place(s + ds, d, lambda xy, h: _clutter(self, xy, h, "sign"))

    def _place(self, station: float, lateral: float, make: Callable[[FloatArray, float], None]) -> None:
        """Put a small object at (station, lateral) unless that is on some road's carriageway."""
        xy = self.road.offset([station], [lateral])
        if self.layout.is_clear(xy, level=1, tolerance=0.35):
            _, heading, _ = self.road.sample([station])
            make(xy[0], float(heading[0]))


@dataclass(frozen=True)
class _Frame:
    """A plan frame at a road station: u along the road, v to the left (metres)."""

    origin: FloatArray
    yaw: float

    def to_world(self, uv: ArrayLike) -> FloatArray:
        uv = np.atleast_2d(np.asarray(uv, dtype=np.float64))
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return self.origin + np.column_stack([c * uv[:, 0] - s * uv[:, 1], s * uv[:, 0] + c * uv[:, 1]])

    def axis(self, u: float, v: float) -> FloatArray:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.array([c * u - s * v, s * u + c * v, 0.0])


def _box_outline(length: float, width: float, n: int = 3) -> FloatArray:
    """Probe points on and inside a footprint centred at the origin (for road clearance checks)."""
    u = np.linspace(-length / 2.0, length / 2.0, n)
    v = np.linspace(-width / 2.0, width / 2.0, n)
    return np.stack(np.meshgrid(u, v), -1).reshape(-1, 2)


def _rect(u0: float, u1: float, v0: float, v1: float) -> FloatArray:
    return np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]])


# -- cars ----------------------------------------------------------------------------------------


def _car_dimensions(rng: np.random.Generator) -> tuple[float, float, float, str]:
    """Length, width, height and body style: hatchbacks to vans, like a German street."""
    style = str(rng.choice(["hatch", "sedan", "sedan", "wagon", "suv", "van"]))
    length, width, height = {
        "hatch": (rng.uniform(3.6, 4.2), rng.uniform(1.65, 1.8), rng.uniform(1.42, 1.55)),
        "sedan": (rng.uniform(4.3, 4.9), rng.uniform(1.75, 1.85), rng.uniform(1.4, 1.5)),
        "wagon": (rng.uniform(4.5, 4.95), rng.uniform(1.75, 1.85), rng.uniform(1.45, 1.55)),
        "suv": (rng.uniform(4.4, 4.9), rng.uniform(1.85, 1.95), rng.uniform(1.65, 1.8)),
        "van": (rng.uniform(4.8, 5.6), rng.uniform(1.9, 2.05), rng.uniform(1.9, 2.4)),
    }[style]
    return length, width, height, style


def _tilted(block: _Block, frame: _Frame, length: float, width: float):
    """Map local (u, v, h) to world points on the ground plane under a footprint (cars follow slopes)."""
    corners = frame.to_world(_rect(-length / 2, length / 2, -width / 2, width / 2))
    g = block.ground(corners)
    g0 = g.mean()
    a = ((g[1] + g[2]) - (g[0] + g[3])) / (2.0 * length)
    b = ((g[2] + g[3]) - (g[0] + g[1])) / (2.0 * width)

    def to_world(uvh: ArrayLike) -> FloatArray:
        uvh = np.atleast_2d(np.asarray(uvh, dtype=np.float64))
        xy = frame.to_world(uvh[:, :2])
        return np.column_stack([xy, g0 + a * uvh[:, 0] + b * uvh[:, 1] + uvh[:, 2]])

    return to_world


def _car(block: _Block, frame: _Frame, dims: tuple[float, float, float, str]) -> None:
    """Lower body, a cabin with sloped wind-screens (glass), and four wheels."""
    length, width, height, style = dims
    rng = block.rng
    to_world = _tilted(block, frame, length, width)
    albedo = float(rng.uniform(0.03, 0.12) if rng.random() < 0.35 else rng.uniform(0.15, 0.7))
    belt = 0.28 + (height - 0.28) * (0.62 if style == "van" else 0.55)
    hl, hw = length / 2.0, width / 2.0
    nose = 0.12 if style == "van" else rng.uniform(0.08, 0.2)
    body = np.array(
        [[-hl, -hw, 0.28], [hl, -hw, 0.3], [hl, hw, 0.3], [-hl, hw, 0.28],
         [-hl, -hw, belt], [hl, -hw, belt - nose], [hl, hw, belt - nose], [-hl, hw, belt]]
    )  # fmt: skip
    block.mesh.hexahedron(to_world(body), Surface.CAR, albedo)
    if style == "van":
        rear, front, top_rear, top_front = -hl + 0.05, hl - 0.5, -hl + 0.1, hl - 1.1
    else:
        rear = -hl + rng.uniform(0.2, 0.5)
        front = hl - rng.uniform(0.9, 1.4)
        top_rear = rear + (rng.uniform(0.05, 0.25) if style in ("wagon", "suv") else rng.uniform(0.35, 0.7))
        top_front = front - rng.uniform(0.6, 0.95)
    inset = 0.12
    cabin = np.array(
        [[rear, -hw + 0.03, belt], [front, -hw + 0.03, belt - nose * 0.3],
         [front, hw - 0.03, belt - nose * 0.3], [rear, hw - 0.03, belt],
         [top_rear, -hw + inset, height], [top_front, -hw + inset, height],
         [top_front, hw - inset, height], [top_rear, hw - inset, height]]
    )  # fmt: skip
    block.mesh.hexahedron(to_world(cabin), Surface.CAR_GLASS, 0.08)
    # A roof panel just above the cabin top: the roof is painted metal, not glass.
    roof = cabin.copy()
    roof[:4] = roof[4:]
    roof[4:, 2] += 0.02
    block.mesh.hexahedron(to_world(roof), Surface.CAR, albedo)
    radius = rng.uniform(0.3, 0.36)
    lateral = frame.axis(0.0, 1.0)
    for u in (-hl + 0.8, hl - 0.85):
        for v in (-hw + 0.02, hw - 0.24):
            base = to_world([[u, v, radius]])[0]
            block.mesh.cylinder(base, lateral, radius, 0.22, Surface.RUBBER, 0.05, sides=8)


# -- buildings -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class BuildingStyle:
    """How one kind of zone builds: lot widths and gaps, setbacks, storeys, windows, roofs (metres)."""

    gap_prob: float
    gap: tuple[float, float]
    width: tuple[float, float]
    spacing: tuple[float, float]
    setback_jitter: float
    depth: tuple[float, float]
    floors: tuple[int, int]
    floor_h: tuple[float, float]
    ground_h: tuple[float, float]
    roof_gable: float
    window: tuple[float, float]
    window_h: tuple[float, float]
    column: tuple[float, float]
    balcony: float
    segments: tuple[int, int]
    wall_albedo: tuple[float, float]


_BUILDING_STYLES: dict[ZoneKind, BuildingStyle] = {
    ZoneKind.URBAN: BuildingStyle(
        gap_prob=0.1,
        gap=(3.0, 9.0),
        width=(8.0, 28.0),
        spacing=(0.0, 0.6),
        setback_jitter=0.8,
        depth=(10.0, 20.0),
        floors=(3, 7),
        floor_h=(2.9, 3.4),
        ground_h=(3.4, 4.6),
        roof_gable=0.25,
        window=(1.0, 1.6),
        window_h=(1.3, 1.7),
        column=(2.4, 3.6),
        balcony=0.35,
        segments=(1, 3),
        wall_albedo=(0.2, 0.6),
    ),
    ZoneKind.RESIDENTIAL: BuildingStyle(
        gap_prob=0.15,
        gap=(4.0, 12.0),
        width=(8.0, 15.0),
        spacing=(3.0, 9.0),
        setback_jitter=4.0,
        depth=(8.0, 13.0),
        floors=(1, 3),
        floor_h=(2.7, 3.0),
        ground_h=(2.8, 3.1),
        roof_gable=0.75,
        window=(0.9, 1.4),
        window_h=(1.1, 1.4),
        column=(2.8, 4.2),
        balcony=0.2,
        segments=(1, 2),
        wall_albedo=(0.3, 0.7),
    ),
    ZoneKind.INDUSTRIAL: BuildingStyle(
        gap_prob=0.2,
        gap=(8.0, 25.0),
        width=(20.0, 50.0),
        spacing=(4.0, 15.0),
        setback_jitter=10.0,
        depth=(15.0, 35.0),
        floors=(1, 3),
        floor_h=(4.0, 5.5),
        ground_h=(4.0, 6.0),
        roof_gable=0.1,
        window=(1.5, 3.0),
        window_h=(1.0, 1.5),
        column=(5.0, 9.0),
        balcony=0.0,
        segments=(1, 2),
        wall_albedo=(0.25, 0.65),
    ),
}


def _building(
    block: _Block, side: int, station: float, width: float, front: float, style: BuildingStyle
) -> None:
    """A building on one lot: one to three segments with their own setback and height, each a body
    with a facade of recessed windows (glass), optional balconies and a flat or gabled roof."""
    rng = block.rng
    sign = 1.0 if side else -1.0
    depth = rng.uniform(*style.depth)
    frame = block.frame(station, sign * front, rng.normal(0.0, math.radians(2.0)))
    probe = _rect(-width / 2, width / 2, 0.0, sign * depth)
    probe = np.concatenate([probe, [[0.0, 0.0], [0.0, sign * depth / 2]]])
    if not block.layout.is_clear(frame.to_world(probe), level=2, tolerance=0.3):
        return
    g = block.ground(frame.to_world(probe))
    base, floor0 = g.min() - 0.6, g.max()
    albedo = float(rng.uniform(*style.wall_albedo))
    n_seg = max(1, min(int(rng.integers(style.segments[0], style.segments[1] + 1)), int(width // 5.0)))
    shares = rng.uniform(0.6, 1.4, n_seg)
    edges = -width / 2 + width * np.concatenate([[0.0], np.cumsum(shares) / shares.sum()])
    floors0 = int(rng.integers(style.floors[0], style.floors[1] + 1))
    floor_h, ground_h = rng.uniform(*style.floor_h), rng.uniform(*style.ground_h)
    gable = rng.random() < style.roof_gable
    for u0, u1 in itertools.pairwise(edges):
        f = rng.uniform(0.0, 1.2) if n_seg > 1 else 0.0
        floors = max(1, floors0 + int(rng.integers(-1, 2)) * (n_seg > 1))
        heights = [ground_h] + [floor_h] * (floors - 1)
        _building_segment(block, frame, sign, (u0, u1), f, depth, base, floor0, heights, albedo, gable, style)


def _building_segment(
    block: _Block,
    frame: _Frame,
    sign: float,
    span: tuple[float, float],
    front: float,
    depth: float,
    base: float,
    floor0: float,
    heights: list[float],
    albedo: float,
    gable: bool,
    style: BuildingStyle,
) -> None:
    """One segment of a building, built in local (u along, w away from the street, z) coordinates."""
    rng = block.rng
    local = _LocalMesh()
    u0, u1 = span
    top = floor0 + sum(heights)
    recess = rng.uniform(0.12, 0.35)
    # Body behind the facade plane; the facade skin with window holes sits `recess` in front of it.
    local.box(u0, u1, front + recess, depth, base, top, Surface.WALL, albedo)
    local.facade(u0, u1, front, base, floor0, Surface.WALL, albedo)
    n_cols = max(1, int((u1 - u0) / rng.uniform(*style.column)))
    pitch = (u1 - u0) / n_cols
    win_w = min(rng.uniform(*style.window), pitch - 0.5)
    win_h = rng.uniform(*style.window_h)
    balcony = rng.random() < style.balcony
    z = floor0
    for level, h in enumerate(heights):
        shop = level == 0 and len(heights) > 2 and rng.random() < 0.6
        sill = 0.35 if shop else rng.uniform(0.8, 1.0)
        za, zb = z + sill, z + sill + min(h - sill - 0.3, (h - 0.9) if shop else win_h)
        ww = min(pitch - 0.3, win_w * (1.8 if shop else 1.0))
        if win_w < 0.4 or zb - za < 0.5:
            local.facade(u0, u1, front, z, z + h, Surface.WALL, albedo)
            z += h
            continue
        local.facade(u0, u1, front, z, za, Surface.WALL, albedo)
        local.facade(u0, u1, front, zb, z + h, Surface.WALL, albedo)
        left = u0
        for col in range(n_cols):
            a = u0 + (col + 0.5) * pitch - ww / 2
            b = a + ww
            local.facade(left, a, front, za, zb, Surface.WALL, albedo)
            local.window(a, b, front, recess, za, zb, albedo)
            left = b
            if balcony and level > 0 and col % 2 == 0:
                local.box(a - 0.4, b + 0.4, front - 1.2, front, z - 0.15, z, Surface.WALL, albedo)
                local.box(a - 0.4, b + 0.4, front - 1.2, front - 1.15, z, z + 1.0, Surface.METAL, 0.35)
        local.facade(left, u1, front, za, zb, Surface.WALL, albedo)
        z += h
    if gable:
        rise = rng.uniform(0.3, 0.6) * (depth - front) / 2.0
        local.gable_roof(
            u0 - 0.3, u1 + 0.3, front - 0.3, depth + 0.3, top, rise, float(rng.uniform(0.1, 0.35))
        )
    else:
        local.box(
            u0, u1, front, front + 0.25, top, top + rng.uniform(0.3, 1.0), Surface.WALL, albedo
        )  # parapet
    block.mesh.add_part(local.to_world(frame, sign))


class _LocalMesh(MeshBuilder):
    """A building's mesh in local (u, w, z) coordinates, moved into the world in one step."""

    def box(self, ua: float, ub: float, wa: float, wb: float, za: float, zb: float, surface: int, alb: float):
        plan = [(ua, wa), (ub, wa), (ub, wb), (ua, wb)]
        self.hexahedron([(u, w, za) for u, w in plan] + [(u, w, zb) for u, w in plan], surface, alb)

    def facade(self, ua: float, ub: float, w: float, za: float, zb: float, surface: int, alb: float) -> None:
        if ub - ua > 1e-3 and zb - za > 1e-3:
            self.quad([(ua, w, za), (ub, w, za), (ub, w, zb), (ua, w, zb)], surface, alb)

    def window(self, ua: float, ub: float, w: float, recess: float, za: float, zb: float, alb: float) -> None:
        """Four reveals around a pane set back by ``recess``: the pane is glass, the reveals wall."""
        wb = w + recess
        for u in (ua, ub):
            self.quad([(u, w, za), (u, wb, za), (u, wb, zb), (u, w, zb)], Surface.WALL, alb)
        for z in (za, zb):
            self.quad([(ua, w, z), (ub, w, z), (ub, wb, z), (ua, wb, z)], Surface.WALL, alb)
        self.facade(ua, ub, wb - 0.02, za, zb, Surface.GLASS, 0.08)

    def gable_roof(
        self, ua: float, ub: float, wa: float, wb: float, z: float, rise: float, alb: float
    ) -> None:
        wm = 0.5 * (wa + wb)
        verts = [(ua, wa, z), (ub, wa, z), (ub, wb, z), (ua, wb, z), (ua, wm, z + rise), (ub, wm, z + rise)]
        self.add(verts, [[0, 1, 5], [0, 5, 4], [3, 4, 5], [3, 5, 2], [0, 4, 3], [1, 2, 5]], Surface.ROOF, alb)

    def to_world(self, frame: _Frame, sign: float) -> MeshPart:
        part = self.build()
        uvw = part.vertices
        xy = frame.to_world(np.column_stack([uvw[:, 0], sign * uvw[:, 1]]))
        part.vertices = np.column_stack([xy, uvw[:, 2]])
        return part


# -- vegetation ----------------------------------------------------------------------------------


CROWN_CLEARANCE = 4.0
"""Lowest leaves above the ground (m): street trees are pruned to clear traffic, and a crown that
reached down over the road would engulf the sensor (seen with seed 7: a frame inside a crown)."""


def _tree(block: _Block, xy: FloatArray, scale: float) -> None:
    """A trunk and a blobby crown (one to three lumps) clear of the road's traffic, or a conifer cone."""
    rng = block.rng
    z = float(block.ground(xy)[0])
    trunk_albedo = float(rng.uniform(0.2, 0.35))
    leaf_albedo = float(rng.uniform(0.35, 0.6))
    if rng.random() < 0.2:
        height = rng.uniform(5.0, 12.0) * scale
        radius = rng.uniform(0.8, 1.6) * scale  # narrow enough to stay off the road from a yard
        block.mesh.cylinder([*xy, z - 0.2], [0, 0, 1], 0.15 * scale, 1.4, Surface.WOOD, trunk_albedo, 6)
        block.mesh.cylinder(
            [*xy, z + 1.0], [0, 0, 1], radius, height, Surface.VEGETATION, leaf_albedo, 10, 0.0
        )
        return
    trunk_h = rng.uniform(1.8, 3.5) * scale
    crown = rng.uniform(1.3, 3.8) * scale
    # The lowest lump reaches about 1.25 crown below the crown centre (0.8 crown above the trunk top).
    trunk_h = max(trunk_h, CROWN_CLEARANCE + 0.45 * crown)
    lean = rng.normal(0.0, 0.05, 2)
    block.mesh.cylinder(
        [*xy, z - 0.2], [lean[0], lean[1], 1.0], rng.uniform(0.1, 0.3) * scale, trunk_h + crown * 0.6,
        Surface.WOOD, trunk_albedo, 7, 0.6,
    )  # fmt: skip
    top = np.array([*(xy + lean * trunk_h), z + trunk_h + crown * 0.8])
    for k in range(int(rng.integers(1, 4))):
        offset = rng.normal(0.0, 0.35 * crown, 3) * (k > 0)
        offset[2] = abs(offset[2])  # extra lumps sit beside or above the first, never below it
        radii = (
            crown * rng.uniform(0.7, 1.0) * np.array([1.0, rng.uniform(0.8, 1.2), rng.uniform(0.75, 1.25)])
        )
        block.mesh.blob(
            top + offset, radii, rng, Surface.VEGETATION, leaf_albedo, 0.3, 2 if crown > 2.0 else 1
        )


def _bush(block: _Block, xy: FloatArray, radius: float) -> None:
    """A squat lumpy blob sitting on (and a little in) the ground."""
    rng = block.rng
    z = float(block.ground(xy)[0])
    radii = radius * np.array([1.0, rng.uniform(0.7, 1.4), rng.uniform(0.5, 0.9)])
    centre = [*xy, z + radii[2] * 0.6]
    block.mesh.blob(centre, radii, rng, Surface.VEGETATION, float(rng.uniform(0.35, 0.6)), 0.35, 1)


# -- poles and street clutter --------------------------------------------------------------------


def _lamp(block: _Block, xy: FloatArray, heading: float, sign: float) -> None:
    """Lamp post with an arm reaching over the road."""
    rng = block.rng
    z = float(block.ground(xy)[0])
    height = rng.uniform(5.5, 9.0)
    albedo = float(rng.uniform(0.3, 0.55))
    block.mesh.cylinder(
        [*xy, z - 0.2], [0, 0, 1], rng.uniform(0.08, 0.13), height, Surface.METAL, albedo, 8, 0.06
    )
    toward = -sign * np.array([-math.sin(heading), math.cos(heading)])
    arm = rng.uniform(0.8, 2.2)
    tip = xy + toward * arm
    block.mesh.cylinder([*xy, z + height - 0.1], [*toward, 0.0], 0.05, arm, Surface.METAL, albedo, 4)
    block.mesh.cylinder([*tip, z + height - 0.35], [0, 0, 1], 0.25, 0.25, Surface.METAL, albedo, 6)


def _traffic_light(block: _Block, xy: FloatArray, heading: float, sign: float) -> None:
    """A signal head on a pole at a corner, sometimes on a mast arm reaching over the lanes."""
    rng = block.rng
    z = float(block.ground(xy)[0])
    height = rng.uniform(3.0, 4.2)
    block.mesh.cylinder([*xy, z - 0.2], [0, 0, 1], 0.09, height + 0.2, Surface.METAL, 0.35, 8)
    block.mesh.hexahedron(
        _upright_box(xy, z + height - 1.0, z + height + 0.1, 0.35, 0.35), Surface.METAL, 0.15
    )
    if rng.random() < 0.3:  # a mast arm over the lanes
        toward = -sign * np.array([-math.sin(heading), math.cos(heading)])
        length = rng.uniform(3.0, 6.0)
        block.mesh.cylinder([*xy, z + height - 0.2], [*toward, 0.0], 0.07, length, Surface.METAL, 0.35, 6)
        tip = xy + toward * length
        block.mesh.hexahedron(
            _upright_box(tip, z + height - 1.2, z + height - 0.2, 0.35, 0.35), Surface.METAL, 0.15
        )


def _upright_box(xy: FloatArray, z0: float, z1: float, sx: float, sy: float, yaw: float = 0.0) -> FloatArray:
    """Corners of a vertical box centred on ``xy``: ``sx`` along ``yaw``, ``sy`` across it."""
    plan = _Frame(np.asarray(xy, dtype=np.float64), yaw).to_world(_rect(-sx / 2, sx / 2, -sy / 2, sy / 2))
    return np.concatenate([np.column_stack([plan, np.full(4, z0)]), np.column_stack([plan, np.full(4, z1)])])


def _power_pole(block: _Block, xy: FloatArray, heading: float) -> None:
    """A wooden utility pole with a cross-arm across the road (country roads, villages)."""
    rng = block.rng
    z = float(block.ground(xy)[0])
    height = rng.uniform(7.5, 10.5)
    block.mesh.cylinder([*xy, z - 0.3], [0, 0, 1], 0.14, height, Surface.WOOD, 0.3, 8, 0.11)
    yaw = heading + math.pi / 2 + float(rng.normal(0.0, 0.1))
    block.mesh.hexahedron(
        _upright_box(xy, z + height - 0.8, z + height - 0.65, 2.0, 0.12, yaw), Surface.WOOD, 0.3
    )


def _clutter(block: _Block, xy: FloatArray, heading: float, kind: str) -> None:
    """Small street objects: signs (retro-reflective), bins, bollards, cabinets, benches, columns."""
    rng = block.rng
    mesh = block.mesh
    z = float(block.ground(xy)[0])
    yaw = heading
    if kind == "sign":
        height = rng.uniform(2.0, 2.8)
        mesh.cylinder([*xy, z - 0.2], [0, 0, 1], 0.035, height + 0.2, Surface.METAL, 0.4, 6)
        size = rng.uniform(0.5, 0.9)
        face = _upright_box(xy, z + height - size / 2, z + height + size / 2, 0.04, size, yaw)
        mesh.hexahedron(face, Surface.SIGN, float(rng.uniform(0.75, 1.0)))
    elif kind == "bin":
        mesh.hexahedron(
            _upright_box(xy, z - 0.1, z + rng.uniform(0.9, 1.3), 0.6, 0.7, yaw), Surface.WALL, 0.2
        )
    elif kind == "bollard":
        for k in range(int(rng.integers(1, 5))):
            p = xy + 1.5 * k * np.array([math.cos(yaw), math.sin(yaw)])
            mesh.cylinder([*p, z - 0.1], [0, 0, 1], 0.08, 1.0, Surface.METAL, 0.45, 6)
    elif kind == "cabinet":
        box = _upright_box(xy, z - 0.1, z + rng.uniform(1.0, 1.6), rng.uniform(0.6, 1.2), 0.4, yaw)
        mesh.hexahedron(box, Surface.METAL, float(rng.uniform(0.3, 0.6)))
    elif kind == "bench":
        mesh.hexahedron(_upright_box(xy, z + 0.35, z + 0.5, 1.8, 0.5, yaw), Surface.WOOD, 0.3)
        mesh.hexahedron(_upright_box(xy, z - 0.1, z + 0.35, 1.4, 0.1, yaw), Surface.METAL, 0.3)
    elif kind == "column":
        mesh.cylinder([*xy, z - 0.1], [0, 0, 1], 0.6, rng.uniform(2.6, 3.4), Surface.WALL, 0.5, 12)
    else:  # a row of parked bicycles: thin frames at hip height
        for k in range(int(rng.integers(2, 6))):
            p = xy + 0.7 * k * np.array([math.cos(yaw), math.sin(yaw)])
            frame = _upright_box(p, z + 0.3, z + 1.0, 0.05, 1.6, yaw)
            mesh.hexahedron(frame, Surface.METAL, 0.3)


# ----------------------------------------------------------------------------------------------
# Scene styles: the same building blocks with other weights and cross-sections


@dataclass(frozen=True)
class SceneStyle:
    """What kind of world a scene is: how the road bends, which zones it passes through, how often
    it crosses other streets, and style-specific changes to each zone's cross-section and buildings."""

    road: RoadShape
    zone_weights: dict[ZoneKind, float]
    crossings: bool = True
    crossing_gap: tuple[float, float] = (70.0, 240.0)
    crossing_half_width: tuple[float, float] = (3.5, 6.5)
    adjust: Callable[[np.random.Generator, Profile], Profile] | None = None
    buildings: dict[ZoneKind, BuildingStyle] = field(default_factory=dict)


def _avenue(rng: np.random.Generator, p: Profile) -> Profile:
    """Two or three lanes each way around a planted median, wide sidewalks lined with trees."""
    u = rng.uniform
    per_direction, trees = int(rng.choice([2, 3])), u(8.0, 12.0)
    return replace(
        p, lanes_left=2 * per_direction - 1, lane_width=u(3.2, 3.6), median=u(2.5, 6.0),
        sidewalk=(u(3.0, 6.0), u(3.0, 6.0)), street_trees=(trees, trees), lamp_spacing=u(25.0, 35.0),
        power_line=-1,
    )  # fmt: skip


def _highway(rng: np.random.Generator, p: Profile) -> Profile:
    """Two or three lanes each way, a concrete median barrier, shoulders with guard rails, buildings
    (if any) far back, and only the odd lamp post."""
    u = rng.uniform
    per_direction = int(rng.choice([2, 3]))
    lamps = u(50.0, 80.0) if rng.random() < 0.3 else 0.0
    return replace(
        p, lanes_left=2 * per_direction - 1, lane_width=u(3.5, 3.75), median=u(3.0, 8.0),
        median_kind="barrier", parking=(u(1.0, 1.7), u(0.5, 1.0)), sidewalk=(0.0, 0.0),
        frontage=("guardrail", "guardrail"), lamp_spacing=lamps, setback=(u(15.0, 40.0), u(15.0, 40.0)),
        power_line=-1,
    )  # fmt: skip


def _oldtown(rng: np.random.Generator, p: Profile) -> Profile:
    """A narrow lane (rarely two), narrow sidewalks and the houses right behind them."""
    u = rng.uniform
    return replace(
        p, lanes_left=int(rng.random() < 0.2), lane_width=u(2.8, 3.3),
        parking=tuple(float(rng.random() < 0.2) * u(2.0, 2.2) for _ in range(2)),
        sidewalk=(u(0.8, 2.0), u(0.8, 2.0)), frontage=("none", "none"), street_trees=(0.0, 0.0),
        lamp_spacing=u(15.0, 25.0), setback=(0.0, 0.0), power_line=-1,
    )  # fmt: skip


SCENES: dict[str, SceneStyle] = {
    "suburban": SceneStyle(RoadShape(), ZONE_WEIGHTS),
    "avenue": SceneStyle(
        RoadShape((80.0, 350.0), 0.3, (60.0, 100.0), (25.0, 45.0), (5.0, 30.0), (150.0, 500.0)),
        {ZoneKind.URBAN: 0.55, ZoneKind.RESIDENTIAL: 0.3, ZoneKind.INDUSTRIAL: 0.15, ZoneKind.OPEN: 0.0},
        crossing_gap=(80.0, 200.0),
        crossing_half_width=(5.0, 9.0),
        adjust=_avenue,
    ),
    "highway": SceneStyle(
        RoadShape((300.0, 1000.0), 0.0, (0.0, 0.0), (1.0, 1.0), (5.0, 35.0), (500.0, 2000.0)),
        {ZoneKind.URBAN: 0.0, ZoneKind.RESIDENTIAL: 0.0, ZoneKind.INDUSTRIAL: 0.15, ZoneKind.OPEN: 0.85},
        crossings=False,
        crossing_gap=(200.0, 600.0),
        adjust=_highway,
    ),
    "oldtown": SceneStyle(
        RoadShape((25.0, 110.0), 0.7, (60.0, 100.0), (10.0, 18.0), (10.0, 45.0), (30.0, 120.0)),
        {ZoneKind.URBAN: 0.85, ZoneKind.RESIDENTIAL: 0.15, ZoneKind.INDUSTRIAL: 0.0, ZoneKind.OPEN: 0.0},
        crossing_gap=(40.0, 110.0),
        crossing_half_width=(2.5, 4.5),
        adjust=_oldtown,
        buildings={
            ZoneKind.URBAN: replace(
                _BUILDING_STYLES[ZoneKind.URBAN],
                gap_prob=0.03,
                gap=(1.5, 4.0),
                width=(5.0, 12.0),
                spacing=(0.0, 0.2),
                setback_jitter=0.2,
                floors=(2, 5),
                roof_gable=0.6,
                balcony=0.15,
            ),
            ZoneKind.RESIDENTIAL: replace(
                _BUILDING_STYLES[ZoneKind.RESIDENTIAL], gap_prob=0.05, spacing=(0.0, 1.5), setback_jitter=0.5
            ),
        },
    ),
}
"""The scene styles by name; ``suburban`` is the original mix (same output for the same seed)."""
SCENE_STYLES = tuple(SCENES)


def scene_style(name: str) -> SceneStyle:
    """The style called ``name``, or a ConfigError listing the valid names."""
    if name not in SCENES:
        raise ConfigError(f"scene must be one of {', '.join(SCENE_STYLES)}, got {name!r}")
    return SCENES[name]


# ----------------------------------------------------------------------------------------------
# Ground tiles and the scene


def _ground_tile(layout: StreetLayout, ix: int, iy: int, rng: np.random.Generator) -> MeshPart:
    """A square of the terrain heightfield, with road, pavement and grass told apart per triangle."""
    n = int(TILE_SIZE / GROUND_STEP)
    axis = np.arange(n + 1) * GROUND_STEP
    gx, gy = np.meshgrid(ix * TILE_SIZE + axis, iy * TILE_SIZE + axis, indexing="ij")
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    vertices = np.column_stack([xy, layout.ground_height(xy)])
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    v00 = (i * (n + 1) + j).ravel()
    v10, v01, v11 = v00 + (n + 1), v00 + 1, v00 + n + 2
    triangles = np.concatenate([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)])
    centroids = vertices[triangles].mean(axis=1)[:, :2]
    distance, edges, index = layout.lateral(centroids)
    kind = layout.sample_kind[index]
    on_road = distance < edges[:, 1]
    paved = (distance < edges[:, 2] + 6.0) & ((kind == ZoneKind.URBAN) | (kind == ZoneKind.INDUSTRIAL))
    surface = np.where(on_road, Surface.ROAD, np.where(paved, Surface.SIDEWALK, Surface.TERRAIN))
    grass = 0.45 + 0.1 * np.sin(centroids @ rng.normal(0.0, 0.15, 2) + rng.uniform(0, 6.3))
    albedo = np.where(on_road, layout.sample_albedo[index], np.where(paved, 0.3, grass))
    albedo = albedo * rng.uniform(0.9, 1.1, len(albedo))
    return MeshPart(vertices, triangles, surface.astype(np.uint8), albedo.astype(np.float32))


class StreetScene:
    """The whole procedural world for one seed; hands out the geometry near given positions."""

    def __init__(self, seed: int, length: float, cache_chunks: int = 512, scene: str = "suburban") -> None:
        self.seed = seed
        self.style_name = scene
        style = scene_style(scene)
        road_length = PREROLL + math.ceil(max(length, 1.0) / ROAD_CHUNK) * ROAD_CHUNK
        self.road = make_road(np.random.default_rng([seed, 1]), road_length, style.road)
        self.terrain = Terrain.random(np.random.default_rng([seed, 2]))
        self.layout = StreetLayout(self.road, self.terrain, np.random.default_rng([seed, 3]), style)
        self._cache: OrderedDict[tuple[int, int, int], MeshPart] = OrderedDict()
        self._cache_chunks = cache_chunks
        n_blocks = math.ceil(self.road.length / BLOCK_LENGTH)
        boxes = []
        for b in range(n_blocks):
            lo = int(b * BLOCK_LENGTH / ROAD_STEP)
            xy = self.road.xy[lo : int((b + 1) * BLOCK_LENGTH / ROAD_STEP) + 1]
            boxes.append(np.concatenate([xy.min(0) - REACH, xy.max(0) + REACH]))
        self._block_boxes = np.array(boxes)

    def chunks_near(self, centres: ArrayLike, radius: float) -> list[tuple[int, int, int]]:
        """Keys of every block and ground tile within ``radius`` (in plan) of any of ``centres``."""
        centres = np.atleast_2d(np.asarray(centres, dtype=np.float64))[:, :2]
        keys: set[tuple[int, int, int]] = set()
        dist = _box_distance(self._block_boxes, centres)
        keys.update((0, int(b), 0) for b in np.flatnonzero(dist <= radius))
        lo = np.floor((centres.min(0) - radius) / TILE_SIZE).astype(int)
        hi = np.floor((centres.max(0) + radius) / TILE_SIZE).astype(int)
        tx, ty = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
        tiles = np.column_stack([tx.ravel(), ty.ravel()])
        tile_boxes = np.concatenate([tiles * TILE_SIZE, (tiles + 1) * TILE_SIZE], axis=1).astype(np.float64)
        dist = _box_distance(tile_boxes, centres)
        keys.update((1, int(x), int(y)) for x, y in tiles[dist <= radius])
        return sorted(keys)

    def chunk(self, key: tuple[int, int, int]) -> MeshPart:
        """One block (``(0, index, 0)``) or ground tile (``(1, ix, iy)``), built on first use."""
        if key in self._cache:
            self._cache.move_to_end(key)
            return self._cache[key]
        kind, a, b = key
        if kind == 0:
            part = _Block(self.layout, a, np.random.default_rng([self.seed, 10, a])).build()
        else:
            rng = np.random.default_rng([self.seed, 11, a + 2**20, b + 2**20])
            part = _ground_tile(self.layout, a, b, rng)
        self._cache[key] = part
        while len(self._cache) > self._cache_chunks:
            self._cache.popitem(last=False)
        return part

    @property
    def cached_chunks(self) -> int:
        """How many chunks are held in memory now (bounded: the scene is never built whole)."""
        return len(self._cache)

    def mesh_near(self, centres: ArrayLike, radius: float) -> MeshPart:
        """Everything within ``radius`` of the centres as one mesh, in a fixed (sorted) chunk order."""
        return MeshPart.concatenate([self.chunk(key) for key in self.chunks_near(centres, radius)])


def _box_distance(boxes: FloatArray, points: FloatArray) -> FloatArray:
    """Smallest plan distance from each box ``(B, 4)`` = (xmin, ymin, xmax, ymax) to any of ``points``."""
    dx = np.maximum(
        np.maximum(boxes[:, None, 0] - points[None, :, 0], points[None, :, 0] - boxes[:, None, 2]), 0
    )
    dy = np.maximum(
        np.maximum(boxes[:, None, 1] - points[None, :, 1], points[None, :, 1] - boxes[:, None, 3]), 0
    )
    return np.sqrt(dx * dx + dy * dy).min(axis=1)
