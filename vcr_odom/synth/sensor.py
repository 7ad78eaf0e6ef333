"""The LiDAR: sensor models (scan patterns, noise, ranges) and the ray caster that scans a scene mesh
with one of them.

The default imitates KITTI's HDL-64E; presets (:data:`SENSOR_MODELS`) add the HDL-32E, VLP-16,
OS1-128 and OS0-128 (a 90 deg field for indoor walks), so training data covers more than one beam
pattern, and two solid-state Livox-like scanners whose non-repetitive patterns never sample the scene
the same way twice:

- ``avia`` (Livox Avia-like): a forward-looking rosette, 70.4 deg x 77.2 deg, 240,000 points/s;
- ``mid360`` (Livox Mid-360-like): 360 deg x 59 deg (-7 to +52 deg elevation), 200,000 points/s.

A spinning sensor's frame is one revolution of fixed rays, turned by a random phase; a solid-state
sensor's rays depend on when the frame was scanned (:meth:`SensorConfig.directions`).
"""

from __future__ import annotations

import math
import os
from typing import Annotated, Any, Literal, Self

import numpy as np
import open3d as o3d
from numpy.typing import NDArray
from pydantic import Field, model_validator

from vcr_odom.errors import ConfigError
from vcr_odom.geometry import rotation_from_euler_zyx
from vcr_odom.settings import Settings
from vcr_odom.synth.mesh import MeshPart, Surface

SPINNING_MODELS = ("hdl64", "hdl32", "vlp16", "os128", "os0")
"""The spinning presets."""
VARIED_MODELS = ("hdl64", "hdl32", "vlp16", "os128")
"""The spinning presets :meth:`~vcr_odom.synth.SynthSequence.varied` draws from: fixed, since adding
a name would change every varied drive (and the training data made from them)."""
SOLID_STATE_MODELS = ("avia", "mid360")
"""The solid-state presets, non-repetitive Livox-like scanners."""
SENSOR_MODELS = SPINNING_MODELS + SOLID_STATE_MODELS
"""Names accepted by :meth:`SensorConfig.model` (``hdl64`` is the default :class:`SensorConfig`)."""

ScanPattern = Literal["spinning", "rosette", "mid360"]
"""How the rays sweep the scene: ``spinning`` (rings of beams, one revolution per frame), ``rosette``
(a Risley-prism pair, Livox Avia-like) or ``mid360`` (a spinning head whose beams nod up and down at an
unrelated rate, Livox Mid-360-like)."""
SOLID_STATE_FIELDS = ("points_per_second", "integration_time", "channels", "horizontal_fov", "elevation_fov")
"""The :class:`SensorConfig` fields of the solid-state patterns (None for a spinning sensor)."""
PATTERN_EPOCH_S = 3600.0
"""A frame of a solid-state sensor scanned without a given time starts at a random time within this
many seconds of scanning: its pattern is then unlike any other frame's."""

_GOLDEN = (1.0 + math.sqrt(5.0)) / 2.0
# Rosette: two wedge prisms turning in opposite directions at rates in the golden ratio (the "most
# irrational" ratio, so the rose never closes). About 120 Hz, like the prisms of Livox's Mid-40;
# a channel draws about 20 petals per 100 ms and the petal axes turn 2.3 times.
_PRISM_HZ = (121.6, -121.6 / _GOLDEN)
# Mid-360: the head turns at about 10 Hz (one revolution per 100 ms frame); the beams nod 43.618 times a
# revolution, so every revolution the nodding has moved on by 0.618 of a nod (the pattern precesses).
# 43.6 nods per revolution spaces the sweeps as far apart as the points along a sweep.
_HEAD_HZ = 10.0
_NODS_PER_TURN = 43.0 + 1.0 / _GOLDEN

MountingHeight = Annotated[float, Field(ge=0.3, le=5.0)]
"""Sensor height above the ground (m): from a low robot to the roof rack of a truck."""
BeamBlock = tuple[float, float, Annotated[int, Field(ge=1)]]
"""Evenly spaced beam elevations ``(top_deg, bottom_deg, count)``."""


