"""How a comparison spells a mapped row: a method spec with ``+loops`` (``vcr+loops``,
``kiss-icp+loops``): that odometry, then ``vcr-odom map``'s loop closure. Kept apart from the
odometry factory (which knows nothing of loops) and light to import (the CLI parses specs early)."""

from __future__ import annotations

from vcr_odom.odometry.factory import canonical_spec, parse_method_spec

LOOPS_SUFFIX = "+loops"


def split_loops(spec: str) -> tuple[str, bool]:
    """``"vcr+loops"`` -> ``("vcr", True)``; a spec without the suffix -> ``(spec, False)``."""
    text = str(spec).strip()
    if text.lower().endswith(LOOPS_SUFFIX):
        return text[: -len(LOOPS_SUFFIX)], True
    return text, False


def parse_row_spec(spec: str) -> tuple[str, str]:
    """:func:`parse_method_spec` of the odometry under a mapped row (a ConfigError names a bad one)."""
    return parse_method_spec(split_loops(spec)[0])


def canonical_row(spec: str) -> str:
    """The row's name: the odometry's canonical spec, ``+loops`` where mapped."""
    base, mapped = split_loops(spec)
    return canonical_spec(base) + (LOOPS_SUFFIX if mapped else "")
