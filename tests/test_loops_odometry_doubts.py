"""What the odometry said about its frames reaches the loop phase: the frames it replaced, and each
frame's fit, which loosens the pose graph's edges where the odometry fitted poorly."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vcr_odom.loops.nodes import Node
from vcr_odom.loops.odometry_doubts import (
    FIT_POWER,
    MAX_FIT_FACTOR,
    OdometryDoubts,
    fit_sigma_factors,
)


def _cloud(field_deg: float) -> np.ndarray:
    """Points on a 10 m circle across ``field_deg`` of azimuth ahead."""
    azimuth = np.radians(np.linspace(-field_deg / 2, field_deg / 2, 200))
    return np.column_stack([10 * np.cos(azimuth), 10 * np.sin(azimuth), np.zeros(200)]).astype(np.float32)


def _nodes(frames: list[int], field_deg: float = 70.0) -> list[Node]:
    """Nodes of a narrow field of view (an Avia's 70 deg) by default."""
    return [
        Node(position=k, frame_index=f, pose=np.eye(4), path_m=float(f), cloud=_cloud(field_deg))
        for k, f in enumerate(frames)
    ]


def test_an_edge_is_loosened_by_its_worst_fit_against_the_runs_median() -> None:
    fits = dict.fromkeys(range(1, 16), 0.9)
    fits[7] = 0.6  # inside the second edge (frames 6-10)
    fits[13] = 0.05  # inside the third (11-15): far below, capped
    factors = fit_sigma_factors(_nodes([0, 5, 10, 15]), fits)
    assert factors == pytest.approx([1.0, (0.9 / 0.6) ** FIT_POWER, MAX_FIT_FACTOR])
    assert factors[1] == pytest.approx(5.0625)
    all_round = fit_sigma_factors(_nodes([0, 5, 10, 15], field_deg=359.0), fits)
    assert all_round == pytest.approx([1.0, 1.0, 1.0]), "a spinning sensor's fits do not say where it erred"


def test_a_frame_fitting_better_than_the_median_or_without_a_fit_loosens_nothing() -> None:
    fits = {1: 0.99, 2: 0.8, 3: 0.8, 4: 0.8, 5: 0.8}  # frames 6-10 have no fit at all
    assert fit_sigma_factors(_nodes([0, 5, 10]), fits) == pytest.approx([1.0, 1.0])
    assert fit_sigma_factors(_nodes([0, 5, 10]), {}) == pytest.approx([1.0, 1.0])
    assert len(fit_sigma_factors(_nodes([0]), fits)) == 0


def test_doubts_are_read_from_a_runs_per_frame_info() -> None:
    infos = [
        {},
        {"prior_fit": 0.9},
        {"prior_fit": 0.4, "flagged": True, "reason": "moved 2 m in 0.1 s"},
        {"prior_fit": math.nan},
        {"prior_fit": None, "flagged": False},
    ]
    doubts = OdometryDoubts.of_run([10, 11, 12, 13, 14], infos)
    assert doubts.flagged_frames == (12,)
    assert doubts.fits == {11: 0.9, 12: 0.4}
