"""A unit turned by hand: still orientations joined by turns, the true specific force and rate.

A hand-held record alternates rests and turns. At rest the unit lies in a pose ``R`` (sensor
frame to a local level frame, z up); the specific force in the sensor frame is
``g R^T e_z``, the rate zero (plus the Earth's rate when a latitude is given). A turn carries
pose ``R_a`` to ``R_b`` about one axis of the sensor frame, ``R(t) = R_a Exp(phi s(t))`` with
``phi = Log(R_a^T R_b)`` and ``s`` a minimum-jerk profile from 0 to 1, so the rate is
``phi s'(t)`` and the angular acceleration ``phi s''(t)``. The hand turns the unit about a
point off the sensor: with the lever arm ``r`` (from that point to the sensor, sensor frame) the
sensor also feels ``alpha x r + omega x (omega x r)``, which a fit must not take for gravity.

Patterns: ``random`` (orientations drawn evenly over the sphere of directions, any heading),
``six_faces`` (the unit set down on each face in turn, +z +x +y -z -x -y, within ``tilt_deg``
and at any heading), ``one_axis`` (turned about the sensor's x axis only: a bad record).
Temperature: ``warmup`` (a cold unit warming, ``start_celsius`` to ``final_celsius`` with time
constant ``warmup_tau_s``) or ``chamber`` (the scenario's plateaus and ramps).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from tak_thermo_ros.core.rotation import exp_map, log_map, rotation_between
from tak_thermo_ros.core.simulation.mapping import fields_from_mapping, first_failed, integer, number, numbers, string
from tak_thermo_ros.core.values import EARTH_RATE

PATTERNS = ('random', 'six_faces', 'one_axis')
TEMPERATURES = ('warmup', 'chamber')
FACE_UP: tuple[tuple[float, float, float], ...] = ((0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0),
                                                   (0.0, 0.0, -1.0), (-1.0, 0.0, 0.0), (0.0, -1.0, 0.0))
"""The six faces in the order the unit is set on them: the up direction in the sensor frame."""


@dataclass(frozen=True)
class HandheldMotion:
    """How the unit is turned by hand (scenario key ``handheld``, every key optional).

    :param pattern: ``random``, ``six_faces`` or ``one_axis``.
    :param orientations: how many rests with ``warmup`` (with ``chamber``: as many as the run holds).
    :param still_s: each rest, seconds (drawn within +-``jitter`` of it).
    :param turn_s: each turn, seconds (likewise).
    :param jitter: the relative spread of the rests' and turns' lengths.
    :param lever_arm_m: from the point the hand turns about to the sensor, sensor frame, metres.
    :param temperature: ``warmup`` or ``chamber``.
    :param final_celsius: where a warming unit ends (``warmup``).
    :param warmup_tau_s: the warming's time constant, seconds.
    :param tilt_deg: ``six_faces``: how far a face may lie from level (uniform within it).
    :param latitude_deg: the Earth's rate seen by the gyroscope at this latitude (``None``: a world that
        does not turn, the default).
    """

    pattern: str = 'random'
    orientations: int = 30
    still_s: float = 8.0
    turn_s: float = 2.0
    jitter: float = 0.2
    lever_arm_m: tuple[float, float, float] = (0.10, -0.05, 0.03)
    temperature: str = 'warmup'
    final_celsius: float = 35.0
    warmup_tau_s: float = 600.0
    tilt_deg: float = 2.0
    latitude_deg: float | None = None

    def __post_init__(self) -> None:
        checks = (
            (self.pattern in PATTERNS, 'pattern', f'expected one of {", ".join(PATTERNS)}'),
            (self.temperature in TEMPERATURES, 'temperature', f'expected one of {", ".join(TEMPERATURES)}'),
            (self.orientations >= 1, 'orientations', 'must be >= 1'),
            (math.isfinite(self.still_s) and self.still_s > 0.0, 'still_s', 'must be > 0 (s)'),
            (math.isfinite(self.turn_s) and self.turn_s > 0.0, 'turn_s', 'must be > 0 (s)'),
            (math.isfinite(self.jitter) and 0.0 <= self.jitter < 1.0, 'jitter', 'must lie within 0..1'),
            (len(self.lever_arm_m) == 3 and all(math.isfinite(v) and abs(v) <= 2.0 for v in self.lever_arm_m),
             'lever_arm_m', 'expected three finite numbers within +-2 m'),
            (math.isfinite(self.final_celsius), 'final_celsius', 'must be finite'),
            (math.isfinite(self.warmup_tau_s) and self.warmup_tau_s > 0.0, 'warmup_tau_s', 'must be > 0 (s)'),
            (math.isfinite(self.tilt_deg) and 0.0 <= self.tilt_deg < 45.0, 'tilt_deg', 'must lie within 0..45'),
            (self.latitude_deg is None or (math.isfinite(self.latitude_deg) and abs(self.latitude_deg) <= 90.0),
             'latitude_deg', 'must lie within -90..90'),
        )
        first_failed(checks, 'handheld')


def motion_from_mapping(raw: Any) -> HandheldMotion:
    """A :class:`HandheldMotion` from a scenario's ``handheld`` mapping.

    :raises ScenarioError: naming the key.
    """
    def read(key: str, value: Any) -> Any:
        default = getattr(HandheldMotion(), key)
        where = f'handheld.{key}'
        if isinstance(default, str):
            return string(value, where)
        if key == 'lever_arm_m':
            return numbers(value, where, what='a list of three numbers')
        if key == 'orientations':
            return integer(value, where)
        if value is None and key == 'latitude_deg':
            return None
        return number(value, where)

    known = ', '.join(f.name for f in fields(HandheldMotion))
    values = fields_from_mapping(raw, HandheldMotion, 'handheld.', read,
                                 not_a_mapping=f'handheld: expected a mapping (every key optional: {known})')
    return HandheldMotion(**values)


@dataclass(frozen=True)
class Trajectory:
    """The true motion of a hand-held record.

    :param time_s: ``(n,)`` sample times from the start.
    :param specific_force: ``(n, 3)`` true specific force in the sensor frame, m/s^2.
    :param rate: ``(n, 3)`` true angular rate in the sensor frame, rad/s (the Earth's included).
    :param still: ``(n,)`` whether the unit rests at each sample.
    :param segment: ``(n,)`` the rest (even) or turn (odd) each sample lies in, ``2 k`` for rest ``k``.
    :param poses: ``(m, 3, 3)`` each rest's pose (sensor frame to the level frame).
    :param up: ``(m, 3)`` each rest's up direction in the sensor frame.
    """

    time_s: np.ndarray
    specific_force: np.ndarray
    rate: np.ndarray
    still: np.ndarray
    segment: np.ndarray
    poses: np.ndarray
    up: np.ndarray


def _minimum_jerk(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``s, ds/dtau, d2s/dtau2`` of ``10 t^3 - 15 t^4 + 6 t^5``."""
    s = tau ** 3 * (10.0 - 15.0 * tau + 6.0 * tau ** 2)
    ds = 30.0 * tau ** 2 * (1.0 - tau) ** 2
    dds = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau)
    return s, ds, dds


