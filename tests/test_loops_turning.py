"""A node records the angle turned since the first frame, every turn counted: a handheld walk round a
courtyard turns 700-900 deg a lap (the lap and the looks about), which its heading drift follows."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vcr_odom.geometry import make_transform, rotation_from_euler_zyx
from vcr_odom.loops.nodes import NodeRecorder


def test_nodes_count_every_turn_even_one_turned_back() -> None:
    """A look to the side and back turns the sensor twice its angle and leaves the heading where it
    was: the drift it gathers counts both turns."""
    recorder = NodeRecorder()
    points = np.random.default_rng(0).uniform(-20.0, 20.0, (4000, 4)).astype(np.float32)
    yaws = [0.0, 30.0, 60.0, 30.0, 0.0, 0.0]  # deg: out 60 and back
    for k, yaw in enumerate(yaws):
        recorder(k, make_transform(rotation_from_euler_zyx(math.radians(yaw), 0, 0), [0.1 * k, 0, 0]), points)
    nodes = recorder.finish()
    assert nodes[0].turned_deg == 0.0
    assert nodes[-1].turned_deg == pytest.approx(120.0, abs=1e-6)
