"""A person walking down the street with a handheld scanner (``--motion handheld``): the pace and pauses
of a walk, the sensor's height in the hand, step bobbing and sway, slow tilts and quick look-around
turns, sampled at each frame as LiDAR -> world poses.

Why a separate model from the car: handheld and solid-state scanners meet rotations a car never makes
(up to 90 deg/s of yaw, +-15 deg of pitch and roll), and odometry must be tested on them.

The walker keeps to the right-hand edge of the carriageway, about 1 m inside the lane edge, beside
the parked cars and the curb. The sidewalk itself is not used: signs, bins, benches and columns stand
anywhere on it, and a sensor walked through one would scan the inside of an object. The lane is always
clear (nothing is placed on a carriageway).

Every quantity is a smooth function of time (cosine ramps, sinusoids, integrals of them), so poses
never jump, and each kind of draw has its own generator seeded from the sequence seed: the same seed
gives byte-identical poses, and each stream is drawn in time order, so a longer walk starts exactly
like a shorter one.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from vcr_odom.errors import ConfigError
from vcr_odom.synth.drive import Drive
from vcr_odom.synth.indoor import IndoorScene
from vcr_odom.synth.road import PREROLL, ROAD_STEP
from vcr_odom.synth.scene import StreetScene

HAND_HEIGHT = (1.2, 1.6)
"""Height (m) of the sensor above the ground, drawn per seed unless given: a chest-to-face hold."""
PACE = (1.0, 1.6)
"""Walking speeds (m/s) between pauses; each lasts 3-8 s and the pace eases from one to the next."""
MAX_SPEED = PACE[1]
"""Fastest walk (m/s): how much road a handheld sequence needs."""
PAUSE_GAP, PAUSE_LENGTH, PAUSE_RAMP = (10.0, 35.0), (1.0, 4.0), 1.0
"""Seconds of walking between pauses, seconds standing, and seconds to slow down or pick up the pace."""
LOOK_GAP, LOOK_ANGLE, LOOK_RATE, LOOK_HOLD = (3.0, 10.0), (30.0, 90.0), (40.0, 75.0), (0.5, 3.0)
"""Look-around turns: seconds between them, degrees turned away, peak rate (deg/s) of the turn away
and of the turn back, seconds spent looking. With the path's own turns (<= 7 deg/s), the yaw wander
(<= 4 deg/s) and the tilts, the sensor never turns faster than 90 deg/s."""
MAX_TILT = 15.0
"""Pitch and roll stay within +-15 deg (a soft limit: ``15 tanh(x / 15)``)."""
LANE_INSET = 1.0
"""Metres inside the lane edge the walker keeps to: lamp posts and trees at the curb stay >= 1.5 m away."""
FINE_STEP = 0.01
"""Seconds between samples of the integrated quantities (distance walked, step phase)."""

Signal = Callable[[NDArray[np.float64]], NDArray[np.float64]]


def make_walk(
    scene: StreetScene | IndoorScene,
    *,
    frames: int,
    height: float | None,
    seed: int,
    frame_period: float,
) -> Drive:
    """The walker's poses at ``frames`` frames ``frame_period`` s apart, starting at :data:`PREROLL`
    on the road (indoors: on the scene's own walkway, and no look-around turn while rounding a corner
    or turning round); ``height`` (m) overrides the drawn hand height (:func:`hand_height`)."""
    times = np.arange(frames) * frame_period
    fine, gate, pace = _gait(seed, times)
    walked = _integral(pace(fine) * gate(fine))
    cadence = 1.75 + 0.4 * (pace(fine) - PACE[0]) / (PACE[1] - PACE[0])  # steps per second
    step_phase = 2.0 * math.pi * _integral(cadence * gate(fine))
    distance = np.interp(times, fine, walked)
    phase = np.interp(times, fine, step_phase)
    walking = gate(times)

    if isinstance(scene, IndoorScene):
        stations, xy, path_heading = scene.walk(distance)
        cornering = fine[scene.turning(walked)]
        ground = scene.ground_height(xy)
    else:
        stations, xy, path_heading = _path(scene, np.random.default_rng([seed, 22]), distance)
        cornering = None
        ground = scene.layout.ground_height(xy)
    yaw = path_heading + _look_around(np.random.default_rng([seed, 23]), times[-1], cornering)(times)
    tilt_rng = np.random.default_rng([seed, 24])
    pitch = _soft_limit(_wander(tilt_rng, mean=(-8.0, 3.0), amplitude=(2.0, 5.0))(times))
    roll = _soft_limit(_wander(tilt_rng, mean=(-3.0, 3.0), amplitude=(2.0, 5.0))(times))
    body = np.random.default_rng([seed, 25])
    bob, sway, nod = body.uniform(0.02, 0.04), body.uniform(0.8, 1.8), body.uniform(0.2, 0.5)
    hand = hand_height(seed) if height is None else height
    drift = _wander(body, mean=(0.0, 0.0), amplitude=(0.005, 0.015))(times)  # m: the arm tires and lifts
    pitch = pitch + nod * walking * np.sin(phase)
    roll = roll + sway * walking * np.sin(0.5 * phase)  # the body sways once per two steps

    poses = np.tile(np.eye(4), (frames, 1, 1))
    poses[:, :3, :3] = Rotation.from_euler(
        "ZYX", np.column_stack([yaw, np.radians(pitch), np.radians(roll)])
    ).as_matrix()
    z = ground + hand + drift + bob * walking * np.sin(phase)
    poses[:, :3, 3] = np.column_stack([xy, z])
    return Drive(stations, pace(times) * walking, poses)


def walk_travel(*, frames: int, seed: int, frame_period: float) -> float:
    """How far (m) the walker of :func:`make_walk` gets from the first frame to the last, whatever
    the path (what a route is sized by)."""
    times = np.arange(frames) * frame_period
    fine, gate, pace = _gait(seed, times)
    return float(np.interp(times[-1], fine, _integral(pace(fine) * gate(fine))))


def _gait(seed: int, times: NDArray[np.float64]) -> tuple[NDArray[np.float64], Signal, Signal]:
    """The fine time grid, the pause gate and the pace of a walk over ``times``."""
    fine = np.arange(0.0, times[-1] + 2.0 * FINE_STEP, FINE_STEP)
    gate = _pauses(np.random.default_rng([seed, 21]), fine[-1])
    pace = _pace(np.random.default_rng([seed, 20]), fine[-1])
    return fine, gate, pace


def hand_height(seed: int) -> float:
    """The seed's hand height (m) in :data:`HAND_HEIGHT`."""
    return float(np.random.default_rng([seed, 26]).uniform(*HAND_HEIGHT))


