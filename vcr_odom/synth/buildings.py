"""Buildings on the lots along a street: rows of facades with recessed glass windows, shop fronts,
balconies and flat or gabled roofs, in the style of the zone they stand in.

Windows are recessed and glass often returns nothing, as on real facades, so walls give the sensor
the broken, structured surfaces it sees in towns rather than flat planes.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from vcr_odom.synth.layout import Profile, ZoneKind
from vcr_odom.synth.mesh import FloatArray, MeshBuilder, MeshPart, Surface
from vcr_odom.synth.parts import PlanFrame, rect

if TYPE_CHECKING:
    from vcr_odom.synth.courtyard import Courtyard
    from vcr_odom.synth.roadside import RoadsideBlock


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


BUILDING_STYLES: dict[ZoneKind, BuildingStyle] = {
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


def building(
    block: RoadsideBlock, side: int, station: float, width: float, front: float, style: BuildingStyle
) -> None:
    """A building on one lot: one to three segments with their own setback and height, each a body
    with a facade of recessed windows (glass), optional balconies and a flat or gabled roof."""
    rng = block.rng
    sign = 1.0 if side else -1.0
    depth = rng.uniform(*style.depth)
    frame = block.frame(station, sign * front, rng.normal(0.0, math.radians(2.0)))
    probe = rect(-width / 2, width / 2, 0.0, sign * depth)
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


COURTYARD_DEPTH = 3.0
"""Metres of body behind each wall of a courtyard's buildings (a roof closes the one inside)."""


def courtyard_buildings(block: RoadsideBlock, courtyard: Courtyard, profile: Profile) -> None:
    """The buildings of a short walked loop's courtyard (:mod:`~vcr_odom.synth.courtyard`) in the
    zone's style: the one inside, each wall a segment facing out, one height all round, a flat roof
    over it; and across the lawn, a building behind each outer facade, facing in."""
    rng = block.rng
    kind = profile.kind if profile.kind in BUILDING_STYLES else ZoneKind.RESIDENTIAL
    style = block.layout.style.buildings.get(kind, BUILDING_STYLES[kind])
    corners = courtyard.inner
    ring = np.vstack([corners, corners[:1]])
    top = _walled_building(block, list(itertools.pairwise(ring)), 1.0, style)
    roof = np.vstack([[0.0, 0.0, top], np.column_stack([corners, np.full(len(corners), top)])])
    fan = [[0, 1 + i, 1 + (i + 1) % len(corners)] for i in range(len(corners))]
    block.mesh.add(roof, fan, Surface.ROOF, float(rng.uniform(0.1, 0.35)))
    for facade in courtyard.outer:
        _walled_building(block, [(facade[0], facade[1])], -1.0, style)


def _walled_building(
    block: RoadsideBlock, walls: list[tuple[FloatArray, FloatArray]], sign: float, style: BuildingStyle
) -> float:
    """A building of one height and wall colour whose facades run from each wall's start to its end,
    its body to their left (``sign`` 1) or right (-1); the top of its walls (m)."""
    rng = block.rng
    along = np.concatenate([np.linspace(a, b, 8) for a, b in walls])
    ground = block.ground(along)
    base, floor0 = ground.min() - 0.6, ground.max()
    albedo = float(rng.uniform(*style.wall_albedo))
    floors = max(2, int(rng.integers(style.floors[0], style.floors[1] + 1)))
    heights = [rng.uniform(*style.ground_h)] + [rng.uniform(*style.floor_h)] * (floors - 1)
    for a, b in walls:
        length = float(np.linalg.norm(b - a))
        frame = PlanFrame(a, math.atan2(b[1] - a[1], b[0] - a[0]))
        _building_segment(
            block, frame, sign, (0.0, length), 0.0, COURTYARD_DEPTH, base, floor0, heights, albedo,
            False, style,
        )  # fmt: skip
    return floor0 + sum(heights)


def _building_segment(
    block: RoadsideBlock,
    frame: PlanFrame,
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

    def box(
        self, ua: float, ub: float, wa: float, wb: float, za: float, zb: float, surface: int, alb: float
    ) -> None:
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

    def to_world(self, frame: PlanFrame, sign: float) -> MeshPart:
        part = self.build()
        uvw = part.vertices
        xy = frame.to_world(np.column_stack([uvw[:, 0], sign * uvw[:, 1]]))
        part.vertices = np.column_stack([xy, uvw[:, 2]])
        return part
