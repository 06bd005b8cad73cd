"""The magnetometer in the simulator: chamber runs with thermal drift, and rotation records.

The true field at the sensor is ``S B + h`` (soft iron ``S``, hard iron ``h`` of the parts that
turn with it), then the sensor's thermal link, the IMU's ``y = K F_c(T) u + b0 + D F_s(T)``
per axis (the same :class:`~tak_thermo_ros.core.link.model.Calibration` forward model), then
white noise. Values in tesla, temperatures in degrees C.

Chosen defaults (the issue leaves them open): the Earth's field 48.4 uT in the sensor frame at
rest (20, 2, 44 uT); a sensor offset of 1-2 uT at 20 C drifting by 1.9-3.8 uT over 5..35 C (a
cubic per axis, as PX4 fits); a scale drift of 2-3e-4 per C; hard iron (4, -3, 2) uT; soft iron
``|S - I|`` up to 0.05 per element (symmetric); noise 0.2 uT per sample and axis.

In a driver scenario (``output: imu``) the key ``magnetometer`` (a mapping, every key
optional, ``{}`` for the defaults) adds ``/imu/mag`` at the Imu's stamps: the field turns with
the table's positions (the rotation taking z to each 'up'), and with ``record_references``
the table's known field is recorded on ``/tak/reference_field`` at each change (a coil or a
surveyed field). :func:`rotation_record` simulates the turns for the ellipsoid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any, Mapping

import numpy as np

from tak_thermo_ros.core.effects import resolve_effect
from tak_thermo_ros.core.link.correction import forward_counts
from tak_thermo_ros.core.link.model import AxisModel, Calibration, MagnetometerCalibration
from tak_thermo_ros.core.records.record import DriverRecord, no_orientation
from tak_thermo_ros.core.records.stamps import ns_from_seconds
from tak_thermo_ros.core.rotation import quaternion_matrix, quaternion_product
from tak_thermo_ros.core.values import STANDARD_GRAVITY
from tak_thermo_ros.errors import CalibrationError, FitError, ScenarioError


@dataclass(frozen=True)
class MagnetometerTruth:
    """The true magnetometer of a simulated unit (tesla, degrees C from ``reference_celsius``).

    :param earth_field: the field in the sensor frame at rest (position z up), tesla.
    :param offset: the sensor's offset per axis at the reference temperature, tesla.
    :param offset_coeffs: per axis, the offset drift's ``(c1, c2, c3)``, tesla per C^k.
    :param scale_coeffs: per axis, ``F_c``'s ``(a1, ...)``, per C^k.
    :param hard_iron: ``h``, tesla.
    :param soft_iron: ``S``, row-major, symmetric.
    :param noise: white noise per sample and axis, tesla.
    :param effects: hidden effects of the library on the thermal link (tesla, degrees C), effect
        name -> its true parameters, as a scenario's ``effects`` (off by default).
    """

    earth_field: tuple[float, float, float] = (20e-6, 2e-6, 44e-6)
    offset: tuple[float, float, float] = (1.5e-6, -0.8e-6, 2.0e-6)
    offset_coeffs: tuple[tuple[float, ...], ...] = ((120e-9, 3.0e-9, -0.15e-9), (-90e-9, 2.4e-9, 0.12e-9),
                                                    (150e-9, -3.0e-9, 0.0))
    scale_coeffs: tuple[tuple[float, ...], ...] = ((3e-4,), (-2e-4,), (2.5e-4,))
    hard_iron: tuple[float, float, float] = (4e-6, -3e-6, 2e-6)
    soft_iron: tuple[float, ...] = (1.05, 0.04, -0.03, 0.04, 0.96, 0.05, -0.03, 0.05, 1.02)
    noise: float = 0.2e-6
    effects: Mapping[str, Mapping[str, float]] = field(default_factory=dict)

    def effect_instances(self, key: str = 'magnetometer.effects') -> tuple:
        """The hidden effects as the library's effect objects with their true parameters."""
        instances = []
        for name, values in self.effects.items():
            try:
                instances.append(resolve_effect(name).from_values(values, key=f'{key}.{name}', complete=False))
            except (FitError, CalibrationError) as err:
                raise ScenarioError(f'{key}.{name}: {err}') from None
        return tuple(instances)

    def link(self, reference_celsius: float, low: float, high: float) -> Calibration:
        """The thermal link, normalised over ``low..high`` degrees C."""
        n_range = (low - reference_celsius, high - reference_celsius)
        axes = tuple(AxisModel.from_polynomials(scale=1.0, offset=offset, offset_coeffs=drift, scale_coeffs=scale,
                                                code_offset_range=n_range, residual_rms=self.noise)
                     for offset, drift, scale in zip(self.offset, self.offset_coeffs, self.scale_coeffs))
        return Calibration(temp_code_ref=reference_celsius, temp_code_min=low, temp_code_max=high,
                           axes=axes, effects=self.effect_instances())  # type: ignore[arg-type]

    def soft_matrix(self) -> np.ndarray:
        """``S`` as a 3x3 array."""
        return np.array(self.soft_iron, dtype=float).reshape(3, 3)

    def correction(self, reference_celsius: float, low: float, high: float) -> MagnetometerCalibration:
        """The exact correction: the thermal link, ``h``, and ``W = S^-1`` (not normalised)."""
        inverse = np.linalg.inv(self.soft_matrix())
        inverse = (inverse + inverse.T) / 2.0
        return MagnetometerCalibration(self.link(reference_celsius, low, high), self.hard_iron,
                                       tuple(float(v) for v in inverse.ravel()))

    def measure(self, field: np.ndarray, temperature: np.ndarray, reference_celsius: float,
                rng: np.random.Generator, stamp_s: np.ndarray | None = None) -> np.ndarray:
        """What the sensor gives for the true field ``(k, 3)`` at board temperatures ``(k,)``.

        The link's forward model with its hidden effects (:func:`forward_counts`, the IMU's),
        driven by the stamps ``(k,)`` in seconds (needed by effects with memory).
        """
        at_sensor = np.asarray(field, dtype=float) @ self.soft_matrix().T + np.asarray(self.hard_iron)
        link = self.link(reference_celsius, -1.0 + reference_celsius, 1.0 + reference_celsius)
        if stamp_s is None:
            stamp_s = np.arange(len(at_sensor), dtype=float)
        exact = forward_counts(link, at_sensor, np.asarray(temperature, dtype=float), stamp_s=stamp_s)
        return exact + rng.standard_normal(exact.shape) * self.noise


