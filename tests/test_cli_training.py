"""Training commands end to end on a tiny synthetic sequence: cache -> train -> resume -> run with VCR."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from vcr_odom.cli.main import cli
from vcr_odom.synth import generate_sequence


@pytest.fixture(scope="module")
def synthetic_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("synthetic-train")
    generate_sequence(root, seq="00", frames=12, seed=4)
    return root


def invoke(*args: object) -> str:
    result = CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return result.stdout


def test_cache_train_resume_and_run_with_the_trained_weights(synthetic_root, tmp_path):
    cache = tmp_path / "seq00.npz"
    invoke("cache", "--data-root", synthetic_root, "--seq", "00", "--out", cache)
    assert cache.is_file()

    common = ["train", "--cache", cache, "--batch-size", "4", "--device", "cpu", "--out", tmp_path / "run"]
    invoke(*common, "--epochs", "1")
    history = json.loads((tmp_path / "run" / "history.json").read_text())
    assert len(history) == 1
    output = invoke(*common, "--epochs", "2", "--resume")
    assert "best epoch" in output
    history = json.loads((tmp_path / "run" / "history.json").read_text())
    assert [entry["epoch"] for entry in history] == [0, 1]

    weights = tmp_path / "run" / "best.safetensors"
    invoke(
        "run",
        "--data-root",
        synthetic_root,
        "--method",
        "vcr",
        "--weights",
        weights,
        "--device",
        "cpu",
        "--vcr-points",
        "256",
        "--frames",
        ":4",
        "--results-dir",
        tmp_path / "results",
    )
    assert (
        json.loads((tmp_path / "results" / "latest" / "config.json").read_text())["config"]["vcr_points"]
        == 256
    )
    metrics = json.loads((tmp_path / "results" / "latest" / "metrics.json").read_text())
    # A global method gets the kiss-icp polish unless --refine says otherwise.
    assert metrics["run"]["method"] == "vcr+kiss-icp" and metrics["run"]["frames_processed"] == 4

    output = invoke(
        "compare",
        "--data-root",
        synthetic_root,
        "-b",
        "vcr+none",
        "-b",
        "icp10",
        "--weights",
        weights,
        "--device",
        "cpu",
        "--frames",
        ":4",
        "--results-dir",
        tmp_path / "compare",
    )
    assert "none (global)" in output  # vcr needs no initial guess, and the table says so
    assert set(json.loads((tmp_path / "compare" / "latest" / "compare.json").read_text())) == {
        "vcr+none",
        "icp10",
    }


def test_vcr_without_weights_names_the_missing_file(synthetic_root, tmp_path, monkeypatch):
    import vcr_odom.model.weights as weights_module

    monkeypatch.setattr(weights_module, "WEIGHTS_DIR", tmp_path / "no-weights")
    result = CliRunner().invoke(
        cli, ["run", "--data-root", str(synthetic_root), "--method", "vcr", "--results-dir", str(tmp_path)]
    )
    assert result.exit_code != 0
    assert "vcr-default.safetensors" in result.output and "vcr-odom train" in result.output


def test_training_options_are_the_configurations_fields():
    """Each generated option has its field's default and bounds, so the two cannot drift apart."""
    from vcr_odom.cli.train import train_command
    from vcr_odom.training import TrainConfig, TrainingData

    options = {param.name: param for param in train_command.params}
    for config in (TrainConfig, TrainingData):
        shared = set(config.model_fields) & set(options)
        for name in shared:
            assert options[name].default == config.model_fields[name].default, name
    assert {"epochs", "lr", "out", "init_weights", "caches", "protocols", "val_fraction"} <= set(options)
    assert (options["val_fraction"].type.min, options["val_fraction"].type.max) == (0.05, 0.5)
    assert options["lr"].type.min == 0 and options["lr"].type.min_open


def test_bad_training_options_are_usage_errors(tmp_path):
    for args, expected in (
        (["--epochs", "0"], "--epochs"),
        (["--seq", "00", "--seq", "01", "--out", tmp_path / "c.npz"], "exactly one --seq"),
        ([], "give training data"),
    ):
        command = "cache" if "--seq" in args else "train"
        result = CliRunner().invoke(cli, [command, *[str(a) for a in args]])
        assert result.exit_code == 2, result.output
        assert expected in result.output


