"""A board powered on and left still: the record a flight controller logs for a thermal calibration, and later in use.

PX4's thermal calibration (``Tools/process_sensor_caldata.py``) and ArduPilot's
(``Tools/scripts/tempcal_IMU.py``) take the log of a static board while it warms up: a
cold-soaked board powered in a warm room for 45 minutes. Its die thermometer reads the
room's warming of the board (a first-order lag ``board_tau_s`` behind the ambient) plus the
chip's own heating (``self_heating_celsius`` within ``self_heating_tau_s``). The sensing
elements lag the die thermometer (``element_lag_s``): every offset and scale follows the
element's temperature, not the thermometer's, so a fast warm-up shows a drift curve that is
not the static one. An in-use log is the same unit powered at the ambient, the ambient
moving in slow ramps (``ambient_knots``).

Each sensor is sampled at its own rate and phase (a ULog's ``sensor_accel`` and
``sensor_gyro``), the temperature with the accelerometer. :func:`simulate_powered` gives
the :class:`~tak_thermo_ros.core.records.record.DriverRecord`, the true element temperature and
the true static links (:class:`~tak_thermo_ros.core.link.model.UnitCalibration`, in degrees C).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from tak_thermo_ros.core.link.model import Calibration, InputKind, UnitCalibration
from tak_thermo_ros.core.records.record import DriverRecord, no_orientation
from tak_thermo_ros.core.records.stamps import ns_from_seconds
from tak_thermo_ros.core.simulation.imu import first_order_lag
from tak_thermo_ros.core.simulation.mapping import fields_from_mapping, first_failed
from tak_thermo_ros.core.simulation.truth import AxisTruth, exact_output
from tak_thermo_ros.core.values import STANDARD_GRAVITY
from tak_thermo_ros.errors import ScenarioError

POWERED_ACCEL: tuple[AxisTruth, AxisTruth, AxisTruth] = (
    AxisTruth(1.0, 0.05, (2.0e-4, 1.2e-6, -1.5e-8), (0.0,), noise_counts=7e-3),
    AxisTruth(1.0, -0.03, (-1.5e-4, 1.5e-6, 1.2e-8), (0.0,), noise_counts=7e-3),
    AxisTruth(1.0, 0.08, (2.5e-4, -1.0e-6, 2.0e-8), (0.0,), noise_counts=7e-3),
)
"""A flight controller's MEMS accelerometer (m/s^2): offsets of about 0.02 mg/C with a little curvature."""
POWERED_GYRO: tuple[AxisTruth, AxisTruth, AxisTruth] = (
    AxisTruth(1.0, 2.0e-3, (4.0e-5, 2.0e-7, -3.0e-9), (0.0,), noise_counts=5e-4),
    AxisTruth(1.0, -1.0e-3, (-3.0e-5, 2.5e-7, 4.0e-9), (0.0,), noise_counts=5e-4),
    AxisTruth(1.0, 3.0e-3, (5.0e-5, -1.5e-7, 3.0e-9), (0.0,), noise_counts=5e-4),
)
"""Its gyroscope (rad/s): about 8 deg/h per C, as a good MEMS gyroscope drifts."""


