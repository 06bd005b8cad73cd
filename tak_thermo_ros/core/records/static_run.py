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

from tak_thermo_ros.core.values import EARTH_RATE
from tak_thermo_ros.errors import TakError

STATIC_TOLERANCE_DEG = 10.0
"""Largest angle between one sample's measured direction and the mean direction of a static run."""


class NotStatic(TakError):
    """A run without a specific-force reference that is not static in one orientation (:func:`check_static`)."""


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


def check_static(static: StaticReference, *, gravity: float, max_tilt_deg: float, where: str,
                 reference_topic: str) -> None:
    """Refuse a run without a specific-force reference that is not static in one orientation.

    :param where: the bag, named in the message.
    :raises NotStatic: the mean is far below gravity, or a sample points more than
        :data:`STATIC_TOLERANCE_DEG` away from the mean direction (the board moved).
    """
    if static.magnitude < 0.1 * gravity:
        msg = (f'{where}: no {reference_topic} and the mean acceleration |{static.magnitude:.4g}| m/s^2 is '
               f'far below gravity: not a static run; record the reference')
        raise NotStatic(msg)
    if max_tilt_deg > STATIC_TOLERANCE_DEG:
        msg = (f'{where}: no {reference_topic} and the board moved (a sample {max_tilt_deg:.1f} deg '
               f'from the mean direction): a static run needs one orientation; record the reference')
        raise NotStatic(msg)


def reference_line(static: StaticReference, *, gravity: float, max_tilt_deg: float) -> str:
    """How a static run's specific-force reference was obtained: two lines (the rule, then the vector)."""
    x, y, z = (float(v) for v in static.specific_force)
    return (f'reference (static run): mean measured direction scaled to gravity {gravity:g} m/s^2\n'
            f'  = ({x:.4f}, {y:.4f}, {z:.4f}) m/s^2; the board turned from it by at most {max_tilt_deg:.2f} deg')


def rate_line(static: StaticReference, latitude_deg: float | None) -> str:
    """How a static run's rate reference was obtained, one line."""
    if latitude_deg is None:
        return 'rate reference (static run): zero'
    x, y, z = (float(v) for v in static.rate)
    return (f"rate reference (static run): the Earth rate's vertical component at latitude {latitude_deg:g} deg "
            f'= ({x:.3e}, {y:.3e}, {z:.3e}) rad/s')
