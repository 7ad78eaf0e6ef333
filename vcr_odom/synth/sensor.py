"""The spinning LiDAR: sensor models (beam layouts, noise, ranges) and the ray caster that scans a
scene mesh with one of them.

The default imitates KITTI's HDL-64E; presets (:data:`SENSOR_MODELS`) add the HDL-32E, VLP-16 and
OS1-128, so training data covers more than one beam pattern.
"""

from __future__ import annotations

import math
import os
from typing import Annotated, Any, Self

import numpy as np
import open3d as o3d
from numpy.typing import NDArray
from pydantic import Field, model_validator

from vcr_odom.errors import ConfigError
from vcr_odom.geometry import rotation_from_euler_zyx
from vcr_odom.settings import Settings
from vcr_odom.synth.mesh import MeshPart, Surface

SENSOR_MODELS = ("hdl64", "hdl32", "vlp16", "os128")
"""Names accepted by :meth:`SensorConfig.model` (``hdl64`` is the default :class:`SensorConfig`)."""

MountingHeight = Annotated[float, Field(ge=0.3, le=5.0)]
"""Sensor height above the ground (m): from a low robot to the roof rack of a truck."""
BeamBlock = tuple[float, float, Annotated[int, Field(ge=1)]]
"""Evenly spaced beam elevations ``(top_deg, bottom_deg, count)``."""


class SensorConfig(Settings):
    """A spinning LiDAR; the defaults are KITTI's HDL-64E.

    Beams are given as blocks of evenly spaced elevations ``(top_deg, bottom_deg, count)``, top first.
    Like the real HDL-64E, the default has two: 32 upper lasers about 1/3 deg apart and 32 lower lasers
    about 1/2 deg apart, spanning +2 deg to -24.8 deg. Other sensors: :meth:`model`.
    """

    name: str = "hdl64"
    beam_blocks: tuple[BeamBlock, ...] = Field(default=((2.0, -8.33, 32), (-8.83, -24.8, 32)), min_length=1)
    azimuth_steps: int = Field(default=2083, ge=1)
    range_noise: float = Field(default=0.02, ge=0)
    """Standard deviation of the range noise (m)."""
    min_range: float = Field(default=2.5, ge=0)
    max_range: float = Field(default=120.0, gt=0)
    height: MountingHeight = 1.73
    dropout: float = Field(default=0.02, ge=0, le=1)
    """Probability that a hit returns nothing (at least; glass and leaves lose more)."""
    reflectance_noise: float = Field(default=0.03, ge=0)
    azimuth_spread: float = Field(default=4.0, ge=0)
    """Per-laser azimuth offsets are drawn within +-this (deg); 0 where lasers fire in one column."""

    @model_validator(mode="after")
    def _min_range_below_max_range(self) -> Self:
        if self.min_range >= self.max_range:
            raise ValueError(
                f"min_range must be below max_range; got {self.min_range:g} and {self.max_range:g}"
            )
        return self

    @classmethod
    def model(cls, name: str) -> SensorConfig:
        """A named sensor preset (see :data:`SENSOR_MODELS`); ``hdl64`` equals ``SensorConfig()``."""
        if name not in _SENSOR_PRESETS:
            raise ConfigError(f"sensor must be one of {', '.join(SENSOR_MODELS)}, got {name!r}")
        return cls(name=name, **_SENSOR_PRESETS[name])

    @property
    def n_beams(self) -> int:
        return sum(int(count) for *_, count in self.beam_blocks)

    @property
    def elevations(self) -> NDArray[np.float64]:
        """Beam elevation angles in radians, top beam first."""
        blocks = [np.linspace(top, bottom, int(count)) for top, bottom, count in self.beam_blocks]
        return np.radians(np.concatenate(blocks))

    @property
    def n_rays(self) -> int:
        return self.n_beams * self.azimuth_steps

    @property
    def beam_azimuth_offsets(self) -> NDArray[np.float64]:
        """Fixed per-laser azimuth offsets (radians, within +-``azimuth_spread`` deg), like the rotational
        corrections of a real HDL-64E: its 64 lasers do not fire along one vertical line."""
        if self.azimuth_spread <= 0.0:
            return np.zeros(self.n_beams)
        spread = self.azimuth_spread
        return np.radians(np.random.default_rng(64).uniform(-spread, spread, self.n_beams))

    def directions(self) -> NDArray[np.float64]:
        """Unit ray directions ``(n_rays, 3)`` in the LiDAR frame, laser by laser (KITTI's ring order),
        each ring turning clockwise from straight behind like the real sensor."""
        elevation = self.elevations[:, None]
        steps = np.arange(self.azimuth_steps) * (2.0 * math.pi / self.azimuth_steps)
        azimuth = math.pi - steps[None, :] + self.beam_azimuth_offsets[:, None]
        ce = np.cos(elevation)
        directions = np.stack(
            [ce * np.cos(azimuth), ce * np.sin(azimuth), np.broadcast_to(np.sin(elevation), azimuth.shape)],
            -1,
        )
        return directions.reshape(-1, 3)


