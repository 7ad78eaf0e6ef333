"""VCR-Net weight files: safetensors with the model configuration and free-form metadata in the header.

Why safetensors: a weight file is data, never code (``torch.load`` of a pickle can run anything), and
its JSON header carries the :class:`VcrConfig` so a file can rebuild its own model. Every failure to
load is a :class:`DataError` naming the file and what is wrong with it, so the CLI can print one line.
"""

from __future__ import annotations

import json
import os
from importlib import resources
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load as load_safetensors
from safetensors.torch import save as save_safetensors

from vcr_odom.errors import ConfigError, DataError
from vcr_odom.io import atomic_write_bytes
from vcr_odom.model.config import INFERENCE_FIELDS, PRESETS, VcrConfig
from vcr_odom.model.network import VCRNet

FORMAT = "vcr-odom-weights/1"

CONFIG_LIMITS: dict[str, int] = {
    "num_points": 16_384,
    "k": 256,
    "point_dim": 4096,
    "graph_dim": 4096,
    "spatial_dim": 4096,
    "feature_dim": 4096,
    "heads": 64,
    "ff_dim": 16_384,
    "top_j": 1024,
    "robust_iterations": 1000,
    "consensus_hypotheses": 1_000_000,
    "consensus_seeds": 65_536,
    "consensus_group": 65_536,
}
"""Upper bounds on a stored :class:`VcrConfig`'s sizes, checked before a model is built from it.

Why: the sizes come from a file, and a corrupt or hostile header (``num_points: 1e8``) would
otherwise have the network try to allocate tens of gigabytes (the attention is N x N) before anything
says the file is wrong. Each bound is 16x or more the ``paper`` preset's value."""
MAX_NETWORK_POINTS = 8192
"""Most points per cloud the network may be fed (``--vcr-points``, ``--pair-points``, ``--num-points``).

Why: the network's memory grows with N squared (kNN graphs and self-attention are N x N, per head):
measured on a CPU, one pair at N = 4096 takes about 0.4 GB over the model's own and 10 s, so 8192
takes about 1.5 GB, while ``--vcr-points 200000`` asked for 62 GB. 8192 is 8x the shipped file's
1024 and 16x the N it was trained on."""
MAX_WEIGHT_MAGNITUDE = 1e4
"""Largest absolute value a weight file may hold. Trained VCR-Net values stay within about 5 (the
shipped files' largest is the log temperature, 5.4; weight decay keeps the rest near 1), so a value
beyond this is a corrupt or scaled file: x1e30 weights ended a run in a LinAlgError at frame 1."""
WEIGHTS_DIR = Path(str(resources.files("vcr_odom.weights")))
"""The shipped weights: the repository's ``weights/`` folder, installed as the package ``vcr_odom.weights``."""


def default_weights_path(preset: str = "default", must_exist: bool = True) -> Path:
    """The repository's shipped weights for ``preset`` (``weights/vcr-<preset>.safetensors``).

    With ``must_exist`` (the default) a missing file raises a DataError that says how to make one.
    """
    if preset not in PRESETS:
        raise ConfigError(f"preset must be one of {', '.join(PRESETS)}; got {preset!r}")
    path = WEIGHTS_DIR / f"vcr-{preset}.safetensors"
    if must_exist and not path.is_file():
        raise DataError(
            f"no shipped weights for the {preset!r} configuration at {path}; train them with "
            f"`vcr-odom train --preset {preset} --out runs/{preset}` and copy runs/{preset}/best.safetensors "
            f"there, or pass --weights FILE"
        )
    return path


def save_weights(
    path: str | os.PathLike[str],
    model: torch.nn.Module,
    config: VcrConfig,
    metadata: dict[str, Any] | None = None,
) -> Path:
    """Write ``model``'s parameters and buffers, ``config`` and JSON-able ``metadata`` atomically."""
    module = getattr(model, "module", model)  # unwrap DistributedDataParallel
    tensors = {name: value.detach().to("cpu").contiguous() for name, value in module.state_dict().items()}
    header = {
        "format": FORMAT,
        "config": json.dumps(config.to_dict(), sort_keys=True),
        "metadata": json.dumps(metadata or {}, sort_keys=True, default=str),
    }
    return atomic_write_bytes(path, save_safetensors(tensors, metadata=header))