def _integral(rate: NDArray[np.float64]) -> NDArray[np.float64]:
    """Trapezoidal running integral of samples :data:`FINE_STEP` apart, 0 at the first."""
    return np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * FINE_STEP)])


def _ease(u: NDArray[np.float64]) -> NDArray[np.float64]:
    """0 -> 1 with zero slope at both ends (half a cosine): peak slope pi/2."""
    return 0.5 - 0.5 * np.cos(math.pi * np.clip(u, 0.0, 1.0))


def _pace(rng: np.random.Generator, duration: float) -> Signal:
    """Walking speed (m/s) over time: a new pace every 3-8 s, eased into."""
    knots, targets = [0.0], [rng.uniform(*PACE)]
    while knots[-1] <= duration:
        knots.append(knots[-1] + rng.uniform(3.0, 8.0))
        targets.append(rng.uniform(*PACE))
    k, v = np.array(knots), np.array(targets)

    def pace(t: NDArray[np.float64]) -> NDArray[np.float64]:
        i = np.clip(np.searchsorted(k, t, side="right") - 1, 0, len(k) - 2)
        return v[i] + (v[i + 1] - v[i]) * _ease((t - k[i]) / (k[i + 1] - k[i]))

    return pace


def _pauses(rng: np.random.Generator, duration: float) -> Signal:
    """1 while walking, 0 while standing: a pause of 1-4 s every 10-35 s, eased over a second."""
    spans = []
    start = rng.uniform(*PAUSE_GAP)
    while start <= duration:
        end = start + rng.uniform(*PAUSE_LENGTH)
        spans.append((start, end))
        start = end + PAUSE_RAMP + rng.uniform(*PAUSE_GAP)

    def gate(t: NDArray[np.float64]) -> NDArray[np.float64]:
        g = np.ones_like(t)
        for a, b in spans:
            g *= 1.0 - _ease((t - a + PAUSE_RAMP) / PAUSE_RAMP) * _ease((b + PAUSE_RAMP - t) / PAUSE_RAMP)
        return g

    return gate


