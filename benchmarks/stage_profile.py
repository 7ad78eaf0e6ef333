"""Per-stage wall time of an odometry run, measured from outside the library.

Wraps the functions each stage consists of (patched for the duration of a ``with`` block) and adds up
the seconds spent in them, per thread and summed, so the library itself holds no timers. The stages:

    load              SequenceBase.frame (KITTI, folder and recorded sequences)
    crop              preprocess.crop_range (the network's input; the polish crops inside its own prepare)
    ground removal    preprocess.remove_ground
    sampling          preprocess.downsample (farthest point sampling)
    encoder           VCRNet.encode
    self-attention    VCRNet.attend, once per frame when it is prepared (where a frame comes without
                      it, matching computes it and it counts as matching)
    matching          VCRNet.match_features: cross-attention, the feature affinity, key points and
                      their virtual points
    pose head         VCRNet.pose_head: consensus, robust re-weighting, gated re-pointing
    registration      other registrars' register (ICP, FPFH + RANSAC)
    polish prepare    the polish's per-frame cloud (IcpPolish.prepare, KissIcpPolish.prepare)
    polish            IcpPolish / KissIcpPolish: refine, from_prior, finish
    kiss-icp          KissIcpOdometry.step (the baseline, all of it)

When stages run in several threads at once their sum can exceed the wall time; ``other`` is the wall
time not inside any stage (chaining, checks, callbacks, waiting).
"""

from __future__ import annotations

import threading
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from typing import Any

STAGES = (
    "load",
    "crop",
    "ground removal",
    "sampling",
    "encoder",
    "self-attention",
    "matching",
    "pose head",
    "registration",
    "polish prepare",
    "polish",
    "kiss-icp",
)


def _targets() -> list[tuple[object, str, str]]:
    """(owner, attribute, stage) of every function that is timed."""
    import vcr_odom.preprocess as preprocess
    from vcr_odom.data.scans import SequenceBase
    from vcr_odom.model.network import VCRNet
    from vcr_odom.odometry.polish import IcpPolish, KissIcpPolish
    from vcr_odom.registration.fpfh import FpfhRansac
    from vcr_odom.registration.kiss import KissIcpOdometry
    from vcr_odom.registration.open3d_icp import Open3dIcp

    return [
        (SequenceBase, "frame", "load"),
        (preprocess, "crop_range", "crop"),
        (preprocess, "remove_ground", "ground removal"),
        (preprocess, "downsample", "sampling"),
        (VCRNet, "encode", "encoder"),
        (VCRNet, "attend", "self-attention"),
        (VCRNet, "match_features", "matching"),
        (VCRNet, "pose_head", "pose head"),
        (Open3dIcp, "register", "registration"),
        (FpfhRansac, "register", "registration"),
        (IcpPolish, "prepare", "polish prepare"),
        (KissIcpPolish, "prepare", "polish prepare"),
        (IcpPolish, "refine", "polish"),
        (KissIcpPolish, "refine", "polish"),
        (IcpPolish, "from_prior", "polish"),
        (KissIcpPolish, "from_prior", "polish"),
        (IcpPolish, "finish", "polish"),
        (KissIcpPolish, "finish", "polish"),
        (KissIcpOdometry, "step", "kiss-icp"),
    ]


class StageProfile:
    """Seconds per stage; nested timed calls (a registration inside a polish) count once, outermost."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self._depth = threading.local()
        self._lock = threading.Lock()

    def _timed(self, function: Callable[..., Any], stage: str) -> Callable[..., Any]:
        def timed(*args: Any, **kwargs: Any) -> Any:
            depth = getattr(self._depth, "value", 0)
            self._depth.value = depth + 1
            started = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                self._depth.value = depth
                if depth == 0:
                    with self._lock:
                        self.seconds[stage] += time.perf_counter() - started

        return timed

    @contextmanager
    def patched(self) -> Iterator[StageProfile]:
        with ExitStack() as undo:
            for owner, name, stage in _targets():
                original = owner.__dict__.get(name) if isinstance(owner, type) else getattr(owner, name)
                if original is None:
                    continue
                setattr(owner, name, self._timed(original, stage))
                undo.callback(setattr, owner, name, original)
            yield self
