"""Where and how a run executes: device choice, seeding and RNG capture, torchrun process groups.

Why here: these are the global-state parts of training; keeping them apart keeps the loop readable.
"""

from __future__ import annotations

import os
import random
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
from torch import nn

from vcr_odom.device import resolve_device


def seed_everything(seed: int) -> None:
    """Seed Python, NumPy and torch (all devices)."""
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def rng_state() -> dict[str, Any]:
    state: dict[str, Any] = {
        "python": random.getstate(),
        "numpy": np.random.get_state(),
        "torch": torch.get_rng_state(),
    }
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict[str, Any]) -> None:
    random.setstate(state["python"])
    np.random.set_state(state["numpy"])
    torch.set_rng_state(state["torch"])
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


@dataclass
class DistContext:
    """The process's place in a torchrun launch (world 1 when not launched by torchrun)."""

    world: int = 1
    rank: int = 0
    local_rank: int = 0
    owns_group: bool = False

    @property
    def main(self) -> bool:
        return self.rank == 0


def init_distributed(device_name: str) -> DistContext:
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return DistContext()
    local_rank = int(os.environ.get("LOCAL_RANK", "0"))
    owns = False
    if not dist.is_initialized():
        cuda = resolve_device(device_name, local_rank).type == "cuda"
        dist.init_process_group("nccl" if cuda else "gloo")
        owns = True
    return DistContext(dist.get_world_size(), dist.get_rank(), local_rank, owns)


def all_reduce_sum(values: list[float], device: torch.device, ctx: DistContext) -> list[float]:
    if ctx.world == 1:
        return values
    tensor = torch.tensor(values, dtype=torch.float64, device=device)
    dist.all_reduce(tensor)
    return tensor.tolist()


def parameter_groups(model: nn.Module, weight_decay: float) -> list[dict[str, Any]]:
    """Weight decay (the paper's Tikhonov term) on weight matrices only: never on biases, LayerNorm
    gains or the soft-pointer temperature, which decay would push towards meaningless values."""
    decay, no_decay = [], []
    for param in model.parameters():
        if param.requires_grad:
            (decay if param.ndim >= 2 else no_decay).append(param)
    return [{"params": decay, "weight_decay": weight_decay}, {"params": no_decay, "weight_decay": 0.0}]


def gather_rng_states(ctx: DistContext) -> list[dict[str, Any]]:
    """Every rank's RNG state (collective under torchrun), so each rank resumes its own stream."""
    state = rng_state()
    if ctx.world == 1:
        return [state]
    gathered: list[Any] = [None] * ctx.world
    dist.all_gather_object(gathered, state)
    return gathered
