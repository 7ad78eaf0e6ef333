"""Triangle meshes of the synthetic world: what each triangle is made of, and the primitives
(boxes, cylinders, lumpy blobs) every scene part is built from."""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


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
