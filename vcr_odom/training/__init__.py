"""Training machinery behind :mod:`vcr_odom.train` (configuration, runtime, tasks, checkpoints, loop)."""

from vcr_odom.training.config import DEVICES, Progress, ProgressEvent, TrainConfig, TrainResult
from vcr_odom.training.runtime import parameter_groups, resolve_device, seed_everything
from vcr_odom.training.tasks import pose_errors

__all__ = [
    "DEVICES",
    "Progress",
    "ProgressEvent",
    "TrainConfig",
    "TrainResult",
    "parameter_groups",
    "pose_errors",
    "resolve_device",
    "seed_everything",
]
