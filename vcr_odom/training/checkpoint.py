"""``last.pt``: the whole training state after an epoch, written atomically, checked when resumed.

Why a pickle (torch.save) and not safetensors: optimiser and scheduler states and RNG states are nested
Python objects. It is read back with ``weights_only=True`` (tensors, containers, numbers, strings and
NumPy's RNG arrays only), so a checkpoint handed over by someone else cannot run code when resumed;
shipped weights are safetensors (``vcr_odom.model.weights``).
"""

from __future__ import annotations

import io
import numbers
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
    (apart from :data:`RESUMED_AS_STARTED`) and validated whole (every field, the model's tensor names
    and shapes, no NaN): a broken file is one DataError naming it and what is wrong, never a traceback
    from the resume. ``state["model_config"]`` is the configuration to go on with, as a :class:`VcrConfig`."""
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
    _check_fields(path, state)
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
    _check_model(path, state["model"], stored)
    _check_finite(path, state)
    state["model_config"] = stored
    return state


FIELDS: dict[str, type | tuple[type, ...]] = {
    "task": str,
    "epoch": int,
    "model": dict,
    "optimiser": dict,
    "scheduler": dict,
    "scaler": dict,
    "rng": list,
    "best_score": numbers.Real,
    "best_epoch": int,
    "history": list,
    "model_config": dict,
}
"""What :func:`load_checkpoint` needs in ``last.pt`` (as :func:`~vcr_odom.training.loop` writes it), by type."""


def _check_fields(path: Path, state: dict[str, Any]) -> None:
    """A DataError naming the first field that is missing or of the wrong kind: a checkpoint cut down
    or edited by hand must fail in one line, not as a KeyError deep in the resume."""
    for name, kind in FIELDS.items():
        if name not in state:
            raise DataError(f"{path}: not a complete checkpoint: it has no {name!r}")
        if not isinstance(state[name], kind) or isinstance(state[name], bool):
            raise DataError(f"{path}: {name!r} is a {type(state[name]).__name__}, not what last.pt holds")
    optimiser = state["optimiser"]
    if not isinstance(optimiser.get("param_groups"), list) or not isinstance(optimiser.get("state"), dict):
        raise DataError(f"{path}: the optimiser state has no 'param_groups' list or 'state' dict")
    if not state["rng"] or not all(isinstance(r, dict) for r in state["rng"]):
        raise DataError(f"{path}: 'rng' holds no random-number-generator states")


def _check_model(path: Path, tensors: dict[str, Any], config: VcrConfig) -> None:
    """The stored parameters against the network ``config`` builds: the same names and shapes."""
    from vcr_odom.model.network import VCRNet  # the network is only built to be compared against

    expected = {name: tuple(t.shape) for name, t in VCRNet(config).state_dict().items()}
    missing = sorted(set(expected) - set(tensors))
    unexpected = sorted(set(tensors) - set(expected))
    if missing or unexpected:
        parts = [
            f"missing {', '.join(missing[:3])}" if missing else "",
            f"unexpected {', '.join(unexpected[:3])}" if unexpected else "",
        ]
        raise DataError(
            f"{path}: the model's tensors are not the network's ({'; '.join(p for p in parts if p)})"
        )
    for name, shape in expected.items():
        found = tensors[name]
        if not isinstance(found, torch.Tensor) or tuple(found.shape) != shape:
            got = tuple(found.shape) if isinstance(found, torch.Tensor) else type(found).__name__
            raise DataError(f"{path}: model tensor {name!r} is {got}, the network's is {shape}")


def _check_finite(path: Path, state: dict[str, Any]) -> None:
    """NaN or infinite values in the model or the optimiser's moments: a run that diverged before it
    was saved, which would fail later in the pose solve (an SVD of NaN) with no word of the file."""
    found = [("model tensor", name, t) for name, t in state["model"].items()]
    for key, moments in state["optimiser"]["state"].items():
        if isinstance(moments, dict):
            found += [("optimiser state", f"{key}.{name}", t) for name, t in moments.items()]
    for kind, name, tensor in found:
        if (
            isinstance(tensor, torch.Tensor)
            and tensor.is_floating_point()
            and not torch.isfinite(tensor).all()
        ):
            raise DataError(
                f"{path}: {kind} {name!r} holds NaN or infinite values (the run diverged before this "
                "checkpoint); start again, or resume from an earlier copy of last.pt"
            )


def check_resumable(path: Path, state: dict[str, Any], optimiser: torch.optim.Optimizer) -> None:
    """The stored optimiser state against ``optimiser`` (the one the run builds): the same parameter
    groups of the same sizes, which torch would otherwise refuse with a ValueError traceback."""
    stored = state["optimiser"]["param_groups"]
    groups = optimiser.param_groups
    sizes = [len(g.get("params", ())) if isinstance(g, dict) else -1 for g in stored]
    wanted = [len(g["params"]) for g in groups]
    if sizes != wanted:
        raise DataError(
            f"{path}: the optimiser state holds {len(sizes)} parameter group(s) of {sizes} parameters, "
            f"the run's optimiser {len(wanted)} of {wanted} (not this task's checkpoint, or edited)"
        )
