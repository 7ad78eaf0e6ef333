"""A heading drifts with each turn the odometry measures: a handheld walk round a courtyard turns
700-900 deg a lap (the lap and the looks about), and its odometry's heading comes back 16-22 deg off.
The drift bound grows with the angle turned, so such a walk's right loops are not rejected as asking
too much; a car, which turns little per metre, keeps its bound."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vcr_odom.geometry import make_transform, rotation_from_euler_zyx
from vcr_odom.loops.drift import DriftModel
from vcr_odom.loops.nodes import NodeRecorder


def test_the_heading_bound_grows_with_the_angle_turned() -> None:
    drift = DriftModel()
    lap_of_a_courtyard = drift.rotation_bound_deg(60.0, turned_deg=800.0)
    assert drift.rotation_bound_deg(60.0) == pytest.approx(11.0)  # by the path alone
    assert lap_of_a_courtyard == pytest.approx(5.0 + 6.0 + 16.0)
    assert lap_of_a_courtyard > 22.0  # walk 881's right loops asked for 16-22 deg
    assert drift.rotation_bound_deg(60.0, turned_deg=5000.0) == drift.rotation_cap_deg
    car_corner = drift.rotation_bound_deg(100.0, turned_deg=90.0) - drift.rotation_bound_deg(100.0)
    assert car_corner == pytest.approx(1.8)


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