_SENSOR_PRESETS: dict[str, dict[str, Any]] = {
    "hdl64": {},
    # Velodyne HDL-32E: 32 lasers 1.33 deg apart, 0.2 deg azimuth at 10 Hz, +-2 cm accuracy.
    "hdl32": {
        "beam_blocks": ((10.67, -30.67, 32),), "azimuth_steps": 1800, "range_noise": 0.015,
        "min_range": 1.0, "max_range": 100.0, "azimuth_spread": 0.0,
    },
    # Velodyne VLP-16 (Puck): 16 lasers 2 deg apart, 0.2 deg azimuth at 10 Hz, +-3 cm accuracy.
    "vlp16": {
        "beam_blocks": ((15.0, -15.0, 16),), "azimuth_steps": 1800, "range_noise": 0.03,
        "min_range": 1.0, "max_range": 100.0, "azimuth_spread": 0.0,
    },
    # Ouster OS1-128 in its 1024x10 mode: 45 deg vertical field, a few cm of range noise.
    "os128": {
        "beam_blocks": ((22.5, -22.5, 128),), "azimuth_steps": 1024, "range_noise": 0.03,
        "min_range": 0.8, "max_range": 120.0, "azimuth_spread": 0.0,
    },
}  # fmt: skip


# Per-surface sensor behaviour (albedo itself is per triangle, in the MeshPart): the probability that
# a hit returns nothing (glass), a one-sided range spread (m) into porous foliage, and retro-reflectors
# (signs, road paint) that stay bright at grazing incidence.
_NO_RETURN = np.zeros(len(Surface), dtype=np.float32)
_NO_RETURN[Surface.GLASS] = 0.6
_NO_RETURN[Surface.CAR_GLASS] = 0.45
_NO_RETURN[Surface.VEGETATION] = 0.1
_POROUS = np.zeros(len(Surface), dtype=np.float32)
_POROUS[Surface.VEGETATION] = 0.12
_RETRO = np.zeros(len(Surface), dtype=bool)
_RETRO[[Surface.SIGN, Surface.PAINT]] = True


