"""``--polish-engine auto``: the engine chosen for a run by the spacing of its frames in time."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from vcr_odom.data.selection import FrameSelection
from vcr_odom.errors import ConfigError
from vcr_odom.odometry.engine_choice import engine_for
from vcr_odom.odometry.run import RunSettings, run_sequence


def test_consecutive_scans_keep_kiss_icps_engine_and_frames_apart_get_vgicp() -> None:
    ten_hz = np.arange(50) * 0.1
    assert engine_for("auto", ten_hz) == "kiss-icp"
    assert engine_for("auto", np.delete(ten_hz, [7, 20, 33])) == "kiss-icp"  # a few dropped scans
    assert engine_for("auto", np.arange(50) * 0.05) == "kiss-icp"  # a 20 Hz sensor
    assert engine_for("auto", np.arange(50) * 0.5) == "vgicp"  # a 2 Hz rate, or every fifth scan
    keyframes = np.cumsum(np.r_[0.0, np.random.default_rng(3).uniform(0.2, 5.0, 40)])
    assert engine_for("auto", keyframes) == "vgicp"
    assert engine_for("auto", np.array([0.0])) == "kiss-icp"  # one frame: no spacing to judge


def test_a_named_engine_is_kept_and_a_bad_choice_is_named() -> None:
    assert engine_for("vgicp-start", np.arange(5) * 0.1) == "vgicp-start"
    assert engine_for("kiss-icp", np.arange(5) * 2.0) == "kiss-icp"
    with pytest.raises(ConfigError, match="'gicp'"):
        engine_for("gicp", None)
    with pytest.raises(ConfigError, match="frame times"):
        engine_for("auto", None)


@pytest.mark.filterwarnings("ignore:.*no timestamps")
def test_a_run_chooses_by_its_selected_frames_and_says_which(
    small_synthetic_root: Path, tmp_path: Path
) -> None:
    """The stride spaces the frames (10 Hz assumed without times): every fifth scan is 0.5 s apart;
    metrics.json names the engine the run used, config.json what was asked."""
    chosen = {}
    for stride in (1, 5):
        selection = FrameSelection(data_root=small_synthetic_root, seq="00", stride=stride, frames=":11")
        outcome = run_sequence(
            RunSettings(
                selection=selection,
                method="icp10",
                polish="kiss-icp",
                polish_engine="auto",
                results_dir=tmp_path / str(stride),
            )
        )
        chosen[stride] = json.loads((outcome.folder / "metrics.json").read_text())["run"]["polish_engine"]
        config = json.loads((outcome.folder / "config.json").read_text())["config"]
        assert config["polish_engine"] == "auto"
    assert chosen == {1: "kiss-icp", 5: "vgicp"}


@pytest.mark.filterwarnings("ignore:.*no timestamps")
def test_auto_is_a_default_for_methods_without_the_polish_and_compare_chooses_per_run(
    small_synthetic_root: Path, tmp_path: Path
) -> None:
    from vcr_odom.cli.main import cli

    args = ["compare", "--data-root", small_synthetic_root, "-b", "icp10+kiss-icp", "-b", "icp10"]
    args += ["--frames", ":11", "--stride", "5", "--polish-engine", "auto", "--results-dir", tmp_path]
    result = CliRunner().invoke(cli, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    folder = (tmp_path / "latest").resolve()
    polished = json.loads((folder / "icp10+kiss-icp" / "metrics.json").read_text())["run"]
    assert polished["polish_engine"] == "vgicp"
    plain = json.loads((folder / "icp10" / "metrics.json").read_text())["run"]
    assert plain["polish_engine"] is None
