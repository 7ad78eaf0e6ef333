"""benchmarks/loop_replay.py: the loop phase replayed on a recorded odometry gives what `map` gives."""

from __future__ import annotations

import json
import pickle
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from click.testing import CliRunner

from vcr_odom.cli.main import cli

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "loop_replay.py"


def _replay(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=600)


def test_a_replay_scores_what_map_made_of_the_same_frames(small_synthetic_root: Path, tmp_path: Path) -> None:
    recording, scores = tmp_path / "00.pkl", tmp_path / "replay.json"
    recorded = _replay(
        "record", "--sequence", str(small_synthetic_root / "sequences" / "00"), "--out", str(recording)
    )
    assert recorded.returncode == 0, recorded.stderr
    replayed = _replay("replay", str(recording), "--json", str(scores))
    assert replayed.returncode == 0, replayed.stderr
    (row,) = json.loads(scores.read_text())

    result = CliRunner().invoke(
        cli,
        [
            "map",
            "--data-root",
            str(small_synthetic_root),
            "--seq",
            "00",
            "--results-dir",
            str(tmp_path / "map"),
        ],
    )
    assert result.exit_code == 0, result.output
    (folder,) = [p for p in (tmp_path / "map").iterdir() if p.name.startswith("20")]
    metrics = json.loads((folder / "metrics.json").read_text())
    loops = json.loads((folder / "loops.json").read_text())
    assert row["frames"] == metrics["memory"]["frames"] == 8
    assert row["candidates"] == len(loops["candidates"]) and row["accepted"] == metrics["loops"]["accepted"]
    assert abs(row["map_ate_m"] - metrics["ate_rpe"]["ate_se3_trans_rmse_m"]) < 1e-9
    assert abs(row["odometry_ate_m"] - metrics["odometry"]["ate_rpe"]["ate_se3_trans_rmse_m"]) < 1e-9
    assert set(row["loop_seconds"]) == {"loops", "graph"} and min(row["loop_seconds"].values()) >= 0
    assert row["odometry_covariance_scale"] == metrics["loops"]["odometry_covariance_scale"]
    assert len(row["right_loop_errors"]) + row["false_closures"] == row["accepted"]

    # --set replaces a recorded option: 8 frames are too short a path for a loop at 30 m, not at 1 m
    assert row["candidates"] == 0 and row["options_set"] == {}
    wider, judged = tmp_path / "wider.json", tmp_path / "candidates"
    options = ["--set", "min_loop_path_m=1", "--set", "revisit_radius_m=50", "--candidates", str(judged)]
    replayed = _replay("replay", str(recording), *options, "--json", str(wider))
    assert replayed.returncode == 0, replayed.stderr
    (row,) = json.loads(wider.read_text())
    assert row["candidates"] > 0 and row["options_set"] == {"min_loop_path_m": "1", "revisit_radius_m": "50"}
    assert len(row["right_loop_errors"]) + row["false_closures"] == row["accepted"]

    # --candidates: each candidate's verdict, and its errors against the truth as the score measures them
    candidates = json.loads((judged / "00.json").read_text())
    assert len(candidates) == row["candidates"]
    assert sum(c["accepted"] for c in candidates) == row["accepted"] > 0  # the premise: a loop kept
    assert all(c["reason"] and (c["accepted"] or c["failed_check"]) for c in candidates)
    kept_errors = sorted(round(c["error_m"], 3) for c in candidates if c["accepted"])
    scored = [round(e["error_m"], 3) for e in row["right_loop_errors"]]
    assert kept_errors == sorted(scored + [f["error_m"] for f in row["false_closure_details"]])


