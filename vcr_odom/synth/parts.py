"""Scene parts placed along the street: parked cars, trees and bushes, lamp posts, traffic lights,
utility poles and small street clutter (signs, bins, bollards, benches, bicycles).

Each part draws its shape from the block's random generator and adds its triangles to the block's
mesh, standing on the ground where it is placed.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from vcr_odom.synth.mesh import FloatArray, Surface

if TYPE_CHECKING:
    from vcr_odom.synth.roadside import RoadsideBlock


@dataclass(frozen=True)
class PlanFrame:
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


def box_outline(length: float, width: float, n: int = 3) -> FloatArray:
    """Probe points on and inside a footprint centred at the origin (for road clearance checks)."""
    u = np.linspace(-length / 2.0, length / 2.0, n)
    v = np.linspace(-width / 2.0, width / 2.0, n)
    return np.stack(np.meshgrid(u, v), -1).reshape(-1, 2)


def rect(u0: float, u1: float, v0: float, v1: float) -> FloatArray:
    """Corners of the rectangle ``[u0, u1] x [v0, v1]`` in plan, counter-clockwise."""
    return np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]])


# -- cars ----------------------------------------------------------------------------------------


def car_dimensions(rng: np.random.Generator) -> tuple[float, float, float, str]:
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


def _tilted(
    block: RoadsideBlock, frame: PlanFrame, length: float, width: float
) -> Callable[[ArrayLike], FloatArray]:
    """Map local (u, v, h) to world points on the ground plane under a footprint (cars follow slopes)."""
    corners = frame.to_world(rect(-length / 2, length / 2, -width / 2, width / 2))
    g = block.ground(corners)
    g0 = g.mean()
    a = ((g[1] + g[2]) - (g[0] + g[3])) / (2.0 * length)
    b = ((g[2] + g[3]) - (g[0] + g[1])) / (2.0 * width)

    def to_world(uvh: ArrayLike) -> FloatArray:
        uvh = np.atleast_2d(np.asarray(uvh, dtype=np.float64))
        xy = frame.to_world(uvh[:, :2])
        return np.column_stack([xy, g0 + a * uvh[:, 0] + b * uvh[:, 1] + uvh[:, 2]])

    return to_world


def car(block: RoadsideBlock, frame: PlanFrame, dims: tuple[float, float, float, str]) -> None:
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


# -- vegetation ----------------------------------------------------------------------------------


CROWN_CLEARANCE = 4.0
"""Lowest leaves above the ground (m): street trees are pruned to clear traffic, and a crown that
reached down over the road would engulf the sensor (a frame cast from inside the leaves)."""


def tree(block: RoadsideBlock, xy: FloatArray, scale: float) -> None:
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


def bush(block: RoadsideBlock, xy: FloatArray, radius: float) -> None:
    """A squat lumpy blob sitting on (and a little in) the ground."""
    rng = block.rng
    z = float(block.ground(xy)[0])
    radii = radius * np.array([1.0, rng.uniform(0.7, 1.4), rng.uniform(0.5, 0.9)])
    centre = [*xy, z + radii[2] * 0.6]
    block.mesh.blob(centre, radii, rng, Surface.VEGETATION, float(rng.uniform(0.35, 0.6)), 0.35, 1)


# -- poles and street clutter --------------------------------------------------------------------


def lamp(block: RoadsideBlock, xy: FloatArray, heading: float, sign: float) -> None:
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


def traffic_light(block: RoadsideBlock, xy: FloatArray, heading: float, sign: float) -> None:
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
    plan = PlanFrame(np.asarray(xy, dtype=np.float64), yaw).to_world(rect(-sx / 2, sx / 2, -sy / 2, sy / 2))
    return np.concatenate([np.column_stack([plan, np.full(4, z0)]), np.column_stack([plan, np.full(4, z1)])])


def power_pole(block: RoadsideBlock, xy: FloatArray, heading: float) -> None:
    """A wooden utility pole with a cross-arm across the road (country roads, villages)."""
    rng = block.rng
    z = float(block.ground(xy)[0])
    height = rng.uniform(7.5, 10.5)
    block.mesh.cylinder([*xy, z - 0.3], [0, 0, 1], 0.14, height, Surface.WOOD, 0.3, 8, 0.11)
    yaw = heading + math.pi / 2 + float(rng.normal(0.0, 0.1))
    block.mesh.hexahedron(
        _upright_box(xy, z + height - 0.8, z + height - 0.65, 2.0, 0.12, yaw), Surface.WOOD, 0.3
    )


def clutter(block: RoadsideBlock, xy: FloatArray, heading: float, kind: str) -> None:
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