@dataclass(frozen=True)
class PoweredRun:
    """A static board powered for ``duration_s`` (times in seconds, temperatures in degrees C).

    :param start_celsius: the board's temperature at power-on (cold-soaked, or the ambient).
    :param ambient_knots: ``((t, celsius), ...)``: the ambient the board warms towards, linear
        between knots, held after the last.
    :param board_tau_s: the board's first-order lag behind the ambient.
    :param self_heating_celsius: the chip's own warming above the board, reached within ``self_heating_tau_s``.
    :param element_lag_s: the sensing elements' first-order lag behind the die thermometer.
    :param accel_rate_hz: accelerometer samples per second; ``gyro_rate_hz`` the gyroscope's,
        ``gyro_phase_s`` its first sample's delay after the accelerometer's.
    :param reference_celsius: the temperature the links' polynomials are counted from.
    :param up: the direction of 'up' in the sensor frame (the board's attitude).
    """

    duration_s: float = 2700.0
    start_celsius: float = 2.0
    ambient_knots: tuple[tuple[float, float], ...] = ((0.0, 25.0),)
    board_tau_s: float = 700.0
    self_heating_celsius: float = 8.0
    self_heating_tau_s: float = 40.0
    element_lag_s: float = 150.0
    accel_rate_hz: float = 10.0
    gyro_rate_hz: float = 10.0
    gyro_phase_s: float = 0.037
    temperature_quantum: float = 1.0 / 128.0
    reference_celsius: float = 25.0
    up: tuple[float, float, float] = (0.0, 0.0, -1.0)
    gravity: float = STANDARD_GRAVITY
    accel_unit: tuple[AxisTruth, AxisTruth, AxisTruth] = POWERED_ACCEL
    gyro_unit: tuple[AxisTruth, AxisTruth, AxisTruth] = POWERED_GYRO
    seed: int = 0
    start_time_s: float = 30.0
    frame_id: str = 'imu0'

    def __post_init__(self) -> None:
        checks = ((self.duration_s > 0, 'duration_s', 'must be > 0'),
                  (self.accel_rate_hz > 0 and self.gyro_rate_hz > 0, 'accel_rate_hz, gyro_rate_hz', 'must be > 0'),
                  (len(self.ambient_knots) >= 1, 'ambient_knots', 'needs at least one (t, celsius)'),
                  (min(self.board_tau_s, self.self_heating_tau_s, self.element_lag_s) >= 0, 'lags', 'must be >= 0'),
                  (self.temperature_quantum > 0, 'temperature_quantum', 'must be > 0'))
        first_failed(checks)

    def die_celsius(self, time_s: np.ndarray) -> np.ndarray:
        """The die thermometer's true temperature at ``time_s`` (seconds since power-on)."""
        knots = np.asarray(self.ambient_knots, dtype=float).reshape(-1, 2)
        ambient = np.interp(time_s, knots[:, 0], knots[:, 1])
        board = first_order_lag(ambient, time_s, self.board_tau_s, self.start_celsius)
        heating = self.self_heating_celsius * (1.0 - np.exp(-time_s / max(self.self_heating_tau_s, 1e-9)))
        return board + heating

    def truth(self) -> UnitCalibration:
        """The true static links (degrees C from ``reference_celsius``), over the run's element temperatures."""
        grid = np.arange(0.0, self.duration_s, 1.0)
        element = first_order_lag(self.die_celsius(grid), grid, self.element_lag_s, self.die_celsius(grid[:1])[0])
        low, high = float(element.min()), float(element.max())

        def link(unit: tuple[AxisTruth, ...]) -> Calibration:
            span = (low - self.reference_celsius, high - self.reference_celsius)
            axes = tuple(a.link(span) for a in unit)
            return Calibration(temp_code_ref=self.reference_celsius, temp_code_min=low, temp_code_max=high,
                               axes=axes)  # type: ignore[arg-type]

        return UnitCalibration(InputKind.IMU, link(self.accel_unit), link(self.gyro_unit))


def powered_from_mapping(raw: Any) -> PoweredRun:
    """A :class:`PoweredRun` from a scenario's ``powered`` mapping (``ambient_knots`` a list of ``[t, celsius]``).

    Every key optional; ``accel_unit`` and ``gyro_unit`` are not set from a mapping.

    :raises ScenarioError: naming the key (``powered.KEY: ...``).
    """
    def read(key: str, value: Any) -> Any:
        try:
            if key == 'ambient_knots':
                return tuple((float(t), float(c)) for t, c in value)
            if key == 'up':
                return tuple(float(v) for v in value)
            if key == 'frame_id':
                return str(value)
            if key == 'seed':
                return int(value)
            return float(value)
        except (TypeError, ValueError):
            msg = f'powered.{key}: {value!r} is not what it takes'
            raise ScenarioError(msg) from None

    names = ', '.join(f.name for f in fields(PoweredRun))
    values = fields_from_mapping(raw, PoweredRun, 'powered.', read, sort_known=True,
                                 exclude=('accel_unit', 'gyro_unit'),
                                 not_a_mapping=f'powered: expected a mapping of {names}')
    try:
        return PoweredRun(**values)
    except ScenarioError as err:
        msg = f'powered.{err}'
        raise ScenarioError(msg) from None


