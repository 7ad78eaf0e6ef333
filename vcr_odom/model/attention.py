"""Self-attention with a per-point weight (paper §IV-B) and cross-attention, the non-local operation
(paper §IV-C, Eqs. Π, Φ1, Φ2), both with LayerNorm and no dropout as the paper's experiments state.

Self-attention: F = R + Attn(R, R) (paper: F = Softmax(R Rᵀ) R), then a per-point weight
w = sigmoid(mlp(F)) in (0, 1) and Ψ = w ⊙ F (paper: W_a = Softmax(mlp(W_c)), Ψ = W_a F). A low weight
marks a point that is hard to match; the network also uses it to pick key points.

Cross-attention: Φ1 = Ψ1 + V_c Π(Ψ1, Ψ2) with Π(Ψ1, Ψ2) = Softmax(θ1 φ2ᵀ / √d) V_g Ψ2 (queries from the
cloud being updated, keys and values from the other), then a feed-forward block, both residual; the same
module (same weights) serves both directions.

Deviation: the paper's mask mlp(W_c) maps an N x N matrix, tying the model to one N; we regress the
weight from each point's features, and use a sigmoid instead of a softmax over points so the
weight does not shrink as 1/N.
Deviation: both attentions use learned query/key/value projections, several heads and 1/√d scaling
(scaled_dot_product_attention); the paper's self-attention has no projections and its Π is written with
the query from Ψ2, which only type-checks when N1 = N2; we read it as the usual non-local operation.
Deviation: residual connections with pre-LayerNorm and a final LayerNorm (without bias, which would
cancel in the feature differences of the affinity), where the paper only says "LayerNorm".
Deviation (``distance_bias``): the self-attention logits of each head get a learned function of the
distance between the two points (Gaussian radial basis, one weight per basis and head). A distance is
unchanged by any rigid motion, so the features stay invariant while each point learns what lies how
far around it: the global context that absolute xyz used to give, without the sensor-frame position.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn


class MultiHeadAttention(nn.Module):
    """Multi-head scaled dot-product attention, channels-last ``(B, N, C)``."""

    def __init__(self, dim: int, heads: int) -> None:
        super().__init__()
        self.heads = heads
        self.query = nn.Linear(dim, dim)
        self.key = nn.Linear(dim, dim)
        self.value = nn.Linear(dim, dim)
        self.out = nn.Linear(dim, dim)

    def _split(self, x: Tensor) -> Tensor:
        b, n, c = x.shape
        return x.view(b, n, self.heads, c // self.heads).transpose(1, 2)

    def forward(self, query: Tensor, context: Tensor, bias: Tensor | None = None) -> Tensor:
        """``bias`` ``(B, heads, N, M)`` is added to the attention logits."""
        q = self._split(self.query(query))
        attended = F.scaled_dot_product_attention(
            q,
            self._split(self.key(context)),
            self._split(self.value(context)),
            attn_mask=None if bias is None else bias.to(q.dtype),
        )
        b, _, n, _ = attended.shape
        return self.out(attended.transpose(1, 2).reshape(b, n, -1))


class DistanceBias(nn.Module):
    """Pairwise distances ``(B, N, N)`` (metres) -> per-head attention logit biases ``(B, heads, N, N)``."""

    CENTRES_M = (0.0, 75.0, 6)
    """Gaussian centres (start, stop, count) over the distances a 2 x 40 m crop can hold."""

    ROW_BLOCK = 128
    """Rows of the distance matrix evaluated at a time without autograd (a few hundred KB per array)."""

    REACH = 7.0
    """Widths beyond the outer centres where every basis function is below exp(-REACH² / 2) ≈ 2e-11;
    distances farther out are evaluated there."""

    def __init__(self, heads: int) -> None:
        super().__init__()
        start, stop, count = self.CENTRES_M
        self.register_buffer("centres", torch.linspace(start, stop, count), persistent=False)
        self.width = (stop - start) / (count - 1)
        self.mix = nn.Linear(count, heads, bias=False)
        nn.init.zeros_(self.mix.weight)  # starts as plain attention

    def forward(self, points: Tensor) -> Tensor:
        distance = torch.cdist(points.float(), points.float())
        if torch.is_grad_enabled() and self.mix.weight.requires_grad:
            basis = torch.exp(-0.5 * ((distance.unsqueeze(-1) - self.centres) / self.width) ** 2)
            return self.mix(basis).permute(0, 3, 1, 2)
        return self._by_horner(distance)

    def _by_horner(self, distance: Tensor) -> Tensor:
        """The same biases without autograd, as a polynomial in exp(v) per head.

        Why: the ``(B, N, N, 6)`` basis is 25 MB at N = 1024, and building it took about 30 of the
        70 ms of a frame's encoding on two CPU cores. The centres are ``width`` apart, so with
        v = (d - first centre) / width, exp(-(v - c)² / 2) = exp(-v² / 2) · exp(v)^c · exp(-c² / 2):
        two exponentials per distance instead of six, evaluated in row blocks that stay in cache.
        Equal to the basis form within float rounding (tested); with six centres the largest power,
        exp(v)^5 at the clamp, is exp(60), well inside float32."""
        count = len(self.centres)
        power = torch.arange(count, dtype=torch.float32, device=distance.device)
        coefficients = (self.mix.weight.float() * torch.exp(-0.5 * power**2)).tolist()  # (heads, count)
        batch, rows, columns = distance.shape
        biases = distance.new_empty(batch, len(coefficients), rows, columns)
        for first in range(0, rows, self.ROW_BLOCK):
            block = slice(first, first + self.ROW_BLOCK)
            v = ((distance[:, block] - float(self.centres[0])) / self.width).clamp_(
                -self.REACH, count - 1 + self.REACH
            )
            growth = torch.exp(v)
            envelope = torch.exp(v.square_().mul_(-0.5))
            for head, weights in enumerate(coefficients):
                value = biases[:, head, block]
                value.fill_(weights[-1])
                for weight in reversed(weights[:-1]):
                    value.mul_(growth).add_(weight)
                value.mul_(envelope)
        return biases


class SelfAttention(nn.Module):
    """R ``(B, N, C)`` -> (Ψ = w ⊙ F ``(B, N, C)``, w ``(B, N)``)."""

    def __init__(self, dim: int, heads: int, distance_bias: bool = False) -> None:
        super().__init__()
        self.norm = nn.LayerNorm(dim)
        self.attention = MultiHeadAttention(dim, heads)
        self.distance_bias = DistanceBias(heads) if distance_bias else None
        self.weight_norm = nn.LayerNorm(dim)
        self.weight_mlp = nn.Sequential(nn.Linear(dim, dim // 2), nn.ReLU(), nn.Linear(dim // 2, 1))

    def forward(self, features: Tensor, points: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """``points`` ``(B, N, 3)`` metres: needed with a distance bias, ignored without."""
        normed = self.norm(features)
        bias = None
        if self.distance_bias is not None:
            if points is None:
                raise ValueError("a self-attention with a distance bias needs the points")
            bias = self.distance_bias(points)
        fused = features + self.attention(normed, normed, bias)
        weight = torch.sigmoid(self.weight_mlp(self.weight_norm(fused))).squeeze(-1)
        return fused * weight.unsqueeze(-1), weight


class CrossAttention(nn.Module):
    """The non-local operation as a residual block, shared by both directions."""

    def __init__(self, dim: int, heads: int, ff_dim: int) -> None:
        super().__init__()
        self.norm_query = nn.LayerNorm(dim)
        self.norm_context = nn.LayerNorm(dim)
        self.attention = MultiHeadAttention(dim, heads)
        self.norm_ff = nn.LayerNorm(dim)
        self.feed_forward = nn.Sequential(nn.Linear(dim, ff_dim), nn.ReLU(), nn.Linear(ff_dim, dim))
        self.norm_out = nn.LayerNorm(dim, bias=False)

    def update(self, own: Tensor, other: Tensor) -> Tensor:
        """Φ_own = Ψ_own + V_c Π(Ψ_own, Ψ_other), then the feed-forward residual and a LayerNorm."""
        phi = own + self.attention(self.norm_query(own), self.norm_context(other))
        phi = phi + self.feed_forward(self.norm_ff(phi))
        return self.norm_out(phi)

    def forward(self, psi1: Tensor, psi2: Tensor) -> tuple[Tensor, Tensor]:
        return self.update(psi1, psi2), self.update(psi2, psi1)
