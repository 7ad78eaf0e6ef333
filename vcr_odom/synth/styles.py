"""Scene styles (``--scene``): the same scene parts with other zone mixes, cross-sections and road
bends, so that training data covers more than one kind of street.

``suburban`` is the original mix (towns, suburbs and country roads, as in KITTI's Karlsruhe drives);
``avenue``, ``highway`` and ``oldtown`` reshape its cross-sections and buildings.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from vcr_odom.errors import ConfigError
from vcr_odom.synth.buildings import BUILDING_STYLES, BuildingStyle
from vcr_odom.synth.layout import Profile, ZoneKind
from vcr_odom.synth.road import RoadShape

ZONE_WEIGHTS = {
    ZoneKind.URBAN: 0.35,
    ZoneKind.RESIDENTIAL: 0.35,
    ZoneKind.INDUSTRIAL: 0.15,
    ZoneKind.OPEN: 0.15,
}
"""The share of each kind of zone along a suburban drive."""


@dataclass(frozen=True)
class SceneStyle:
    """What kind of world a scene is: how the road bends, which zones it passes through, how often
    it crosses other streets, and style-specific changes to each zone's cross-section and buildings."""

    road: RoadShape
    zone_weights: dict[ZoneKind, float]
    crossings: bool = True
    crossing_gap: tuple[float, float] = (70.0, 240.0)
    crossing_half_width: tuple[float, float] = (3.5, 6.5)
    adjust: Callable[[np.random.Generator, Profile], Profile] | None = None
    buildings: dict[ZoneKind, BuildingStyle] = field(default_factory=dict)


def _avenue(rng: np.random.Generator, p: Profile) -> Profile:
    """Two or three lanes each way around a planted median, wide sidewalks lined with trees."""
    u = rng.uniform
    per_direction, trees = int(rng.choice([2, 3])), u(8.0, 12.0)
    return replace(
        p, lanes_left=2 * per_direction - 1, lane_width=u(3.2, 3.6), median=u(2.5, 6.0),
        sidewalk=(u(3.0, 6.0), u(3.0, 6.0)), street_trees=(trees, trees), lamp_spacing=u(25.0, 35.0),
        power_line=-1,
    )  # fmt: skip


def _highway(rng: np.random.Generator, p: Profile) -> Profile:
    """Two or three lanes each way, a concrete median barrier, shoulders with guard rails, buildings
    (if any) far back, and only the odd lamp post."""
    u = rng.uniform
    per_direction = int(rng.choice([2, 3]))
    lamps = u(50.0, 80.0) if rng.random() < 0.3 else 0.0
    return replace(
        p, lanes_left=2 * per_direction - 1, lane_width=u(3.5, 3.75), median=u(3.0, 8.0),
        median_kind="barrier", parking=(u(1.0, 1.7), u(0.5, 1.0)), sidewalk=(0.0, 0.0),
        frontage=("guardrail", "guardrail"), lamp_spacing=lamps, setback=(u(15.0, 40.0), u(15.0, 40.0)),
        power_line=-1,
    )  # fmt: skip


def _oldtown(rng: np.random.Generator, p: Profile) -> Profile:
    """A narrow lane (rarely two), narrow sidewalks and the houses right behind them."""
    u = rng.uniform
    return replace(
        p, lanes_left=int(rng.random() < 0.2), lane_width=u(2.8, 3.3),
        parking=tuple(float(rng.random() < 0.2) * u(2.0, 2.2) for _ in range(2)),
        sidewalk=(u(0.8, 2.0), u(0.8, 2.0)), frontage=("none", "none"), street_trees=(0.0, 0.0),
        lamp_spacing=u(15.0, 25.0), setback=(0.0, 0.0), power_line=-1,
    )  # fmt: skip


SCENES: dict[str, SceneStyle] = {
    "suburban": SceneStyle(RoadShape(), ZONE_WEIGHTS),
    "avenue": SceneStyle(
        RoadShape((80.0, 350.0), 0.3, (60.0, 100.0), (25.0, 45.0), (5.0, 30.0), (150.0, 500.0)),
        {ZoneKind.URBAN: 0.55, ZoneKind.RESIDENTIAL: 0.3, ZoneKind.INDUSTRIAL: 0.15, ZoneKind.OPEN: 0.0},
        crossing_gap=(80.0, 200.0),
        crossing_half_width=(5.0, 9.0),
        adjust=_avenue,
    ),
    "highway": SceneStyle(
        RoadShape((300.0, 1000.0), 0.0, (0.0, 0.0), (1.0, 1.0), (5.0, 35.0), (500.0, 2000.0)),
        {ZoneKind.URBAN: 0.0, ZoneKind.RESIDENTIAL: 0.0, ZoneKind.INDUSTRIAL: 0.15, ZoneKind.OPEN: 0.85},
        crossings=False,
        crossing_gap=(200.0, 600.0),
        adjust=_highway,
    ),
    "oldtown": SceneStyle(
        RoadShape((25.0, 110.0), 0.7, (60.0, 100.0), (10.0, 18.0), (10.0, 45.0), (30.0, 120.0)),
        {ZoneKind.URBAN: 0.85, ZoneKind.RESIDENTIAL: 0.15, ZoneKind.INDUSTRIAL: 0.0, ZoneKind.OPEN: 0.0},
        crossing_gap=(40.0, 110.0),
        crossing_half_width=(2.5, 4.5),
        adjust=_oldtown,
        buildings={
            ZoneKind.URBAN: replace(
                BUILDING_STYLES[ZoneKind.URBAN],
                gap_prob=0.03,
                gap=(1.5, 4.0),
                width=(5.0, 12.0),
                spacing=(0.0, 0.2),
                setback_jitter=0.2,
                floors=(2, 5),
                roof_gable=0.6,
                balcony=0.15,
            ),
            ZoneKind.RESIDENTIAL: replace(
                BUILDING_STYLES[ZoneKind.RESIDENTIAL], gap_prob=0.05, spacing=(0.0, 1.5), setback_jitter=0.5
            ),
        },
    ),
}
"""The scene styles by name; ``suburban`` is the original mix (same output for the same seed)."""
SCENE_STYLES = tuple(SCENES)


def scene_style(name: str) -> SceneStyle:
    """The style called ``name``, or a ConfigError listing the valid names."""
    if name not in SCENES:
        raise ConfigError(f"scene must be one of {', '.join(SCENE_STYLES)}, got {name!r}")
    return SCENES[name]
