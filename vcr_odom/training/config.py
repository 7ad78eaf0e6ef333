"""Settings and results of a training run (``TrainConfig`` is stored in every checkpoint and weight file)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from vcr_odom.device import DEVICES
from vcr_odom.errors import ConfigError
from vcr_odom.model.network import VCRNet


@dataclass
class TrainConfig:
    """Optimisation settings shared by training and pre-training (recorded in every checkpoint).

    ``gamma``: false-match weight of Loss_cor; None = the model configuration's ``gamma``.
    ``amp``: mixed precision (``amp_dtype`` bfloat16 or float16) via torch.autocast, on CUDA only.
    ``grad_clip``: max global gradient norm, None = off. ``select_on``: ``loss`` (validation loss) or
    ``rmse`` (rotation RMSE / 1° + translation RMSE / 0.25 m, the issue's targets) for best.safetensors.
    ``init_weights``: start from these weights (e.g. a pre-training's best.safetensors).
    ``deterministic``: torch.use_deterministic_algorithms, for bit-reproducible runs.
    ``time_limit_s``: no new epoch starts once the mean epoch so far would end past this many seconds
    of this run (a lent GPU's time is counted); None = every epoch.
    The ``triplet_*`` fields are Algorithm 1's (pre-training only).
    """

    epochs: int = 30
    batch_size: int = 8
    lr: float = 1e-3
    weight_decay: float = 1e-4
    gamma: float | None = None
    seed: int = 0
    device: str = "auto"
    amp: bool = True
    amp_dtype: str = "bfloat16"
    num_workers: int = 0
    grad_clip: float | None = 10.0
    out: Path = Path("runs/train")
    log_every: int = 10
    select_on: str = "loss"
    init_weights: Path | None = None
    deterministic: bool = False
    time_limit_s: float | None = None
    triplet_anchors: int = 32
    triplet_negatives: int = 8
    triplet_margin: float = 0.5
    triplet_norm_weight: float = 0.05

    def __post_init__(self) -> None:
        if self.time_limit_s is not None and not (math.isfinite(self.time_limit_s) and self.time_limit_s > 0):
            raise ConfigError(
                f"time_limit_s must be None or a number of seconds > 0; got {self.time_limit_s!r}"
            )
        self.out = Path(self.out)
        self.init_weights = Path(self.init_weights) if self.init_weights is not None else None
        for name in ("epochs", "batch_size", "log_every", "triplet_anchors", "triplet_negatives"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(f"{name} must be an integer >= 1; got {value!r}")
        if not isinstance(self.num_workers, int) or self.num_workers < 0:
            raise ConfigError(f"num_workers must be an integer >= 0; got {self.num_workers!r}")
        for name in ("lr", "weight_decay", "triplet_margin", "triplet_norm_weight"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise ConfigError(f"{name} must be a finite number >= 0; got {value!r}")
        if self.lr <= 0:
            raise ConfigError(f"lr must be > 0; got {self.lr!r}")
        for name in ("gamma", "grad_clip"):
            value = getattr(self, name)
            if value is not None and not (
                isinstance(value, int | float) and math.isfinite(value) and value > 0
            ):
                raise ConfigError(f"{name} must be None or a number > 0; got {value!r}")
        if self.device not in DEVICES:
            raise ConfigError(f"device must be one of {', '.join(DEVICES)}; got {self.device!r}")
        if self.amp_dtype not in ("bfloat16", "float16"):
            raise ConfigError(f"amp_dtype must be bfloat16 or float16; got {self.amp_dtype!r}")
        if self.select_on not in ("loss", "rmse"):
            raise ConfigError(f"select_on must be loss or rmse; got {self.select_on!r}")

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["out"] = str(self.out)
        data["init_weights"] = str(self.init_weights) if self.init_weights is not None else None
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainConfig:
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in known})


@dataclass
class TrainResult:
    """What a run produced; ``model`` is the final (last-epoch) network, unwrapped, on its device."""

    model: VCRNet
    out: Path
    best_path: Path
    checkpoint_path: Path
    history: list[dict[str, Any]]
    best_epoch: int
    best_score: float


@dataclass
class ProgressEvent:
    """Sent to the ``progress`` callback (rank 0 only). ``kind``: ``start``, ``step`` or ``epoch``.

    ``step`` events come every ``log_every`` steps and at the last step of an epoch; ``metrics`` holds
    running training means for ``step`` and the history entry for ``epoch``.
    """

    kind: str
    task: str
    epoch: int
    epochs: int
    step: int = 0
    steps: int = 0
    metrics: dict[str, float] = field(default_factory=dict)


Progress = Callable[[ProgressEvent], None]
