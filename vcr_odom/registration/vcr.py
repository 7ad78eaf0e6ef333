"""VCR-Net behind the :class:`Registrar` interface: a learned global registration, no initial guess.

``prepare`` does all per-frame work once (ground removal, down-sampling to N points, the encoder),
so in odometry each frame is encoded once and its features serve both pairs it belongs to.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from vcr_odom.data.base import Points
from vcr_odom.geometry import Transform
from vcr_odom.model.weights import default_weights_path, load_weights
from vcr_odom.preprocess import PreprocessConfig, preprocess
from vcr_odom.registration.base import RegistrationResult
from vcr_odom.training.runtime import resolve_device


@dataclass
class VcrFrame:
    """A frame as the network sees it: ``points`` (1, N, 3) on the device and their encoder features."""

    points: torch.Tensor
    features: torch.Tensor


class VcrRegistrar:
    """Relative pose from two prepared frames with a trained VCR-Net (``weights`` or the shipped file)."""

    name = "vcr"
    needs_initial_guess = False

    def __init__(self, weights: str | Path | None = None, device: str = "auto", seed: int = 0) -> None:
        path = Path(weights) if weights is not None else default_weights_path("default")
        self.device = resolve_device(device)
        self.model, self.config, self.metadata = load_weights(path, device=str(self.device))
        self.model.eval()
        self.weights_path = path
        # Pre-processing as in training: ground removed, exactly N points by farthest point sampling.
        self.preprocess_config = PreprocessConfig(n_points=self.config.num_points, method="fps", seed=seed)

    @torch.inference_mode()
    def prepare(self, points: Points) -> VcrFrame:
        """Encode a frame. A cloud of exactly N points is taken as already pre-processed (the pairs
        protocol's clouds are): ground removal and sampling again would only drop or shuffle points."""
        if len(points) == self.config.num_points:
            xyz = np.asarray(points, dtype=np.float32)[:, :3]
        else:
            xyz = preprocess(points, self.preprocess_config)[:, :3]
        tensor = torch.as_tensor(np.ascontiguousarray(xyz), dtype=torch.float32, device=self.device)[None]
        return VcrFrame(tensor, self.model.encode(tensor))

    @torch.inference_mode()
    def register(
        self, source: VcrFrame, target: VcrFrame, initial_guess: Transform | None = None
    ) -> RegistrationResult:
        output = self.model.register_features(source.points, source.features, target.points, target.features)
        transform = output.transform[0].detach().to("cpu", torch.float64).numpy()
        return RegistrationResult(transform)
