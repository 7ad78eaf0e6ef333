"""Independent geometry references for tests (not part of the library)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation


def weighted_kabsch(source: ArrayLike, target: ArrayLike, weights: ArrayLike | None = None) -> np.ndarray:
    """Least-squares rigid transform mapping ``source`` onto ``target``, by scipy's ``align_vectors``.

    scipy solves Wahba's problem for the centred points and always returns a proper rotation, so it
    checks an SVD head independently of how that head handles reflections.
    """
    src = np.asarray(source, dtype=np.float64)[:, :3]
    tgt = np.asarray(target, dtype=np.float64)[:, :3]
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    src_mean, tgt_mean = w @ src, w @ tgt
    rotation, _ = Rotation.align_vectors(tgt - tgt_mean, src - src_mean, weights=w)
    transform = np.eye(4)
    transform[:3, :3] = rotation.as_matrix()
    transform[:3, 3] = tgt_mean - transform[:3, :3] @ src_mean
    return transform
