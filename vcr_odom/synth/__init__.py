"""Synthetic LiDAR sequences (``vcr-odom synth``): a car drives through a procedural street (or a person
walks it, or the corridors of a building's floor) and a LiDAR ray-casts it (spinning, or a Livox-like
solid-state scanner); the result is written in the KITTI odometry layout.

It is the built-in data set of ``vcr-odom`` (demo, tests, training): ground truth is exact, any length
is available, and the same seed always gives byte-identical files. For variety in training data the
sensor, its mounting height, the street style, the speed, stops and the frame rate can all be chosen;
:meth:`SynthSequence.varied` draws them from a seed.

Modules, from the ground up: :mod:`~vcr_odom.synth.mesh` (triangles and primitives),
:mod:`~vcr_odom.synth.road` (terrain and the driven centre line), :mod:`~vcr_odom.synth.layout`
(zones, cross-sections, cross streets), :mod:`~vcr_odom.synth.parts` and
:mod:`~vcr_odom.synth.buildings` (what stands beside the road), :mod:`~vcr_odom.synth.roadside`
(placing them block by block), :mod:`~vcr_odom.synth.styles` (the ``--scene`` styles),
:mod:`~vcr_odom.synth.scene` (the world for one seed, built lazily), :mod:`~vcr_odom.synth.routes`
(streets that come back: :mod:`~vcr_odom.synth.paths`, :mod:`~vcr_odom.synth.closed_roads`,
:mod:`~vcr_odom.synth.turnaround`, :mod:`~vcr_odom.synth.repeating`), :mod:`~vcr_odom.synth.sensor`
(sensor models and ray casting), :mod:`~vcr_odom.synth.drive` (the car's path and speeds),
:mod:`~vcr_odom.synth.handheld` (a walk with a handheld scanner), :mod:`~vcr_odom.synth.indoor`
(the indoor floor: :mod:`~vcr_odom.synth.corridors`, the corridor ring and the walker's track;
:mod:`~vcr_odom.synth.floorplan`, walls, halls and rooms; :mod:`~vcr_odom.synth.fittings`, their
meshes), :mod:`~vcr_odom.synth.keyframes` (keyframes and voxel thinning), :mod:`~vcr_odom.synth.sequence` (the sequence) and
:mod:`~vcr_odom.synth.kitti_layout` (writing it).
"""

from vcr_odom.synth.calibration import KITTI_TR, kitti_calib
from vcr_odom.synth.drive import Drive
from vcr_odom.synth.indoor import IndoorScene
from vcr_odom.synth.kitti_layout import (
    SEQUENCE_NAME,
    WrittenSequence,
    generate_sequence,
    write_bin,
    write_sequence,
)
from vcr_odom.synth.mesh import MeshPart, Surface
from vcr_odom.synth.routes import ROUTES
from vcr_odom.synth.scene import StreetScene
from vcr_odom.synth.sensor import SENSOR_MODELS, LidarSimulator, SensorConfig
from vcr_odom.synth.sequence import FRAME_PERIOD, HEIGHT_RANGE, SCENES, SynthConfig, SynthSequence
from vcr_odom.synth.styles import SCENE_STYLES

__all__ = [
    "FRAME_PERIOD",
    "HEIGHT_RANGE",
    "KITTI_TR",
    "ROUTES",
    "SCENES",
    "SCENE_STYLES",
    "SENSOR_MODELS",
    "SEQUENCE_NAME",
    "Drive",
    "IndoorScene",
    "LidarSimulator",
    "MeshPart",
    "SensorConfig",
    "StreetScene",
    "Surface",
    "SynthConfig",
    "SynthSequence",
    "WrittenSequence",
    "generate_sequence",
    "kitti_calib",
    "write_bin",
    "write_sequence",
]
