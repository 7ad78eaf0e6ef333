"""VCR-Net behind the :class:`Registrar` interface: a learned global registration, no initial guess.

``prepare`` does all per-frame work once (ground removal, down-sampling to N points, the encoder),
so in odometry each frame is encoded once and its features serve both pairs it belongs to.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from vcr_odom.data.base import Points
from vcr_odom.device import resolve_device
from vcr_odom.errors import ConfigError, DataError
from vcr_odom.geometry import Transform, project_to_se3
from vcr_odom.model.config import INFERENCE_FIELDS, VcrConfig
from vcr_odom.model.weights import MAX_NETWORK_POINTS, default_weights_path, load_weights
from vcr_odom.preprocess import network_preprocess_config, preprocess
from vcr_odom.registration.base import DEGENERATE, TOO_FEW_POINTS, RegistrationResult

GPU_BATCH_SIZE = 16
"""Pairs per network call on CUDA (``batch_size=None``); 1 on the CPU."""

DEFAULT_PASSES = 2
"""Network passes per pair for weights with the legacy ``xyz`` encoder (the invariant encoder runs one:
see :func:`default_passes`). The second pass registers the source moved by the first estimate, a
residual of a few decimetres, where a position-dependent encoder is most accurate; the model card
gives the figures."""

MIN_CORRESPONDENCE_SPREAD = 0.01
"""Below this :func:`correspondence_spread` the estimate is reported as ``status: degenerate
correspondences``: a street scan's virtual points span tens of metres in two directions, so a spread
this small means they collapsed onto a line, where the rotation about it is undetermined."""


@dataclass
class VcrFrame:
    """A frame as the network sees it: ``points`` (1, n, 3) on the device (n = N, or fewer where the
    frame has fewer: :meth:`VcrRegistrar.network_input`), their encoder features and
    self-attention (``attended``: features and point weights), all of which depend on the frame alone.

    ``distinct_points`` below the network's k + 1 (a frame of one point repeated, a near-empty scan)
    means its kNN graphs are meaningless: every pair with it is reported ``too few points``, so the
    odometry falls back and flags the frame by its index instead of aborting the run.
    """

    points: torch.Tensor
    features: torch.Tensor
    distinct_points: int = -1
    attended: tuple[torch.Tensor, torch.Tensor] | None = None


class VcrRegistrar:
    """Relative pose from two prepared frames with a trained VCR-Net (``weights`` or the shipped file)."""

    name = "vcr"
    needs_initial_guess = False

    def __init__(
        self,
        weights: str | Path | None = None,
        device: str = "auto",
        seed: int = 0,
        batch_size: int | None = None,
        passes: int | None = None,
        num_points: int | None = None,
    ) -> None:
        path = Path(weights) if weights is not None else default_weights_path("default")
        self.device = resolve_device(device)
        # Batches pay off where the network is launch-bound (a GPU); on a CPU they only add latency.
        default_batch = GPU_BATCH_SIZE if self.device.type == "cuda" else 1
        self.batch_size = default_batch if batch_size is None else int(batch_size)
        if self.batch_size < 1:
            raise ConfigError(f"batch_size must be >= 1; got {batch_size!r}")
        if passes is not None and int(passes) < 1:
            raise ConfigError(f"passes must be >= 1; got {passes!r}")
        self.weights_path = path
        self.model, self.config, self.metadata = load_weights(path, device=str(self.device))
        self.passes = default_passes(self.config) if passes is None else int(passes)
        self.model.eval()
        self.seed = seed
        # Pre-processing as in training: ground removed, exactly N points by farthest point sampling
        # within the weights' input range.
        self.preprocess_config = network_preprocess_config(self.config, seed)
        if num_points is not None and num_points != self.config.num_points:
            self.use_inference_settings(num_points=num_points)

    def use_inference_settings(self, **changes: Any) -> None:
        """Run the same tensors with other :data:`INFERENCE_FIELDS` (point count, crop, pose head): a
        speed/robustness trade (``--vcr-points``) or a benchmark's variant (weights/MODEL_CARD.md)."""
        unknown = sorted(set(changes) - set(INFERENCE_FIELDS))
        if unknown:
            raise ConfigError(
                f"not inference settings: {', '.join(unknown)}; valid: {', '.join(INFERENCE_FIELDS)}"
            )
        if "num_points" in changes:
            changes["num_points"] = check_network_points(
                changes["num_points"], self.config.k, self.weights_path
            )
        self.config = self.config.with_changes(**changes)
        self.model.config = self.config
        self.preprocess_config = network_preprocess_config(self.config, self.seed)

    def network_input(self, points: Points) -> NDArray[np.float32]:
        """N points, or all of them where a frame has fewer: the network runs on any count above its
        k (every layer is shared over points), and repeating points to make up N would give its kNN
        graphs zero-length edges it never saw in training. A cloud of exactly N points is taken as
        already pre-processed (the pairs protocol's clouds are): ground removal and sampling again
        would only drop or shuffle points."""
        if len(points) == self.config.num_points:
            xyz = np.asarray(points, dtype=np.float32)[:, :3]
        else:
            xyz = preprocess(points, self.preprocess_config, pad=False)[:, :3]
        if 0 < len(xyz) <= self.config.k:
            # Too few for a kNN graph (a near-empty scan, 5000 copies of one point): repeated up to N
            # so that the frame runs, and then every pair with it is flagged (too_few_points).
            xyz = xyz[np.arange(self.config.num_points) % len(xyz)]
        return np.ascontiguousarray(xyz, dtype=np.float32)

    def too_few_points(self, frame: VcrFrame) -> bool:
        """Fewer distinct points than the network's kNN graphs need (k + 1)."""
        return 0 <= frame.distinct_points <= self.config.k

    @torch.inference_mode()
    def prepare(self, points: Points) -> VcrFrame:
        return self.prepare_batch([points])[0]

    @torch.inference_mode()
    def prepare_batch(self, frames: Sequence[Points]) -> list[VcrFrame]:
        """Pre-process each frame (CPU), then encode and self-attend them in one forward pass per point
        count (all but a sparse frame have N): done once per frame, not once per pair (a frame is the
        source of one pair, the target of the next)."""
        return self.encode_inputs([self.network_input(points) for points in frames])

    @torch.inference_mode()
    def encode_inputs(self, inputs: Sequence[NDArray[np.float32]]) -> list[VcrFrame]:
        """Encode clouds that already are the network's input (:meth:`network_input`'s, perhaps turned):
        a sparse one, fewer than N points, would otherwise be pre-processed a second time."""
        prepared: list[VcrFrame | None] = [None] * len(inputs)
        for group in _same_size(inputs, key=len):  # one batch per point count (a sparse frame has fewer)
            tensor = torch.as_tensor(
                np.stack([inputs[i] for i in group]), dtype=torch.float32, device=self.device
            )
            features = self.model.encode(tensor)
            psi, weights = self.model.attend(tensor, features)
            for row, i in enumerate(group):
                distinct = len(np.unique(inputs[i], axis=0))
                attended = (psi[row : row + 1], weights[row : row + 1])
                prepared[i] = VcrFrame(tensor[row : row + 1], features[row : row + 1], distinct, attended)
        return prepared  # type: ignore[return-value]

    @torch.inference_mode()
    def register(
        self, source: VcrFrame, target: VcrFrame, initial_guess: Transform | None = None
    ) -> RegistrationResult:
        return self.register_batch([(source, target)])[0]

    @torch.inference_mode()
    def register_batch(self, pairs: Sequence[tuple[VcrFrame, VcrFrame]]) -> list[RegistrationResult]:
        """``T_target_source`` of every ``(source, target)`` pair, in one batched pass per ``passes``:
        each pass after the first re-encodes the source moved by the estimate so far and registers
        what is left (see :data:`DEFAULT_PASSES`). A pose solve that fails (an SVD of non-finite
        correspondences: weights the load-time checks did not catch) is a DataError naming the
        weights, not a LinAlgError traceback."""
        try:
            return self._register_batch(pairs)
        except (torch.linalg.LinAlgError, np.linalg.LinAlgError) as error:
            reason = (str(error).splitlines() or [type(error).__name__])[0]
            raise DataError(
                f"{self.weights_path}: the network's pose solve failed ({reason}); "
                "these weights give non-finite correspondences: use the shipped weights or retrain"
            ) from error

    def _register_batch(self, pairs: Sequence[tuple[VcrFrame, VcrFrame]]) -> list[RegistrationResult]:
        groups = _same_size(pairs, key=lambda pair: (pair[0].points.shape[1], pair[1].points.shape[1]))
        if len(groups) > 1:  # a sparse frame among them: each point count is batched on its own
            results: list[RegistrationResult | None] = [None] * len(pairs)
            for group in groups:
                for i, result in zip(group, self.register_batch([pairs[i] for i in group]), strict=True):
                    results[i] = result
            return results  # type: ignore[return-value]
        sources, targets = zip(*pairs, strict=True)
        source_points = torch.cat([f.points for f in sources])
        source_features = torch.cat([f.features for f in sources])
        target_points = torch.cat([f.points for f in targets])
        target_features = torch.cat([f.features for f in targets])
        source_attended, target_attended = _attended(sources), _attended(targets)
        transforms = np.tile(np.eye(4), (len(pairs), 1, 1))
        for pass_index in range(self.passes):
            if pass_index:  # the moved source is a new cloud: encoded and attended afresh
                moved = _moved(source_points, transforms)
                output = self.model.register_features(
                    moved,
                    self.model.encode(moved),
                    target_points,
                    target_features,
                    target_attended=target_attended,
                )
            else:
                output = self.model.register_features(
                    source_points,
                    source_features,
                    target_points,
                    target_features,
                    source_attended=source_attended,
                    target_attended=target_attended,
                )
            transforms = _project_finite(output.transform) @ transforms
        # Spread of the last pass: the one whose correspondences gave the final rotation.
        spread = correspondence_spread(output.virtual_points).to("cpu").tolist()
        results = []
        for (source, target), transform, ratio in zip(pairs, transforms, spread, strict=True):
            info: dict[str, Any] = {"correspondence_spread": ratio, "passes": self.passes}
            if not ratio >= MIN_CORRESPONDENCE_SPREAD:  # also catches NaN
                info["status"] = DEGENERATE
            sparse = [frame.distinct_points for frame in (source, target) if self.too_few_points(frame)]
            if sparse:
                info |= {"status": TOO_FEW_POINTS, "distinct_points": min(sparse)}
            results.append(RegistrationResult(transform.copy(), info=info))
        return results