def test_a_recording_is_made_with_the_point_to_plane_finish_it_is_asked_for(
    small_synthetic_root: Path, tmp_path: Path
) -> None:
    """`record --point-to-plane on` must record the odometry `run --point-to-plane on` makes (the finish
    is off by default on this spinning sensor, so an option left unpassed would record another one)."""
    from vcr_odom.data.selection import FrameSelection
    from vcr_odom.geometry import camera_to_lidar_poses
    from vcr_odom.io import read_kitti_poses

    sequence = str(small_synthetic_root / "sequences" / "00")
    recordings = {}
    for finish in ("on", "off"):
        out = tmp_path / f"{finish}.pkl"
        recorded = _replay("record", "--sequence", sequence, "--out", str(out), "--point-to-plane", finish)
        assert recorded.returncode == 0, recorded.stderr
        recordings[finish] = pickle.loads(out.read_bytes())
    assert recordings["on"]["point_to_plane"] == "on"

    args = ["run", "--data-root", str(small_synthetic_root), "--seq", "00", "--point-to-plane", "on"]
    result = CliRunner().invoke(cli, [*args, "--results-dir", str(tmp_path / "run")])
    assert result.exit_code == 0, result.output
    (folder,) = [p for p in (tmp_path / "run").iterdir() if p.name.startswith("20")]
    tr = FrameSelection(data_root=small_synthetic_root, seq="00").open().tr_velo_to_cam
    ran = read_kitti_poses(folder / "trajectory_kitti.txt")
    ran = ran if tr is None else camera_to_lidar_poses(ran, tr)
    finished, unfinished = (np.asarray(recordings[k]["poses"]) for k in ("on", "off"))
    assert np.abs(finished[:, :3, :] - ran[:, :3, :]).max() < 1e-5
    assert np.abs(finished - unfinished).max() > 1e-5, "the finish changed nothing: the test shows nothing"


def test_a_file_that_is_not_a_recording_is_refused_by_name(tmp_path: Path) -> None:
    other = tmp_path / "other.pkl"
    other.write_bytes(pickle.dumps({"format": 0}))
    replayed = _replay("replay", str(other))
    assert replayed.returncode != 0
    assert f"{other}: not a recording of format 1" in replayed.stderr


@pytest.mark.parametrize(
    ("item", "says"),
    [
        ("passage_atempts=3", "NAME one of loops, node_spacing_m"),
        ("max_heading_drift=2", "NAME one of loops, node_spacing_m"),
        ("passage_attempts", "expected NAME=VALUE"),
        ("passage_attempts=0", "passage_attempts: Input should be greater than or equal to 1"),
    ],
)
def test_a_loop_option_that_does_not_exist_or_fit_is_refused_by_name(
    tmp_path: Path, item: str, says: str
) -> None:
    replayed = _replay("replay", str(tmp_path / "never_read.pkl"), "--set", item)
    assert replayed.returncode == 2
    assert f"--set {item}:" in replayed.stderr and says in replayed.stderr


@pytest.mark.slow
def test_a_replay_keeps_the_loops_map_closed_on_a_walk(tmp_path: Path) -> None:
    """The courtyard walk 881 (Avia, handheld, 600 frames), where `map` closes loops: the replay must be
    handed the same nodes and settings to keep the same loops and measure the same odometry scale."""
    from vcr_odom.synth import generate_sequence

    generate_sequence(
        tmp_path / "walk", seq="881", frames=600, seed=881, motion="handheld", route="loop", sensor="avia"
    )
    recording, scores = tmp_path / "881.pkl", tmp_path / "replay.json"
    sequence = tmp_path / "walk" / "sequences" / "881"
    assert _replay("record", "--sequence", str(sequence), "--out", str(recording)).returncode == 0
    assert _replay("replay", str(recording), "--json", str(scores)).returncode == 0
    (row,) = json.loads(scores.read_text())

    args = [
        "map",
        "--data-root",
        str(tmp_path / "walk"),
        "--seq",
        "881",
        "--results-dir",
        str(tmp_path / "map"),
    ]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    (folder,) = [p for p in (tmp_path / "map").iterdir() if p.name.startswith("20")]
    loops = json.loads((folder / "loops.json").read_text())
    metrics = json.loads((folder / "metrics.json").read_text())
    assert metrics["loops"]["accepted"] >= 1, "the walk closes: nothing to compare otherwise"
    assert row["accepted"] == metrics["loops"]["accepted"]
    assert row["candidates"] == len(loops["candidates"])
    assert row["odometry_covariance_scale"] == pytest.approx(
        metrics["loops"]["odometry_covariance_scale"], abs=1e-3
    )
    assert abs(row["map_ate_m"] - metrics["ate_rpe"]["ate_se3_trans_rmse_m"]) < 1e-3


