"""KISS-SLAM as an optional baseline: a "not installed" row when the extra is missing; where installed,
its trajectory on the frames every method reads, and its row (with closures) in ``compare``."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from vcr_odom.data.selection import FrameSelection
from vcr_odom.errors import ConfigError, MissingExtraError
from vcr_odom.evaluation.compare import CompareSettings, run_comparison
from vcr_odom.geometry import normalise_to_first
from vcr_odom.odometry.frame_loop import run_odometry
from vcr_odom.registration import make_method

INSTALLED = importlib.util.find_spec("kiss_slam") is not None
needs_kiss_slam = pytest.mark.skipif(
    not INSTALLED, reason="kiss-slam not installed (pip install 'vcr-odom[slam]')"
)
NOT_INSTALLED = "not installed: pip install 'vcr-odom[slam]'"


@pytest.fixture
def without_kiss_slam(monkeypatch: pytest.MonkeyPatch) -> None:
    """``import kiss_slam`` fails, as where the extra is not installed (installed or not here)."""
    for name in ("kiss_slam", "kiss_slam.config", "kiss_slam.slam"):
        monkeypatch.setitem(sys.modules, name, None)


@pytest.fixture(scope="module")
def tiny_drive():
    """12 frames (about 7 m) of the sparse 16-beam sensor: cheap to cast and to register."""
    from vcr_odom.synth import SynthSequence

    return SynthSequence(frames=12, seed=3, sensor="vlp16")


def _compare(root: Path, results: Path, *methods: str, stride: int = 1):
    selection = FrameSelection(data_root=root, seq="00", stride=stride)
    return run_comparison(CompareSettings(selection=selection, methods=methods, results_dir=results))


def test_missing_kiss_slam_names_the_extra(without_kiss_slam: None) -> None:
    with pytest.raises(
        MissingExtraError, match=r"kiss-slam is not installed: pip install 'vcr-odom\[slam\]'"
    ):
        make_method("kiss-slam")


def test_compare_shows_a_not_installed_row_and_runs_the_others(
    without_kiss_slam: None, small_synthetic_root: Path, tmp_path: Path
) -> None:
    comparison = _compare(small_synthetic_root, tmp_path, "kiss-icp", "kiss-slam")
    rows = {o.method: o for o in comparison.odometry}
    assert list(rows) == ["kiss-icp", "kiss-slam"]
    assert rows["kiss-slam"].status == NOT_INSTALLED and rows["kiss-slam"].report is None
    assert rows["kiss-icp"].status == "" and rows["kiss-icp"].report is not None
    folder = comparison.folder
    assert not (folder / "kiss-slam").exists()  # nothing ran: no result folder
    summary = json.loads((folder / "compare.json").read_text())
    assert summary["kiss-slam"] == {"status": NOT_INSTALLED}
    marker = json.loads((folder / "result.json").read_text())
    assert marker["status"] == "complete" and marker["methods_done"] == ["kiss-icp"]
    assert marker["methods_skipped"] == {"kiss-slam": NOT_INSTALLED}


def test_compare_cli_prints_the_not_installed_row(
    without_kiss_slam: None, small_synthetic_root: Path, tmp_path: Path
) -> None:
    from vcr_odom.cli.main import cli

    args = ["compare", "--data-root", small_synthetic_root, "-b", "kiss-icp", "-b", "kiss-slam"]
    result = CliRunner().invoke(cli, [str(a) for a in [*args, "--results-dir", tmp_path]])
    assert result.exit_code == 0, result.output
    assert "kiss-slam (not" in result.stdout  # the row (its cell may wrap) ...
    assert f"kiss-slam: {NOT_INSTALLED}" in result.stdout  # ... and what installs it, under the table


def test_compare_of_kiss_slam_alone_without_it_is_a_clear_error(
    without_kiss_slam: None, small_synthetic_root: Path, tmp_path: Path
) -> None:
    with pytest.raises(ConfigError, match="nothing to compare: kiss-slam is not installed"):
        _compare(small_synthetic_root, tmp_path, "kiss-slam")
    assert not any(tmp_path.iterdir())  # found before the result folder was made


def test_kiss_slam_takes_no_polish_and_no_pairs() -> None:
    from vcr_odom.evaluation.compare import works_on_pairs
    from vcr_odom.odometry.factory import parse_method_spec

    with pytest.raises(ConfigError, match="kiss-slam is a sequential odometry"):
        parse_method_spec("kiss-slam+icp")
    assert not works_on_pairs("kiss-slam")


@needs_kiss_slam
def test_kiss_slam_follows_ground_truth_and_is_kiss_icp_without_closures(tiny_drive) -> None:
    from vcr_odom.evaluation.kiss_slam import run_kiss_slam

    indices = list(range(len(tiny_drive)))
    result = run_kiss_slam(tiny_drive, indices)
    assert result.poses.shape == (len(indices), 4, 4) and result.poses.dtype == np.float64
    np.testing.assert_allclose(result.poses[0], np.eye(4), atol=1e-12)
    assert result.frame_indices == indices and result.num_closures == 0  # 7 m: one local map, no loop
    assert result.wall_seconds > 0 and result.run.stage_seconds["optimise"] >= 0
    gt = normalise_to_first(tiny_drive.gt_poses)
    path = np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1).sum()
    errors = np.linalg.norm(result.poses[:, :3, 3] - gt[:, :3, 3], axis=1)
    assert errors.max() < 0.05 * path, (errors.max(), path)
    # Within its first local map (100 m) and without a closure KISS-SLAM is its kiss-icp: configured
    # as the kiss-icp row (no deskewing, its voxel size), it gives the same trajectory: a fair row.
    kiss_icp = run_odometry(tiny_drive, make_method("kiss-icp"), indices)
    np.testing.assert_allclose(result.poses, kiss_icp.poses, atol=1e-9)


@needs_kiss_slam
def test_kiss_slam_reads_the_selected_frames(tiny_drive) -> None:
    from vcr_odom.evaluation.kiss_slam import run_kiss_slam

    result = run_kiss_slam(tiny_drive, range(1, 12, 3))
    assert result.frame_indices == [1, 4, 7, 10] and result.poses.shape == (4, 4, 4)
    np.testing.assert_allclose(result.poses[0], np.eye(4), atol=1e-12)
    np.testing.assert_allclose(result.run.timestamps, tiny_drive.timestamps[[1, 4, 7, 10]])


@needs_kiss_slam
def test_compare_runs_kiss_slam_beside_the_others(small_synthetic_root: Path, tmp_path: Path) -> None:
    from vcr_odom.cli.main import cli

    args = ["compare", "--data-root", small_synthetic_root, "-b", "kiss-icp", "-b", "kiss-slam"]
    result = CliRunner().invoke(cli, [str(a) for a in [*args, "--stride", 2, "--results-dir", tmp_path]])
    assert result.exit_code == 0, result.output
    table = result.stdout
    assert "closures" in table and "kiss-slam" in table and "not installed" not in table
    folder = Path(tmp_path / "latest").resolve()
    summary = json.loads((folder / "compare.json").read_text())
    slam = summary["kiss-slam"]
    assert slam["run"]["slam"]["loop_closures"] == 0 and slam["run"]["frames_processed"] == 4
    assert slam["ate_rpe"]["ate_trans_rmse_m"] < 0.5
    # Its folder is a result unit like the others': the same frames, trajectory files and marker.
    frames = [json.loads((folder / m / "frames.json").read_text()) for m in ("kiss-icp", "kiss-slam")]
    assert frames[0]["frame_indices"] == frames[1]["frame_indices"] == [0, 2, 4, 6]
    marker = json.loads((folder / "kiss-slam" / "result.json").read_text())
    assert marker["status"] == "complete" and marker["method"] == "kiss-slam"
    assert (folder / "kiss-slam" / "trajectory_kitti.txt").is_file()
    metrics = json.loads((folder / "kiss-slam" / "metrics.json").read_text())
    assert metrics["run"]["slam"]["config"]["local_mapper"]["splitting_distance"] == 100.0


@needs_kiss_slam
def test_closures_name_the_frames_their_local_maps_start_at(tiny_drive) -> None:
    from vcr_odom.registration.kiss_slam import KissSlamOdometry, LoopClosure

    slam = KissSlamOdometry()
    slam._map_starts = [0, 3, 6, 9]  # as if local maps had started at these steps
    slam._slam.closures = [(0, 3)]
    frames = [10, 12, 14, 16, 18, 20, 22, 24, 26, 28]
    assert slam.closures(frames) == [LoopClosure(local_maps=(0, 3), frames=(10, 28))]
