"""A synthetic sequence: what to generate (:class:`SynthConfig`) and the drive itself
(:class:`SynthSequence`), a :class:`~vcr_odom.data.base.LidarSequence` whose frames are ray-cast on
demand.

Conventions: LiDAR frame x forward, y left, z up; poses are LiDAR-frame 4x4 matrices with frame 0 =
identity, the convention of every sequence the odometry reads.
"""

from __future__ import annotations

from functools import cached_property
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, field_validator, model_validator

from vcr_odom.geometry import invert
from vcr_odom.settings import Settings
from vcr_odom.synth.calibration import KITTI_TR
from vcr_odom.synth.drive import Drive, drive_travel, make_drive
from vcr_odom.synth.handheld import MAX_SPEED, hand_height, make_walk, walk_travel
from vcr_odom.synth.indoor import INDOOR_ROUTES, INDOOR_SCENE, MAX_HAND_HEIGHT, IndoorScene
from vcr_odom.synth.keyframes import KEYFRAME_ANGLE, select_keyframes, thin_voxels
from vcr_odom.synth.road import Road
from vcr_odom.synth.routes import Route, build_route
from vcr_odom.synth.scene import StreetScene
from vcr_odom.synth.sensor import (
    SENSOR_MODELS,
    VARIED_MODELS,
    LidarSimulator,
    MountingHeight,
    SensorConfig,
)
from vcr_odom.synth.styles import SCENE_STYLES, scene_style

FRAME_PERIOD = 0.1
"""Seconds between frames by default: the HDL-64E spins at 10 Hz in KITTI."""
HEIGHT_RANGE = (1.5, 2.1)
"""Mounting heights (m) :meth:`SynthSequence.varied` draws from: low hatchbacks to vans and roof racks."""
SCENES = (*SCENE_STYLES, INDOOR_SCENE)
"""Every ``--scene``: the street styles (:data:`~vcr_odom.synth.styles.SCENE_STYLES`, what
:meth:`SynthSequence.varied` draws from) and the indoor floor (:mod:`~vcr_odom.synth.indoor`)."""