def truth_from_mapping(raw: Any, *, key: str = 'magnetometer') -> MagnetometerTruth:
    """A :class:`MagnetometerTruth` from a scenario mapping, every key optional (tesla).

    :raises ScenarioError: naming the key.
    """
    if not isinstance(raw, Mapping):
        msg = f'{key}: expected a mapping (every key optional: {", ".join(f.name for f in fields(MagnetometerTruth))})'
        raise ScenarioError(msg)
    names = {f.name for f in fields(MagnetometerTruth)}
    unknown = sorted(set(raw) - names)
    if unknown:
        msg = f'{key}.{unknown[0]}: unknown key'
        raise ScenarioError(msg)
    values: dict[str, Any] = {}
    for name, value in raw.items():
        try:
            if name == 'noise':
                values[name] = float(value)
            elif name == 'effects':
                if not isinstance(value, Mapping):
                    raise TypeError
                values[name] = {str(effect): dict(params) for effect, params in value.items()}
            elif name in ('offset_coeffs', 'scale_coeffs'):
                values[name] = tuple(tuple(float(v) for v in axis) for axis in value)
            else:
                values[name] = tuple(float(v) for v in value)
        except (TypeError, ValueError):
            msg = f'{key}.{name}: expected numbers'
            raise ScenarioError(msg) from None
    truth = MagnetometerTruth(**values)
    truth.effect_instances(f'{key}.effects')
    lengths = {'earth_field': 3, 'offset': 3, 'hard_iron': 3, 'soft_iron': 9, 'offset_coeffs': 3, 'scale_coeffs': 3}
    for name, length in lengths.items():
        if len(getattr(truth, name)) != length:
            msg = f'{key}.{name}: expected {length} entries'
            raise ScenarioError(msg)
    soft = truth.soft_matrix()
    if not np.allclose(soft, soft.T) or np.linalg.eigvalsh(soft)[0] <= 0.0:
        msg = f'{key}.soft_iron: must be symmetric positive definite'
        raise ScenarioError(msg)
    if not (math.isfinite(truth.noise) and truth.noise >= 0.0):
        msg = f'{key}.noise: must be a finite number >= 0 (tesla)'
        raise ScenarioError(msg)
    return truth


def up_rotation(up: np.ndarray) -> np.ndarray:
    """The smallest rotation taking the sensor's z axis to ``up`` (the frame of a table position).

    Returns ``R`` such that a field ``B`` given in the rest frame is ``R.T @ B`` in the sensor frame.
    """
    up = np.asarray(up, dtype=float) / np.linalg.norm(up)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, up)
    sine, cosine = np.linalg.norm(axis), float(z @ up)
    if sine < 1e-12:
        return np.eye(3) if cosine > 0 else np.diag([1.0, -1.0, -1.0])
    axis /= sine
    skew = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + sine * skew + (1.0 - cosine) * skew @ skew


def table_field(truth: MagnetometerTruth, positions: np.ndarray, position_index: np.ndarray) -> np.ndarray:
    """The true field ``(k, 3)`` in the sensor frame at each sample's table position."""
    per_position = np.array([up_rotation(up).T @ np.asarray(truth.earth_field) for up in positions])
    return per_position[position_index]


