"""Registration methods behind one small interface, built by name with :func:`make_method`.

Pairwise methods implement :class:`Registrar`; kiss-icp keeps a map across frames and implements
:class:`SequentialOdometry`, KISS-SLAM also revises its trajectory at the end
(:class:`FinishingOdometry`). Implementations are imported on demand, so importing this package is
cheap and an optional one (kiss-slam) is needed only when built.
"""

from __future__ import annotations

import inspect
from typing import Any

from vcr_odom.errors import ConfigError
from vcr_odom.registration.base import (
    FinishedTrajectory,
    FinishingOdometry,
    Registrar,
    RegistrationResult,
    SequentialOdometry,
    identity_guess,
)

METHOD_NAMES: dict[str, str] = {
    "icp10": "open3d point-to-plane ICP, 10 iterations (the paper's ICP(10)); needs an initial guess",
    "icp": "open3d point-to-plane ICP, run to convergence; needs an initial guess",
    "icp-p2p10": "open3d point-to-point ICP, 10 iterations; needs an initial guess",
    "icp-p2p": "open3d point-to-point ICP, run to convergence; needs an initial guess",
    "fpfh": "open3d FPFH features + RANSAC global registration; no initial guess",
    "kiss-icp": "kiss-icp's own odometry pipeline (local map, adaptive threshold, constant velocity)",
    "vcr": "VCR-Net, learned global registration (no initial guess); needs trained weights",
    "kiss-slam": "KISS-SLAM: kiss-icp, loop closures between local maps, a pose graph (optional: "
    "pip install 'vcr-odom[slam]')",
}
"""Method name -> one-line description (for ``--help`` and error messages)."""

SEQUENTIAL_METHODS = ("kiss-icp", "kiss-slam")
"""Methods that keep their own map across frames: no polish, no meaning on isolated pairs."""

_ICP_SETTINGS: dict[str, dict[str, Any]] = {
    "icp10": {"variant": "point_to_plane", "max_iterations": 10},
    "icp": {"variant": "point_to_plane", "max_iterations": 100},
    "icp-p2p10": {"variant": "point_to_point", "max_iterations": 10},
    "icp-p2p": {"variant": "point_to_point", "max_iterations": 100},
}


def _method_class(key: str) -> type:
    if key in _ICP_SETTINGS:
        from vcr_odom.registration.open3d_icp import Open3dIcp

        return Open3dIcp
    if key == "fpfh":
        from vcr_odom.registration.fpfh import FpfhRansac

        return FpfhRansac
    if key == "vcr":
        from vcr_odom.registration.vcr import VcrRegistrar

        return VcrRegistrar
    if key == "kiss-slam":
        from vcr_odom.registration.kiss_slam import KissSlamOdometry

        return KissSlamOdometry
    from vcr_odom.registration.kiss import KissIcpOdometry

    return KissIcpOdometry


def make_method(name: str, **options: Any) -> Registrar | SequentialOdometry:
    """Build the method called ``name``; ``options`` override its constructor defaults.

    Raises :class:`ConfigError` for an unknown name or option, listing the valid ones, and its
    :class:`~vcr_odom.errors.MissingExtraError` for an optional method that is not installed.
    """
    key = name.strip().lower()
    if key not in METHOD_NAMES:
        raise ConfigError(f"unknown method {name!r}; valid methods: {', '.join(METHOD_NAMES)}")
    cls = _method_class(key)
    valid = [p for p in inspect.signature(cls).parameters if p not in ("name", "needs_initial_guess")]
    unknown = sorted(set(options) - set(valid))
    if unknown:
        raise ConfigError(
            f"method {key!r}: unknown option(s) {', '.join(unknown)}; valid: {', '.join(valid)}"
        )
    defaults: dict[str, Any] = {**_ICP_SETTINGS.get(key, {})}
    if "name" in inspect.signature(cls).parameters:
        defaults["name"] = key
    return cls(**{**defaults, **options})


__all__ = [
    "METHOD_NAMES",
    "SEQUENTIAL_METHODS",
    "FinishedTrajectory",
    "FinishingOdometry",
    "Registrar",
    "RegistrationResult",
    "SequentialOdometry",
    "identity_guess",
    "make_method",
]
