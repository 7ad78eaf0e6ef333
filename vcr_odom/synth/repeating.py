"""A street whose roadside repeats exactly (``--route blocks``): the same block of buildings, trees,
poles and clutter every B metres along a straight road over ground that repeats too.

Why: places that look the same but are not are the trap of loop closure (perceptual aliasing); a drive
down such a street never comes back, so any loop found on it is false.

The road is straight along x, the zone is one, and the terrain is made periodic along x with period B
(B a whole number of ground-grid steps), so block k is block 0 moved by k B metres, to float precision.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from vcr_odom.synth.layout import StreetLayout
from vcr_odom.synth.mesh import FloatArray, MeshPart
from vcr_odom.synth.road import ROAD_STEP, Road, Terrain
from vcr_odom.synth.roadside import RoadsideBlock

BLOCK_PERIOD = (30.0, 60.0)
"""Range (m) of the repeat period B, drawn per seed."""
PERIOD_STEP = 2.0
"""B is a multiple of this (the ground grid's spacing), so the ground mesh repeats with the blocks."""


def block_period(rng: np.random.Generator) -> float:
    """The seed's repeat period B (m)."""
    return PERIOD_STEP * round(rng.uniform(*BLOCK_PERIOD) / PERIOD_STEP)


def straight_road(length: float) -> Road:
    """A straight road along +x from the origin."""
    n = math.ceil(length / ROAD_STEP) + 1
    xy = np.column_stack([np.arange(n) * ROAD_STEP, np.zeros(n)])
    return Road(xy, np.zeros(n), np.zeros(n))


def periodic_terrain(terrain: Terrain, period: float) -> Terrain:
    """``terrain`` made periodic along x: every wave's x wavenumber rounded to a multiple of
    2 pi / period (long hills become slopes across the road only), and no tilt along it."""

    def snap(vectors: FloatArray) -> FloatArray:
        unit = 2.0 * math.pi / period
        return np.column_stack([np.round(vectors[:, 0] / unit) * unit, vectors[:, 1]])

    return replace(
        terrain,
        tilt=np.array([0.0, terrain.tilt[1]]),
        wave_vectors=snap(terrain.wave_vectors),
        bump_vectors=snap(terrain.bump_vectors),
        ripple_vectors=snap(terrain.ripple_vectors),
    )


class RepeatedRoadside:
    """Block ``k`` of the roadside is one template block moved ``k`` periods along the road."""

    TEMPLATE = 1
    """Which period of the road the template is built on (any whole one would do)."""

    def __init__(self, layout: StreetLayout, period: float, rng: np.random.Generator) -> None:
        self.period = period
        self._template = RoadsideBlock(layout, self.TEMPLATE, rng, length=period).build()

    def block(self, index: int) -> MeshPart:
        """The roadside of ``[index B, (index + 1) B)``."""
        shift = np.array([(index - self.TEMPLATE) * self.period, 0.0, 0.0])
        t = self._template
        return MeshPart(t.vertices + shift, t.triangles, t.surface, t.albedo)
