"""Training loop: overfitting, exact resume, pre-training, device checks and a two-process gloo DDP run."""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch
from click.testing import CliRunner
from torch.utils.data import Dataset

from vcr_odom.cli.main import cli
from vcr_odom.errors import ConfigError, DataError
from vcr_odom.model import VcrConfig
from vcr_odom.model.weights import load_weights, save_weights
from vcr_odom.training import (
    ProgressEvent,
    TrainConfig,
    TrainResult,
    pose_errors,
    pretrain,
    resolve_device,
    train,
)

TINY = VcrConfig(
    num_points=64,
    k=8,
    point_dim=16,
    graph_dim=16,
    spatial_dim=16,
    feature_dim=32,
    heads=2,
    ff_dim=32,
    top_j=4,
)


def _rotation(yaw: float) -> torch.Tensor:
    c, s = math.cos(yaw), math.sin(yaw)
    return torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class RandomPairs(Dataset):
    """The pair contract of vcr_odom.training: random clouds, random rigid transforms, target = R source + t (shuffled
    rows); ``set_epoch`` changes the transforms per epoch, as the paper protocol's dataset does."""

    def __init__(self, size: int, seed: int = 0, n: int = 64) -> None:
        self.size, self.seed, self.n, self.epoch = size, seed, n, 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return self.size

    def __getitem__(self, index: int) -> dict[str, object]:
        g = torch.Generator().manual_seed(self.seed * 7919 + index)
        source = torch.randn(self.n, 3, generator=g) * torch.tensor([10.0, 10.0, 1.0])
        g_epoch = torch.Generator().manual_seed(self.seed * 7919 + index + 104729 * (self.epoch + 1))
        yaw = float(torch.empty(()).uniform_(-0.3, 0.3, generator=g_epoch))
        transform = torch.eye(4)
        transform[:3, :3] = _rotation(yaw)
        transform[:3, 3] = torch.randn(3, generator=g_epoch) * torch.tensor([1.0, 1.0, 0.1])
        target = source @ transform[:3, :3].T + transform[:3, 3]
        target = target[torch.randperm(self.n, generator=g)]
        return {"source": source, "target": target, "transform": transform, "meta": f"pair {index}"}


class MislabelledPairs(RandomPairs):
    """Three pairs whose labels are off by a known rotation (yaw, applied to the source side) and a
    known shift, so that a network that registers perfectly has known validation errors."""

    YAW_DEG = (2.0, 4.0, 8.0)
    SHIFT_M = (0.1, 0.2, 0.4)

    def __init__(self) -> None:
        super().__init__(3, seed=1)

    def __getitem__(self, index: int) -> dict[str, object]:
        sample = super().__getitem__(index)
        label = sample["transform"].clone()  # type: ignore[union-attr]
        label[:3, :3] = label[:3, :3] @ _rotation(math.radians(self.YAW_DEG[index]))
        label[0, 3] += self.SHIFT_M[index]
        return {**sample, "transform": label}


def _config(tmp_path: Path, **changes: object) -> TrainConfig:
    base = {"epochs": 2, "batch_size": 2, "lr": 1e-3, "device": "cpu", "out": tmp_path, "seed": 3}
    base.update(changes)
    return TrainConfig(**base)  # type: ignore[arg-type]


def test_loss_decreases_on_a_tiny_overfit_set(tmp_path: Path) -> None:
    data, mislabelled = RandomPairs(2), MislabelledPairs()
    events: list[ProgressEvent] = []
    result = train(TINY, data, mislabelled, _config(tmp_path, epochs=12, lr=3e-3), progress=events.append)
    losses = [entry["train_loss"] for entry in result.history]
    assert losses[-1] < 0.7 * losses[0], losses
    assert "val_trans_loss" in result.history[-1]
    assert {e.kind for e in events} == {"start", "step", "epoch"}
    assert events[0].kind == "start" and events[0].metrics == {"train_pairs": 2, "val_pairs": 3}
    # The network registers these moved copies all but exactly, so the validation RMSEs are those
    # of the labels' known errors, over pairs (batches of 2 + 1: a mean of batch means would differ).
    rot_rmse = math.sqrt(sum(a * a for a in MislabelledPairs.YAW_DEG) / 3)
    trans_rmse = math.sqrt(sum(d * d for d in MislabelledPairs.SHIFT_M) / 3)
    assert result.history[-1]["val_rot_rmse_deg"] == pytest.approx(rot_rmse, rel=1e-3)
    assert result.history[-1]["val_trans_rmse_m"] == pytest.approx(trans_rmse, rel=1e-3)
    history = json.loads((tmp_path / "history.json").read_text())
    assert [entry["epoch"] for entry in history] == list(range(12))
    assert (tmp_path / "run.json").is_file() and (tmp_path / "last.pt").is_file()
    _, _, metadata = load_weights(result.best_path, TINY)
    assert metadata["epoch"] == result.best_epoch
    assert metadata["score"] == pytest.approx(min(entry["val_loss"] for entry in result.history))


