"""``scripts/set_inference_settings.py``: a shipped file's inference settings change, its tensors do not."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import torch

from vcr_odom.model.config import VcrConfig
from vcr_odom.model.network import VCRNet
from vcr_odom.model.weights import read_weights, save_weights

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "set_inference_settings.py"


def _weights(tmp_path: Path) -> Path:
    torch.manual_seed(0)
    config = VcrConfig(num_points=64, feature_dim=32, ff_dim=64, point_dim=16, graph_dim=16, spatial_dim=32)
    return save_weights(tmp_path / "w.safetensors", VCRNet(config), config, {"inference_settings": "first"})


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, check=False)


def test_the_copy_runs_with_the_new_setting_and_keeps_every_tensor_and_the_history(tmp_path: Path) -> None:
    source = _weights(tmp_path)
    out = tmp_path / "crop80.safetensors"
    done = _run(
        str(source), "--set", "input_max_range=80", "--note", "chosen on seeds 1-4", "--out", str(out)
    )
    assert done.returncode == 0, done.stderr
    tensors, config, metadata = read_weights(out)
    old_tensors, old_config, _ = read_weights(source)
    assert config.input_max_range == 80.0
    assert config.with_changes(input_max_range=old_config.input_max_range) == old_config
    assert tensors.keys() == old_tensors.keys()
    assert all(torch.equal(tensors[name], old_tensors[name]) for name in tensors)
    assert metadata["inference_settings"] == "first; input_max_range=80.0 (chosen on seeds 1-4)"


def test_an_architecture_field_or_a_bad_value_is_refused_by_name_and_nothing_is_written(
    tmp_path: Path,
) -> None:
    source = _weights(tmp_path)
    before = source.read_bytes()
    refused = _run(str(source), "--set", "feature_dim=64", "--note", "x")
    assert refused.returncode != 0
    assert "feature_dim" in refused.stderr and "input_max_range" in refused.stderr
    invalid = _run(str(source), "--set", "input_max_range=-5", "--note", "x")
    assert invalid.returncode != 0
    assert "input_max_range" in invalid.stderr
    assert source.read_bytes() == before


def test_the_point_count_is_an_inference_setting_parsed_as_a_whole_number(tmp_path: Path) -> None:
    """No tensor depends on N, so a file trained on 512 points can ship with 1024 (the model card)."""
    source = _weights(tmp_path)
    out = tmp_path / "n128.safetensors"
    done = _run(str(source), "--set", "num_points=128", "--note", "denser", "--out", str(out))
    assert done.returncode == 0, done.stderr
    _, config, _ = read_weights(out)
    assert config.num_points == 128
    model = VCRNet(config)
    model.load_state_dict(read_weights(out)[0])
    with torch.no_grad():
        output = model(torch.randn(1, 128, 3) * 10.0, torch.randn(1, 128, 3) * 10.0)
    assert output.key_points.shape == (1, config.key_points(128), 3)
    refused = _run(
        str(source), "--set", "num_points=1e3", "--note", "x", "--out", str(tmp_path / "bad.safetensors")
    )
    assert refused.returncode != 0
    assert "num_points" in refused.stderr and "whole number" in refused.stderr
    assert not (tmp_path / "bad.safetensors").exists()