def test_truth_loops_hand_the_graph_each_loop_as_the_truth_measures_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """``replay --truth-loops``: the graph gets the truth's T_target_source in place of the measured one,
    and the loop phase's own graph is back once the replay is done."""
    monkeypatch.syspath_prepend(str(SCRIPT.parent))
    import loop_replay

    from vcr_odom.geometry import invert, make_transform
    from vcr_odom.loops import pipeline
    from vcr_odom.loops.graph import LoopEdge

    seen: list[list[LoopEdge]] = []
    monkeypatch.setattr(pipeline, "optimise", lambda poses, info, loops, *a, **k: seen.append(list(loops)))
    gt = np.stack([make_transform(np.eye(3), np.array([float(k), 0.5 * k, 0.0])) for k in range(6)])
    nodes = [SimpleNamespace(position=p) for p in (0, 2, 5)]
    node_poses = gt[[0, 2, 5]]
    wrong = LoopEdge(2, 0, make_transform(np.eye(3), np.array([9.0, 9.0, 9.0])), np.eye(6))
    with loop_replay._loops_measured_by(gt, nodes):
        pipeline.optimise(node_poses, [np.eye(6)] * 2, [wrong])
    pipeline.optimise(node_poses, [np.eye(6)] * 2, [wrong])

    (given,), (after,) = seen
    np.testing.assert_allclose(given.transform, invert(gt[0]) @ gt[5])
    np.testing.assert_allclose(given.information, wrong.information)
    assert (given.source, given.target) == (2, 0)
    np.testing.assert_allclose(after.transform, wrong.transform)


def test_right_loops_errors_are_pooled_over_recordings_own_clouds_and_submaps_apart(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.syspath_prepend(str(SCRIPT.parent))
    import loop_replay

    rows = [
        {"right_loop_errors": [{"error_m": 0.3, "error_deg": 1.0, "submaps": True}]},
        {
            "right_loop_errors": [
                {"error_m": 0.4, "error_deg": 0.0, "submaps": True},
                {"error_m": 0.1, "error_deg": 0.2, "submaps": False},
            ]
        },
        {"right_loop_errors": []},
    ]
    pooled = loop_replay.right_loop_errors(rows)
    assert pooled["submaps"] == pytest.approx((2, np.sqrt(0.125), np.sqrt(0.5)))
    assert pooled["own clouds"] == pytest.approx((1, 0.1, 0.2))
    assert loop_replay.right_loop_errors(rows[2:]) == {}


def test_a_kept_loops_error_is_scored_under_the_information_the_graph_gave_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """``error_chi2``: measured = exp(xi) true (xi a left perturbation in the target's frame, rotation
    then translation, as loops.json's ``information`` reads it) scores xi' I xi; a loop without
    information (one the graph did not take) scores None."""
    monkeypatch.syspath_prepend(str(SCRIPT.parent))
    import loop_closure
    from scipy.spatial.transform import Rotation

    from vcr_odom.geometry import invert, make_transform

    gt = np.stack(
        [make_transform(Rotation.from_rotvec([0, 0, 0.1 * k]).as_matrix(), [k, 0.5 * k, 0]) for k in range(8)]
    )
    xi = np.array([0.01, -0.02, 0.03, 0.5, -0.2, 0.1])
    true = invert(gt[2]) @ gt[7]
    measured = make_transform(Rotation.from_rotvec(xi[:3]).as_matrix(), xi[3:]) @ true
    information = np.diag([1e4, 2e4, 3e4, 4.0, 5.0, 6.0])
    loop = {
        "source_frame": 7,
        "target_frame": 2,
        "measured_T_target_source": measured.tolist(),
        "information": information.tolist(),
    }
    position = {k: k for k in range(8)}
    assert loop_closure.error_chi2(gt, position, loop) == pytest.approx(float(xi @ information @ xi))
    assert loop_closure.error_chi2(gt, position, {**loop, "information": None}) is None
