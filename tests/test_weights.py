"""Weight files: round trip, and one clear DataError naming the file for each way loading can fail."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from safetensors.torch import save_file
from test_train import TINY

from vcr_odom.errors import DataError
from vcr_odom.model import VCRNet
from vcr_odom.model.weights import default_weights_path, load_weights, save_weights


@pytest.fixture()
def saved(tmp_path: Path) -> tuple[Path, VCRNet]:
    torch.manual_seed(0)
    model = VCRNet(TINY).eval()
    path = save_weights(tmp_path / "w.safetensors", model, TINY, {"epoch": 3, "note": "tiny"})
    return path, model


def test_round_trip_gives_identical_outputs(saved: tuple[Path, VCRNet]) -> None:
    path, model = saved
    loaded, config, metadata = load_weights(path)
    assert config == TINY
    assert metadata == {"epoch": 3, "note": "tiny"}
    assert not loaded.training
    source, target = torch.randn(2, 64, 3) * 5, torch.randn(2, 64, 3) * 5
    with torch.no_grad():
        assert torch.equal(model(source, target).transform, loaded(source, target).transform)
    assert not list(path.parent.glob(".*.tmp"))  # written atomically, no temporary left behind


def test_load_with_the_matching_config(saved: tuple[Path, VCRNet]) -> None:
    path, _ = saved
    _, config, _ = load_weights(path, TINY)
    assert config == TINY


def test_missing_file_names_it(tmp_path: Path) -> None:
    path = tmp_path / "absent.safetensors"
    with pytest.raises(DataError, match=r"not found.*absent\.safetensors"):
        load_weights(path)


@pytest.mark.parametrize("content", [b"", b"garbage that is not safetensors", b"\xff" * 64])
def test_corrupt_file_names_it(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "corrupt.safetensors"
    path.write_bytes(content)
    with pytest.raises(DataError, match=r"corrupt\.safetensors.*not a readable safetensors"):
        load_weights(path)


def test_truncated_file_names_it(saved: tuple[Path, VCRNet]) -> None:
    path, _ = saved
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(DataError, match=r"w\.safetensors.*not a readable safetensors"):
        load_weights(path)


def test_foreign_safetensors_file_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "other.safetensors"
    save_file({"x": torch.zeros(2)}, str(path))
    with pytest.raises(DataError, match=r"other\.safetensors.*not VCR-Net weights"):
        load_weights(path)


def test_config_mismatch_lists_the_fields(saved: tuple[Path, VCRNet]) -> None:
    path, _ = saved
    with pytest.raises(
        DataError, match=r"w\.safetensors.*another configuration.*feature_dim: file 32, requested 64"
    ):
        load_weights(path, TINY.with_changes(feature_dim=64, ff_dim=64))


def test_tensor_mismatch_lists_missing_unexpected_and_shapes(tmp_path: Path) -> None:
    state = {k: v.clone() for k, v in VCRNet(TINY).state_dict().items()}
    dropped = sorted(state)[0]
    del state[dropped]
    state["extra.weight"] = torch.zeros(1)
    reshaped = "log_temperature"
    state[reshaped] = torch.zeros(2)
    path = tmp_path / "mismatch.safetensors"

    class Holder(torch.nn.Module):
        def state_dict(self, *args: object, **kwargs: object) -> dict[str, torch.Tensor]:  # type: ignore[override]
            return state

    save_weights(path, Holder(), TINY, {})
    with pytest.raises(DataError) as error:
        load_weights(path)
    message = str(error.value)
    assert "mismatch.safetensors" in message
    assert f"missing tensors: {dropped}" in message
    assert "unexpected tensors: extra.weight" in message
    assert "log_temperature (2,) (model ())" in message


def test_default_weights_path_points_into_the_repository() -> None:
    path = default_weights_path("default", must_exist=False)
    assert path == Path(__file__).resolve().parents[1] / "weights" / "vcr-default.safetensors"


def test_absent_default_weights_say_how_to_train(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setattr("vcr_odom.model.weights.WEIGHTS_DIR", tmp_path)
    with pytest.raises(DataError, match=r"vcr-paper\.safetensors.*vcr-odom train --preset paper"):
        default_weights_path("paper")
