"""The whole procedural world for one seed, handed out as meshes near given positions.

Everything is a pure function of the seed. Geometry is generated lazily in chunks (blocks of
road-side objects, squares of ground) so that a long drive only ever holds what the sensor can reach;
a chunk's content never depends on which other chunks were built before it.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from vcr_odom.synth.layout import StreetLayout, ZoneKind
from vcr_odom.synth.mesh import FloatArray, MeshPart, Surface
from vcr_odom.synth.paths import DrivePath
from vcr_odom.synth.repeating import RepeatedRoadside
from vcr_odom.synth.road import PREROLL, ROAD_CHUNK, ROAD_STEP, Road, Terrain, make_road
from vcr_odom.synth.roadside import BLOCK_LENGTH, RoadsideBlock
from vcr_odom.synth.styles import scene_style

TILE_SIZE = 64.0
"""Side (m) of a square of ground generated at once."""
GROUND_STEP = 2.0
"""Ground grid spacing (m): the hills are smooth (wavelengths >= 120 m), so 2 m facets are exact to mm."""
REACH = 90.0
"""Furthest any road-side object reaches from the road centre line (m); bounds each block's extent."""


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


@dataclass(frozen=True)
class RouteWorld:
    """A route's street and how it is driven (:mod:`~vcr_odom.synth.routes` builds it): the road and
    its plan, the terrain, the path the car follows, and for repeated blocks their period (m)."""

    road: Road
    terrain: Terrain
    layout: StreetLayout
    path: DrivePath
    repeat: float | None = None


class StreetScene:
    """The whole procedural world for one seed; hands out the geometry near given positions.

    Without ``world`` it is the open street of ``length`` metres (plus its preroll), driven once; a
    route's ``world`` gives another street and path (a loop, a figure eight, out and back, repeated
    blocks), built in chunks the same way.
    """

    def __init__(
        self,
        seed: int,
        length: float,
        cache_chunks: int = 512,
        scene: str = "suburban",
        world: RouteWorld | None = None,
    ) -> None:
        self.seed = seed
        self.style_name = scene
        style = scene_style(scene)
        self._repeated: RepeatedRoadside | None = None
        if world is None:
            road_length = PREROLL + math.ceil(max(length, 1.0) / ROAD_CHUNK) * ROAD_CHUNK
            self.road = make_road(np.random.default_rng([seed, 1]), road_length, style.road)
            self.terrain = Terrain.random(np.random.default_rng([seed, 2]))
            self.layout = StreetLayout(self.road, self.terrain, np.random.default_rng([seed, 3]), style)
            self.path = DrivePath.along(self.road)
        else:
            self.road = world.road
            self.terrain = world.terrain
            self.layout = world.layout
            self.path = world.path
            if world.repeat is not None:
                rng = np.random.default_rng([seed, 10])
                self._repeated = RepeatedRoadside(self.layout, world.repeat, rng)
        self._cache: OrderedDict[tuple[int, int, int], MeshPart] = OrderedDict()
        self._cache_chunks = cache_chunks
        block_length = BLOCK_LENGTH if world is None or world.repeat is None else world.repeat
        n_blocks = math.ceil(self.road.length / block_length)
        boxes = []
        for b in range(n_blocks):
            lo = int(b * block_length / ROAD_STEP)
            xy = self.road.xy[lo : int((b + 1) * block_length / ROAD_STEP) + 1]
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
        if kind == 0 and self._repeated is not None:
            part = self._repeated.block(a)
        elif kind == 0:
            part = RoadsideBlock(self.layout, a, np.random.default_rng([self.seed, 10, a])).build()
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
