"""Training and self-supervised pre-training of VCR-Net, and the pairs they learn from.

- :func:`train` optimises the paper's correspondence loss and :func:`pretrain` the encoder's triplet
  loss, on any datasets of pairs; both run one loop (:mod:`vcr_odom.training.loop`): a checkpoint every
  epoch with exact ``resume``, seeding, ``device`` auto/cpu/cuda, mixed precision on CUDA, and
  DistributedDataParallel under ``torchrun``.
- :class:`PairConfig` and :class:`PairDataset` (:mod:`~vcr_odom.training.pairs`,
  :mod:`~vcr_odom.training.datasets`) draw the pairs from frame caches
  (:mod:`vcr_odom.data.frame_cache`).
- :func:`cache_sequence`, :func:`fit_on` (:mod:`~vcr_odom.training.commands`)
  are the ``cache``, ``train`` and ``pretrain`` commands, from sequences and caches to weights.

The pair contract: items are dicts with ``source`` and ``target`` ``(N, 3)`` float32, ``transform``
``(4, 4)`` T_target_source and ``meta``; an optional ``set_epoch(epoch)`` is called at the start of
every epoch (training and validation sets alike).

Files in ``TrainConfig.out`` (rank 0 only): ``last.pt`` (full training state, every epoch, atomic),
``best.safetensors`` (best validation score so far: model selection never sees test data; load it with
:func:`vcr_odom.model.weights.load_weights`), ``history.json`` (one entry per epoch), ``run.json``.
"""

from vcr_odom.device import DEVICES, resolve_device
from vcr_odom.training.commands import (
    FrameSource,
    FramesProgress,
    TrainingData,
    cache_sequence,
    fit_on,
    sequence_caches,
    training_sets,
)
from vcr_odom.training.config import Progress, ProgressEvent, TrainConfig, TrainResult
from vcr_odom.training.datasets import PairDataset, PairDatasets, PairSample, train_val_datasets
from vcr_odom.training.loop import pretrain, train
from vcr_odom.training.pairs import (
    PROTOCOLS,
    PairConfig,
    pair_indices,
    pairs_within,
    random_rigid_transform,
    split_frames,
)
from vcr_odom.training.runtime import parameter_groups, seed_everything
from vcr_odom.training.tasks import pose_errors

__all__ = [
    "DEVICES",
    "PROTOCOLS",
    "FrameSource",
    "FramesProgress",
    "PairConfig",
    "PairDataset",
    "PairDatasets",
    "PairSample",
    "Progress",
    "ProgressEvent",
    "TrainConfig",
    "TrainResult",
    "TrainingData",
    "cache_sequence",
    "fit_on",
    "pair_indices",
    "pairs_within",
    "parameter_groups",
    "pose_errors",
    "pretrain",
    "random_rigid_transform",
    "resolve_device",
    "seed_everything",
    "sequence_caches",
    "split_frames",
    "train",
    "train_val_datasets",
    "training_sets",
]
