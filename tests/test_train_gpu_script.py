"""``scripts/train_gpu.sh train``, rehearsed on the CPU at tiny scale, on an image without open3d or
kiss-icp (as the lent GPU machine is): it must train from carried caches and leave loadable weights."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from vcr_odom.data.frame_cache import build_frame_cache
from vcr_odom.model.config import VcrConfig
from vcr_odom.model.weights import load_weights
from vcr_odom.preprocess import network_preprocess_config
from vcr_odom.synth import SynthSequence
from vcr_odom.training import PairConfig

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "train_gpu.sh"


def _without_open3d(tmp_path: Path) -> dict[str, str]:
    """An environment in which ``import open3d`` and ``import kiss_icp`` fail, as on the GPU image."""
    blocked = tmp_path / "blocked"
    for name in ("open3d", "kiss_icp"):
        (blocked / name).mkdir(parents=True)
        (blocked / name / "__init__.py").write_text(f"raise ImportError('{name} is not on this image')\n")
    return {
        **os.environ,
        "PYTHONPATH": str(blocked),
        "PYTHON": sys.executable,
        "PRESET": "default",
        "EPOCHS": "2",
        "BATCH": "2",
        "DEVICE": "cpu",
        "MAX_PAIRS": "2",
        "OMP_NUM_THREADS": "1",
    }


def test_gpu_script_trains_from_carried_caches_without_open3d(tmp_path: Path) -> None:
    model = VcrConfig.preset("default")
    caches = tmp_path / "caches"
    caches.mkdir()
    config = PairConfig(num_points=model.num_points, preprocess=network_preprocess_config(model))
    build_frame_cache(SynthSequence(frames=6, seed=11), None, config, copies=2).save(caches / "s.npz")
    out = tmp_path / "out"
    done = subprocess.run(
        ["bash", str(SCRIPT), "train", str(caches), str(out)],
        cwd=ROOT,
        env=_without_open3d(tmp_path),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    _, config_loaded, _ = load_weights(out / "best.safetensors")
    assert config_loaded == model
    history = json.loads((out / "history.json").read_text())
    assert len(history) == 2
    assert "2 training / " in done.stdout


@pytest.mark.parametrize("mode", ["train", "bogus"])
def test_gpu_script_usage_errors_are_clear(tmp_path: Path, mode: str) -> None:
    args = ["bash", str(SCRIPT), mode, str(tmp_path / "nothing"), str(tmp_path / "out")]
    done = subprocess.run(args, cwd=ROOT, env=_without_open3d(tmp_path), capture_output=True, text=True)
    assert done.returncode != 0
    expected = "no .npz frame caches" if mode == "train" else "usage: train_gpu.sh"
    assert expected in done.stderr