def test_resume_equals_straight_training(tmp_path: Path) -> None:
    straight = train(TINY, RandomPairs(4), RandomPairs(2, seed=1), _config(tmp_path / "a", epochs=2))

    def stop_after_first_epoch(event: ProgressEvent) -> None:  # as if the run were killed (Ctrl-C)
        if event.kind == "epoch":
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(
            TINY,
            RandomPairs(4),
            RandomPairs(2, seed=1),
            _config(tmp_path / "b"),
            progress=stop_after_first_epoch,
        )
    assert len(json.loads((tmp_path / "b" / "history.json").read_text())) == 1
    torch.manual_seed(12345)  # the resumed run must not depend on the caller's RNG state
    resumed = train(TINY, RandomPairs(4), RandomPairs(2, seed=1), _config(tmp_path / "b"), resume=True)
    assert len(resumed.history) == 2
    for (name, a), (_, b) in zip(
        straight.model.state_dict().items(), resumed.model.state_dict().items(), strict=True
    ):
        assert torch.equal(a, b), name
    assert straight.history == resumed.history


def test_a_run_killed_inside_an_epoch_resumes_from_its_last_step_checkpoint(tmp_path: Path) -> None:
    """With ``checkpoint_every`` a run killed mid-epoch loses only the steps since the last step
    checkpoint, and the resumed run ends with the parameters and history of one that never stopped."""
    data, val = RandomPairs(8), RandomPairs(2, seed=1)
    straight = train(TINY, data, val, _config(tmp_path / "a", epochs=2, batch_size=2))
    steps_seen: list[tuple[int, int]] = []

    def kill_at_epoch_1_step_3(event: ProgressEvent) -> None:
        if event.kind == "step":
            steps_seen.append((event.epoch, event.step))
            if (event.epoch, event.step) == (1, 3):
                raise KeyboardInterrupt

    config = _config(tmp_path / "b", epochs=2, batch_size=2, checkpoint_every=2, log_every=1)
    with pytest.raises(KeyboardInterrupt):
        train(TINY, data, val, config, progress=kill_at_epoch_1_step_3)
    torch.manual_seed(12345)
    resumed_steps: list[tuple[int, int]] = []
    resumed = train(
        TINY, data, val, config, resume=True, progress=lambda e: resumed_steps.append((e.epoch, e.step))
    )
    assert [s for s in resumed_steps if s != (1, 0)] == [(1, 3), (1, 4)]  # steps 1-2 not run again
    for (name, a), (_, b) in zip(
        straight.model.state_dict().items(), resumed.model.state_dict().items(), strict=True
    ):
        assert torch.equal(a, b), name
    assert straight.history == resumed.history


def _resume(model_config: VcrConfig, tmp_path: Path, epochs: int) -> TrainResult:
    """``train`` resumed from the checkpoint in ``tmp_path``, with two random pairs."""
    return train(model_config, RandomPairs(2), RandomPairs(2), _config(tmp_path, epochs=epochs), resume=True)


def test_resume_without_checkpoint_or_with_another_model(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="no checkpoint"):
        train(TINY, RandomPairs(2), RandomPairs(2), _config(tmp_path, epochs=1), resume=True)
    train(TINY, RandomPairs(2), RandomPairs(2), _config(tmp_path, epochs=1))
    with pytest.raises(ConfigError, match="top_j: checkpoint 4, requested 8"):
        _resume(TINY.with_changes(top_j=8), tmp_path, epochs=2)
    with pytest.raises(ConfigError, match="'train' checkpoint"):
        pretrain(TINY, RandomPairs(2), RandomPairs(2), _config(tmp_path, epochs=2), resume=True)