class LidarSimulator:
    """Ray-casts one scene with open3d's Embree-backed :class:`RaycastingScene`: one call per frame."""

    def __init__(self, mesh: MeshPart, sensor: SensorConfig) -> None:
        self.sensor = sensor
        self.surface = mesh.surface
        self.albedo = mesh.albedo
        self._directions = sensor.directions().astype(np.float32)
        self._axes = np.ascontiguousarray(self._directions.T)  # x, y, z rows: fast gathers per axis
        self._threads = _available_cores()
        self._scene = o3d.t.geometry.RaycastingScene()
        if len(mesh):
            self._scene.add_triangles(
                o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                o3d.core.Tensor(mesh.triangles.astype(np.uint32)),
            )

    def scan(self, pose: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.float32]:
        """Points ``(N, 4)`` float32 (x, y, z in the LiDAR frame, reflectance in [0, 1]) for a sensor
        at world pose ``pose`` (LiDAR -> world).

        The spin phase is random per frame (a real sensor's firing grid is not locked to the car), so
        two frames never share a sampling pattern a network could lock on to.
        """
        sensor = self.sensor
        phase = rng.uniform(0.0, 2.0 * math.pi / sensor.azimuth_steps)
        spin = rotation_from_euler_zyx(-phase, 0.0, 0.0)
        rays = np.empty((len(self._directions), 6), dtype=np.float32)
        rays[:, :3] = pose[:3, 3]
        _rotate_into(self._directions, pose[:3, :3] @ spin, rays[:, 3:])
        hits = self._scene.cast_rays(o3d.core.Tensor.from_numpy(rays), nthreads=self._threads)
        t_hit = hits["t_hit"].numpy()
        index = np.flatnonzero(t_hit <= sensor.max_range)  # inf (no hit) compares False
        n = len(index)
        t_hit = t_hit[index]
        primitive = hits["primitive_ids"].numpy()[index]
        surface = self.surface[primitive]
        # Range: Gaussian noise everywhere, a one-sided spread into foliage.
        measured = t_hit + rng.standard_normal(n, dtype=np.float32) * np.float32(sensor.range_noise)
        porous = np.flatnonzero(_POROUS[surface])
        measured[porous] += (
            np.abs(rng.standard_normal(len(porous), dtype=np.float32)) * _POROUS[surface[porous]]
        )
        # Incidence over all rays (contiguous, cheaper than gathering first); misses are never selected.
        cos_all = np.einsum("ij,ij->i", hits["primitive_normals"].numpy(), rays[:, 3:])
        reflectance = self._reflectance(surface, self.albedo[primitive], np.abs(cos_all[index]), t_hit, rng)
        returned = rng.random(n, dtype=np.float32) >= np.maximum(
            _NO_RETURN[surface], np.float32(sensor.dropout)
        )
        returned &= (measured >= sensor.min_range) & (measured <= sensor.max_range)
        keep = index[returned]
        r = measured[returned]
        x, y, z = (self._axes[i][keep] for i in range(3))
        c, s = np.float32(spin[0, 0]), np.float32(spin[1, 0])
        return np.stack([(c * x - s * y) * r, (s * x + c * y) * r, z * r, reflectance[returned]], axis=1)

    def _reflectance(
        self,
        surface: NDArray[np.uint8],
        albedo: NDArray[np.float32],
        cos_incidence: NDArray[np.float32],
        distance: NDArray[np.float32],
        rng: np.random.Generator,
    ) -> NDArray[np.float32]:
        """Albedo with a mild incidence falloff (retro-reflectors keep their brightness), weak far returns,
        speckle and a noise floor, quantised to 0.01.

        Shaped by eye after KITTI's HDL-64E scans, whose reflectance is moderate near the car (median
        about 0.3) and weak far away, so that a network trained here meets familiar intensities.
        """
        shading = np.where(_RETRO[surface], 0.85 + 0.15 * cos_incidence, 0.55 + 0.45 * cos_incidence)
        value = albedo * shading / (1.0 + (distance * np.float32(1.0 / 42.0)) ** 6)
        # 10 % speckle plus a constant floor, drawn as one Gaussian of the combined spread.
        sigma = np.sqrt((0.1 * value) ** 2 + np.float32(self.sensor.reflectance_noise) ** 2)
        value += sigma * rng.standard_normal(len(value), dtype=np.float32)
        return np.round(np.clip(value, 0.0, 1.0), 2)


def _rotate_into(
    vectors: NDArray[np.float32], rotation: NDArray[np.float64], out: NDArray[np.float32]
) -> None:
    """``out = vectors @ rotation.T`` column by column: a BLAS call here would start its own threads and
    fight Embree's for the same cores."""
    r = rotation.astype(np.float32)
    for i in range(3):
        np.multiply(vectors[:, 0], r[i, 0], out=out[:, i])
        out[:, i] += vectors[:, 1] * r[i, 1]
        out[:, i] += vectors[:, 2] * r[i, 2]


def _available_cores() -> int:
    """Cores this process may use (Embree's automatic choice over-subscribes shared machines)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)
