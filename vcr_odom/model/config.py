"""VCR-Net hyper-parameters: one frozen dataclass, two presets, a dict round-trip for weight files.

The ``paper`` preset follows the paper's experiments section (N=1024, k=20, 512-d LPD-Net output, K=896,
J=32, attention feed-forward width 1024, 4 heads). The ``default`` preset is a narrower network sized for
at least 10 pairs/s at batch 1 on 2 CPU cores (see ``vcr_odom.model.profile``).

Deviation: the paper does not give γ (false-match weight of Loss_cor), the temperature of the soft
pointer, nor the input scaling; the values here are ours and are recorded with the weights.

Weight files written before a field existed load with that field's :data:`LEGACY_VALUES` (the behaviour
the file was trained with), not with today's default.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from vcr_odom.errors import ConfigError

PRESETS = ("paper", "default")
ENCODERS = ("invariant", "xyz")
"""``invariant``: features from relative geometry only (``vcr_odom.model.invariant_encoder``), unchanged
by a translation or a rotation about z of the cloud; ``xyz``: the first layer sees absolute coordinates
(``vcr_odom.model.encoder``, the weights shipped before the invariant encoder)."""

LEGACY_VALUES: dict[str, object] = {
    "encoder": "xyz",
    "input_max_range": 80.0,
    "robust_iterations": 0,
    "consensus_hypotheses": 0,
    "inference_sharpening": 1.0,
    "distance_bias": False,
}
"""What a weight file that lacks a field was trained with."""


@dataclass(frozen=True)
class VcrConfig:
    """Every architecture and loss constant of VCR-Net (the model itself works for any N >= k + 1).

    Network:
      ``num_points``: N points per cloud fed by pre-processing (the paper: 1024).
      ``k``: neighbours of the feature-space and Cartesian kNN graphs (paper: 20).
      ``point_dim``, ``graph_dim``, ``spatial_dim``: widths of the pointwise MLP (3->p->p), of the two
      feature-space EdgeConv layers and of the Cartesian-space EdgeConv layer (paper code: 64/128/256).
      ``feature_dim``: LPD-Net output width (paper: 512). ``heads``: attention heads (paper: 4).
      ``ff_dim``: feed-forward width of the attention blocks (the paper's "embedding dimension 1024").
      ``coordinate_scale``: metres per network unit; xyz is divided by it before the first layer so a
      KITTI scan (tens of metres) lands in the range the initialisation expects.
      ``encoder``: one of :data:`ENCODERS`. ``distance_bias``: self-attention logits get a learned
      function of the distance between the two points (invariant to any rigid motion), so a point's
      feature can say where it lies relative to the rest of the scene, not in the sensor frame.
    Input:
      ``input_max_range``: the network sees points within this distance of the sensor (metres; the
      ``run`` crop for the other methods is 80 m). Farthest point sampling over 2-80 m spends ~28 % of
      512 points on the sparse rings beyond 40 m (1 % of a scan's points), whose pattern moves with the
      sensor and has no counterpart metres later.
    Virtual correspondences:
      ``top_k_fraction``: K = round(fraction * N) key points of the source (paper: 896/1024 = 0.875).
      ``top_j``: candidates per key point (paper: 32; must be > 1, J = 1 has no gradient).
      ``temperature``: initial soft-pointer temperature (learned, stored as its log); the affinity is
      the negative mean squared feature difference divided by it. At initialisation unrelated points
      differ by ~0.2 per channel and feature-space neighbours by ~0.01, so 0.01 starts with logit gaps
      of ~20 to the far points and ~1 among neighbours; sharper pointers also shrink the bias of
      virtual points at the edges of a sparse scan (0.1 left ~5 cm of z bias on a real KITTI pair).
      ``weighted_svd``: weight each key point by its self-attention weight in the SVD (paper: no).
      ``robust_iterations``: after the paper's SVD, this many re-solves with Cauchy weights
      ``1 / (1 + (r / c)²)`` of each key point's residual r, c halving down to ``robust_scale``
      (metres). Key points without a counterpart in the other scan get a virtual point somewhere in
      its cloud; with full weight they pull the estimate towards the two clouds' centroids, i.e.
      towards zero motion. 0 = the paper's single unweighted SVD.
      ``consensus_hypotheses``: where > 0, the re-weighting starts from the best of this many motions
      fitted to three correspondences each (most support within ``consensus_threshold`` metres)
      instead of the unweighted SVD, whose start is outside the re-weighting's basin when many
      virtual points are wrong. Both are inference settings: no gradient flows through them.
      ``inference_sharpening``: outside training the soft pointer's temperature is divided by this, so
      each virtual point is (nearly) its best candidate instead of a blend of J candidates. A blend
      is drawn towards the middle of the candidates, i.e. towards the target cloud, around its own
      sensor: towards zero motion. Training keeps the learned temperature (its gradient needs the blend).
    Loss:
      ``gamma``: the paper's γ, the weight of the false-match term of Loss_cor (dimensionless).
      ``match_radius``: None = the paper's true-match test (the GT-aligned virtual point's nearest
      source point is its key point); a float (metres) = true when the virtual point lies within it.
    """

    num_points: int = 512
    k: int = 16
    point_dim: int = 64
    graph_dim: int = 64
    spatial_dim: int = 128
    feature_dim: int = 128
    heads: int = 4
    ff_dim: int = 256
    coordinate_scale: float = 30.0
    top_k_fraction: float = 0.875
    top_j: int = 16
    temperature: float = 0.01
    weighted_svd: bool = False
    encoder: str = "invariant"
    distance_bias: bool = True
    input_max_range: float = 40.0
    robust_iterations: int = 5
    robust_scale: float = 0.125
    consensus_hypotheses: int = 256
    consensus_threshold: float = 1.0
    inference_sharpening: float = 64.0
    gamma: float = 1.0
    match_radius: float | None = None

    def __post_init__(self) -> None:
        _check_int(self, "num_points", 4)
        _check_int(self, "k", 1)
        if self.k >= self.num_points:
            raise ConfigError(f"k must be < num_points ({self.num_points}); got {self.k}")
        for name in ("point_dim", "graph_dim", "spatial_dim", "feature_dim", "heads", "ff_dim"):
            _check_int(self, name, 1)
        if self.feature_dim % self.heads:
            raise ConfigError(f"heads must divide feature_dim ({self.feature_dim}); got {self.heads}")
        _check_int(self, "top_j", 2)
        if self.top_j > self.num_points:
            raise ConfigError(f"top_j must be <= num_points ({self.num_points}); got {self.top_j}")
        if not 0.0 < self.top_k_fraction <= 1.0 or self.key_points(self.num_points) < 3:
            raise ConfigError(
                f"top_k_fraction must be in (0, 1] and give K >= 3 key points; got {self.top_k_fraction}"
            )
        for name in ("coordinate_scale", "temperature", "gamma"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ConfigError(f"{name} must be a finite number > 0; got {value!r}")
        if self.match_radius is not None and not (
            isinstance(self.match_radius, int | float)
            and math.isfinite(self.match_radius)
            and self.match_radius > 0
        ):
            raise ConfigError(f"match_radius must be None or a number > 0; got {self.match_radius!r}")
        for name in ("weighted_svd", "distance_bias"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"{name} must be a bool; got {getattr(self, name)!r}")
        if self.encoder not in ENCODERS:
            raise ConfigError(f"encoder must be one of {', '.join(ENCODERS)}; got {self.encoder!r}")
        _check_int(self, "robust_iterations", 0)
        _check_int(self, "consensus_hypotheses", 0)
        for name in ("input_max_range", "robust_scale", "consensus_threshold", "inference_sharpening"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ConfigError(f"{name} must be a finite number > 0; got {value!r}")

    def key_points(self, n: int) -> int:
        """K for a cloud of ``n`` points: round(top_k_fraction * n), at least 3 and at most n."""
        return max(3, min(n, round(self.top_k_fraction * n)))

    @classmethod
    def preset(cls, name: str) -> VcrConfig:
        """``paper`` or ``default``."""
        if name == "paper":
            return cls(
                num_points=1024,
                k=20,
                point_dim=64,
                graph_dim=128,
                spatial_dim=256,
                feature_dim=512,
                heads=4,
                ff_dim=1024,
                top_k_fraction=0.875,
                top_j=32,
            )
        if name == "default":
            return cls()
        raise ConfigError(f"preset must be one of {', '.join(PRESETS)}; got {name!r}")

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (saved next to the weights)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> VcrConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise ConfigError (a file for another model); a
        missing key of :data:`LEGACY_VALUES` takes the value older files were trained with."""
        if not isinstance(data, dict):
            raise ConfigError(f"a VcrConfig dict is needed; got {type(data).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"unknown VcrConfig field(s): {', '.join(unknown)}")
        return cls(**(LEGACY_VALUES | data))

    def with_changes(self, **changes: Any) -> VcrConfig:
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)


def _check_int(config: VcrConfig, name: str, minimum: int) -> None:
    value = getattr(config, name)
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ConfigError(f"{name} must be an integer >= {minimum}; got {value!r}")
