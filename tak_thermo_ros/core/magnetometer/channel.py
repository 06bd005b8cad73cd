"""The magnetometer channel: the IMU's correction link per axis, then the hard and soft iron.

``B_corrected = W (B_thermal - h)``, ``B_thermal`` from the same
:class:`~tak_thermo_ros.core.link.correction.Corrector` (and effect library) as the
accelerometer and the gyroscope, with the field in tesla in place of the code and the
temperature in degrees C. :class:`MagCorrector` has the interface of
:class:`~tak_thermo_ros.core.link.correction.UnitCorrector` (three channels), so that the
node's logic (:mod:`tak_thermo_ros.core.link.online`), ``apply`` and ``validate`` run it alike;
its vectorised and per-sample paths agree bit for bit.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from tak_thermo_ros.core.link.correction import Corrector, OutOfRange, acceleration_variance
from tak_thermo_ros.core.link.model import MagnetometerCalibration
from tak_thermo_ros.core.magnetometer.iron import correct_iron, correct_iron_sample
from tak_thermo_ros.errors import CalibrationError, TakError

TESLA_LIMIT = 1e-3
"""Largest plausible median field magnitude in tesla (1 mT = 10 G, beyond any magnetometer's
range near the Earth's 22-67 uT): a topic above it is not in tesla (gauss? microtesla?)."""


def field_unit_problem(values: np.ndarray) -> str | None:
    """Why ``(k, 3)`` finite field values are not a field in tesla, or ``None``."""
    values = np.asarray(values, dtype=float).reshape(-1, 3)
    finite = values[np.all(np.isfinite(values), axis=1)]
    if not len(finite):
        return None
    median = float(np.median(np.linalg.norm(finite, axis=1)))
    if median > TESLA_LIMIT:
        return (f'median |B| {median:.4g} is not a field in tesla (the Earth\'s is 2.2e-5..6.7e-5 T; '
                f'at most {TESLA_LIMIT:g} T accepted): a topic in gauss (1 G = 1e-4 T) or microtesla? '
                f'sensor_msgs/MagneticField is in tesla')
    return None


def check_tesla(values: np.ndarray, where: str) -> None:
    """Refuse field values that are not in tesla (:func:`field_unit_problem`), naming ``where``."""
    problem = field_unit_problem(values)
    if problem is not None:
        raise TakError(f'{where}: {problem}')


class MagCorrector:
    """The magnetometer's correction: its thermal link, then the iron.

    :param mag: the magnetometer's calibration.
    :param out_of_range: policy for temperatures outside the calibrated range.
    """

    channels = 3

    def __init__(self, mag: MagnetometerCalibration, *, out_of_range: OutOfRange = OutOfRange.CLAMP) -> None:
        self.mag = mag
        self.thermal = Corrector(mag.thermal, out_of_range=out_of_range)
        self._hard = tuple(mag.hard_iron)
        self._soft = tuple(mag.soft_iron)

    @property
    def signals(self) -> tuple[str, ...]:
        """The recorded signals the thermal link needs (``aux:TOPIC``)."""
        return self.thermal.signals

    def reset(self) -> None:
        """Forget the online state of effects with memory."""
        self.thermal.reset()

    def correct(self, values: np.ndarray, temperature: np.ndarray, *, stamp_s: np.ndarray | None = None,
                aux: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
        """Corrected field ``(k, 3)`` in tesla from the raw field ``(k, 3)`` and the temperature ``(k,)``."""
        thermal = self.thermal.correct(values, temperature, stamp_s=stamp_s, aux=aux)
        return correct_iron(thermal, self._hard, self._soft)

    def correct_sample(self, values: tuple[float, ...], temperature: float, *, stamp_s: float = 0.0,
                       aux: Mapping[str, float] | None = None) -> tuple[float, float, float]:
        """One sample of plain floats; the node's path, bit-identical to :meth:`correct`."""
        x, y, z = self.thermal.correct_sample(values[0], values[1], values[2], temperature, stamp_s=stamp_s, aux=aux)
        return correct_iron_sample(x, y, z, self._hard, self._soft)

    def out_of_range_count(self, temperature: np.ndarray) -> int:
        """How many temperatures lie outside the thermal link's calibrated range."""
        return self.thermal.out_of_range_count(temperature)


def magnetic_covariance(mag: MagnetometerCalibration) -> tuple[float, ...]:
    """The ``magnetic_field_covariance`` (row-major, tesla^2) of the corrected field.

    ``W diag(sigma^2) W^T`` with ``sigma`` the thermal fit's residual per axis over its scale
    (the noise the correction passes on, turned by the soft iron); all zero when the residual
    is unknown (``sensor_msgs/MagneticField``: zeros mean unknown).
    """
    variance = np.diag(acceleration_variance(mag.thermal))
    soft = mag.soft_iron_matrix
    covariance = soft @ variance @ soft.T
    covariance = (covariance + covariance.T) / 2.0
    values = tuple(float(v) for v in covariance.ravel())
    if not all(math.isfinite(v) for v in values):
        msg = 'calibration.mag: residual_rms / scale gives no finite covariance'
        raise CalibrationError(msg)
    return values
