"""What became of a loop candidate: the verification's verdict, its scores and its measured transform,
as ``loops.json`` lists them and the pose graph reads them."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vcr_odom.geometry import Transform
from vcr_odom.loops.candidates import LoopCandidate


@dataclass
class LoopDecision:
    """What became of a candidate, as ``loops.json`` lists it."""

    candidate: LoopCandidate
    source_frame: int
    target_frame: int
    accepted: bool = False
    reason: str = ""
    check: str = ""
    """The check it failed (one of :data:`~vcr_odom.loops.verify.CHECKS`; empty while accepted)."""
    measured: Transform | None = None
    information: NDArray[np.float64] | None = None
    scores: dict[str, Any] = field(default_factory=dict)
    corroborated: bool = False
    """Its two starts agreed (:mod:`~vcr_odom.loops.corroboration`): the pose graph's trust."""

    def reject(self, check: str, reason: str) -> None:
        """Turn the loop away: ``check`` names the check it failed, ``reason`` says why (loops.json)."""
        self.accepted, self.check, self.reason = False, check, reason

    @property
    def ends(self) -> tuple[int, int]:
        """The candidate's (source, target) node indices."""
        return self.candidate.source, self.candidate.target

    def to_dict(self) -> dict[str, Any]:
        candidate = self.candidate
        return {
            "source_node": candidate.source,
            "target_node": candidate.target,
            "source_frame": self.source_frame,
            "target_frame": self.target_frame,
            "path_between_m": round(candidate.path_m, 3),
            "frames_between": candidate.frames,
            "odometry_distance_m": round(candidate.distance_m, 3),
            "accepted": self.accepted,
            "reason": self.reason,
            "failed_check": self.check or None,
            "corroborated": self.corroborated,
            **self.scores,
            "odometry_T_target_source": candidate.prior.tolist(),
            "measured_T_target_source": None if self.measured is None else self.measured.tolist(),
        }
