"""benchmarks/loop_drift.py: the drift it adds and how it scores the loops kept under it."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from vcr_odom.geometry import invert, make_transform, rotation_angle, rotation_from_euler_zyx

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture
def loop_drift(monkeypatch: pytest.MonkeyPatch) -> Any:
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    import loop_drift

    return loop_drift


def _straight(count: int) -> np.ndarray:
    return np.stack([make_transform(np.eye(3), [float(k), 0.0, 0.0]) for k in range(count)])


def _arc(count: int) -> np.ndarray:
    """A metre a pose round a circle of 20 m (SE(3) alignment needs more than a line)."""
    poses = []
    for k in range(count):
        angle = k / 20.0
        rotation = rotation_from_euler_zyx(angle + math.pi / 2, 0.0, 0.0)
        poses.append(make_transform(rotation, [20.0 * math.cos(angle), 20.0 * math.sin(angle), 0.0]))
    return np.stack(poses)


def test_the_added_drift_scales_each_step_and_turns_by_the_metres_driven(loop_drift) -> None:
    truth = _straight(101)  # 100 m straight ahead
    drifted = loop_drift.drifted(truth, 0.02, 0.01, 0.0)
    steps = np.linalg.norm(np.diff(drifted[:, :3, 3], axis=0), axis=1)
    np.testing.assert_allclose(steps, 1.02)
    assert math.degrees(rotation_angle(drifted[-1][:3, :3])) == pytest.approx(1.0)  # 0.01 deg a metre


def test_a_loop_off_by_a_metre_or_more_is_false_and_the_worst_is_named(loop_drift) -> None:
    truth = _arc(60)
    nodes = [SimpleNamespace(position=k) for k in range(0, 60, 5)]

    def loop(source: int, target: int, off_m: float, accepted: bool = True) -> SimpleNamespace:
        measured = invert(truth[target]) @ truth[source] @ make_transform(np.eye(3), [0.0, off_m, 0.0])
        return SimpleNamespace(
            source_frame=source, target_frame=target, loop=SimpleNamespace(transform=measured), accepted=accepted,
            check="" if accepted else "odometry", candidate=SimpleNamespace(source=source // 5),
        )  # fmt: skip

    decisions = [loop(50, 10, 0.3), loop(55, 15, 2.5), loop(45, 5, 12.0), loop(40, 0, 20.0, accepted=False)]
    row = loop_drift._row(truth, truth, nodes, decisions, truth)
    assert (row["accepted"], row["false_closures"], row["rejected_for_odometry"]) == (3, 2, 1)
    assert row["inconsistent"] == 0 and row["candidates"] == 4
    assert row["worst_false_m"] == pytest.approx(12.0)
    assert math.isnan(row["ate_ratio"])  # no drift: the odometry is the truth
    drifted = loop_drift.drifted(truth, 0.05, 0.0, 0.0)
    assert loop_drift._row(truth, drifted, nodes, decisions[:1], truth)["worst_false_m"] == 0.0


def test_a_drift_bound_is_refused_as_a_loop_setting(tmp_path: Path) -> None:
    """``--set NAME=VALUE`` takes LoopSettings' fields (checked before any drive is read, as
    benchmarks/loop_replay.py checks them): the drift bounds it used to loop over are gone."""
    import subprocess
    import sys

    script = BENCHMARKS / "loop_drift.py"
    never = tmp_path / "never" / "sequences" / "00"
    item = "max_heading_drift=2"
    done = subprocess.run(
        [sys.executable, str(script), "--sequence", str(never), "--set", item],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 2, done.stderr
    assert f"--set {item}:" in done.stderr and "NAME one of loops, node_spacing_m" in done.stderr
