"""Training and self-supervised pre-training of VCR-Net: the two entry points the CLI calls.

:func:`train` optimises the paper's correspondence loss (§IV-F; the transformation loss and the pose
RMSEs are only monitored) and :func:`pretrain` the encoder's triplet loss (Algorithm 1). Both run the
same loop (:mod:`vcr_odom.training.loop`): checkpoints every epoch with exact ``resume``, seeding,
``device`` auto/cpu/cuda, mixed precision on CUDA, and DistributedDataParallel under ``torchrun``.

Datasets follow the pair contract of ``vcr_odom.data.pairs``: items are dicts with ``source`` and
``target`` ``(N, 3)`` float32, ``transform`` ``(4, 4)`` T_target_source and ``meta``; an optional
``set_epoch(epoch)`` is called at the start of every epoch (training and validation sets alike).

Files in ``TrainConfig.out`` (rank 0 only): ``last.pt`` (full training state, every epoch, atomic),
``best.safetensors`` (best validation score so far: model selection never sees test data; load it with
:func:`vcr_odom.model.weights.load_weights`), ``history.json`` (one entry per epoch), ``run.json``.
"""

from __future__ import annotations

from torch.utils.data import Dataset

from vcr_odom.device import resolve_device
from vcr_odom.model.config import VcrConfig
from vcr_odom.training.config import DEVICES, Progress, ProgressEvent, TrainConfig, TrainResult
from vcr_odom.training.loop import fit
from vcr_odom.training.runtime import seed_everything
from vcr_odom.training.tasks import Pretraining, Registration

__all__ = [
    "DEVICES",
    "Progress",
    "ProgressEvent",
    "TrainConfig",
    "TrainResult",
    "pretrain",
    "resolve_device",
    "seed_everything",
    "train",
]


def train(
    model_config: VcrConfig,
    train_dataset: Dataset,
    val_dataset: Dataset,
    train_config: TrainConfig,
    resume: bool = False,
    progress: Progress | None = None,
) -> TrainResult:
    """Train VCR-Net with the correspondence loss; ``best.safetensors`` is chosen on ``val_dataset``."""
    return fit(Registration(), model_config, train_dataset, val_dataset, train_config, resume, progress)


def pretrain(
    model_config: VcrConfig,
    train_dataset: Dataset,
    val_dataset: Dataset,
    train_config: TrainConfig,
    resume: bool = False,
    progress: Progress | None = None,
) -> TrainResult:
    """Pre-train the encoder with the triplet loss. Its ``best.safetensors`` holds a whole VCRNet (encoder
    trained, the rest at initialisation), to pass as ``TrainConfig.init_weights`` to :func:`train`."""
    return fit(Pretraining(), model_config, train_dataset, val_dataset, train_config, resume, progress)
