"""A synthetic sequence: what to generate (:class:`SynthConfig`) and the drive itself
(:class:`SynthSequence`), a :class:`~vcr_odom.data.base.LidarSequence` whose frames are ray-cast on
demand.

Conventions: LiDAR frame x forward, y left, z up; poses are LiDAR-frame 4x4 matrices with frame 0 =
identity, the convention of every sequence the odometry reads.
"""

from __future__ import annotations

from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, field_validator

from vcr_odom.geometry import invert
from vcr_odom.settings import Settings
from vcr_odom.synth.calibration import KITTI_TR
from vcr_odom.synth.drive import Drive, make_drive
from vcr_odom.synth.scene import StreetScene
from vcr_odom.synth.sensor import SENSOR_MODELS, LidarSimulator, MountingHeight, SensorConfig
from vcr_odom.synth.styles import SCENE_STYLES

FRAME_PERIOD = 0.1
"""Seconds between frames by default: the HDL-64E spins at 10 Hz in KITTI."""
HEIGHT_RANGE = (1.5, 2.1)
"""Mounting heights (m) :meth:`SynthSequence.varied` draws from: low hatchbacks to vans and roof racks."""


class SynthConfig(Settings):
    """What a synthetic sequence is: its length, seed, speed, sensor, street style, stops and frame rate.

    The same configuration always gives byte-identical frames and poses (shipped weights and training
    caches were made from them). ``sensor`` may be given as a preset name (:data:`SENSOR_MODELS`);
    ``height`` overrides its mounting height (m). ``window`` is how many consecutive frames share one
    ray-casting scene: it bounds memory and never changes a frame.
    """

    frames: int = Field(default=200, ge=2, description="Number of frames.")
    seed: int = Field(
        default=0,
        ge=0,
        description="Seed of the scene and the drive; the same seed writes byte-identical files.",
    )
    speed: float = Field(
        default=10.0,
        ge=1.0,
        le=30.0,
        description="Typical speed in m/s; the drive varies between 0.5x and 1.5x and slows for turns.",
    )
    sensor: SensorConfig = Field(default_factory=SensorConfig)
    height: MountingHeight | None = None
    scene: str = "suburban"
    stops: bool = False
    frame_period: float = Field(default=FRAME_PERIOD, ge=0.02, le=1.0)
    """Seconds between frames: 1-50 Hz."""
    window: int = Field(default=200, ge=1)

    @field_validator("sensor", mode="before")
    @classmethod
    def _sensor_by_name(cls, value: Any) -> Any:
        if value is None:
            return SensorConfig()
        if isinstance(value, str):
            if value not in SENSOR_MODELS:
                raise ValueError(f"must be one of {', '.join(SENSOR_MODELS)}")
            return SensorConfig.model(value)
        return value

    @field_validator("scene")
    @classmethod
    def _known_scene(cls, value: str) -> str:
        if value not in SCENE_STYLES:
            raise ValueError(f"must be one of {', '.join(SCENE_STYLES)}")
        return value

    @property
    def mounted_sensor(self) -> SensorConfig:
        """The sensor at its mounting height (``height`` when given)."""
        return self.sensor if self.height is None else self.sensor.with_changes(height=self.height)