@dataclass(frozen=True)
class PoweredRecord:
    """A simulated powered run: what the log holds, and the hidden truth.

    :param record: the driver record, each sensor on its own stamps.
    :param element_celsius: per sensor, the true element temperature at each of its samples.
    :param specific_force: ``(3,)`` the true specific force in the sensor frame, m/s^2.
    :param noise: per sensor, the white noise per sample, per axis.
    """

    run: PoweredRun
    record: DriverRecord
    element_celsius: dict[str, np.ndarray] = field(default_factory=dict)
    specific_force: np.ndarray = field(default_factory=lambda: np.zeros(3))
    noise: dict[str, np.ndarray] = field(default_factory=dict)

    def true_offsets(self, sensor: str) -> np.ndarray:
        """``(k, 3)``: what the sensor gives without noise minus its true input, at each of its samples."""
        unit = self.run.accel_unit if sensor == 'accel' else self.run.gyro_unit
        force = self.specific_force if sensor == 'accel' else np.zeros(3)
        return _exact(unit, force, self.element_celsius[sensor] - self.run.reference_celsius) - force


def _exact(unit: tuple[AxisTruth, ...], inputs: np.ndarray, n: np.ndarray) -> np.ndarray:
    """``(k, 3)``: the noise-free output for a constant input ``(3,)`` at element temperatures ``n``."""
    return exact_output(unit, np.broadcast_to(inputs, (len(n), 3)), n)


def simulate_powered(run: PoweredRun) -> PoweredRecord:
    """Simulate one powered run (deterministic for a given seed)."""
    rng = np.random.default_rng(run.seed)
    up = np.asarray(run.up, dtype=float)
    force = run.gravity * up / np.linalg.norm(up)
    stamps, element, values, noise = {}, {}, {}, {}
    for sensor, rate, phase, unit, inputs in (('accel', run.accel_rate_hz, 0.0, run.accel_unit, force),
                                              ('gyro', run.gyro_rate_hz, run.gyro_phase_s, run.gyro_unit,
                                               np.zeros(3))):
        time_s = phase + np.arange(int(math.floor((run.duration_s - phase) * rate)) + 1) / rate
        die = run.die_celsius(time_s)
        element[sensor] = first_order_lag(die, time_s, run.element_lag_s, float(run.die_celsius(np.zeros(1))[0]))
        exact = _exact(unit, inputs, element[sensor] - run.reference_celsius)
        noise[sensor] = np.array([a.noise_counts for a in unit])
        values[sensor] = exact + rng.standard_normal(exact.shape) * noise[sensor]
        stamps[sensor] = ns_from_seconds(run.start_time_s + time_s)
        if sensor == 'accel':
            temperature = np.round(die / run.temperature_quantum) * run.temperature_quantum
    accel_stamps, gyro_stamps = stamps['accel'], stamps['gyro']
    messages = np.union1d(accel_stamps, gyro_stamps)
    orientation, covariance = no_orientation(len(messages))
    record = DriverRecord(stamp_ns=messages, accel=values['accel'], gyro=values['gyro'], orientation=orientation,
                          orientation_covariance=covariance, temp_stamp_ns=accel_stamps.copy(),
                          temperature=temperature, frame_id=run.frame_id, accel_stamp_ns=accel_stamps,
                          gyro_stamp_ns=gyro_stamps)
    return PoweredRecord(run=run, record=record, element_celsius=element, specific_force=force, noise=noise)