def read_weights(path: str | os.PathLike[str]) -> tuple[dict[str, torch.Tensor], VcrConfig, dict[str, Any]]:
    """Tensors, stored configuration and metadata of a weight file, checked to be one of ours."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"weights file not found: {path}")
    raw = path.read_bytes()
    try:
        tensors = load_safetensors(raw)
        header = _header_metadata(raw)
    except (SafetensorError, ValueError, KeyError, json.JSONDecodeError) as error:
        raise DataError(
            f"{path}: not a readable safetensors file (corrupt or truncated?): {error}"
        ) from error
    if header.get("format") != FORMAT or "config" not in header:
        raise DataError(f"{path}: a safetensors file but not VCR-Net weights (no {FORMAT!r} header)")
    try:
        config = VcrConfig.from_dict(json.loads(header["config"]))
        metadata = json.loads(header.get("metadata", "{}"))
    except (json.JSONDecodeError, ConfigError, TypeError) as error:
        raise DataError(f"{path}: the stored model configuration is invalid: {error}") from error
    check_config_limits(path, config)
    check_finite(path, tensors)
    check_plausible(path, tensors)
    return tensors, config, metadata


def check_config_limits(path: Path, config: VcrConfig) -> None:
    """DataError naming every size of ``config`` beyond :data:`CONFIG_LIMITS`."""
    stored = config.to_dict()
    over = [
        f"{name} = {stored[name]!r} (at most {limit})"
        for name, limit in CONFIG_LIMITS.items()
        if isinstance(stored.get(name), int) and stored[name] > limit
    ]
    if over:
        raise DataError(
            f"{path}: the stored model configuration asks for sizes no VCR-Net uses ({'; '.join(over)}); "
            "the file is corrupt or not made by vcr-odom"
        )


def check_finite(path: Path, tensors: dict[str, torch.Tensor]) -> None:
    """DataError naming the tensors holding NaN or inf: such a network returns NaN transforms (or fails
    deep in an SVD) on every pair, so it is refused where the file is read."""
    bad = [
        name
        for name, tensor in sorted(tensors.items())
        if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all())
    ]
    if bad:
        shown = ", ".join(bad[:5]) + (f" and {len(bad) - 5} more" if len(bad) > 5 else "")
        raise DataError(f"{path}: weights hold NaN or inf values (in {shown}); the file is corrupt")


def check_plausible(path: Path, tensors: dict[str, torch.Tensor]) -> None:
    """DataError for weights no training produces: every weight matrix zero (a wiped or blank file,
    which runs and returns the identity for every pair: a frozen trajectory with only a warning), or
    a value beyond :data:`MAX_WEIGHT_MAGNITUDE` (a scaled file, whose pose solve fails)."""
    floats = {name: t for name, t in sorted(tensors.items()) if t.is_floating_point() and t.numel()}
    matrices = [t for t in floats.values() if t.ndim >= 2]
    if matrices and not any(bool(t.any()) for t in matrices):
        raise DataError(
            f"{path}: every weight matrix is zero (a blank or wiped file); expected trained VCR-Net weights"
        )
    largest, name = max(((float(t.abs().max()), name) for name, t in floats.items()), default=(0.0, ""))
    if largest > MAX_WEIGHT_MAGNITUDE:
        raise DataError(
            f"{path}: weights hold {largest:.3g} (in {name}); trained VCR-Net weights stay within "
            f"+-{MAX_WEIGHT_MAGNITUDE:g}, so the file is corrupt or scaled"
        )


def check_forward(path: Path, model: VCRNet) -> None:
    """DataError unless ``model`` registers a fixed small synthetic pair to finite, non-degenerate
    output: what :func:`check_plausible` cannot see (weights that are each plausible but together
    give NaN, or virtual points that all coincide) is found where the file is read, not at frame 1.
    Runs on the CPU with the global random state untouched."""
    config = model.config
    count = max(64, 2 * (config.k + 1), config.top_j + 1)
    generator = torch.Generator().manual_seed(0)
    source = torch.rand(1, count, 3, generator=generator) * torch.tensor([30.0, 30.0, 3.0]) - 15.0
    angle = torch.tensor(0.1)
    rotation = torch.tensor(
        [[angle.cos(), -angle.sin(), 0.0], [angle.sin(), angle.cos(), 0.0], [0.0, 0.0, 1.0]]
    )
    target = source @ rotation.T + torch.tensor([1.0, 0.5, 0.0])
    try:
        with torch.random.fork_rng(devices=[]), torch.inference_mode():
            output = model.eval()(source, target)
    except torch.linalg.LinAlgError as error:
        raise DataError(
            f"{path}: the network's pose solve fails on a test pair ({error}); the weights are corrupt"
        ) from None
    virtual = output.virtual_points.double()
    finite = bool(torch.isfinite(output.transform).all() and torch.isfinite(virtual).all())
    spread = float((virtual - virtual.mean(dim=1, keepdim=True)).abs().max()) if finite else 0.0
    if not finite or spread < 1e-6:
        what = "non-finite poses" if not finite else "virtual points that all coincide"
        raise DataError(
            f"{path}: the network gives {what} on a test pair; the weights are corrupt or untrained"
        )


def load_weights(
    path: str | os.PathLike[str],
    config: VcrConfig | None = None,
    device: str | torch.device = "cpu",
    *,
    inference_from_config: bool = False,
) -> tuple[VCRNet, VcrConfig, dict[str, Any]]:
    """Rebuild the VCRNet stored in ``path`` (in eval mode, on ``device``).

    With ``config``, the file must have been trained with exactly that configuration; otherwise the
    file's own configuration is used. ``inference_from_config``: only the fields tensors were fitted
    to must agree, and the model runs with ``config``'s :data:`INFERENCE_FIELDS` (a fine-tune starting
    from a shipped file whose point count or crop was changed after training).
    """
    path = Path(path)
    tensors, stored, metadata = read_weights(path)
    if config is not None and inference_from_config:
        stored = stored.with_changes(**{name: getattr(config, name) for name in INFERENCE_FIELDS})
    if config is not None and config != stored:
        wanted, found = config.to_dict(), stored.to_dict()
        diffs = [f"{k}: file {found[k]!r}, requested {wanted[k]!r}" for k in wanted if wanted[k] != found[k]]
        raise DataError(f"{path}: weights were trained with another configuration ({'; '.join(diffs)})")
    model = VCRNet(stored)
    check_state_dict(path, model.state_dict(), tensors)
    model.load_state_dict(tensors)
    check_forward(path, model)
    return model.to(device).eval(), stored, metadata


def check_state_dict(path: Path, expected: dict[str, torch.Tensor], found: dict[str, torch.Tensor]) -> None:
    """DataError listing missing and unexpected tensors and shape mismatches, if any."""
    problems = []
    missing = sorted(set(expected) - set(found))
    unexpected = sorted(set(found) - set(expected))
    if missing:
        problems.append(f"missing tensors: {', '.join(missing)}")
    if unexpected:
        problems.append(f"unexpected tensors: {', '.join(unexpected)}")
    shapes = [
        f"{name} {tuple(found[name].shape)} (model {tuple(expected[name].shape)})"
        for name in sorted(set(expected) & set(found))
        if found[name].shape != expected[name].shape
    ]
    if shapes:
        problems.append(f"shape mismatches: {', '.join(shapes)}")
    if problems:
        raise DataError(f"{path}: tensors do not match the model: {'; '.join(problems)}")


def _header_metadata(raw: bytes) -> dict[str, str]:
    """The ``__metadata__`` of a safetensors header (8-byte little-endian length, then JSON)."""
    if len(raw) < 8:
        raise ValueError("file shorter than a safetensors header")
    length = int.from_bytes(raw[:8], "little")
    if length > len(raw) - 8:
        raise ValueError("header length beyond end of file")
    header = json.loads(raw[8 : 8 + length])
    metadata = header.get("__metadata__", {}) if isinstance(header, dict) else {}
    return metadata if isinstance(metadata, dict) else {}