class SensorConfig(Settings):
    """A LiDAR; the defaults are KITTI's HDL-64E, a spinning sensor.

    Spinning sensors (``pattern="spinning"``): beams are given as blocks of evenly spaced elevations
    ``(top_deg, bottom_deg, count)``, top first. Like the real HDL-64E, the default has two: 32 upper
    lasers about 1/3 deg apart and 32 lower lasers about 1/2 deg apart, spanning +2 deg to -24.8 deg.

    Solid-state sensors (``pattern="rosette"`` or ``"mid360"``) are given by their field of view,
    point rate, laser channels and integration time (:data:`SOLID_STATE_FIELDS`, all needed; a spinning
    sensor leaves them None), and ignore ``beam_blocks``, ``azimuth_steps`` and ``azimuth_spread``.
    Other sensors: :meth:`model`.
    """

    name: str = "hdl64"
    pattern: ScanPattern = "spinning"
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
    points_per_second: float | None = Field(default=None, gt=0)
    """Solid-state: rays fired per second, all channels together."""
    integration_time: float | None = Field(default=None, gt=0, le=1.0)
    """Solid-state: seconds of scanning gathered into one frame."""
    channels: int | None = Field(default=None, ge=1)
    """Solid-state: lasers firing together (a rosette's are offset along its longer field of view)."""
    horizontal_fov: float | None = Field(default=None, gt=0, le=360)
    """Solid-state: horizontal field of view (deg), centred straight ahead; 360 for ``mid360``."""
    elevation_fov: tuple[float, float] | None = None
    """Solid-state: lowest and highest elevation (deg)."""

    @model_validator(mode="after")
    def _min_range_below_max_range(self) -> Self:
        if self.min_range >= self.max_range:
            raise ValueError(
                f"min_range must be below max_range; got {self.min_range:g} and {self.max_range:g}"
            )
        return self

    @model_validator(mode="after")
    def _pattern_has_its_fields(self) -> Self:
        """Each pattern's own fields are given, and only those: a field that would be silently ignored
        is refused instead."""
        if self.pattern == "spinning":
            for field in SOLID_STATE_FIELDS:
                if getattr(self, field) is not None:
                    raise ValueError(f"{field} applies to the rosette and mid360 patterns, not to spinning")
            return self
        for field in SOLID_STATE_FIELDS:
            if getattr(self, field) is None:
                raise ValueError(f"{field} is needed for the {self.pattern} pattern")
        _check_solid_state(self)
        return self

    @classmethod
    def model(cls, name: str) -> SensorConfig:
        """A named sensor preset (see :data:`SENSOR_MODELS`); ``hdl64`` equals ``SensorConfig()``."""
        if name not in _SENSOR_PRESETS:
            raise ConfigError(f"sensor must be one of {', '.join(SENSOR_MODELS)}, got {name!r}")
        return cls(name=name, **_SENSOR_PRESETS[name])

    @property
    def spinning(self) -> bool:
        return self.pattern == "spinning"

    @property
    def n_beams(self) -> int:
        """Lasers: a spinning sensor's beams, a solid-state sensor's channels."""
        if not self.spinning:
            return int(self.channels or 0)
        return sum(int(count) for *_, count in self.beam_blocks)

    @property
    def elevations(self) -> NDArray[np.float64]:
        """Beam elevation angles in radians, top beam first (spinning sensors only)."""
        if not self.spinning:
            raise ValueError(f"a {self.pattern} sensor has no fixed beam elevations")
        blocks = [np.linspace(top, bottom, int(count)) for top, bottom, count in self.beam_blocks]
        return np.radians(np.concatenate(blocks))

    @property
    def n_rays(self) -> int:
        """Rays cast for one frame (before misses, dropout and range limits)."""
        if not self.spinning:
            return self.n_beams * self._rays_per_channel(self.integration_time or 0.0)
        return self.n_beams * self.azimuth_steps

    def _rays_per_channel(self, duration: float) -> int:
        return round(float(self.points_per_second or 0.0) * duration / self.n_beams)

    @property
    def beam_azimuth_offsets(self) -> NDArray[np.float64]:
        """Fixed per-laser azimuth offsets (radians, within +-``azimuth_spread`` deg), like the rotational
        corrections of a real HDL-64E: its 64 lasers do not fire along one vertical line."""
        if self.azimuth_spread <= 0.0:
            return np.zeros(self.n_beams)
        spread = self.azimuth_spread
        return np.radians(np.random.default_rng(64).uniform(-spread, spread, self.n_beams))

    def directions(self, start: float = 0.0, duration: float | None = None) -> NDArray[np.float64]:
        """Unit ray directions ``(n, 3)`` in the LiDAR frame.

        Spinning: one revolution (``n_rays``), laser by laser (KITTI's ring order), each ring turning
        clockwise from straight behind like the real sensor; a revolution is the same whenever it is
        scanned, so ``start`` and ``duration`` must be left out.

        Solid-state: the rays fired from ``start`` (s of scanning) for ``duration`` (s; default
        ``integration_time``), channel by channel in firing order. The pattern never repeats, so two
        different start times give different rays, and a longer duration covers the field more densely.
        """
        if not self.spinning:
            return self._solid_state_directions(
                start, self.integration_time if duration is None else duration
            )
        if start != 0.0 or duration is not None:
            raise ValueError("a spinning sensor's frame is one revolution: start and duration do not apply")
        elevation = self.elevations[:, None]
        steps = np.arange(self.azimuth_steps) * (2.0 * math.pi / self.azimuth_steps)
        azimuth = math.pi - steps[None, :] + self.beam_azimuth_offsets[:, None]
        ce = np.cos(elevation)
        directions = np.stack(
            [ce * np.cos(azimuth), ce * np.sin(azimuth), np.broadcast_to(np.sin(elevation), azimuth.shape)],
            -1,
        )
        return directions.reshape(-1, 3)

    def _solid_state_directions(self, start: float, duration: float | None) -> NDArray[np.float64]:
        """The pattern's azimuth and elevation at each firing time, as unit vectors."""
        if duration is None or duration <= 0.0:
            raise ValueError(f"duration must be positive; got {duration}")
        rate = float(self.points_per_second or 0.0) / self.n_beams
        times = start + np.arange(self._rays_per_channel(duration)) / rate
        pattern = _rosette if self.pattern == "rosette" else _mid360
        azimuth, elevation = pattern(self, times)
        ce = np.cos(elevation)
        return np.stack([ce * np.cos(azimuth), ce * np.sin(azimuth), np.sin(elevation)], -1).reshape(-1, 3)