class SynthConfig(Settings):
    """What a synthetic sequence is: its length, seed, speed, sensor, scene (a street style, or the
    indoor floor), stops, frame rate, motion (a car or a walker with a handheld scanner), route (an
    open street, or one that comes back) and what of it is kept (keyframes, thinning).

    The same configuration always gives byte-identical frames and poses (shipped weights and training
    caches were made from them; the new fields' defaults keep them so). ``sensor`` may be given as a
    preset name (:data:`SENSOR_MODELS`); ``height`` overrides its mounting height (m), or the hand
    height of a walk. ``window`` is how many consecutive frames share one ray-casting scene: it bounds
    memory and never changes a frame. ``frames`` counts the generated frames; with ``keyframes`` only
    some of them make the sequence.
    """

    frames: int = Field(
        default=200, ge=2, le=100_000, description="Number of frames (at most 100000: 2.8 h at 10 Hz)."
    )
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
    scene: str = Field(
        default="suburban",
        description="suburban, avenue, highway, oldtown: street styles. indoor: one floor of a building, "
        "a ring of corridors (2-3.5 m wide, 2.6-3.5 m ceilings) round a core of rooms, with doors, niches, "
        "columns, clutter and a hall or two; walked only (motion handheld) on route loop or return.",
    )
    stops: bool = False
    frame_period: float = Field(default=FRAME_PERIOD, ge=0.02, le=1.0)
    """Seconds between frames: 1-50 Hz."""
    window: int = Field(default=200, ge=1)
    motion: Literal["car", "handheld"] = Field(
        default="car",
        description="car: a car drives the road. handheld: a person walks beside the road, or the corridors "
        "of the indoor scene (1.0-1.6 m/s, "
        "pauses, step bobbing, tilts up to +-15 deg, look-around turns up to 90 deg/s) holding the "
        "sensor 1.2-1.6 m high (--height sets it).",
    )
    keyframes: float | None = Field(
        default=None,
        gt=0.0,
        le=100.0,
        description="Keep only keyframes: frames where the sensor moved at least this many metres or "
        "turned at least --keyframe-angle since the last kept one (e.g. 1.0); times and poses are "
        "those of the kept frames. Default: every frame.",
    )
    keyframe_angle: float = Field(
        default=KEYFRAME_ANGLE,
        gt=0.0,
        le=180.0,
        description="With --keyframes: a turn of this many degrees also makes a keyframe.",
    )
    thin: float | None = Field(
        default=None,
        ge=0.01,
        le=10.0,
        description="Voxel-thin each written cloud to one measured point (with its reflectance) per "
        "cube of this size in m (e.g. 0.3). Default: no thinning.",
    )
    route: Route = Field(
        default="street",
        description="street: an open street driven once. loop: a closed street driven about 1.25 times "
        "round (revisits in the same direction). figure8: a street crossing itself, driven about 1.25 "
        "times round (its crossing passed twice, 90-110 deg apart). return: out, round a turning loop at "
        "the street's end and back in the other direction's lane past the start (revisits at 180 deg, "
        "a lane apart; beyond the median on avenues and highways). blocks: a straight street whose "
        "roadside repeats exactly every 30-60 m, driven once (look-alike places, no revisit). Loops "
        "(250-1500 m round; walked, 50-1500 m), figure eights (400-2000 m) and returns are sized to the "
        "frames and speed: at 10 m/s and 10 Hz the first revisit comes after about 350 frames on a loop "
        "or figure eight and 200 on a return; a walk at 10 Hz needs about 450 on a loop (a 50 m lap "
        "on a footpath round a building, with more buildings round the courtyard), 2500 on a figure "
        "eight and 1000 on a return. In the indoor scene: loop goes round its "
        "corridor ring about 1.25 times (40-250 m round), return walks out along the corridors, turns "
        "round in a hall and walks back past the start; both are sized to the walk.",
    )

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
        if value not in SCENES:
            raise ValueError(f"must be one of {', '.join(SCENES)}")
        return value

    @model_validator(mode="after")
    def _car_options_need_the_car(self) -> SynthConfig:
        if self.motion == "handheld":
            default_speed = type(self).model_fields["speed"].default
            if self.speed != default_speed:
                raise ValueError(
                    f"speed: applies to motion 'car' only; a handheld walk keeps its own 1.0-1.6 m/s "
                    f"(got speed {self.speed:g} with motion 'handheld')"
                )
            if self.stops:
                raise ValueError(
                    "stops: applies to motion 'car' only; a handheld walk pauses now and then by itself"
                )
        return self

    @model_validator(mode="after")
    def _indoor_is_walked_round_its_corridors(self) -> SynthConfig:
        if self.scene != INDOOR_SCENE:
            return self
        if self.motion != "handheld":
            raise ValueError(
                f"motion: the indoor scene is walked, not driven: use motion 'handheld' (--motion handheld); "
                f"got {self.motion!r}"
            )
        if self.route not in INDOOR_ROUTES:
            raise ValueError(
                f"route: the indoor scene is walked on route {' or '.join(map(repr, INDOOR_ROUTES))} "
                f"(--route loop: round the corridor ring; --route return: out, round in a hall and back); "
                f"got {self.route!r}"
            )
        if self.height is not None and self.height > MAX_HAND_HEIGHT:
            raise ValueError(
                f"height: at most {MAX_HAND_HEIGHT:g} m in the indoor scene (under its beams and ceilings); "
                f"got {self.height:g}"
            )
        return self

    @property
    def mounted_sensor(self) -> SensorConfig:
        """The sensor at its mounting height: ``height`` when given, else the preset's for a car and
        the seed's hand height for a walk."""
        if self.height is not None:
            return self.sensor.with_changes(height=self.height)
        if self.motion == "handheld":
            return self.sensor.with_changes(height=hand_height(self.seed))
        return self.sensor


