"""Loop closure in rooms: nodes keep a grid of the scene's reach, and a revisit turned 60 deg in a corridor
is measured right (on 1 m voxels its fit was 5.9 deg off and would have been accepted)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from vcr_odom.data import open_sequence
from vcr_odom.geometry import invert, make_transform, rotation_angle, rotation_from_euler_zyx
from vcr_odom.loops.candidates import LoopCandidate
from vcr_odom.loops.nodes import CLOUD_VOXEL_M, NodeRecorder, node_cloud_voxel
from vcr_odom.synth import SensorConfig, SynthSequence

WALK = {"scene": "indoor", "motion": "handheld", "route": "loop", "frame_period": 0.5}


@pytest.fixture(scope="module")
def walk() -> SynthSequence:
    """An OS0 walk (512 columns: it casts fast) whose frames 8 and 78 stand 3.9 m apart, turned 59 deg."""
    sensor = SensorConfig.model("os0").with_changes(azimuth_steps=512)
    return SynthSequence(frames=80, seed=7, sensor=sensor, **WALK)


@pytest.mark.filterwarnings("ignore:.*no timestamps")
def test_street_nodes_keep_the_1m_grid_and_room_nodes_get_the_reachs(
    kitti_sample_root: Path, walk: SynthSequence
) -> None:
    street = np.asarray(open_sequence("00", data_root=kitti_sample_root).frame(0))
    assert node_cloud_voxel(street) == CLOUD_VOXEL_M
    recorder = NodeRecorder(spacing_m=1e-6)
    for index in (8, 9, 10):
        recorder(index, walk.world_poses[index], walk.frame(index))
    nodes = recorder.finish()
    assert 0.1 <= recorder.cloud_voxel <= 0.3
    assert {node.cloud_voxel for node in nodes} == {recorder.cloud_voxel}  # one grid for the run
    fixed = NodeRecorder(cloud_voxel=1.0)
    fixed(8, walk.world_poses[8], walk.frame(8))
    assert fixed.finish()[0].cloud_voxel == 1.0 and len(fixed.nodes[0].cloud) < len(nodes[0].cloud)


def test_an_indoor_revisit_turned_60_degrees_is_measured_right(walk: SynthSequence) -> None:
    from vcr_odom.loops.verify import LoopVerifier
    from vcr_odom.registration.vcr import VcrRegistrar

    truth = invert(walk.world_poses[8]) @ walk.world_poses[78]
    recorder = NodeRecorder(spacing_m=1e-6)
    for index in (8, 78):
        recorder(index, walk.world_poses[index], walk.frame(index))
    nodes = recorder.finish()
    drift = make_transform(rotation_from_euler_zyx(math.radians(4), 0, 0), [1.5, -1.0, 0.2])
    candidate = LoopCandidate(1, 0, drift @ truth, 100.0, float(np.linalg.norm(truth[:3, 3])))
    decision = LoopVerifier(VcrRegistrar(device="cpu")).verify(candidate, nodes)
    assert decision.accepted, decision.reason
    error = invert(truth) @ decision.measured
    assert np.linalg.norm(error[:3, 3]) < 0.1
    assert math.degrees(rotation_angle(error[:3, :3])) < 0.5