def test_a_run_resumes_with_the_pose_head_it_started_with(tmp_path: Path) -> None:
    """A checkpoint written before a pose-head default changed (here: no compatible seeds, no gated
    rounds) resumes under today's defaults, and the run goes on with its own settings, which its best
    file records; the point count still has to match."""
    started = TINY.with_changes(consensus_seeds=0, gated_rounds=0)
    train(started, RandomPairs(2), RandomPairs(2), _config(tmp_path, epochs=1))
    resumed = _resume(TINY, tmp_path, epochs=2)
    assert len(resumed.history) == 2
    assert resumed.model.config == started
    _, stored, _ = load_weights(resumed.best_path, started)
    assert stored == started
    with pytest.raises(ConfigError, match="num_points: checkpoint 64, requested 128"):
        _resume(TINY.with_changes(num_points=128), tmp_path, epochs=3)


def test_pretrain_trains_the_encoder_only_and_feeds_train(tmp_path: Path) -> None:
    data = RandomPairs(2)
    result = pretrain(TINY, data, data, _config(tmp_path / "pre", epochs=3, lr=3e-3))
    assert "train_triplet" in result.history[0] and "val_regulariser" in result.history[0]
    pretrained, _, _ = load_weights(result.best_path, TINY)
    fresh = train(
        TINY, data, data, _config(tmp_path / "t", epochs=1, init_weights=result.best_path, lr=1e-12)
    )
    for name, value in pretrained.encoder.state_dict().items():
        assert torch.allclose(value, fresh.model.encoder.state_dict()[name], atol=1e-6), name


def test_a_fine_tune_starts_from_a_file_whose_inference_settings_were_changed_but_not_another_network(
    tmp_path: Path,
) -> None:
    """The shipped file runs with more points and a wider crop than it was trained with; fine-tuning
    from it must start from its tensors with the trainer's settings, and still refuse other layers."""
    data = RandomPairs(2)
    first = train(TINY, data, data, _config(tmp_path / "first", epochs=1))
    shipped = TINY.with_changes(num_points=2 * TINY.num_points, input_max_range=80.0, consensus_hypotheses=7)
    path = save_weights(tmp_path / "shipped.safetensors", first.model, shipped, {})
    tuned = train(TINY, data, data, _config(tmp_path / "tuned", epochs=1, init_weights=path, lr=1e-12))
    assert tuned.model.config == TINY
    for name, value in first.model.state_dict().items():
        assert torch.allclose(value, tuned.model.state_dict()[name], atol=1e-6), name
    with pytest.raises(DataError, match="top_j: file 4, requested 8"):
        train(
            TINY.with_changes(top_j=8), data, data, _config(tmp_path / "other", epochs=1, init_weights=path)
        )


def test_cuda_without_cuda_is_a_config_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(ConfigError, match="CUDA is not available"):
        resolve_device("cuda")
    assert resolve_device("auto").type == "cpu"
    with pytest.raises(ConfigError, match="CUDA is not available"):
        train(TINY, RandomPairs(2), RandomPairs(2), _config(tmp_path, device="cuda"))


def test_bad_train_config_values_are_config_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="device"):
        _config(tmp_path, device="tpu")
    with pytest.raises(ConfigError, match="epochs"):
        _config(tmp_path, epochs=0)


DDP_SCRIPT = """
import os, sys, torch
sys.path.insert(0, {tests!r})
from test_train import TINY, RandomPairs, _config
from vcr_odom.training import train
from pathlib import Path
out = Path({out!r})
result = train(TINY, RandomPairs(6), RandomPairs(3, seed=1), _config(out / "run", epochs=1))
torch.save(result.model.state_dict(), out / f"rank{{os.environ['RANK']}}.pt")
"""