class SynthSequence:
    """A synthetic drive or walk as a :class:`~vcr_odom.data.base.LidarSequence`, generated on demand.

    Built from a :class:`SynthConfig`, from its fields as keywords (``SynthSequence(frames=6,
    seed=2)``), or both (keywords change the given configuration). The defaults give the original
    sequences, byte for byte.

    Frames are ray-cast in windows of ``window`` frames: each window gets one ray-casting scene of
    everything the sensor can reach from its poses, so memory and build time stay bounded for any
    length and a frame's content never depends on which frames were asked for before.

    With ``keyframes`` the sequence is the kept frames of the generated stream (``frames`` counts the
    stream, ``len()`` the kept ones; :attr:`kept` maps one to the other): a keyframe is the stream's
    frame, its time the stream's time, its pose relative to the first keyframe (stream frame 0).
    ``thin`` voxel-thins every frame returned.
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
        self.motion = config.motion
        self.route = config.route
        extras = [config.scene] if config.scene != "suburban" else []
        extras += [self.sensor.name] if self.sensor.name != "hdl64" else []
        extras += ["handheld"] if config.motion == "handheld" else []
        extras += [config.route] if config.route != "street" else []
        self.name = "-".join([f"synth-seed{config.seed}", *extras])
        self.label = self.name
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
        sensor = str(rng.choice(VARIED_MODELS))  # not SENSOR_MODELS: the same seeds, the same drives
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
    def scene(self) -> StreetScene | IndoorScene:
        if self.scene_style == INDOOR_SCENE:
            travel = walk_travel(frames=self.frames, seed=self.seed, frame_period=self.frame_period)
            return IndoorScene(self.seed, self.route, travel)
        # Road long enough for the fastest possible drive plus what the sensor sees beyond its end.
        fastest = self.speed * 1.5 if self.motion == "car" else MAX_SPEED
        reach = self.frames * self.frame_period * fastest + self.sensor.max_range + 60.0
        if self.route == "street":
            return StreetScene(self.seed, reach, scene=self.scene_style)
        style = scene_style(self.scene_style)
        world = build_route(
            self.route, self.seed, style, reach, self._travel, walked=self.motion == "handheld"
        )
        return StreetScene(self.seed, reach, scene=self.scene_style, world=world)

    def _travel(self, path: Road) -> float:
        """How far along ``path`` this sequence's motion goes (what routes are sized by)."""
        if self.motion == "handheld":
            return walk_travel(frames=self.frames, seed=self.seed, frame_period=self.frame_period)
        return drive_travel(
            path,
            frames=self.frames,
            speed=self.speed,
            seed=self.seed,
            stops=self.stops,
            frame_period=self.frame_period,
        )

    @cached_property
    def drive(self) -> Drive:
        """The generated stream's motion: every frame, kept or not."""
        if self.motion == "handheld":
            return make_walk(
                self.scene,
                frames=self.frames,
                height=self.sensor.height,
                seed=self.seed,
                frame_period=self.frame_period,
            )
        assert isinstance(self.scene, StreetScene)  # SynthConfig keeps cars out of the indoor scene
        return make_drive(
            self.scene,
            frames=self.frames,
            speed=self.speed,
            height=self.sensor.height,
            seed=self.seed,
            stops=self.stops,
            frame_period=self.frame_period,
        )

    @cached_property
    def kept(self) -> NDArray[np.int64]:
        """Indices into the generated stream of the frames this sequence is made of."""
        if self.config.keyframes is None:
            return np.arange(self.frames)
        return select_keyframes(self.drive.world_poses, self.config.keyframes, self.config.keyframe_angle)

    def __len__(self) -> int:
        return len(self.kept)

    @property
    def world_poses(self) -> NDArray[np.float64]:
        """LiDAR -> world poses of the procedural world (not re-anchored), of the kept frames."""
        if self.config.keyframes is None:
            return self.drive.world_poses
        return self.drive.world_poses[self.kept]

    @cached_property
    def _relative_poses(self) -> NDArray[np.float64]:
        return invert(self.world_poses[0])[None] @ self.world_poses

    @property
    def gt_poses(self) -> NDArray[np.float64]:
        """LiDAR-frame poses with frame 0 = identity; a copy, safe to modify."""
        return self._relative_poses.copy()

    @property
    def timestamps(self) -> NDArray[np.float64]:
        """Seconds since the first frame, on the generated stream's clock."""
        return (
            self.kept * self.frame_period
            if self.config.keyframes is not None
            else (np.arange(self.frames) * self.frame_period)
        )

    @property
    def timestamps_assumed(self) -> bool:
        """The drive's own clock: never a guess."""
        return False

    @property
    def tr_velo_to_cam(self) -> NDArray[np.float64]:
        return KITTI_TR.copy()

    @property
    def length(self) -> float:
        """Length of the drive (or walk) in metres, over every generated frame."""
        return self.drive.length

    def frame(self, index: int) -> NDArray[np.float32]:
        """Ray-cast frame ``index``: float32 ``(N, 4)`` in the LiDAR frame, like a KITTI ``.bin``.

        A keyframe is the generated stream's frame (same scan noise), thinned when ``thin`` is set."""
        if not 0 <= index < len(self):
            raise IndexError(f"frame {index} out of range for a sequence of {len(self)} frames")
        stream = int(self.kept[index])
        simulator = self._simulator(stream // self.window)
        points = simulator.scan(self.drive.world_poses[stream], np.random.default_rng([self.seed, 5, stream]))
        return points if self.config.thin is None else thin_voxels(points, self.config.thin)

    def frame_and_pose(self, index: int) -> tuple[NDArray[np.float32], NDArray[np.float64]]:
        """A frame and its LiDAR-frame ground-truth pose (frame 0 = identity), without writing."""
        return self.frame(index), self._relative_poses[index].copy()

    def _simulator(self, window: int) -> LidarSimulator:
        if window not in self._simulators:
            self._simulators.clear()  # one window at a time keeps memory flat
            poses = self.drive.world_poses[window * self.window : (window + 1) * self.window]
            mesh = self.scene.mesh_near(poses[:, :2, 3], self.sensor.max_range + 1.0)
            self._simulators[window] = LidarSimulator(mesh, self.sensor)
        return self._simulators[window]