def test_caches_carry_their_crop_and_training_refuses_one_the_model_would_not_see(synthetic_root, tmp_path):
    """The shipped file runs with an 80 m crop: a cache made for it says so, and training a 40 m
    model on it (or the other way round) stops with the cache's name and both crops."""
    from vcr_odom.data.frame_cache import FrameCache

    wide = tmp_path / "wide.npz"
    invoke(
        "cache",
        "--data-root",
        synthetic_root,
        "--seq",
        "00",
        "--frames",
        "0:6",
        "--input-max-range",
        "80",
        "--out",
        wide,
    )
    assert FrameCache.load(wide).preprocess["max_range"] == 80.0
    result = CliRunner().invoke(
        cli,
        ["train", "--cache", str(wide), "--epochs", "1", "--device", "cpu", "--out", str(tmp_path / "run")],
    )
    assert result.exit_code != 0
    assert "wide.npz" in result.output and "80 m" in result.output and "40 m" in result.output
    assert not (tmp_path / "run" / "best.safetensors").exists()


def test_the_point_count_is_an_option_of_cache_and_train_and_must_agree(synthetic_root, tmp_path):
    """The shipped file runs on 1024 points: a cache and a fine-tune can be made at any count, and a
    cache of another count is refused by name before any training."""
    from vcr_odom.data.frame_cache import FrameCache

    small = tmp_path / "small.npz"
    invoke(
        "cache", "--data-root", synthetic_root, "--seq", "00", "--num-points", "64", "--out", small,
    )  # fmt: skip
    assert FrameCache.load(small).num_points == 64
    refused = CliRunner().invoke(
        cli,
        ["train", "--cache", str(small), "--epochs", "1", "--device", "cpu", "--out", str(tmp_path / "r")],
    )
    assert refused.exit_code != 0
    assert "small.npz" in refused.output and "512" in refused.output
    invoke(
        "train", "--cache", small, "--num-points", "64", "--epochs", "1", "--batch-size", "2",
        "--device", "cpu", "--out", tmp_path / "run",
    )  # fmt: skip
    assert (tmp_path / "run" / "best.safetensors").is_file()
    bad = CliRunner().invoke(
        cli, ["train", "--cache", str(small), "--num-points", "8", "--out", str(tmp_path)]
    )
    assert bad.exit_code == 2 and "num_points" in bad.output


def test_vcr_odom_train_runs_under_torchrun_on_two_cpu_processes(synthetic_root, tmp_path):
    """The command a cluster runs (docs/scaling.md): torchrun starts two ranks of ``vcr-odom train``
    (gloo on CPU); each takes half the batches, and rank 0 alone writes the run's files."""
    cache = tmp_path / "seq00.npz"
    invoke("cache", "--data-root", synthetic_root, "--seq", "00", "--out", cache)
    torchrun = Path(sys.executable).with_name("torchrun")
    done = subprocess.run(
        [
            str(torchrun),
            "--standalone",
            "--nproc-per-node",
            "2",
            "-m",
            "vcr_odom.cli.main",
            "train",
            "--cache",
            str(cache),
            "--batch-size",
            "2",
            "--device",
            "cpu",
            "--epochs",
            "1",
            "--out",
            str(tmp_path / "run"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
        env={**os.environ, "OMP_NUM_THREADS": "1", "CUDA_VISIBLE_DEVICES": "", "COLUMNS": "200"},
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.count("best epoch 1") == 1
    steps = re.search(r"train epoch 1/1 \S+ (\d+)/(\d+)", done.stdout)
    pairs = int(re.search(r"(\d+) training and", done.stdout).group(1))
    assert steps is not None and int(steps.group(2)) == -(-pairs // (2 * 2))  # half the pairs per rank
    assert json.loads((tmp_path / "run" / "history.json").read_text())[0]["epoch"] == 0
    assert (tmp_path / "run" / "best.safetensors").is_file()
