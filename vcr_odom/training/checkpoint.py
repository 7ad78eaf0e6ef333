"""``last.pt``: the whole training state after an epoch, written atomically, checked when resumed.

Why a pickle (torch.save) and not safetensors: optimiser and scheduler states and RNG states are nested
Python objects. It is read back with ``weights_only=True`` (tensors, containers, numbers, strings and
NumPy's RNG arrays only), so a checkpoint handed over by someone else cannot run code when resumed;
shipped weights are safetensors (``vcr_odom.model.weights``).
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np
import torch

from vcr_odom.errors import ConfigError, DataError
from vcr_odom.io import atomic_write_bytes
from vcr_odom.model.config import INFERENCE_FIELDS, VcrConfig

CHECKPOINT_VERSION = 1
NUMPY_RNG_GLOBALS = [np._core.multiarray._reconstruct, np.ndarray, np.dtype, type(np.dtype(np.uint32))]
"""What ``np.random.get_state()`` pickles as, allowed beside the weights-only unpickler's own types."""
ALLOWED_NAMES = {f"{g.__module__}.{g.__qualname__}" for g in NUMPY_RNG_GLOBALS}


def save_checkpoint(path: Path, state: dict[str, Any]) -> Path:
    """Write ``state`` (plus the format version) to ``path`` through a temporary file and a rename."""
    buffer = io.BytesIO()
    torch.save({"version": CHECKPOINT_VERSION, **state}, buffer)
    return atomic_write_bytes(path, buffer.getvalue())


RESUMED_AS_STARTED: frozenset[str] = frozenset(INFERENCE_FIELDS) - {"num_points", "input_max_range"}
"""Settings a resumed run takes from its checkpoint where the requested ones differ.

Why: these are the pose head's inference steps, whose defaults change between releases (a release
that adds a step gives it a new default); a run started before must neither be stranded nor change
its forward pass halfway. The point count and the crop shape the training caches, so they must match."""


def load_checkpoint(path: Path, task: str, model_config: VcrConfig) -> dict[str, Any]:
    """The checkpoint to resume from, checked to belong to the same task and model configuration
    (apart from :data:`RESUMED_AS_STARTED`); ``state["model_config"]`` is the configuration to go on
    with, as a :class:`VcrConfig`."""
    if not path.is_file():
        raise DataError(f"cannot resume: no checkpoint at {path} (run once without --resume first)")
    try:
        unsafe = set(torch.serialization.get_unsafe_globals_in_checkpoint(path)) - ALLOWED_NAMES
        if unsafe:  # never unpickled: refused by name
            raise DataError(
                f"{path}: refused: the checkpoint holds objects other than tensors and plain data "
                f"({', '.join(sorted(unsafe))}; not written by vcr-odom, or tampered with)"
            )
        with torch.serialization.safe_globals(NUMPY_RNG_GLOBALS):
            state = torch.load(path, map_location="cpu", weights_only=True)
    except DataError:
        raise
    except Exception as error:  # any unpickling failure: a bad file
        raise DataError(f"{path}: not a readable checkpoint (corrupt or truncated?): {error}") from error
    if not isinstance(state, dict) or state.get("version") != CHECKPOINT_VERSION:
        raise DataError(f"{path}: not a vcr-odom checkpoint of version {CHECKPOINT_VERSION}")
    if state["task"] != task:
        raise ConfigError(f"{path} is a {state['task']!r} checkpoint; cannot resume it with {task!r}")
    try:  # read like a weight file's: a field older than the checkpoint takes its legacy value
        stored = VcrConfig.from_dict(state["model_config"])
    except ConfigError as error:
        raise DataError(f"{path}: the stored model configuration is invalid: {error}") from error
    found, wanted = stored.to_dict(), model_config.to_dict()
    differing = [k for k, v in wanted.items() if found[k] != v and k not in RESUMED_AS_STARTED]
    if differing:
        diffs = [f"{k}: checkpoint {found[k]!r}, requested {wanted[k]!r}" for k in differing]
        raise ConfigError(f"{path}: model configuration differs from the checkpoint ({'; '.join(diffs)})")
    state["model_config"] = stored
    return state
