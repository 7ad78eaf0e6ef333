"""Which torch device a run uses: shared by inference (``registration/vcr.py``) and training."""

from __future__ import annotations

import torch

from vcr_odom.errors import ConfigError

DEVICES = ("auto", "cpu", "cuda")


def resolve_device(name: str, local_rank: int = 0) -> torch.device:
    """``auto`` picks CUDA when available; ``cuda`` without CUDA is a ConfigError."""
    if name not in DEVICES:
        raise ConfigError(f"device must be one of {', '.join(DEVICES)}; got {name!r}")
    if name == "cuda" or (name == "auto" and torch.cuda.is_available()):
        if not torch.cuda.is_available():
            raise ConfigError(
                "--device cuda was requested but CUDA is not available (use --device cpu or auto)"
            )
        return torch.device("cuda", local_rank)
    return torch.device("cpu")
