"""Which torch device a run uses: shared by inference (``registration/vcr.py``) and training."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

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


@contextmanager
def cores_shared_by(workers: int) -> Iterator[None]:
    """torch's CPU threads divided among ``workers`` threads that run torch work at the same time, and
    restored afterwards (torch's thread count is process-wide).

    Why: with the network on every pair, one thread encodes the next frame while another registers
    the current pair; each asking torch for every core left the two fighting over them (on two cores,
    one torch thread each ran 15 % more frames a second; docs/results.md "Benchmarks and speed")."""
    previous = torch.get_num_threads()
    torch.set_num_threads(max(1, previous // max(1, workers)))
    try:
        yield
    finally:
        torch.set_num_threads(previous)
