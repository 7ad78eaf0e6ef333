"""Settings and results of a training run (``TrainConfig`` is stored in every checkpoint and weight file)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, model_validator

from vcr_odom.device import DEVICES
from vcr_odom.model.network import VCRNet
from vcr_odom.settings import Settings


class TrainConfig(Settings):
    """Optimisation settings shared by training and pre-training (recorded in every checkpoint).

    The ``triplet_*`` fields are Algorithm 1's (pre-training only).
    """

    epochs: int = Field(30, ge=1, strict=True, description="Epochs of the cosine learning-rate schedule.")
    batch_size: int = Field(
        8,
        ge=1,
        le=512,
        strict=True,
        description="Pairs per optimiser step (per process; memory grows with it).",
    )
    lr: float = Field(1e-3, gt=0, allow_inf_nan=False, description="Initial Adam learning rate.")
    weight_decay: float = Field(
        1e-4, ge=0, allow_inf_nan=False, description="Weight decay of weight matrices (not of biases)."
    )
    gamma: float | None = Field(
        None,
        gt=0,
        allow_inf_nan=False,
        description="False-match weight of Loss_cor; None = the model configuration's gamma.",
    )
    seed: int = Field(0, ge=0, description="Seeds the initialisation, the data order and every pair.")
    device: Literal[DEVICES] = Field("auto", description="Where to train (auto: CUDA when present).")
    amp: bool = Field(True, description="Mixed precision (amp_dtype) via torch.autocast, on CUDA only.")
    amp_dtype: Literal["bfloat16", "float16"] = "bfloat16"
    num_workers: int = Field(0, ge=0, strict=True, description="DataLoader worker processes.")
    grad_clip: float | None = Field(
        10.0, gt=0, allow_inf_nan=False, description="Max global gradient norm; None = no clipping."
    )
    out: Path = Field(
        Path("runs/train"), description="Checkpoints (last.pt), best.safetensors, history.json."
    )
    log_every: int = Field(10, ge=1, strict=True, description="Steps between progress events.")
    checkpoint_every: int | None = Field(
        None,
        ge=1,
        strict=True,
        description="Also write last.pt every this many steps inside an epoch, so that a killed run "
        "resumes mid-epoch (an epoch on 2 CPU cores can take hours); None = at epoch ends only.",
    )
    objective: Literal["correspondence", "matching"] = Field(
        "correspondence",
        description="correspondence: the paper's Loss_cor on the virtual points (what the first "
        "shipped weights were trained with). matching: the features must rank the right target points "
        "first (cross-entropy of the affinity), the self-attention weight must say which points have a "
        "counterpart, and the paper's head must get the pose (vcr_odom.model.losses.matching_loss).",
    )
    counterpart_radius: float = Field(
        2.0,
        gt=0,
        allow_inf_nan=False,
        description="matching: metres from a point's true position within which a target point counts "
        "as its counterpart (a down-sampled scan holds no exact one).",
    )
    overlap_weight: float = Field(
        1.0, ge=0, allow_inf_nan=False, description="matching: weight of the overlap term."
    )
    pose_weight: float = Field(
        0.5, ge=0, allow_inf_nan=False, description="matching: weight of the pose term."
    )
    correspondence_weight: float = Field(
        0.1,
        ge=0,
        allow_inf_nan=False,
        description="matching: weight of the paper's Loss_cor added to it (keeps the virtual points' blend "
        "near the truth).",
    )
    select_on: Literal["loss", "rmse", "inliers"] = Field(
        "loss",
        description="What picks best.safetensors: validation loss; rotation RMSE / 1° + translation "
        "RMSE / 0.25 m; or inliers, the validation share of key points whose best match lies within "
        "counterpart_radius of the truth (matching objective).",
    )
    init_weights: Path | None = Field(
        None, description="Start from these weights (e.g. pretrain's best.safetensors)."
    )

    @model_validator(mode="after")
    def _inliers_need_matching(self) -> TrainConfig:
        if self.select_on == "inliers" and self.objective != "matching":
            raise ValueError("select_on 'inliers' needs objective 'matching' (only it measures them)")
        return self

    deterministic: bool = Field(
        False, description="torch.use_deterministic_algorithms, for bit-reproducible runs."
    )
    time_limit_s: float | None = Field(
        None,
        gt=0,
        allow_inf_nan=False,
        description="No new epoch starts once the mean epoch so far would end past this many seconds "
        "of this run (a lent GPU's time is counted); None = every epoch.",
    )
    triplet_anchors: int = Field(32, ge=1, strict=True)
    triplet_negatives: int = Field(8, ge=1, strict=True)
    triplet_margin: float = Field(0.5, ge=0, allow_inf_nan=False)
    triplet_norm_weight: float = Field(0.05, ge=0, allow_inf_nan=False)


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

    ``start`` comes once, before the first epoch of this call, with ``metrics`` ``train_pairs`` and
    ``val_pairs`` (the sizes of the two sets); ``step`` events come every ``log_every`` steps and at
    the last step of an epoch, with running training means; ``epoch`` carries the history entry.
    """

    kind: str
    task: str
    epoch: int
    epochs: int
    step: int = 0
    steps: int = 0
    metrics: dict[str, float] = field(default_factory=dict)


Progress = Callable[[ProgressEvent], None]
