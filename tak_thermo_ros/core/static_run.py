"""The reference of a static run: a unit that sits in one orientation through the thermal cycle.

Without a turntable or a rate table the truth is not recorded, but it is known: the specific
force is gravity, pointing up, whose direction in the sensor frame is the mean measured
direction; the angular rate is zero, or the Earth's rate where the user wants it. Only the
Earth rate's vertical component is known from one orientation (its horizontal component
needs the heading, which a static IMU does not give), so that is what ``latitude`` adds:
``Omega_E sin(latitude)`` along the measured up direction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

EARTH_RATE = 7.2921159e-5
"""The Earth's rotation rate, rad/s (WGS 84)."""

STATIC_TOLERANCE_DEG = 10.0
"""Largest angle between one sample's measured direction and the mean direction of a static run."""


@dataclass(frozen=True)
class StaticReference:
    """The reference of a static run, estimated from its measurements.

    :param specific_force: ``(3,)`` true specific force along the sensor axes, m/s^2.
    :param rate: ``(3,)`` true angular rate along the sensor axes, rad/s.
    :param direction: ``(3,)`` unit mean measured direction of the specific force.
    :param magnitude: ``|mean measured specific force|``, m/s^2.
    :param tilt_deg: ``(k,)`` angle of each sample's measured direction from the mean one.
    """

    specific_force: np.ndarray
    rate: np.ndarray
    direction: np.ndarray
    magnitude: float
    tilt_deg: np.ndarray

    @property
    def worst_row(self) -> int:
        """Index of the sample farthest from the mean direction."""
        return int(np.argmax(self.tilt_deg)) if len(self.tilt_deg) else 0

    @property
    def max_tilt_deg(self) -> float:
        """The largest tilt, degrees."""
        return float(self.tilt_deg[self.worst_row]) if len(self.tilt_deg) else 0.0


def static_reference(acceleration: np.ndarray, *, gravity: float,
                     latitude_deg: float | None = None) -> StaticReference:
    """The reference of a run held in one orientation, from its measured specific force.

    :param acceleration: ``(k, 3)`` measured specific force, m/s^2 (finite rows only).
    :param gravity: local gravity, m/s^2: the magnitude of the reference.
    :param latitude_deg: adds the Earth rate's vertical component to the rate reference.
    """
    acceleration = np.asarray(acceleration, dtype=float)
    mean = acceleration.mean(axis=0) if len(acceleration) else np.zeros(3)
    magnitude = float(np.linalg.norm(mean))
    direction = mean / magnitude if magnitude > 0.0 else np.zeros(3)
    norms = np.linalg.norm(acceleration, axis=1)
    cosine = np.clip((acceleration @ direction) / np.where(norms > 0.0, norms, 1.0), -1.0, 1.0)
    rate = np.zeros(3)
    if latitude_deg is not None:
        rate = EARTH_RATE * math.sin(math.radians(latitude_deg)) * direction
    return StaticReference(specific_force=gravity * direction, rate=rate, direction=direction,
                           magnitude=magnitude, tilt_deg=np.degrees(np.arccos(cosine)))