def _check_solid_state(sensor: SensorConfig) -> None:
    """Field-of-view bounds each solid-state pattern can draw (raises ValueError naming the field)."""
    bottom, top = sensor.elevation_fov or (0.0, 0.0)
    if not -90.0 <= bottom < top <= 90.0:
        raise ValueError(
            f"elevation_fov must be (bottom, top) with -90 <= bottom < top <= 90; got {(bottom, top)}"
        )
    if sensor.pattern == "mid360" and sensor.horizontal_fov != 360.0:
        raise ValueError(
            f"horizontal_fov must be 360 for the mid360 pattern (its head spins); got {sensor.horizontal_fov:g}"
        )
    if sensor.pattern == "rosette":
        width = float(sensor.horizontal_fov or 0.0)
        if width > 180.0:
            raise ValueError(
                f"horizontal_fov of a rosette must be at most 180 (it looks ahead); got {width:g}"
            )
        if sensor.channels == 1 and not math.isclose(width, top - bottom):
            raise ValueError(
                "elevation_fov must span horizontal_fov for a one-channel rosette (a rose is round); "
                f"got {top - bottom:g} and {width:g}"
            )
    if sensor.n_rays < 1:
        raise ValueError("points_per_second x integration_time gives less than one ray per channel")


def _rosette(
    sensor: SensorConfig, times: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Azimuth and elevation ``(channels, n)`` (radians) of a Risley-prism pair, Livox Avia-like.

    Each prism deflects the beam by a fixed angle in the direction it has turned to; the two
    deflections add, so the beam traces a rose of radius twice the deflection about the optical axis
    (straight ahead, at the middle of ``elevation_fov``). The prisms turn at irrationally related rates,
    so the rose never closes and the petals keep turning: the longer the scan, the fuller the circle.
    The channels share the prisms and are offset from each other along the longer field of view,
    stretching the circle to the full ``horizontal_fov`` x ``elevation_fov``.
    """
    bottom, top = sensor.elevation_fov or (0.0, 0.0)
    width, height = float(sensor.horizontal_fov or 0.0), top - bottom
    radius = min(width, height) / 2.0
    spread = abs(width - height) / 2.0
    offsets = np.linspace(-spread, spread, sensor.n_beams) if sensor.n_beams > 1 else np.zeros(1)
    # Deflection in the plane across the optical axis (deg): horizontal and vertical components.
    angles = [2.0 * math.pi * hz * times for hz in _PRISM_HZ]
    across = radius / 2.0 * (np.cos(angles[0]) + np.cos(angles[1]))
    up = radius / 2.0 * (np.sin(angles[0]) + np.sin(angles[1]))
    along_width = offsets[:, None] if width > height else 0.0
    along_height = offsets[:, None] if width <= height else 0.0
    azimuth = np.broadcast_to(across[None, :] + along_width, (len(offsets), len(times)))
    elevation = np.broadcast_to((bottom + top) / 2.0 + up[None, :] + along_height, azimuth.shape)
    return np.radians(azimuth), np.radians(elevation)


def _mid360(
    sensor: SensorConfig, times: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Azimuth and elevation ``(channels, n)`` (radians) of a Livox Mid-360-like scanner.

    The head turns at about :data:`_HEAD_HZ` (:func:`_head_hz`); each beam nods sinusoidally across
    ``elevation_fov`` a non-integer number of times per revolution, so each revolution's sweeps fall
    between the last one's (the pattern precesses and never repeats). The channels look the same way
    but nod out of step, by 1/(2 x channels) of a nod each, so that their rising and falling sweeps
    interleave evenly.
    """
    bottom, top = sensor.elevation_fov or (0.0, 0.0)
    turn = 2.0 * math.pi * _head_hz(float(sensor.points_per_second or 0.0) / sensor.n_beams) * times
    stagger = math.pi * np.arange(sensor.n_beams)[:, None] / sensor.n_beams
    nod = np.sin(_NODS_PER_TURN * turn[None, :] + stagger)
    elevation = np.radians((bottom + top) / 2.0 + (top - bottom) / 2.0 * nod)
    azimuth = np.broadcast_to(np.mod(turn + math.pi, 2.0 * math.pi) - math.pi, elevation.shape)
    return azimuth, elevation


def _head_hz(shots_per_second: float) -> float:
    """About :data:`_HEAD_HZ`, set so that a revolution holds a whole number of shots and 0.618 of
    one: at exactly 10 Hz and 50,000 shots/s, every revolution would fire at the same azimuths."""
    whole = max(round(shots_per_second / _HEAD_HZ) - 1, 0)
    return shots_per_second / (whole + 1.0 / _GOLDEN)


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
    # Ouster OS0-128 in its 1024x10 mode: the OS1-128's noise and reflectance, a 90 deg vertical field
    # (-45 to +45 deg: floor and ceiling close by indoors), 0.3-50 m.
    "os0": {
        "beam_blocks": ((45.0, -45.0, 128),), "azimuth_steps": 1024, "range_noise": 0.03,
        "min_range": 0.3, "max_range": 50.0, "azimuth_spread": 0.0,
    },
    # Livox Avia, non-repetitive (circular) scan: 70.4 x 77.2 deg, 6 lasers, 240,000 points/s (first
    # return), 2 cm range precision (1 sigma at 20 m), 1 m blind zone; detection 190 m at 10 %
    # reflectivity (320 m at 80 %: few scene surfaces lie farther away than 190 m along a street).
    "avia": {
        "pattern": "rosette", "points_per_second": 240_000.0, "integration_time": 0.1, "channels": 6,
        "horizontal_fov": 70.4, "elevation_fov": (-38.6, 38.6), "range_noise": 0.02,
        "min_range": 1.0, "max_range": 190.0, "azimuth_spread": 0.0,
    },
    # Livox Mid-360: 360 x 59 deg (-7 to +52 deg), 200,000 points/s, 10 Hz frames, 0.1 m blind zone;
    # detection 40 m at 10 % and 70 m at 80 % reflectivity; range precision 2 cm at 10 m (3 cm close
    # up). Four channels spread around the head is a modelling choice, not the published design.
    "mid360": {
        "pattern": "mid360", "points_per_second": 200_000.0, "integration_time": 0.1, "channels": 4,
        "horizontal_fov": 360.0, "elevation_fov": (-7.0, 52.0), "range_noise": 0.02,
        "min_range": 0.1, "max_range": 70.0, "azimuth_spread": 0.0,
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
        # A spinning sensor's rays are fixed (turned per frame); a solid-state one's are made per frame.
        self._directions = sensor.directions().astype(np.float32) if sensor.spinning else None
        self._threads = _available_cores()
        self._scene = o3d.t.geometry.RaycastingScene()
        if len(mesh):
            self._scene.add_triangles(
                o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                o3d.core.Tensor(mesh.triangles.astype(np.uint32)),
            )

    def scan(
        self, pose: NDArray[np.float64], rng: np.random.Generator, time: float | None = None
    ) -> NDArray[np.float32]:
        """Points ``(N, 4)`` float32 (x, y, z in the LiDAR frame, reflectance in [0, 1]) for a sensor
        at world pose ``pose`` (LiDAR -> world).

        Two frames never share a sampling pattern a network could lock on to. A spinning sensor's
        phase is random per frame (a real sensor's firing grid is not locked to the car); it ignores
        ``time``, so its draws, and its frames, stay those of every earlier version. A solid-state
        sensor scans from ``time`` (s; consecutive frames' times continue its pattern) or, when None,
        from a random time within :data:`PATTERN_EPOCH_S` drawn from ``rng``.
        """
        directions, spin = self._frame_rays(rng, time)
        return self._cast(pose, spin, directions, rng)

    def _frame_rays(
        self, rng: np.random.Generator, time: float | None
    ) -> tuple[NDArray[np.float32], NDArray[np.float64]]:
        """This frame's ray directions in the sensor and the turn (about z) that still applies to them."""
        sensor = self.sensor
        if self._directions is not None:
            phase = rng.uniform(0.0, 2.0 * math.pi / sensor.azimuth_steps)
            return self._directions, rotation_from_euler_zyx(-phase, 0.0, 0.0)
        start = rng.uniform(0.0, PATTERN_EPOCH_S) if time is None else time
        return sensor.directions(start).astype(np.float32), np.eye(3)

    def _cast(
        self,
        pose: NDArray[np.float64],
        spin: NDArray[np.float64],
        directions: NDArray[np.float32],
        rng: np.random.Generator,
    ) -> NDArray[np.float32]:
        """Cast ``directions`` (turned by ``spin``) from ``pose``; noise, dropout and reflectance."""
        sensor = self.sensor
        axes = np.ascontiguousarray(directions.T)  # x, y, z rows: fast gathers per axis
        rays = np.empty((len(directions), 6), dtype=np.float32)
        rays[:, :3] = pose[:3, 3]
        _rotate_into(directions, pose[:3, :3] @ spin, rays[:, 3:])
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
        x, y, z = (axes[i][keep] for i in range(3))
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
