"""Real users' mistakes through the CLI: each is one line naming the input, with the documented exit
code (0 done, 1 error, 2 usage, 130 interrupted), found before the work starts where it can be."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from click.testing import CliRunner, Result
from conftest import SMALL_SYNTHETIC_FRAMES

from vcr_odom.cli.main import cli
from vcr_odom.model.config import VcrConfig
from vcr_odom.model.network import VCRNet
from vcr_odom.model.weights import save_weights

FRAMES = SMALL_SYNTHETIC_FRAMES


@pytest.fixture
def synthetic_root(small_synthetic_root: Path) -> Path:
    return small_synthetic_root


def invoke(*args: object) -> Result:
    return CliRunner().invoke(cli, [str(a) for a in args])


def assert_fails(result: Result, code: int, *named: object) -> None:
    """Exit ``code``, no traceback, and the message names every one of ``named``."""
    assert result.exit_code == code, result.output
    assert "Traceback" not in result.output
    for name in named:
        assert str(name) in result.output, (name, result.output)


def no_results(results: Path) -> bool:
    return not results.exists() or not [p for p in results.iterdir() if not p.name.startswith(".")]


# -- the convention ---------------------------------------------------------------------------------


def test_help_documents_the_exit_codes() -> None:
    result = invoke("--help")
    assert result.exit_code == 0
    assert "Exit codes" in result.output
    for code in ("0", "1", "2", "130"):
        assert f"  {code} " in result.output
    assert "interrupted" in result.output and "usage" in result.output


def test_a_bad_option_is_a_usage_error(synthetic_root: Path, tmp_path: Path) -> None:
    assert_fails(invoke("run", "--data-root", synthetic_root, "--method", "nope"), 2, "nope")
    results = tmp_path / "results"
    result = invoke("run", "--data-root", synthetic_root, "--frames", "a:b", "--results-dir", results)
    assert_fails(result, 2, "--frames")
    assert no_results(results)


def test_a_polish_voxel_without_the_kiss_icp_polish_is_refused_before_the_run(
    synthetic_root: Path, tmp_path: Path
) -> None:
    results = tmp_path / "results"
    for command, method in (("run", "icp"), ("map", "vcr+icp")):
        result = invoke(
            command, "--data-root", synthetic_root, "--method", method.split("+")[0],
            *(["--polish", "icp"] if "+" in method else []), "--polish-voxel", "0.3", "--results-dir", results,
        )  # fmt: skip
        assert_fails(result, 2, "--polish-voxel", f"and {method} has none")
        assert no_results(results)
    assert_fails(invoke("run", "--data-root", synthetic_root, "--polish-voxel", "0"), 2, "--polish-voxel")
    result = invoke(
        "run", "--data-root", synthetic_root, "--method", "icp", "--polish-engine", "vgicp",
        "--results-dir", results,
    )  # fmt: skip
    assert_fails(result, 2, "--polish-engine", "and icp has none")
    assert_fails(
        invoke("run", "--data-root", synthetic_root, "--polish-engine", "gicp"), 2, "--polish-engine"
    )
    assert no_results(results)
    result = invoke(
        "run",
        "--data-root",
        synthetic_root,
        "--method",
        "icp",
        "--point-to-plane",
        "on",
        "--results-dir",
        results,
    )
    assert_fails(result, 2, "--point-to-plane", "and icp has none")
    assert no_results(results)
    result = invoke(
        "compare", "--data-root", synthetic_root, "-b", "icp", "-b", "kiss-icp", "-b", "vcr+icp",
        "--point-to-plane", "off", "--polish-voxel", "0.3", "--results-dir", results,
    )  # fmt: skip
    assert_fails(result, 2, "--polish-voxel, --point-to-plane", "icp, kiss-icp, vcr+icp")
    assert no_results(results)
    result = invoke(
        "compare", "--data-root", synthetic_root, "-b", "icp", "-b", "kiss-icp",
        "--polish-engine", "vgicp", "--results-dir", results,
    )  # fmt: skip
    assert_fails(result, 2, "--polish-engine", "icp, kiss-icp")
    assert no_results(results)


def test_a_library_error_is_exit_1_in_one_line(synthetic_root: Path, tmp_path: Path) -> None:
    short = tmp_path / "short.txt"
    short.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * 3)
    result = invoke("eval", "--gt", synthetic_root / "poses" / "00.txt", "--est", short)
    assert_fails(result, 1, "short.txt", "3 poses")
    assert len(result.output.strip().splitlines()) == 1


# -- wrong results with exit 0 become errors --------------------------------------------------------


@pytest.mark.parametrize("first", ["5.0", "zero"])
def test_eval_refuses_a_calibration_that_is_not_rigid(
    synthetic_root: Path, tmp_path: Path, first: str
) -> None:
    lines = (synthetic_root / "sequences" / "00" / "calib.txt").read_text().splitlines()
    edited = []
    for line in lines:
        if line.startswith("Tr:"):
            values = line.split()[1:]
            values = ["0"] * 12 if first == "zero" else [first, *values[1:]]
            line = "Tr: " + " ".join(values)
        edited.append(line)
    calib = tmp_path / "calib.txt"
    calib.write_text("\n".join(edited) + "\n")
    poses = synthetic_root / "poses" / "00.txt"
    result = invoke("eval", "--gt", poses, "--est", poses, "--calib", calib)
    assert_fails(result, 1, calib, "Tr")


# -- outputs checked before the work ----------------------------------------------------------------


def test_results_dir_that_is_a_file_is_refused_before_the_run(synthetic_root: Path, tmp_path: Path) -> None:
    blocker = tmp_path / "blocker"
    blocker.write_text("a file")
    for results in (blocker, blocker / "results"):
        result = invoke("run", "--data-root", synthetic_root, "--method", "icp10", "--results-dir", results)
        assert_fails(result, 2, "--results-dir", blocker)
        compare = invoke("compare", "--data-root", synthetic_root, "-b", "icp10", "--results-dir", results)
        assert_fails(compare, 2, "--results-dir", blocker)
    assert blocker.read_text() == "a file"


def test_synth_out_under_a_file_is_refused(tmp_path: Path) -> None:
    blocker = tmp_path / "blocker"
    blocker.write_text("a file")
    assert_fails(invoke("synth", "--out", blocker / "data", "--frames", "2"), 2, "--out", blocker)


def test_synth_does_not_replace_a_folder_it_did_not_write(tmp_path: Path) -> None:
    images = tmp_path / "sequences" / "00" / "image_2"
    images.mkdir(parents=True)
    assert_fails(invoke("synth", "--out", tmp_path, "--frames", "2"), 2, "image_2")
    assert images.is_dir()


def test_save_map_with_a_wrong_extension_fails_before_the_run(synthetic_root: Path, tmp_path: Path) -> None:
    results = tmp_path / "results"
    for bad in (tmp_path / "map.xyz", tmp_path / "blocker" / "map.ply", tmp_path):
        (tmp_path / "blocker").write_text("a file")
        result = invoke(
            "run",
            "--data-root",
            synthetic_root,
            "--method",
            "icp10",
            "--save-map",
            bad,
            "--results-dir",
            results,
        )
        assert result.exit_code == 2, result.output
        assert "--save-map" in result.output and "Traceback" not in result.output
    assert no_results(results)


def test_eval_outputs_are_checked_before_scoring(synthetic_root: Path, tmp_path: Path) -> None:
    poses = synthetic_root / "poses" / "00.txt"
    blocker = tmp_path / "blocker"
    blocker.write_text("a file")
    assert_fails(invoke("eval", "--gt", poses, "--est", poses, "--json", blocker / "x.json"), 2, "--json")
    assert_fails(invoke("eval", "--gt", poses, "--est", poses, "--json", tmp_path), 2, "--json")
    assert_fails(invoke("eval", "--gt", poses, "--est", poses, "--plot", tmp_path / "p.xyz"), 2, "--plot")


# -- compare combinations ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["-b", "icp10", "--seed", "3"], "--seed"),
        (["-b", "icp10", "--pairs", "consecutive"], "--pairs"),
        (["-b", "icp10", "--weights", "{weights}"], "--weights"),
        (["-b", "icp10", "--consult", "every-frame"], "--consult"),
        (["-b", "kiss-icp", "--protocol", "pairs"], "kiss-icp"),
        (["-b", "fpfh", "--protocol", "pairs", "--pairs", "consecutive"], "ground-truth"),
    ],
)
def test_bad_compare_combinations_fail_before_any_work(
    synthetic_root: Path, tmp_path: Path, args: list[str], named: str
) -> None:
    folder = tmp_path / "scans"  # a plain folder without poses: no ground truth
    shutil.copytree(synthetic_root / "sequences" / "00" / "velodyne", folder)
    weights = tmp_path / "w.safetensors"
    weights.write_bytes(b"x")
    results = tmp_path / "results"
    filled = [a.format(weights=weights) for a in args]
    result = invoke("compare", "--folder", folder, *filled, "--results-dir", results)
    assert_fails(result, 2, named)
    assert no_results(results)


def test_vcr_options_without_vcr_are_refused_by_run(synthetic_root: Path, tmp_path: Path) -> None:
    result = invoke("run", "--data-root", synthetic_root, "--method", "icp", "--vcr-passes", "2")
    assert_fails(result, 2, "--vcr-passes")
    result = invoke("run", "--data-root", synthetic_root, "--method", "kiss-icp", "--vcr-points", "512")
    assert_fails(result, 2, "--vcr-points")


# -- files that are not what they claim -------------------------------------------------------------


def test_poses_and_calib_that_are_not_text_name_the_file(synthetic_root: Path, tmp_path: Path) -> None:
    binary = tmp_path / "binary.txt"
    binary.write_bytes(b"1 0 0 \xff\xfe 0 1 0 0 0 0 1 0\n")
    poses = synthetic_root / "poses" / "00.txt"
    assert_fails(invoke("eval", "--gt", binary, "--est", poses), 1, binary)
    assert_fails(invoke("eval", "--gt", poses, "--est", poses, "--calib", binary), 1, binary)
    scans = synthetic_root / "sequences" / "00" / "velodyne"
    results = tmp_path / "results"
    for extra in (["--poses", binary], ["--poses", poses, "--calib", binary]):
        result = invoke("run", "--folder", scans, *extra, "--method", "icp10", "--results-dir", results)
        assert_fails(result, 1, binary, "UTF-8")
    assert no_results(results)


def weights_file(path: Path, config: VcrConfig | None = None, poison: bool = False) -> Path:
    torch.manual_seed(0)
    model = VCRNet(VcrConfig())
    if poison:
        with torch.no_grad():
            next(model.parameters()).fill_(float("nan"))
    return save_weights(path, model, config or VcrConfig())


def test_weights_holding_nan_are_refused_before_the_run(synthetic_root: Path, tmp_path: Path) -> None:
    weights = weights_file(tmp_path / "nan.safetensors", poison=True)
    results = tmp_path / "results"
    result = invoke("run", "--data-root", synthetic_root, "--weights", weights, "--results-dir", results)
    assert_fails(result, 1, weights, "NaN")
    assert no_results(results)


def test_weights_asking_for_absurd_sizes_are_refused_before_building(
    synthetic_root: Path, tmp_path: Path
) -> None:
    weights = weights_file(tmp_path / "huge.safetensors")
    raw = weights.read_bytes()
    length = int.from_bytes(raw[:8], "little")
    header = json.loads(raw[8 : 8 + length])
    config = json.loads(header["__metadata__"]["config"])
    config["num_points"] = 100_000_000
    header["__metadata__"]["config"] = json.dumps(config)
    encoded = json.dumps(header).encode()
    encoded += b" " * (-len(encoded) % 8)
    weights.write_bytes(len(encoded).to_bytes(8, "little") + encoded + raw[8 + length :])
    result = invoke(
        "run", "--data-root", synthetic_root, "--weights", weights, "--results-dir", tmp_path / "r"
    )
    assert_fails(result, 1, weights, "num_points")


def test_weights_whose_header_is_not_utf8_name_the_file(synthetic_root: Path, tmp_path: Path) -> None:
    weights = weights_file(tmp_path / "latin.safetensors")
    raw = weights.read_bytes()
    weights.write_bytes(raw.replace(b"vcr-odom-weights/1", b"vcr-odom-weights\xff1", 1))
    result = invoke(
        "run", "--data-root", synthetic_root, "--weights", weights, "--results-dir", tmp_path / "r"
    )
    assert_fails(result, 1, weights)


# -- a frame that breaks a method -------------------------------------------------------------------


def test_a_frame_of_one_repeated_point_is_flagged_by_index(synthetic_root: Path, tmp_path: Path) -> None:
    folder = tmp_path / "scans"
    shutil.copytree(synthetic_root / "sequences" / "00" / "velodyne", folder)
    np.tile(np.array([[5.0, 3.0, 1.0, 0.5]], dtype=np.float32), (5000, 1)).tofile(folder / "000003.bin")
    results = tmp_path / "results"
    result = invoke(
        "run",
        "--folder",
        folder,
        "--method",
        "vcr",
        "--polish",
        "none",
        "--device",
        "cpu",
        "--results-dir",
        results,
    )
    assert result.exit_code == 0, result.output
    assert "flagged" in result.output and "[3, 4]" in result.output
    metrics = json.loads(((results / "latest") / "metrics.json").read_text())
    assert metrics["run"]["flagged_reasons"] == {"3": "too few points", "4": "too few points"}


def test_eval_warns_about_a_partial_or_unmarked_estimate(synthetic_root: Path, tmp_path: Path) -> None:
    poses = synthetic_root / "poses" / "00.txt"
    unmarked = invoke("eval", "--gt", poses, "--est", poses)
    # rich wraps the warning at the console width, so compare with the line breaks taken out
    assert unmarked.exit_code == 0 and "result.json not found" in " ".join(unmarked.output.split())
    folder = tmp_path / "partial"
    folder.mkdir()
    shutil.copy(poses, folder / "trajectory_kitti.txt")
    (folder / "result.json").write_text(
        json.dumps(
            {"status": "partial", "frames_done": 8, "frames_selected": 20, "reason": "interrupted (Ctrl-C)"}
        )
    )
    partial = invoke("eval", "--gt", poses, "--est", folder / "trajectory_kitti.txt")
    text = " ".join(partial.output.split())
    assert partial.exit_code == 0 and "partial" in text and "8 of 20" in text