class SynthSequence:
    """A synthetic drive as a :class:`~vcr_odom.data.base.LidarSequence`, generated on demand.

    Built from a :class:`SynthConfig`, from its fields as keywords (``SynthSequence(frames=6,
    seed=2)``), or both (keywords change the given configuration). The defaults give the original
    sequences, byte for byte.

    Frames are ray-cast in windows of ``window`` frames: each window gets one ray-casting scene of
    everything the sensor can reach from its poses, so memory and build time stay bounded for any
    length and a frame's content never depends on which frames were asked for before.
    """

    def __init__(self, config: SynthConfig | None = None, /, **options: Any) -> None:
        if config is None:
            config = SynthConfig(**options)
        elif not isinstance(config, SynthConfig):
            raise TypeError(f"SynthSequence takes a SynthConfig or keyword options, got {config!r}")
        elif options:
            config = config.with_changes(**options)
        self.config = config
        self.frames = config.frames
        self.seed = config.seed
        self.speed = config.speed
        self.sensor = config.mounted_sensor
        self.window = config.window
        self.scene_style = config.scene
        self.stops = config.stops
        self.frame_period = config.frame_period
        extras = [config.scene] if config.scene != "suburban" else []
        extras += [self.sensor.name] if self.sensor.name != "hdl64" else []
        self.name = "-".join([f"synth-seed{config.seed}", *extras])
        self._simulators: dict[int, LidarSimulator] = {}

    @classmethod
    def varied(cls, seed: int, frames: int = 200, window: int = 200) -> SynthSequence:
        """A drive with a random sensor, mounting height, scene style, speed and stops (all drawn from
        ``seed``), so training data covers more than one car and one kind of street."""
        rng = np.random.default_rng([seed, 6])
        scene = str(rng.choice(SCENE_STYLES))
        speeds = {"highway": (18.0, 28.0), "avenue": (8.0, 16.0), "oldtown": (3.0, 8.0)}
        # Drawn in this order (speed, sensor, height, stops): the same seed gives the same drive.
        speed = float(rng.uniform(*speeds.get(scene, (6.0, 14.0))))
        sensor = str(rng.choice(SENSOR_MODELS))
        height = float(rng.uniform(*HEIGHT_RANGE))
        stops = scene != "highway" and bool(rng.random() < 0.5)
        return cls(
            frames=frames,
            seed=seed,
            speed=speed,
            sensor=sensor,
            window=window,
            height=height,
            scene=scene,
            stops=stops,
        )

    @cached_property
    def scene(self) -> StreetScene:
        # Road long enough for the fastest possible drive plus what the sensor sees beyond its end.
        reach = self.frames * self.frame_period * self.speed * 1.5 + self.sensor.max_range + 60.0
        return StreetScene(self.seed, reach, scene=self.scene_style)

    @cached_property
    def drive(self) -> Drive:
        return make_drive(
            self.scene,
            frames=self.frames,
            speed=self.speed,
            height=self.sensor.height,
            seed=self.seed,
            stops=self.stops,
            frame_period=self.frame_period,
        )

    def __len__(self) -> int:
        return self.frames

    @property
    def world_poses(self) -> NDArray[np.float64]:
        """LiDAR -> world poses of the procedural world (not re-anchored)."""
        return self.drive.world_poses

    @cached_property
    def _relative_poses(self) -> NDArray[np.float64]:
        return invert(self.world_poses[0])[None] @ self.world_poses

    @property
    def gt_poses(self) -> NDArray[np.float64]:
        """LiDAR-frame poses with frame 0 = identity; a copy, safe to modify."""
        return self._relative_poses.copy()

    @property
    def timestamps(self) -> NDArray[np.float64]:
        return np.arange(self.frames) * self.frame_period

    @property
    def timestamps_assumed(self) -> bool:
        """The drive's own clock: never a guess."""
        return False

    @property
    def tr_velo_to_cam(self) -> NDArray[np.float64]:
        return KITTI_TR.copy()

    @property
    def length(self) -> float:
        """Length of the drive in metres."""
        return self.drive.length

    def frame(self, index: int) -> NDArray[np.float32]:
        """Ray-cast frame ``index``: float32 ``(N, 4)`` in the LiDAR frame, like a KITTI ``.bin``."""
        if not 0 <= index < self.frames:
            raise IndexError(f"frame {index} out of range for a sequence of {self.frames} frames")
        simulator = self._simulator(index // self.window)
        return simulator.scan(self.world_poses[index], np.random.default_rng([self.seed, 5, index]))

    def frame_and_pose(self, index: int) -> tuple[NDArray[np.float32], NDArray[np.float64]]:
        """A frame and its LiDAR-frame ground-truth pose (frame 0 = identity), without writing."""
        return self.frame(index), self._relative_poses[index].copy()

    def _simulator(self, window: int) -> LidarSimulator:
        if window not in self._simulators:
            self._simulators.clear()  # one window at a time keeps memory flat
            poses = self.world_poses[window * self.window : (window + 1) * self.window]
            mesh = self.scene.mesh_near(poses[:, :2, 3], self.sensor.max_range + 1.0)
            self._simulators[window] = LidarSimulator(mesh, self.sensor)
        return self._simulators[window]
