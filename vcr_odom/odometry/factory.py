"""Methods by name, as the CLI spells them: the one place that decides the default polish and passes.

``build_odometry("vcr")`` in Python and ``vcr-odom run --method vcr`` build the same thing.
"""

from __future__ import annotations

from typing import Any

from vcr_odom.errors import ConfigError
from vcr_odom.odometry.chain import Consult, DoubtRule, Odometry
from vcr_odom.odometry.limits import InitialGuess, MotionLimits
from vcr_odom.odometry.polish import POLISHES, make_polish
from vcr_odom.registration import METHOD_NAMES, SEQUENTIAL_METHODS, make_method
from vcr_odom.registration.base import Registrar, SequentialOdometry

GLOBAL_METHODS = ("vcr", "fpfh")
DEFAULT_GLOBAL_POLISH = "kiss-icp"
"""The polish a global method gets unless the spec names one (docs/usage.md "Choosing the polish" has the
measurements behind it); local methods (ICP, kiss-icp) get none."""

DEFAULT_CONSULT = "on-doubt"
"""A polished global method asks its registrar where the motion prior's polished result is in doubt:
as accurate as asking on every pair wherever measured (docs/results.md "Benchmarks and speed"), at a fraction of the work."""

POLISHED_VCR_PASSES = 1
"""VCR-Net passes per pair when a polish refines the estimate: the polish refines the residual a
second pass would, so the second pass would only cost a re-encoding and a registration."""


def default_polish(method: str) -> str:
    return DEFAULT_GLOBAL_POLISH if method in GLOBAL_METHODS else "none"


def parse_method_spec(spec: str) -> tuple[str, str]:
    """``"vcr+icp"`` -> ``("vcr", "icp")``; a bare name gets its default polish (``"vcr"`` ->
    ``("vcr", "kiss-icp")``, ``"icp"`` -> ``("icp", "none")``); ``"vcr+none"`` is VCR-Net alone."""
    name, plus, polish = str(spec).strip().lower().partition("+")
    if name not in METHOD_NAMES:
        raise ConfigError(f"unknown method {name!r} in {spec!r}; valid methods: {', '.join(METHOD_NAMES)}")
    polish = polish if plus else default_polish(name)
    if polish not in POLISHES:
        raise ConfigError(f"unknown polish {polish!r} in {spec!r}; valid choices: {', '.join(POLISHES)}")
    if name in SEQUENTIAL_METHODS and polish != "none":
        raise ConfigError(f"{name} is a sequential odometry with its own registration: it takes no +{polish}")
    return name, polish


def canonical_spec(spec: str) -> str:
    """The spec as tables and folders name it, one spelling per method: a global method's polish is
    always written out (``vcr`` -> ``vcr+kiss-icp``, ``vcr+none`` stays), a local method's only when
    it has one (``icp10``, ``icp10+icp``). Parsing it again gives the same method."""
    name, polish = parse_method_spec(spec)
    if polish == "none" and name not in GLOBAL_METHODS:
        return name
    return f"{name}+{polish}"


def registrar_options(name: str, polished: bool, options: dict[str, Any]) -> dict[str, Any]:
    """``options`` without unset (None) values, plus the pass count of a polished VCR-Net: one
    (:data:`POLISHED_VCR_PASSES`); unpolished, the weights decide (``default_passes``)."""
    options = {key: value for key, value in options.items() if value is not None}
    if name == "vcr" and polished and "passes" not in options:
        options["passes"] = POLISHED_VCR_PASSES
    return options


def build_odometry(
    spec: str,
    *,
    initial_guess: InitialGuess | str = InitialGuess.CONSTANT_VELOCITY,
    limits: MotionLimits | None = None,
    polish_options: dict[str, Any] | None = None,
    consult: Consult = DEFAULT_CONSULT,
    doubt: DoubtRule | None = None,
    **method_options: Any,
) -> Odometry | SequentialOdometry:
    """The odometry called ``spec`` (``name`` or ``name+polish``; see :func:`parse_method_spec`).

    ``method_options`` go to the registration method (e.g. ``weights=``, ``device=``, ``passes=`` for
    VCR-Net), ``polish_options`` to the polish (e.g. ``second_start=False``); ``consult``: when a
    polished method asks its registrar (:data:`~vcr_odom.odometry.chain.CONSULT_CHOICES`); ``doubt``:
    when ``on-doubt`` asks (default :class:`~vcr_odom.odometry.chain.DoubtRule`).
    """
    name, polish_name = parse_method_spec(spec)
    method = make_method(name, **registrar_options(name, polish_name != "none", method_options))
    if isinstance(method, Registrar):
        polish = make_polish(polish_name, **(polish_options or {}))
        odometry = Odometry(
            method,
            polish,
            initial_guess=InitialGuess(initial_guess),
            limits=limits,
            consult=consult,
            doubt=doubt,
        )
        odometry.name = canonical_spec(spec)
        return odometry
    if polish_options:
        raise ConfigError(f"{name} takes no polish options")
    return method
