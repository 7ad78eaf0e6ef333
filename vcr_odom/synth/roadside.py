"""What stands beside the road, one block of road at a time: lane paint, medians, sidewalks, hedges and
fences, parked cars, buildings, yards, lamps, trees and street clutter, placed by each stretch's
cross-section and kept off every carriageway.

A block draws only from its own random generator, so its content never depends on which other blocks
were built before it.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from vcr_odom.synth.buildings import BUILDING_STYLES, building, courtyard_buildings
from vcr_odom.synth.layout import Profile, StreetLayout, ZoneKind
from vcr_odom.synth.mesh import FloatArray, MeshBuilder, MeshPart, Surface
from vcr_odom.synth.parts import (
    PlanFrame,
    box_outline,
    bush,
    car,
    car_dimensions,
    clutter,
    lamp,
    power_pole,
    traffic_light,
    tree,
)

BLOCK_LENGTH = 50.0
"""Road-side objects are generated per 50 m of road: small enough to load only what is in range."""


class RoadsideBlock:
    """Builds the road-side content of one block of road (both sides) into a mesh."""

    def __init__(
        self, layout: StreetLayout, index: int, rng: np.random.Generator, length: float = BLOCK_LENGTH
    ) -> None:
        self.layout = layout
        self.road = layout.road
        self.rng = rng
        self.mesh = MeshBuilder()
        self.s0 = index * length
        self.s1 = min(self.s0 + length, self.road.length)

    # -- helpers
    def ground(self, xy: ArrayLike) -> FloatArray:
        return self.layout.ground_height(xy)

    def frame(self, station: float, lateral: float, yaw_offset: float = 0.0) -> PlanFrame:
        xy, heading, _ = self.road.sample([station])
        normal = np.array([-math.sin(heading[0]), math.cos(heading[0])])
        return PlanFrame(xy[0] + lateral * normal, float(heading[0]) + yaw_offset)

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
        features = self.layout.features
        courtyard = features.courtyard if features is not None else None
        for lo, hi in self.layout.free_intervals(self.s0, self.s1):
            profile = self.layout.profile_at(0.5 * (lo + hi))
            self.lane_markings(lo, hi, profile)
            if profile.median > 0.0:
                self.median(lo, hi, profile)
            for side in (0, 1):
                self.sidewalk(lo, hi, side, profile)
                if courtyard is not None and side == courtyard.side:
                    continue  # the verge between the path and the building inside stays clear
                self.frontage(lo, hi, side, profile)
                self.parked_cars(lo, hi, side, profile)
                if courtyard is None:  # a courtyard's own buildings stand across the lawn instead
                    self.buildings(lo, hi, side, profile)
                self.yards(lo, hi, side, profile)
                self.street_furniture(lo, hi, side, profile)
        if courtyard is not None and self.s0 == 0.0:
            courtyard_buildings(self, courtyard, self.layout.profile_at(0.0))
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
            tree(self, self.road.offset([s], [centre])[0], rng.uniform(0.8, 1.1))

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
            dims = car_dimensions(rng)
            length = dims[0]
            if s + length > hi:
                break
            lateral = sign * (profile.curb(side) - dims[1] / 2.0 - rng.uniform(0.1, 0.3))
            flip = side == 1 and rng.random() < 0.7
            frame = self.frame(s + length / 2.0, lateral, math.pi if flip else 0.0)
            footprint = frame.to_world(box_outline(length, dims[1]))
            if self.layout.is_clear(footprint, level=0, tolerance=0.0):
                car(self, frame, dims)
            s += length + rng.uniform(0.6, 3.5)

    # -- buildings
    def buildings(self, lo: float, hi: float, side: int, profile: Profile) -> None:
        """Rows of buildings on lots along the street, in the style of the zone."""
        if profile.kind == ZoneKind.OPEN:
            return
        rng = self.rng
        style = self.layout.style.buildings.get(profile.kind, BUILDING_STYLES[profile.kind])
        s = lo
        while s < hi - 5.0:
            if rng.random() < style.gap_prob:
                s += rng.uniform(*style.gap)
                continue
            width = rng.uniform(*style.width)
            if hi - (s + width) < 5.0:  # no sliver lot at the end of the block: the last lot takes the rest
                width = hi - s
            front = profile.outer(side) + profile.setback[side] + rng.uniform(0.0, style.setback_jitter)
            building(self, side, s + width / 2.0, width, front, style)
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
                    bush(self, xy[0], radius)
            elif self.layout.is_clear(xy, level=2, tolerance=-1.0):
                tree(self, xy[0], rng.uniform(0.7, 1.3))
        if profile.kind == ZoneKind.OPEN and profile.street_trees[side] > 0.0:
            d = sign * (profile.outer(side) + rng.uniform(1.5, 4.0))
            for s in self.along(profile.street_trees[side], lo, hi, jitter=1.5):
                xy = self.road.offset([s], [d])
                if self.layout.is_clear(xy, level=1, tolerance=-1.0):
                    tree(self, xy[0], rng.uniform(0.9, 1.3))

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
                self._place(s, sign * (curb + (0.5 if walk else 1.2)), lambda xy, h: lamp(self, xy, h, sign))
        spacing = profile.street_trees[side]
        if spacing > 0.0 and profile.kind != ZoneKind.OPEN and walk > 2.0:
            for s in self.along(spacing, lo, hi, jitter=1.0):
                self._place(s, sign * (curb + 1.0), lambda xy, h: tree(self, xy, rng.uniform(0.7, 1.1)))
        if profile.power_line == side:
            d = sign * (profile.outer(side) + 3.0)
            for s in self.along(40.0, lo, hi, jitter=3.0):
                self._place(s, d, lambda xy, h: power_pole(self, xy, h))
        clutter_per_50m = {
            ZoneKind.URBAN: 10,
            ZoneKind.RESIDENTIAL: 4,
            ZoneKind.INDUSTRIAL: 3,
            ZoneKind.OPEN: 1,
        }
        for _ in range(rng.poisson(clutter_per_50m[profile.kind] * (hi - lo) / 50.0)):
            s = rng.uniform(lo, hi)
            d = curb + (rng.uniform(0.3, max(0.4, walk - 0.3)) if walk else rng.uniform(0.8, 2.5))
            kind = str(rng.choice(["sign", "sign", "bin", "bollard", "cabinet", "bench", "column", "bike"]))
            if kind == "column" and profile.kind != ZoneKind.URBAN:
                kind = "sign"
            self._place(s, sign * d, lambda xy, h, k=kind: clutter(self, xy, h, k))

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
                        self._place(s + ds, d, lambda xy, h, g=sign: traffic_light(self, xy, h, g))
                    else:
                        self._place(s + ds, d, lambda xy, h: clutter(self, xy, h, "sign"))

    def _place(self, station: float, lateral: float, make: Callable[[FloatArray, float], None]) -> None:
        """Put a small object at (station, lateral) unless that is on some road's carriageway."""
        xy = self.road.offset([station], [lateral])
        if self.layout.is_clear(xy, level=1, tolerance=0.35):
            _, heading, _ = self.road.sample([station])
            make(xy[0], float(heading[0]))