def check_network_points(num_points: object, k: int, weights: Path) -> int:
    """``num_points`` (``--vcr-points``) as an int within what the network can take: more than its
    k neighbours (a kNN graph needs k + 1 points) and at most :data:`MAX_NETWORK_POINTS` (its
    memory grows with N squared: 200000 asked for 62 GB); else a ConfigError naming the option."""
    valid = isinstance(num_points, int | np.integer) and not isinstance(num_points, bool)
    if not valid or not k < int(num_points) <= MAX_NETWORK_POINTS:  # type: ignore[call-overload]
        raise ConfigError(
            f"--vcr-points (num_points) must be a whole number from {k + 1} (more than the network's "
            f"k = {k} neighbours of {weights}) to {MAX_NETWORK_POINTS} (its memory grows with the "
            f"square); got {num_points!r}"
        )
    return int(num_points)  # type: ignore[call-overload]


def default_passes(config: VcrConfig) -> int:
    """One pass for the invariant encoder: the source moved by the first estimate has the same
    features (to float rounding), hence the same correspondences, and a second pass returns the
    identity at twice the cost. Two for the legacy ``xyz`` encoder (:data:`DEFAULT_PASSES`)."""
    return 1 if config.encoder == "invariant" else DEFAULT_PASSES


def _same_size(items: Sequence[Any], key: Callable[[Any], Any]) -> list[list[int]]:
    """Indices of ``items`` grouped by ``key`` (first appearance order): what can be stacked."""
    groups: dict[Any, list[int]] = {}
    for index, item in enumerate(items):
        groups.setdefault(key(item), []).append(index)
    return list(groups.values())


