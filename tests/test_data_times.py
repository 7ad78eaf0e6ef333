"""Timestamps are honest: validated, found beside the scans, given with --times, or flagged as assumed."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from vcr_odom.cli.main import cli
from vcr_odom.data import FolderSequence, KittiSequence, LidarSequence, open_sequence
from vcr_odom.data.selection import FrameSelection
from vcr_odom.errors import ConfigError, DataError, DataWarning
from vcr_odom.io import write_times

EXIT_ERROR, EXIT_USAGE = 1, 2


def write_bins(folder: Path, count: int) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    for index in range(count):
        rng.uniform(-20, 20, size=(50, 4)).astype(np.float32).tofile(folder / f"{index:06d}.bin")
    return folder


def test_times_txt_beside_the_scans_is_found_and_not_assumed(tmp_path):
    scans = write_bins(tmp_path / "scans", 4)
    write_times(scans / "times.txt", [10.0, 10.1, 10.25, 10.3])
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)
        sequence = FolderSequence(scans)
    assert sequence.times_path == scans / "times.txt" and not sequence.timestamps_assumed
    np.testing.assert_allclose(sequence.timestamps, [10.0, 10.1, 10.25, 10.3])
    assert len(sequence) == 4  # times.txt is not a scan


def test_given_times_win_over_the_folders_own(tmp_path):
    scans = write_bins(tmp_path / "scans", 3)
    write_times(scans / "times.txt", [0.0, 0.1, 0.2])
    write_times(tmp_path / "real.txt", [5.0, 5.2, 5.4])
    sequence = FolderSequence(scans, times=tmp_path / "real.txt")
    np.testing.assert_allclose(sequence.timestamps, [5.0, 5.2, 5.4])


def test_assumed_rate_is_flagged_and_the_warning_says_how_to_give_real_times(tmp_path):
    scans = write_bins(tmp_path / "scans", 3)
    with pytest.warns(DataWarning) as caught:
        sequence = FolderSequence(scans)
    message = str(caught[0].message)
    assert str(scans) in message and "10 Hz" in message
    assert "--times FILE" in message and "times.txt beside the scans" in message
    assert sequence.timestamps_assumed and isinstance(sequence, LidarSequence)
    np.testing.assert_allclose(sequence.timestamps, [0.0, 0.1, 0.2])


def test_kitti_flags_assumed_times_and_says_where_times_txt_goes(tmp_path):
    write_bins(tmp_path / "sequences" / "04" / "velodyne", 3)
    with pytest.warns(DataWarning, match=r"sequences/04.*times\.txt.*--times FILE") as caught:
        sequence = KittiSequence(tmp_path, "04")
    assert len(caught) == 1 and sequence.timestamps_assumed
    write_times(tmp_path / "sequences" / "04" / "times.txt", [0.0, 0.1, 0.2])
    assert not KittiSequence(tmp_path, "04").timestamps_assumed


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        ("0\n0\n0\n", r"times\.txt:2: timestamps must be strictly increasing"),
        ("0.0\n0.2\n0.1\n", r"times\.txt:3: timestamps must be strictly increasing"),
        ("0.0 1\n0.1 1\n0.2 1\n", r"times\.txt:1: expected one number.*2 columns"),
        ("0.0\n0.1\n", r"times\.txt: 2 timestamps but 3 frames"),
    ],
    ids=["all-zero", "decreasing", "two-columns", "one-line-short"],
)
def test_a_broken_times_txt_beside_the_scans_is_an_error_not_ignored(tmp_path, content, expected):
    scans = write_bins(tmp_path / "scans", 3)
    (scans / "times.txt").write_text(content)
    with pytest.raises(DataError, match=expected):
        FolderSequence(scans)


def test_nanosecond_times_are_refused_saying_that_seconds_are_expected(tmp_path):
    scans = write_bins(tmp_path / "scans", 3)
    write_times(tmp_path / "ns.txt", [1.6e18, 1.6e18 + 1e8, 1.6e18 + 2e8])
    with pytest.raises(DataError, match=r"ns\.txt.*expected seconds.*nanoseconds"):
        FolderSequence(scans, times=tmp_path / "ns.txt")


def test_frame_selection_passes_times_through(tmp_path):
    scans = write_bins(tmp_path / "scans", 3)
    write_times(tmp_path / "t.txt", [1.0, 2.0, 3.0])
    sequence = FrameSelection(folder=scans, times=tmp_path / "t.txt").open()
    np.testing.assert_allclose(sequence.timestamps, [1.0, 2.0, 3.0])
    assert not sequence.timestamps_assumed
    with pytest.raises(ConfigError, match="--times"):
        open_sequence("00", data_root=tmp_path, times=tmp_path / "t.txt")


# --- the CLI ----------------------------------------------------------------------------------------


def invoke(*args: str):
    return CliRunner().invoke(cli, list(args))


def test_cli_times_option_reaches_the_trajectory_file(tmp_path):
    from vcr_odom.synth import SynthSequence

    synth = SynthSequence(frames=3, seed=0)
    scans = tmp_path / "scans"
    scans.mkdir()
    for index in range(3):
        synth.frame(index).tofile(scans / f"{index}.bin")
    write_times(tmp_path / "stamps.txt", [100.0, 100.1, 100.2])
    result = invoke(
        "run", "--folder", str(scans), "--times", str(tmp_path / "stamps.txt"), "--method", "icp",
        "--results-dir", str(tmp_path / "results"),
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "assuming 10 Hz" not in result.output
    (folder,) = [path for path in (tmp_path / "results").iterdir() if not path.is_symlink()]
    tum = folder / "trajectory_tum.txt"
    stamps = [float(line.split()[0]) for line in tum.read_text().splitlines()]
    np.testing.assert_allclose(stamps, [100.0, 100.1, 100.2])


def test_cli_bad_times_file_exits_1_naming_the_file_and_line(tmp_path):
    scans = write_bins(tmp_path / "scans", 3)
    (tmp_path / "stamps.txt").write_text("0.0\n0.0\n0.1\n")
    result = invoke("run", "--folder", str(scans), "--times", str(tmp_path / "stamps.txt"), "--method", "icp")
    assert result.exit_code == EXIT_ERROR
    assert f"{tmp_path / 'stamps.txt'}:2:" in result.output and "strictly increasing" in result.output


def test_cli_times_with_a_kitti_sequence_is_a_usage_error(tmp_path):
    write_bins(tmp_path / "sequences" / "00" / "velodyne", 3)
    write_times(tmp_path / "t.txt", [0.0, 0.1, 0.2])
    result = invoke(
        "run", "--data-root", str(tmp_path), "--times", str(tmp_path / "t.txt"), "--method", "icp"
    )
    assert result.exit_code == EXIT_USAGE and "--times" in result.output


def test_a_times_txt_one_folder_up_is_suggested_not_used(tmp_path):
    velodyne = write_bins(tmp_path / "sequences" / "00" / "velodyne", 3)
    write_times(tmp_path / "sequences" / "00" / "times.txt", [0.0, 0.1, 0.2])
    with pytest.warns(DataWarning, match=r"sequences/00/times\.txt may be it: pass it with --times"):
        sequence = FolderSequence(velodyne)
    assert sequence.timestamps_assumed