def _pose(up: np.ndarray, heading: float) -> np.ndarray:
    """The pose whose up direction in the sensor frame is ``up``, at ``heading`` about the vertical."""
    level = rotation_between(up / np.linalg.norm(up), np.array([0.0, 0.0, 1.0]))
    return exp_map(np.array([0.0, 0.0, heading])) @ level


def rest_poses(motion: HandheldMotion, count: int, rng: np.random.Generator) -> np.ndarray:
    """``(count, 3, 3)`` the poses of the rests, by the motion's pattern."""
    if motion.pattern == 'one_axis':
        angles = rng.uniform(0.0, 2.0 * math.pi, count)
        return exp_map(np.column_stack([angles, np.zeros(count), np.zeros(count)]))
    if motion.pattern == 'six_faces':
        up = np.array(FACE_UP)[np.arange(count) % len(FACE_UP)]
        tilt = math.radians(motion.tilt_deg) * np.sqrt(rng.uniform(size=count))
        axis = np.cross(up, rng.standard_normal((count, 3)))
        up = np.einsum('kab,kb->ka', exp_map(tilt[:, None] * axis / np.linalg.norm(axis, axis=1, keepdims=True)), up)
    else:
        up = rng.standard_normal((count, 3))
    return _posed(up, rng)


def _posed(up: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``(k, 3, 3)`` the poses whose up directions are ``up`` ``(k, 3)``, each at a heading drawn uniform."""
    headings = rng.uniform(0.0, 2.0 * math.pi, len(up))
    return np.array([_pose(direction, heading) for direction, heading in zip(up, headings)])


def hand_trajectory(motion: HandheldMotion, *, rate_hz: float, gravity: float, seed: int,
                    duration_s: float | None = None) -> Trajectory:
    """The rests and turns of a hand-held record, sampled at ``rate_hz``.

    :param duration_s: fill this long with rests and turns (``None``: ``motion.orientations`` rests).
    """
    rng = np.random.default_rng([seed, 22])
    lengths: list[float] = []
    elapsed = 0.0
    while True:
        still = motion.still_s * rng.uniform(1.0 - motion.jitter, 1.0 + motion.jitter)
        lengths.append(still)
        elapsed += still
        rests = (len(lengths) + 1) // 2
        if (duration_s is None and rests >= motion.orientations) or (duration_s is not None and elapsed >= duration_s):
            break
        turn = motion.turn_s * rng.uniform(1.0 - motion.jitter, 1.0 + motion.jitter)
        lengths.append(turn)
        elapsed += turn
    edges = np.concatenate([[0.0], np.cumsum(lengths)])
    total = edges[-1] if duration_s is None else duration_s
    count = int(math.floor(total * rate_hz)) + 1
    time_s = np.arange(count) / rate_hz
    segment = np.minimum(np.searchsorted(edges, time_s, side='right') - 1, len(lengths) - 1)
    poses = rest_poses(motion, (len(lengths) + 1) // 2, rng)
    arm = np.asarray(motion.lever_arm_m, dtype=float)
    rotation = poses[segment // 2].copy()
    rate = np.zeros((count, 3))
    alpha = np.zeros((count, 3))
    turning = segment % 2 == 1
    if len(poses) > 1:
        # Each turn about one axis of the sensor frame: phi = Log(R_a^T R_b), all turns at once.
        phi = log_map(np.swapaxes(poses[:-1], 1, 2) @ poses[1:])
        rows = np.flatnonzero(turning)
        turn = segment[rows] // 2
        length = (edges[1:] - edges[:-1])[segment[rows]]
        s, ds, dds = _minimum_jerk((time_s[rows] - edges[segment[rows]]) / length)
        rotation[rows] = poses[turn] @ exp_map(s[:, None] * phi[turn])
        rate[rows] = ds[:, None] * phi[turn] / length[:, None]
        alpha[rows] = dds[:, None] * phi[turn] / length[:, None] ** 2
    up_body = rotation[:, 2, :]  # R^T e_z: the third row of R
    lever = np.cross(alpha, arm) + np.cross(rate, np.cross(rate, arm))
    force = gravity * up_body + lever
    if motion.latitude_deg is not None:
        latitude = math.radians(motion.latitude_deg)
        earth = EARTH_RATE * np.array([math.cos(latitude), 0.0, math.sin(latitude)])
        rate = rate + np.einsum('nji,j->ni', rotation, earth)
    return Trajectory(time_s=time_s, specific_force=force, rate=rate, still=~turning, segment=segment,
                      poses=poses, up=poses[:, 2, :])