def random_rotations(count: int, rng: np.random.Generator, turn: str = 'tumble') -> np.ndarray:
    """``(count, 3, 3)`` random rotations of one of three kinds.

    Uniform over every orientation (``tumble``), about z only (``yaw``: too few orientations),
    or z kept within 40 degrees of up (``cap``).
    """
    if turn == 'yaw':
        angle = rng.uniform(0.0, 2.0 * math.pi, count)
        cosine, sine = np.cos(angle), np.sin(angle)
        rotations = np.zeros((count, 3, 3))
        rotations[:, 0, 0], rotations[:, 0, 1] = cosine, -sine
        rotations[:, 1, 0], rotations[:, 1, 1] = sine, cosine
        rotations[:, 2, 2] = 1.0
        return rotations
    quaternion = rng.standard_normal((count, 4))[:, [1, 2, 3, 0]]  # drawn as (w, x, y, z)
    if turn == 'cap':
        # Keep turns about an axis near z, of any angle, plus tilts up to 40 degrees.
        tilt = np.radians(40.0) * np.sqrt(rng.uniform(0.0, 1.0, count))
        azimuth = rng.uniform(0.0, 2.0 * math.pi, count)
        yaw = rng.uniform(0.0, 2.0 * math.pi, count)
        axis = np.column_stack([np.cos(azimuth), np.sin(azimuth), np.zeros(count)])
        tilt_q = np.column_stack([axis * np.sin(tilt / 2)[:, None], np.cos(tilt / 2)])
        yaw_q = np.column_stack([np.zeros(count), np.zeros(count), np.sin(yaw / 2), np.cos(yaw / 2)])
        quaternion = quaternion_product(tilt_q, yaw_q)
    elif turn != 'tumble':
        msg = f"turn: expected 'tumble', 'yaw' or 'cap', got {turn!r}"
        raise ScenarioError(msg)
    return quaternion_matrix(quaternion)


def rotation_truth(truth: MagnetometerTruth, *, samples: int = 2000, turn: str = 'tumble',
                   seed: int = 0) -> np.ndarray:
    """``(samples, 3)`` the Earth's field in the sensor frame that :func:`rotation_record` turns through.

    The same random draws as the record of the same ``samples``, ``turn`` and ``seed`` (its first).
    """
    rotations = random_rotations(samples, np.random.default_rng([seed, 18]), turn)
    return np.einsum('kji,j->ki', rotations, np.asarray(truth.earth_field))


def rotation_record(truth: MagnetometerTruth, *, samples: int = 2000, rate_hz: float = 10.0,
                    temperature_celsius: float = 20.0, reference_celsius: float = 20.0, turn: str = 'tumble',
                    seed: int = 0, start_time_s: float = 1_700_000_000.0, frame_id: str = 'tak_imu',
                    accel_noise: float = 0.004, gyro_noise: float = 0.0008, warm_to_celsius: float | None = None,
                    record_temperature: bool = True) -> DriverRecord:
    """A rotation record of the installed unit for the ellipsoid fit.

    The driver's Imu (gravity turned with the unit, ideal otherwise), its temperature and
    ``/imu/mag``. The temperature is constant, or (``warm_to_celsius``) a unit warming up while
    it is turned: from ``temperature_celsius`` towards ``warm_to_celsius`` with a time constant of
    a third of the record (95 % of the way at its end). ``record_temperature`` false: the driver
    publishes none (the field still drifts with the board's temperature).
    """
    rng = np.random.default_rng([seed, 18])
    rotations = random_rotations(samples, rng, turn)
    field = np.einsum('kji,j->ki', rotations, np.asarray(truth.earth_field))
    temperature = np.full(samples, float(temperature_celsius))
    if warm_to_celsius is not None:
        progress = 1.0 - np.exp(-3.0 * np.arange(samples) / max(samples - 1, 1))
        temperature = temperature + (float(warm_to_celsius) - float(temperature_celsius)) * progress
    stamps_s = start_time_s + np.arange(samples) / rate_hz
    mag = truth.measure(field, temperature, reference_celsius, rng, stamps_s)
    gravity = np.einsum('kji,j->ki', rotations, np.array([0.0, 0.0, STANDARD_GRAVITY]))
    stamps = ns_from_seconds(stamps_s)
    orientation, covariance = no_orientation(samples)
    temp_rows = np.arange(0, samples, 5) if record_temperature else np.zeros(0, dtype=np.int64)
    return DriverRecord(stamp_ns=stamps, accel=gravity + rng.standard_normal((samples, 3)) * accel_noise,
                        gyro=rng.standard_normal((samples, 3)) * gyro_noise, orientation=orientation,
                        orientation_covariance=covariance, temp_stamp_ns=stamps[temp_rows],
                        temperature=temperature[temp_rows], frame_id=frame_id, mag_stamp_ns=stamps.copy(), mag=mag,
                        mag_frame_id=frame_id)