def _path(
    scene: StreetScene, rng: np.random.Generator, distance: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Path stations, positions ``(N, 2)`` and headings where the walker is after walking ``distance``
    metres: the car's path (the road, on the open street) moved right to :data:`LANE_INSET` inside
    the lane edge, wandering +-0.3 m over tens of metres (zone changes ease in over about 10 m)."""
    road = scene.path.line
    first = round(PREROLL / ROAD_STEP)
    stations = np.arange(first, len(road.xy)) * ROAD_STEP
    lane = np.array([scene.layout.profile_at(float(s)).lane_width for s in scene.path.road_station[first:]])
    sigma = round(5.0 / ROAD_STEP)
    kernel = np.exp(-0.5 * (np.arange(-3 * sigma, 3 * sigma + 1) / sigma) ** 2)
    lane = np.convolve(np.pad(lane, 3 * sigma, mode="edge"), kernel / kernel.sum(), mode="valid")
    wavelength, phase = rng.uniform(20.0, 45.0), rng.uniform(0.0, 2.0 * math.pi)
    lateral = -(lane / 2.0 - LANE_INSET) + 0.3 * np.sin(2.0 * math.pi * stations / wavelength + phase)
    xy = road.offset(stations, lateral)
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    if distance[-1] > along[-1]:
        raise ConfigError("road too short for the walk")  # cannot happen: the road is sized for it
    step = np.gradient(xy, axis=0)
    heading = np.unwrap(np.arctan2(step[:, 1], step[:, 0]))
    where = np.column_stack([np.interp(distance, along, xy[:, 0]), np.interp(distance, along, xy[:, 1])])
    return np.interp(distance, along, stations), where, np.interp(distance, along, heading)


def _look_around(
    rng: np.random.Generator, duration: float, quiet: NDArray[np.float64] | None = None
) -> Signal:
    """Yaw (rad) added to the path's heading: every 3-10 s a turn of 30-90 deg to one side at up to
    40-75 deg/s, a look of 0.5-3 s, and a turn back; plus a slow wander of a few degrees. A turn
    under way within half a second of any of the ``quiet`` times (s: the walker rounding a corner)
    is left out; the draws stay the same."""
    wander = _wander(rng, mean=(0.0, 0.0), amplitude=(0.5, 1.3))  # first: the turns' count varies
    turns = []  # (start, angle, seconds away, seconds held, seconds back)
    start = rng.uniform(*LOOK_GAP)
    while start <= duration:
        angle = math.radians(rng.uniform(*LOOK_ANGLE)) * (1.0 if rng.random() < 0.5 else -1.0)
        away = 0.5 * math.pi * abs(angle) / math.radians(rng.uniform(*LOOK_RATE))
        hold = rng.uniform(*LOOK_HOLD)
        back = 0.5 * math.pi * abs(angle) / math.radians(rng.uniform(*LOOK_RATE))
        turns.append((start, angle, away, hold, back))
        start += away + hold + back + rng.uniform(*LOOK_GAP)
    if quiet is not None and len(quiet):
        spans = [(a - 0.5, a + away + hold + back + 0.5) for a, _, away, hold, back in turns]
        turns = [
            turn
            for turn, (a, b) in zip(turns, spans, strict=True)
            if np.searchsorted(quiet, a) == np.searchsorted(quiet, b)  # no quiet time within
        ]

    def look(t: NDArray[np.float64]) -> NDArray[np.float64]:
        yaw = np.radians(wander(t))
        for a, angle, away, hold, back in turns:
            turn_back = a + away + hold
            yaw += angle * (_ease((t - a) / away) - _ease((t - turn_back) / back))
        return yaw

    return look


def _wander(rng: np.random.Generator, mean: tuple[float, float], amplitude: tuple[float, float]) -> Signal:
    """A slow smooth wander: a drawn ``mean`` plus three sinusoids of the drawn ``amplitude`` and
    10-30 s periods (the units of ``mean`` and ``amplitude``)."""
    offset = rng.uniform(*mean)
    amplitudes = rng.uniform(*amplitude, 3)
    omegas = 2.0 * math.pi / rng.uniform(10.0, 30.0, 3)
    phases = rng.uniform(0.0, 2.0 * math.pi, 3)

    def signal(t: NDArray[np.float64]) -> NDArray[np.float64]:
        return offset + np.sin(np.multiply.outer(t, omegas) + phases) @ amplitudes

    return signal


def _soft_limit(degrees: NDArray[np.float64]) -> NDArray[np.float64]:
    """Tilts kept within +-:data:`MAX_TILT` degrees without a kink."""
    return MAX_TILT * np.tanh(degrees / MAX_TILT)