@pytest.mark.skipif(not torch.distributed.is_available(), reason="torch.distributed not built")
def test_two_process_gloo_ddp_step(tmp_path: Path) -> None:
    torchrun = Path(sys.executable).with_name("torchrun")
    if not torchrun.exists():
        torchrun = Path(shutil.which("torchrun") or "torchrun")
    script = tmp_path / "ddp.py"
    script.write_text(textwrap.dedent(DDP_SCRIPT.format(tests=str(Path(__file__).parent), out=str(tmp_path))))
    env = {**os.environ, "OMP_NUM_THREADS": "1", "CUDA_VISIBLE_DEVICES": ""}
    done = subprocess.run(
        [str(torchrun), "--standalone", "--nproc-per-node", "2", str(script)],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    rank0, rank1 = (torch.load(tmp_path / f"rank{r}.pt") for r in (0, 1))
    for name, value in rank0.items():
        assert torch.equal(value, rank1[name]), name
    fresh = train(TINY, RandomPairs(2), RandomPairs(2), _config(tmp_path / "fresh", epochs=1, lr=1e-12))
    initial = fresh.model.state_dict()  # same seed, rank 0's initialisation, a negligible step
    assert any(not torch.allclose(v, initial[k], atol=1e-7) for k, v in rank0.items())  # DDP did train
    history = json.loads((tmp_path / "run" / "history.json").read_text())
    assert len(history) == 1  # one writer (rank 0), one epoch


class _RunsCode:
    """Pickles as a call to ``os.system``: what a hostile checkpoint would hold."""

    def __reduce__(self) -> tuple[object, tuple[str]]:
        import os

        return (os.system, ("touch ran-code",))


def test_resume_refuses_a_checkpoint_that_would_run_code(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, small_synthetic_root: Path
) -> None:
    train(TINY, RandomPairs(2), RandomPairs(2), _config(tmp_path, epochs=1))
    state = torch.load(tmp_path / "last.pt", weights_only=False)
    state["history"] = [_RunsCode()]
    torch.save(state, tmp_path / "last.pt")
    monkeypatch.chdir(tmp_path)
    with pytest.raises(DataError, match=r"last\.pt: refused: the checkpoint holds objects other than"):
        train(TINY, RandomPairs(2), RandomPairs(2), _config(tmp_path, epochs=2), resume=True)
    assert not (tmp_path / "ran-code").exists()

    # The command: a DataError exits 1 naming the file; the run's files are left as they were.
    before = {path.name: path.read_bytes() for path in tmp_path.iterdir() if path.is_file()}
    result = CliRunner().invoke(
        cli,
        [
            "train", "--data-root", str(small_synthetic_root), "--seq", "00", "--protocol", "same-scan",
            "--epochs", "2", "--device", "cpu", "--out", str(tmp_path), "--resume",
        ],
    )  # fmt: skip
    assert result.exit_code == 1, result.output
    assert f"{tmp_path / 'last.pt'}: refused" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "ran-code").exists()
    assert {path.name: path.read_bytes() for path in tmp_path.iterdir() if path.is_file()} == before
    torch.load(tmp_path / "last.pt", weights_only=False)  # the control: unpickled, the file does run code
    assert (tmp_path / "ran-code").exists()


def test_corrupt_checkpoint_is_a_data_error_naming_it(tmp_path: Path) -> None:
    (tmp_path / "last.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(DataError, match=r"last\.pt: not a readable checkpoint"):
        train(TINY, RandomPairs(2), RandomPairs(2), _config(tmp_path), resume=True)


def test_pose_errors_resolve_small_angles() -> None:
    yaw = math.radians(0.01)
    rotation = _rotation(yaw).unsqueeze(0)
    angle, distance = pose_errors(
        rotation, torch.tensor([[0.3, 0.4, 0.0]]), torch.eye(3)[None], torch.zeros(1, 3)
    )
    assert angle.item() == pytest.approx(0.01, rel=1e-3)
    assert distance.item() == pytest.approx(0.5)
    big, _ = pose_errors(
        _rotation(math.radians(170)).unsqueeze(0), torch.zeros(1, 3), torch.eye(3)[None], torch.zeros(1, 3)
    )
    assert big.item() == pytest.approx(170, rel=1e-5)


def test_time_limit_stops_before_an_epoch_that_would_overrun(tmp_path: Path) -> None:
    """A lent GPU's minutes: no epoch starts once the mean epoch would end past the limit; the
    epochs done keep their checkpoint and best weights. Without a limit every epoch runs."""
    data = RandomPairs(2)
    limited = train(TINY, data, data, _config(tmp_path / "limited", epochs=4, time_limit_s=1e-6))
    assert len(limited.history) == 1 and limited.best_path.is_file()
    full = train(TINY, data, data, _config(tmp_path / "full", epochs=2))
    assert len(full.history) == 2
    with pytest.raises(ConfigError, match="time_limit_s"):
        _config(tmp_path, time_limit_s=0.0)