def _attended(frames: Sequence[VcrFrame]) -> tuple[torch.Tensor, torch.Tensor] | None:
    """The frames' self-attention, batched, where every frame carries it (else None: computed)."""
    attended = [frame.attended for frame in frames]
    if any(item is None for item in attended):
        return None
    return torch.cat([item[0] for item in attended]), torch.cat([item[1] for item in attended])  # type: ignore[index]


def _project_finite(transform: torch.Tensor) -> NDArray[np.float64]:
    """The network's float32 SVD output re-orthonormalised in float64 (for chaining and kiss-icp's
    Sophus); non-finite estimates stay non-finite so that they are reported, not hidden."""
    transforms = transform.detach().to("cpu", torch.float64).numpy()
    finite = np.isfinite(transforms).all(axis=(1, 2))
    transforms[finite] = project_to_se3(transforms[finite])
    return transforms


def _moved(points: torch.Tensor, transforms: NDArray[np.float64]) -> torch.Tensor:
    """``points`` (B, N, 3) moved by each pair's transform; a non-finite estimate moves nothing (its
    pair stays non-finite through the composition and is reported degenerate)."""
    usable = np.where(np.isfinite(transforms).all(axis=(1, 2))[:, None, None], transforms, np.eye(4))
    rotation = torch.as_tensor(usable[:, :3, :3], dtype=points.dtype, device=points.device)
    translation = torch.as_tensor(usable[:, None, :3, 3], dtype=points.dtype, device=points.device)
    return points @ rotation.transpose(1, 2) + translation


def correspondence_spread(virtual_points: torch.Tensor) -> torch.Tensor:
    """Second over first singular value of each pair's centred virtual points ``(B, K, 3)``: near 0
    when they collapse onto a line or a point, where the SVD's rotation is undetermined."""
    centred = virtual_points.double() - virtual_points.double().mean(dim=1, keepdim=True)
    singular = torch.linalg.svdvals(centred)
    return singular[:, 1] / singular[:, 0].clamp_min(1e-12)
