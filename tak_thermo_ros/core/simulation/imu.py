"""Thermal-chamber simulator: the paper's protocol, seeded and deterministic.

The chamber holds plateaus joined by ramps; the board (ADC and temperature sensor) follows
the chamber through a first-order lag; the temperature code is a rounded affine function of
board temperature; a turntable cycles through the six +/-g positions and tilted ones, so
every axis also sees 0 g and mixed inputs; the channel codes follow the paper's model with
white noise, rounded to 16-bit two's complement with saturation.

Effects beyond the paper's model can be hidden in a run (all off by default): ``effects`` maps
library effect names (``tak_thermo_ros.core.effects``) to their true parameters, and the SAME
effect classes that fit and correct add their forward contribution, driven by the true
(unrounded) temperature code and the sample stamps (power-on = the first sample).
``supply_voltage_drift`` adds an offset that follows an unobserved, slowly varying supply
voltage (not in the bag, not correlated with temperature): the case no library effect explains.
``record_supply`` records that voltage on a topic (then it is observed: ``aux:TOPIC``).

Every number lives in a :class:`Scenario`, loadable from YAML (all keys optional).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import Any, Mapping

from tak_thermo_ros.core.effects import resolve_effect
from tak_thermo_ros.core.effects.base import Effect

import numpy as np

from tak_thermo_ros.core.link.model import AXES, AxisModel, Calibration, InputKind, UnitCalibration
from tak_thermo_ros.core.noise.model import NoiseModel, floor_tau, model_floor_tau
from tak_thermo_ros.core.simulation.noise import bias_wander, filtered_white
from tak_thermo_ros.core.records.record import (
    COUNTS_MAX,
    COUNTS_MIN,
    ChannelRecord,
    DriverRecord,
    hold_last_index,
    no_orientation,
    ns_from_seconds,
    seconds_from_ns,
)
from tak_thermo_ros.core.simulation.motion import HandheldMotion, Trajectory, hand_trajectory, motion_from_mapping
from tak_thermo_ros.core.simulation.magnetometer import (
    MagnetometerTruth,
    rotation_record,
    table_field,
    truth_from_mapping,
)
from tak_thermo_ros.core.values import STANDARD_GRAVITY
from tak_thermo_ros.errors import CalibrationError, FitError, ScenarioError

_SQRT1_2 = math.sqrt(0.5)
_SQRT1_3 = math.sqrt(1.0 / 3.0)
DEFAULT_POSITIONS: tuple[tuple[float, float, float], ...] = (
    (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0),
    (0.0, 1.0, 0.0), (0.0, -1.0, 0.0),
    (0.0, 0.0, 1.0), (0.0, 0.0, -1.0),
    (_SQRT1_2, _SQRT1_2, 0.0), (0.0, -_SQRT1_2, _SQRT1_2),
    (-_SQRT1_2, 0.0, -_SQRT1_2), (_SQRT1_3, _SQRT1_3, _SQRT1_3),
)
"""Turntable positions: the direction of 'up' in the sensor frame (specific force / g)."""

SUPPLY_AXIS_WEIGHTS: tuple[float, float, float] = (1.0, -0.7, 0.5)
"""Sensitivity of axes x, y, z to the unobserved supply voltage, relative to x."""
SUPPLY_PERIODS_HOURS: tuple[float, float] = (0.4, 2.0)
"""The supply voltage is three sinusoids with periods drawn from this range and random phases."""
SUPPLY_NOMINAL_VOLTS = 12.0
SUPPLY_VOLTS_RMS = 0.2
"""A recorded supply voltage is ``SUPPLY_NOMINAL_VOLTS + SUPPLY_VOLTS_RMS * supply_voltage()``."""
SUPPLY_TYPES = ('battery_state', 'float64')

PROFILES: dict[str, dict[str, Any]] = {
    'paper': {},
    'cycle': {'plateaus_celsius': (5.0, 35.0, 10.0, 30.0, 20.0), 'ramp_celsius_per_minute': 0.5},
    'fast_ramps': {'plateaus_celsius': (5.0, 35.0, 5.0, 35.0), 'ramp_celsius_per_minute': 2.0},
}
"""Scenario overrides for temperature profiles: ``replace(Scenario(), **PROFILES['cycle'])``.

``paper``: the paper's staircase (one cooling ramp, then heating only). ``cycle``: alternating
heating and cooling onto plateaus, visiting temperatures from both sides (tells hysteresis,
which persists on plateaus, from lag, which decays). ``fast_ramps``: full-range heating and
cooling ramps at 2 C/min (a lag's loop opening grows with the ramp rate).
"""


@dataclass(frozen=True)
class AxisTruth:
    """The true channel of one axis (raw polynomial coefficients in ``n = N_t - N_t,ref``).

    :param scale: ``K0``, counts per m/s^2 per cycle.
    :param offset: ``dNs0``, counts.
    :param offset_coeffs: ``(c1, ...)``: ``dNs(n) - dNs0 = c1 n + c2 n^2 + ...``, counts.
    :param scale_coeffs: ``(a1, ...)`` of ``F_c(n) = 1 + a1 n + ...``.
    :param noise_counts: standard deviation of the white noise, counts (per sample: the white
        noise density is ``noise_counts / sqrt(sample_rate_hz)``).
    :param bias_instability: the flicker bias ``B``, counts (driver: m/s^2 or rad/s), whose Allan
        deviation is flat at ``0.664 B`` over two decades around ``bias_instability_tau``
        (:mod:`tak_thermo_ros.core.simulation.noise`). 0 = off.
    :param bias_instability_tau: s, the middle of that flat band.
    :param random_walk: the bias's random walk ``K``, counts*sqrt(Hz) (Allan variance ``K^2 tau / 3``). 0 = off.
    :param gauss_markov: standard deviations of Gauss-Markov processes in the bias (counts; driver
        units), one per process; empty = none.
    :param gauss_markov_time: their correlation times, s (as many).
    :param filter_time_constant: s, a driver's first-order low-pass on the white noise, run at
        ``Scenario.decimation`` times the output rate before every ``decimation``-th sample is
        kept (the density ``noise_counts / sqrt(rate)`` is the long-term one). 0 = none.
    :param resolution: a driver output's quantum (driver units): the output is rounded to whole
        multiples of it. 0 = none (a counts run is rounded to whole codes anyway).
    """

    scale: float
    offset: float
    offset_coeffs: tuple[float, ...]
    scale_coeffs: tuple[float, ...]
    noise_counts: float = 1.5
    bias_instability: float = 0.0
    bias_instability_tau: float = 100.0
    random_walk: float = 0.0
    gauss_markov: tuple[float, ...] = ()
    gauss_markov_time: tuple[float, ...] = ()
    filter_time_constant: float = 0.0
    resolution: float = 0.0

    def link(self, code_offset_range: tuple[float, float], residual_rms: float | None = None) -> AxisModel:
        """This axis as a link's :class:`AxisModel`, ``F_s`` normalised over ``code_offset_range``."""
        return AxisModel.from_polynomials(scale=self.scale, offset=self.offset, offset_coeffs=self.offset_coeffs,
                                          scale_coeffs=self.scale_coeffs, code_offset_range=code_offset_range,
                                          residual_rms=residual_rms)


def exact_output(unit: tuple[AxisTruth, ...], inputs: np.ndarray, n: np.ndarray) -> np.ndarray:
    """``(k, 3)``: the paper's model without noise for inputs ``(k, 3)`` at ``n = T - T_ref`` ``(k,)``."""
    return np.column_stack([a.link((-1.0, 1.0)).forward(inputs[:, i], n) for i, a in enumerate(unit)])


DEFAULT_UNIT: tuple[AxisTruth, AxisTruth, AxisTruth] = (
    AxisTruth(255.1, -12.3, (0.05, 1.5e-5, 2.0e-8), (2.0e-6, 1.0e-9)),
    AxisTruth(254.3, 8.7, (-0.04, 2.0e-5, -1.0e-8), (-1.5e-6, 2.0e-9)),
    AxisTruth(256.0, 3.1, (0.03, -1.0e-5, 3.0e-8), (1.0e-6, -1.0e-9)),
)

DEFAULT_DRIVER_ACCEL: tuple[AxisTruth, AxisTruth, AxisTruth] = (
    AxisTruth(1.0021, 0.051, (2.0e-3, 1.2e-5, 1.0e-7), (1.1e-4, 1.5e-6), noise_counts=0.004),
    AxisTruth(0.9983, -0.034, (-1.6e-3, 1.6e-5, -8.0e-8), (-0.9e-4, 2.0e-6), noise_counts=0.004),
    AxisTruth(1.0012, 0.082, (1.2e-3, -0.8e-5, 2.4e-7), (0.6e-4, -1.0e-6), noise_counts=0.005),
)
"""A MEMS accelerometer as its driver reports it: m/s^2 (factory scale about 1), drift per degree C."""

DEFAULT_DRIVER_GYRO: tuple[AxisTruth, AxisTruth, AxisTruth] = (
    AxisTruth(1.0013, 0.0021, (3.0e-4, 2.0e-6, -3.0e-8), (5.0e-5, 1.0e-7), noise_counts=0.0008),
    AxisTruth(0.9991, -0.0013, (-2.2e-4, 3.0e-6, 2.0e-8), (-4.0e-5, 2.0e-7), noise_counts=0.0008),
    AxisTruth(1.0024, 0.0030, (1.5e-4, -2.5e-6, 4.0e-8), (3.0e-5, -1.5e-7), noise_counts=0.0009),
)
"""A MEMS gyroscope as its driver reports it: rad/s; bias drift of about 0.4 deg/s over 25 C."""

RATE_TABLE_POSITIONS: tuple[tuple[float, float, float], ...] = tuple(
    tuple(sign * (1.0 if j == i else 0.0) for j in range(3))  # type: ignore[misc]
    for i in range(3) for sign in (1.0, -1.0) for _ in range(3))
RATE_TABLE_RATES: tuple[float, ...] = (0.0, 1.0, -1.0) * 6
"""A rate table: each axis up and down, resting then turning at +-1 rad/s about the vertical
(the axis that is up), so every gyroscope axis sees three rates and the accelerometer +-g."""


@dataclass(frozen=True)
class Scenario:
    """A simulated chamber run. Times in seconds, temperatures in Celsius.

    :param sample_rate_hz: counts messages per second (one per conversion cycle).
    :param temp_code_every: a temperature-code message every this many counts messages.
    :param start_celsius: chamber and board temperature at power-on.
    :param plateaus_celsius: chamber plateaus, in order.
    :param plateau_hours: duration of each plateau.
    :param ramp_celsius_per_minute: chamber ramp rate between plateaus.
    :param board_lag_s: time constant of the board's first-order lag behind the chamber.
    :param temp_code_ref: temperature code at ``reference_celsius``.
    :param codes_per_celsius: temperature-sensor gain.
    :param reference_celsius: normal conditions.
    :param dwell_s: time the turntable holds each position.
    :param positions: unit 'up' vectors in the sensor frame.
    :param gravity: local gravity, m/s^2.
    :param unit: the true channels of axes x, y, z.
    :param seed: random seed of the noise.
    :param frame_id: frame of the counts messages.
    :param start_time_s: stamp of the first sample, seconds since the epoch.
    :param nominal_scale: the data-sheet ``K0`` per axis recorded in the bag, counts per m/s^2.
    :param effects: hidden effects, effect name -> its true parameters (a parameter left out
        takes its default; amplitudes default to 0), e.g.
        ``{'thermal_lag': {'tau_s': 1800.0, 'slope_z': 0.03}}``. Off (empty) by default.
    :param supply_voltage_drift: RMS on axis x, counts, of an offset driven by an unobserved
        supply voltage (three slow sinusoids, periods 0.4-2 h, random phases from the seed;
        axes y and z see it with weights -0.7 and 0.5). 0 = off.
    :param output: ``'counts'`` (the paper's bag contract) or ``'imu'`` (a driver bag:
        ``sensor_msgs/msg/Imu`` in m/s^2 and rad/s, the temperature in degrees C).
    :param accel_unit: with ``output: imu``, the accelerometer in driver units (polynomials in
        degrees C from ``reference_celsius``; ``noise_counts`` in m/s^2).
    :param gyro_unit: with ``output: imu``, the gyroscope (rad/s).
    :param gyro_effects: hidden effects on the gyroscope, as ``effects`` (which, with
        ``output: imu``, act on the accelerometer).
    :param table_rates: rotation rate about the up direction at each position, rad/s (empty:
        a table that only tilts); the angular-rate reference is ``rate * position``.
    :param temperature_resolution_celsius: the driver's temperature quantum, degrees C.
    :param record_references: with ``output: imu``, write the reference topics (a calibration
        run on a table); ``false``: a bag as ``ros2 bag record`` of the driver alone gives.
    :param record_supply: topic on which the supply voltage behind ``supply_voltage_drift`` is
        recorded (volts, ``12 + 0.2 * signal``, with each temperature message), or ``''`` (default:
        not recorded, the drift stays unexplained); the run's signal ``aux:TOPIC``.
    :param record_supply_type: its message type: ``battery_state`` (``sensor_msgs/BatteryState``,
        the voltage in float32, header stamp) or ``float64`` (``std_msgs/Float64``, bag time).
    :param rotation: with ``output: imu`` and a ``magnetometer``, ``tumble`` (every orientation),
        ``yaw`` (about z only) or ``cap`` (within 40 deg of z up) writes instead a rotation record
        for the iron (2000 samples at ``sample_rate_hz``, at ``start_celsius``); ``''``: a chamber run.
    :param warm_to_celsius: with ``rotation``, the unit warms while it is turned, from
        ``start_celsius`` towards this (a time constant of a third of the record); ``None``: constant.
    :param record_temperature: with ``output: imu``, publish the temperature on ``/imu/temperature``;
        ``false``: a driver that publishes none (the sensors still drift with the board's temperature).
    :param decimation: the driver's internal rate over ``sample_rate_hz``: an axis's
        ``filter_time_constant`` runs at that rate before the samples are kept (1: at the output rate).
    :param magnetometer: with ``output: imu``, a magnetometer on ``/imu/mag``
        (:mod:`tak_thermo_ros.core.simulation.magnetometer`; YAML: a mapping, ``{}`` for the
        defaults), or ``None`` (default: none).
    :param handheld: with ``output: imu``, a record of a unit turned by hand through still
        orientations instead of a table run (:mod:`tak_thermo_ros.core.simulation.motion`; YAML: a
        mapping, ``{}`` for the defaults): no reference topics; ``None`` (default): a table run.
    """

    sample_rate_hz: float = 1.0
    temp_code_every: int = 5
    start_celsius: float = 20.0
    plateaus_celsius: tuple[float, ...] = (5.0, 15.0, 20.0, 30.0, 35.0)
    plateau_hours: float = 3.0
    ramp_celsius_per_minute: float = 0.5
    board_lag_s: float = 600.0
    temp_code_ref: float = 8200.0
    codes_per_celsius: float = 40.0
    reference_celsius: float = 20.0
    dwell_s: float = 60.0
    positions: tuple[tuple[float, float, float], ...] = DEFAULT_POSITIONS
    gravity: float = STANDARD_GRAVITY
    unit: tuple[AxisTruth, AxisTruth, AxisTruth] = DEFAULT_UNIT
    seed: int = 0
    frame_id: str = 'tak_imu'
    start_time_s: float = 1_700_000_000.0
    nominal_scale: tuple[float, float, float] = (255.0, 255.0, 255.0)
    effects: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    supply_voltage_drift: float = 0.0
    output: str = 'counts'
    accel_unit: tuple[AxisTruth, AxisTruth, AxisTruth] = DEFAULT_DRIVER_ACCEL
    gyro_unit: tuple[AxisTruth, AxisTruth, AxisTruth] = DEFAULT_DRIVER_GYRO
    gyro_effects: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    table_rates: tuple[float, ...] = ()
    temperature_resolution_celsius: float = 1.0 / 256.0
    record_references: bool = True
    record_supply: str = ''
    record_supply_type: str = 'battery_state'
    magnetometer: MagnetometerTruth | None = None
    rotation: str = ''
    warm_to_celsius: float | None = None
    record_temperature: bool = True
    decimation: int = 1
    handheld: HandheldMotion | None = None

    def __post_init__(self) -> None:
        for key in ('effects', 'gyro_effects'):
            value = getattr(self, key)
            if not isinstance(value, Mapping):
                msg = f'{key}: expected a mapping of effect names to their parameters'
                raise ScenarioError(msg)
            object.__setattr__(self, key, {str(name): dict(values) if isinstance(values, Mapping) else values
                                           for name, values in value.items()})
        self.effect_instances()
        self.effect_instances('gyro_effects')
        if self.output not in ('counts', 'imu'):
            msg = f"output: expected 'counts' or 'imu', got {self.output!r}"
            raise ScenarioError(msg)
        if self.rotation and (self.magnetometer is None or self.rotation not in ('tumble', 'yaw', 'cap')):
            msg = f"rotation: expected 'tumble', 'yaw' or 'cap' with a magnetometer, got {self.rotation!r}"
            raise ScenarioError(msg)
        if self.handheld is not None and (self.output != 'imu' or self.rotation):
            msg = 'handheld: needs output: imu and no rotation (a driver\'s record of a unit turned by hand)'
            raise ScenarioError(msg)
        if self.magnetometer is not None and self.output != 'imu':
            msg = 'magnetometer: needs output: imu (a driver bag; the paper\'s codes have no magnetometer)'
            raise ScenarioError(msg)
        if self.table_rates and len(self.table_rates) != len(self.positions):
            msg = f'table_rates: expected one rate per position ({len(self.positions)}), got {len(self.table_rates)}'
            raise ScenarioError(msg)
        if self.record_supply and not (self.record_supply.startswith('/') and ':' not in self.record_supply):
            msg = f"record_supply: expected a topic name such as '/power/battery_state', got {self.record_supply!r}"
            raise ScenarioError(msg)
        if self.record_supply_type not in SUPPLY_TYPES:
            msg = f'record_supply_type: expected one of {", ".join(SUPPLY_TYPES)}, got {self.record_supply_type!r}'
            raise ScenarioError(msg)
        if not (math.isfinite(self.temperature_resolution_celsius) and self.temperature_resolution_celsius > 0):
            msg = 'temperature_resolution_celsius: must be a finite number > 0'
            raise ScenarioError(msg)
        checks = (
            (self.sample_rate_hz > 0, 'sample_rate_hz', 'must be > 0'),
            (self.temp_code_every >= 1, 'temp_code_every', 'must be >= 1'),
            (len(self.plateaus_celsius) >= 1, 'plateaus_celsius', 'needs at least one plateau'),
            (self.plateau_hours > 0, 'plateau_hours', 'must be > 0'),
            (self.ramp_celsius_per_minute > 0, 'ramp_celsius_per_minute', 'must be > 0'),
            (self.board_lag_s >= 0, 'board_lag_s', 'must be >= 0'),
            (self.codes_per_celsius != 0, 'codes_per_celsius', 'must not be 0'),
            (self.dwell_s > 0, 'dwell_s', 'must be > 0'),
            (len(self.positions) >= 1, 'positions', 'needs at least one position'),
            (len(self.nominal_scale) == 3 and all(k > 0 for k in self.nominal_scale),
             'nominal_scale', 'needs three values > 0'),
            (all(axis.scale > 0 for axis in self.unit), 'unit.*.scale', 'must be > 0'),
            (all(axis.noise_counts >= 0 for axis in self.unit), 'unit.*.noise_counts', 'must be >= 0'),
            *((all(math.isfinite(getattr(a, key)) and getattr(a, key) >= 0 for a in unit), f'{name}.*.{key}',
               'must be a finite number >= 0')
              for name, unit in (('unit', self.unit), ('accel_unit', self.accel_unit), ('gyro_unit', self.gyro_unit))
              for key in ('bias_instability', 'random_walk')),
            *((all(math.isfinite(a.bias_instability_tau) and a.bias_instability_tau > 0 for a in unit),
               f'{name}.*.bias_instability_tau', 'must be a finite number > 0 (s)')
              for name, unit in (('unit', self.unit), ('accel_unit', self.accel_unit), ('gyro_unit', self.gyro_unit))),
            (math.isfinite(self.supply_voltage_drift) and self.supply_voltage_drift >= 0,
             'supply_voltage_drift', 'must be a finite number >= 0 (counts)'),
            (self.decimation >= 1, 'decimation', 'must be an integer >= 1'),
            *((all(math.isfinite(getattr(a, key)) and getattr(a, key) >= 0 for a in unit), f'{name}.*.{key}',
               'must be a finite number >= 0')
              for name, unit in (('unit', self.unit), ('accel_unit', self.accel_unit), ('gyro_unit', self.gyro_unit))
              for key in ('filter_time_constant', 'resolution')),
            *((all(len(a.gauss_markov) == len(a.gauss_markov_time) and all(v >= 0 for v in a.gauss_markov)
                   and all(math.isfinite(t) and t > 0 for t in a.gauss_markov_time) for a in unit),
               f'{name}.*.gauss_markov', 'needs as many standard deviations >= 0 as correlation times > 0 '
               '(gauss_markov_time)')
              for name, unit in (('unit', self.unit), ('accel_unit', self.accel_unit), ('gyro_unit', self.gyro_unit))),
        )
        for ok, key, problem in checks:
            if not ok:
                msg = f'{key}: {problem}'
                raise ScenarioError(msg)

    def effect_instances(self, key: str = 'effects') -> tuple[Effect, ...]:
        """The hidden effects (``effects`` or ``gyro_effects``) as effect objects with their true parameters.

        :raises ScenarioError: naming ``effects.<name>`` or ``effects.<name>.<parameter>``.
        """
        instances = []
        for name, values in getattr(self, key).items():
            if not isinstance(values, Mapping):
                msg = f'{key}.{name}: expected a mapping of parameter names to numbers'
                raise ScenarioError(msg)
            try:
                cls = resolve_effect(name)
            except FitError as err:
                msg = f'{key}.{name}: {err}'
                raise ScenarioError(msg) from None
            try:
                instances.append(cls.from_values(values, key=f'{key}.{name}', complete=False))
            except CalibrationError as err:
                raise ScenarioError(str(err)) from None
        return tuple(instances)

    def noise_truth(self, sensor: str = 'accel') -> NoiseModel:
        """The simulated noise of a sensor as a :class:`~tak_thermo_ros.core.noise.model.NoiseModel`.

        ``accel`` is ``unit`` on a counts run (counts), ``accel_unit`` on a driver run (m/s^2);
        ``gyro`` is ``gyro_unit`` (rad/s). ``source='file'``: the truth, as a user's file gives it.
        """
        unit = self.sensor_unit(sensor)
        rate = self.sample_rate_hz
        filtered = [a.noise_counts ** 2 / rate for a in unit]
        # Rounding to the resolution adds white noise of variance q^2 / 12 per sample (the noise
        # spans several quanta), after the filter.
        rounding = [(a.resolution ** 2 / 12.0 if self.output == 'imu' else 0.0) / rate for a in unit]
        white = tuple(math.sqrt(f + q) for f, q in zip(filtered, rounding))
        bias = tuple(a.bias_instability for a in unit)
        walk = tuple(a.random_walk for a in unit)
        share = tuple(f / (f + q) if a.filter_time_constant > 0.0 and f > 0.0 else 0.0
                      for a, f, q in zip(unit, filtered, rounding))
        slots = max(len(a.gauss_markov) for a in unit)
        sigmas = tuple(tuple(a.gauss_markov[i] if i < len(a.gauss_markov) else 0.0 for a in unit)
                       for i in range(slots))
        times = tuple(tuple(a.gauss_markov_time[i] if i < len(a.gauss_markov) else 1.0 for a in unit)
                      for i in range(slots))
        model = NoiseModel(white_noise_density=white, bias_instability=bias, random_walk=walk,  # type: ignore[arg-type]
                           bias_instability_tau=floor_tau(white, bias, walk),  # type: ignore[arg-type]
                           update_rate=rate, source='file', gauss_markov=sigmas,  # type: ignore[arg-type]
                           gauss_markov_time=times, filter_share=share,  # type: ignore[arg-type]
                           filter_time_constant=tuple(a.filter_time_constant for a in unit))  # type: ignore[arg-type]
        if model.has_extra_terms():
            return replace(model, bias_instability_tau=model_floor_tau(model))
        return model

    def sensor_unit(self, sensor: str) -> tuple[AxisTruth, ...]:
        """The true axes of ``accel`` (``unit`` on a counts run, ``accel_unit`` on a driver run) or ``gyro``."""
        if sensor == 'gyro':
            return self.gyro_unit
        if sensor == 'accel':
            return self.accel_unit if self.output == 'imu' else self.unit
        msg = f'sensor: expected accel or gyro, got {sensor!r}'
        raise ScenarioError(msg)

    def duration_s(self) -> float:
        """Total length of the run."""
        temps = (self.start_celsius, *self.plateaus_celsius)
        ramps = sum(abs(b - a) for a, b in zip(temps[:-1], temps[1:])) / self.ramp_celsius_per_minute * 60.0
        return ramps + len(self.plateaus_celsius) * self.plateau_hours * 3600.0

    def truth(self) -> Calibration:
        """The true correction link, normalised over the codes this run can reach."""
        low, high = min(self.start_celsius, *self.plateaus_celsius), max(self.start_celsius, *self.plateaus_celsius)
        codes = sorted(self.temp_code_ref + self.codes_per_celsius * (t - self.reference_celsius) for t in (low, high))
        n_range = (codes[0] - self.temp_code_ref, codes[1] - self.temp_code_ref)
        axes = tuple(a.link(n_range, a.noise_counts) for a in self.unit)
        return Calibration(temp_code_ref=self.temp_code_ref, temp_code_min=codes[0],
                           temp_code_max=codes[1], axes=axes,  # type: ignore[arg-type]
                           effects=self.effect_instances())

    def temperature_span(self) -> tuple[float, float]:
        """The lowest and highest temperature the run can reach, degrees C (or its codes' Celsius)."""
        ends = (self.start_celsius, *self.plateaus_celsius)
        if self.handheld is not None and self.handheld.temperature == 'warmup':
            ends = (self.start_celsius, self.handheld.final_celsius)
        low, high = min(ends), max(ends)
        return (low, high) if high > low else (low - 0.5, high + 0.5)

    def driver_truth(self) -> UnitCalibration:
        """The true links of a driver-output run, in degrees C from ``reference_celsius``."""
        low, high = self.temperature_span()
        n_range = (low - self.reference_celsius, high - self.reference_celsius)

        def link(unit: tuple[AxisTruth, ...], key: str) -> Calibration:
            axes = tuple(a.link(n_range, a.noise_counts) for a in unit)
            return Calibration(temp_code_ref=self.reference_celsius, temp_code_min=low, temp_code_max=high,
                               axes=axes, effects=self.effect_instances(key))  # type: ignore[arg-type]

        mag = None if self.magnetometer is None else self.magnetometer.correction(self.reference_celsius, low, high)
        return UnitCalibration(InputKind.IMU, link(self.accel_unit, 'effects'), link(self.gyro_unit, 'gyro_effects'),
                               mag)


@dataclass(frozen=True)
class SimulatedRun:
    """A simulated run: the bag contents plus the hidden truth.

    :param record: what the bag holds.
    :param board_celsius: ``(k,)`` true board temperature at each counts sample.
    :param chamber_celsius: ``(k,)`` chamber temperature at each counts sample.
    :param true_temp_code: ``(k,)`` unrounded temperature code at each counts sample.
    :param specific_force: ``(k, 3)`` true input at each counts sample.
    :param truth: the true calibration (counts output; the accelerometer's with ``output: imu``).
    :param driver: with ``output: imu``, what the driver bag holds (``record`` is then its
        accelerometer channel).
    :param angular_rate: ``(k, 3)`` true angular rate, rad/s (``output: imu``).
    :param unit_truth: with ``output: imu``, the true links of both sensors.
    :param trajectory: with ``handheld``, the true motion (rests, turns, poses).
    """

    record: ChannelRecord
    board_celsius: np.ndarray
    chamber_celsius: np.ndarray
    true_temp_code: np.ndarray
    specific_force: np.ndarray
    truth: Calibration
    scenario: Scenario = field(repr=False, default_factory=Scenario)
    driver: DriverRecord | None = None
    angular_rate: np.ndarray | None = None
    unit_truth: UnitCalibration | None = None
    trajectory: Trajectory | None = None


def chamber_profile(scenario: Scenario, time_s: np.ndarray) -> np.ndarray:
    """Chamber temperature: ramps at the set rate between plateaus, plateaus held."""
    knots_t = [0.0]
    knots_c = [scenario.start_celsius]
    for plateau in scenario.plateaus_celsius:
        ramp = abs(plateau - knots_c[-1]) / scenario.ramp_celsius_per_minute * 60.0
        knots_t += [knots_t[-1] + ramp, knots_t[-1] + ramp + scenario.plateau_hours * 3600.0]
        knots_c += [plateau, plateau]
    return np.interp(time_s, knots_t, knots_c)


def first_order_lag(signal: np.ndarray, time_s: np.ndarray, tau_s: float, initial: float) -> np.ndarray:
    """Exact discretisation of ``tau dy/dt = u - y`` for a piecewise-constant input."""
    if tau_s <= 0.0:
        return signal.astype(float).copy()
    steps = np.diff(time_s, prepend=time_s[0])
    out = np.empty(len(signal))
    value = initial
    decay = np.exp(-steps / tau_s)
    for k in range(len(signal)):
        value = signal[k] + (value - signal[k]) * decay[k]
        out[k] = value
    return out


def simulate(scenario: Scenario | None = None) -> SimulatedRun:
    """Simulate one run of the scenario (deterministic for a given seed)."""
    scenario = scenario or Scenario()
    if scenario.output == 'imu':
        run = _simulate_driver(scenario)
        if scenario.record_temperature:
            return run
        driver = replace(run.driver, temp_stamp_ns=np.zeros(0, dtype=np.int64), temperature=np.zeros(0))
        return replace(run, driver=driver, record=driver.channel('accel'))
    rng = np.random.default_rng(scenario.seed)
    count = int(math.floor(scenario.duration_s() * scenario.sample_rate_hz)) + 1
    time_s = np.arange(count) / scenario.sample_rate_hz
    chamber = chamber_profile(scenario, time_s)
    board = first_order_lag(chamber, time_s, scenario.board_lag_s, scenario.start_celsius)
    true_code = scenario.temp_code_ref + scenario.codes_per_celsius * (board - scenario.reference_celsius)

    positions = np.asarray(scenario.positions, dtype=float)
    position_index = (np.floor(time_s / scenario.dwell_s).astype(np.int64)) % len(positions)
    force = scenario.gravity * positions[position_index]

    truth = scenario.truth()
    exact = exact_output(scenario.unit, force, true_code - scenario.temp_code_ref)
    noise = white_noise(scenario, scenario.unit, 0, rng, count)
    noise += sensor_wander(scenario, scenario.unit, 0, count)
    stamps = ns_from_seconds(scenario.start_time_s + time_s)
    exact = exact + hidden_terms(scenario, force, true_code, seconds_from_ns(stamps), time_s)
    counts = np.clip(np.round(exact + noise), COUNTS_MIN, COUNTS_MAX)

    temp_rows = np.arange(0, count, scenario.temp_code_every)
    changes = np.flatnonzero(np.diff(position_index, prepend=-1) != 0)
    record = ChannelRecord(
        counts_stamp_ns=stamps, counts=counts,
        temp_stamp_ns=stamps[temp_rows], temp_code=np.round(true_code[temp_rows]),
        reference_stamp_ns=stamps[changes], reference=force[changes],
        frame_id=scenario.frame_id, nominal_scale=tuple(scenario.nominal_scale),  # type: ignore[arg-type]
        aux=recorded_supply(scenario, stamps[temp_rows], time_s[temp_rows]))
    return SimulatedRun(record=record, board_celsius=board, chamber_celsius=chamber,
                        true_temp_code=true_code, specific_force=force, truth=truth,
                        scenario=scenario)


def supply_voltage(scenario: Scenario, time_s: np.ndarray) -> np.ndarray:
    """The unobserved supply-voltage signal, RMS about 1 (dimensionless), seeded."""
    rng = np.random.default_rng([scenario.seed, 7])
    low, high = SUPPLY_PERIODS_HOURS
    periods = rng.uniform(low, high, size=3) * 3600.0
    phases = rng.uniform(0.0, 2.0 * math.pi, size=3)
    signal = sum(np.sin(2.0 * math.pi * time_s / period + phase) for period, phase in zip(periods, phases))
    return signal / math.sqrt(1.5)


def supply_signal_name(scenario: Scenario) -> str:
    """The recorded supply's signal name ``aux:TOPIC``, or ``''`` when it is not recorded."""
    return f'aux:{scenario.record_supply}' if scenario.record_supply else ''


def recorded_supply(scenario: Scenario, stamp_ns: np.ndarray,
                    time_s: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The record's ``aux`` entry of the recorded supply voltage (volts), empty when not recorded."""
    if not scenario.record_supply:
        return {}
    volts = SUPPLY_NOMINAL_VOLTS + SUPPLY_VOLTS_RMS * supply_voltage(scenario, time_s)
    if scenario.record_supply_type == 'battery_state':
        volts = volts.astype(np.float32).astype(float)  # BatteryState.voltage is a float32
    return {supply_signal_name(scenario): (np.asarray(stamp_ns, dtype=np.int64), volts)}


def _simulate_driver(scenario: Scenario) -> SimulatedRun:
    """A driver bag: the Imu in SI units, the temperature in degrees C, on a tilt and rate table."""
    if scenario.rotation:
        return _rotation_run(scenario)
    if scenario.handheld is not None:
        return _handheld_run(scenario)
    rng = np.random.default_rng(scenario.seed)
    count = int(math.floor(scenario.duration_s() * scenario.sample_rate_hz)) + 1
    time_s = np.arange(count) / scenario.sample_rate_hz
    chamber = chamber_profile(scenario, time_s)
    board = first_order_lag(chamber, time_s, scenario.board_lag_s, scenario.start_celsius)
    positions = np.asarray(scenario.positions, dtype=float)
    position_index = (np.floor(time_s / scenario.dwell_s).astype(np.int64)) % len(positions)
    force = scenario.gravity * positions[position_index]
    rates = np.asarray(scenario.table_rates or (0.0,) * len(positions), dtype=float)
    rate = rates[position_index][:, None] * positions[position_index]
    stamps = ns_from_seconds(scenario.start_time_s + time_s)
    stamp_s = seconds_from_ns(stamps)
    accel = _driver_channels(scenario, scenario.accel_unit, 'effects', force, board, stamp_s, time_s, rng)
    gyro = _driver_channels(scenario, scenario.gyro_unit, 'gyro_effects', rate, board, stamp_s, time_s, rng)
    temp_rows = np.arange(0, count, scenario.temp_code_every)
    quantum = scenario.temperature_resolution_celsius
    step = np.flatnonzero(np.diff(position_index, prepend=-1) != 0)
    if not scenario.record_references:
        step = step[:0]
    orientation, orientation_covariance = no_orientation(count)
    driver = DriverRecord(
        stamp_ns=stamps, accel=accel, gyro=gyro, orientation=orientation,
        orientation_covariance=orientation_covariance, temp_stamp_ns=stamps[temp_rows],
        temperature=np.round(board[temp_rows] / quantum) * quantum,
        reference_stamp_ns=stamps[step], reference=force[step],
        rate_reference_stamp_ns=stamps[step], rate_reference=rate[step], frame_id=scenario.frame_id,
        aux=recorded_supply(scenario, stamps[temp_rows], time_s[temp_rows]))
    if scenario.magnetometer is not None:
        # Its own noise stream: the other channels stay as without a magnetometer.
        field_truth = table_field(scenario.magnetometer, positions, position_index)
        mag = scenario.magnetometer.measure(field_truth, board, scenario.reference_celsius,
                                            np.random.default_rng([scenario.seed, 18]), stamp_s)
        driver = replace(driver, mag_stamp_ns=stamps.copy(), mag=mag, mag_frame_id=scenario.frame_id,
                         mag_reference_stamp_ns=stamps[step], mag_reference=field_truth[step])
    unit_truth = scenario.driver_truth()
    return SimulatedRun(record=driver.channel('accel'), board_celsius=board, chamber_celsius=chamber,
                        true_temp_code=board, specific_force=force, truth=unit_truth.accel,
                        scenario=scenario, driver=driver, angular_rate=rate, unit_truth=unit_truth)


def _driver_channels(scenario: Scenario, unit: tuple[AxisTruth, ...], key: str, inputs: np.ndarray,
                     board: np.ndarray, stamp_s: np.ndarray, time_s: np.ndarray,
                     rng: np.random.Generator) -> np.ndarray:
    """One sensor's three channels as its driver gives them: the link, hidden effects, noise and wander."""
    exact = exact_output(unit, inputs, board - scenario.reference_celsius)
    exact += _effect_terms(scenario.effect_instances(key), inputs, board, stamp_s)
    if scenario.supply_voltage_drift > 0.0 and key == 'effects':
        exact += _supply_terms(scenario, time_s)
    index = 0 if key == 'effects' else 1
    exact += white_noise(scenario, unit, index, rng, len(time_s))
    return quantized(exact + sensor_wander(scenario, unit, index, len(time_s)), unit)


def _handheld_run(scenario: Scenario) -> SimulatedRun:
    """A unit turned by hand through still orientations (``scenario.handheld``): no reference topics."""
    motion = scenario.handheld
    assert motion is not None
    rng = np.random.default_rng(scenario.seed)
    duration = scenario.duration_s() if motion.temperature == 'chamber' else None
    path = hand_trajectory(motion, rate_hz=scenario.sample_rate_hz, gravity=scenario.gravity, seed=scenario.seed,
                           duration_s=duration)
    time_s = path.time_s
    count = len(time_s)
    if motion.temperature == 'chamber':
        chamber = chamber_profile(scenario, time_s)
        board = first_order_lag(chamber, time_s, scenario.board_lag_s, scenario.start_celsius)
    else:
        chamber = motion.final_celsius + (scenario.start_celsius - motion.final_celsius) * np.exp(
            -time_s / motion.warmup_tau_s)
        board = chamber
    stamps = ns_from_seconds(scenario.start_time_s + time_s)
    stamp_s = seconds_from_ns(stamps)
    accel = _driver_channels(scenario, scenario.accel_unit, 'effects', path.specific_force, board, stamp_s,
                             time_s, rng)
    gyro = _driver_channels(scenario, scenario.gyro_unit, 'gyro_effects', path.rate, board, stamp_s, time_s, rng)
    temp_rows = np.arange(0, count, scenario.temp_code_every)
    quantum = scenario.temperature_resolution_celsius
    orientation, orientation_covariance = no_orientation(count)
    driver = DriverRecord(stamp_ns=stamps, accel=accel, gyro=gyro, orientation=orientation,
                          orientation_covariance=orientation_covariance, temp_stamp_ns=stamps[temp_rows],
                          temperature=np.round(board[temp_rows] / quantum) * quantum, frame_id=scenario.frame_id,
                          aux=recorded_supply(scenario, stamps[temp_rows], time_s[temp_rows]))
    unit_truth = scenario.driver_truth()
    return SimulatedRun(record=driver.channel('accel'), board_celsius=board, chamber_celsius=chamber,
                        true_temp_code=board, specific_force=path.specific_force, truth=unit_truth.accel,
                        scenario=scenario, driver=driver, angular_rate=path.rate, unit_truth=unit_truth,
                        trajectory=path)


def sensor_wander(scenario: Scenario, unit: tuple[AxisTruth, ...], sensor_index: int, count: int) -> np.ndarray:
    """``(count, 3)``: the bias instability, random walk and Gauss-Markov processes of a sensor's axes.

    Zeros when off. Drawn from their own stream (``[seed, 16, sensor_index]``): a scenario without
    them draws the same white noise as before they existed.
    """
    bias = tuple(a.bias_instability for a in unit)
    walk = tuple(a.random_walk for a in unit)
    markov = tuple(tuple(zip(a.gauss_markov, a.gauss_markov_time)) for a in unit)
    if not any(bias) and not any(walk) and not any(markov):
        return np.zeros((count, 3))
    return bias_wander([scenario.seed, 16, sensor_index], count, scenario.sample_rate_hz, bias,
                       tuple(a.bias_instability_tau for a in unit), walk, markov)


def white_noise(scenario: Scenario, unit: tuple[AxisTruth, ...], sensor_index: int, rng: np.random.Generator,
                count: int) -> np.ndarray:
    """``(count, 3)``: a sensor's white noise, through the driver's filter and decimation where an axis has one.

    The run's own stream draws as before (so the other channels do not change); a filtered
    axis takes its noise from its own stream (``[seed, 17, sensor_index, axis]``) instead.
    """
    noise = rng.standard_normal((count, 3)) * np.array([a.noise_counts for a in unit])
    for axis, truth in enumerate(unit):
        if truth.filter_time_constant > 0.0:
            own = np.random.default_rng([scenario.seed, 17, sensor_index, axis])
            noise[:, axis] = filtered_white(own, count, scenario.sample_rate_hz,
                                            truth.noise_counts / math.sqrt(scenario.sample_rate_hz),
                                            truth.filter_time_constant, scenario.decimation)
    return noise


def quantized(values: np.ndarray, unit: tuple[AxisTruth, ...]) -> np.ndarray:
    """``values`` rounded to each axis's ``resolution`` (axes without one unchanged)."""
    out = np.asarray(values, dtype=float).copy()
    for axis, truth in enumerate(unit):
        if truth.resolution > 0.0:
            out[:, axis] = np.round(out[:, axis] / truth.resolution) * truth.resolution
    return out


def _rotation_run(scenario: Scenario) -> SimulatedRun:
    """A rotation record of the magnetometer (``scenario.rotation``), at ``start_celsius``."""
    driver = rotation_record(scenario.magnetometer, samples=2000, rate_hz=scenario.sample_rate_hz,
                             temperature_celsius=scenario.start_celsius, reference_celsius=scenario.reference_celsius,
                             turn=scenario.rotation, seed=scenario.seed, start_time_s=scenario.start_time_s,
                             frame_id=scenario.frame_id, warm_to_celsius=scenario.warm_to_celsius)
    constant = np.full(len(driver.stamp_ns), scenario.start_celsius)
    if scenario.warm_to_celsius is not None:
        constant = driver.temperature[hold_last_index(driver.temp_stamp_ns, driver.stamp_ns)]
    unit_truth = scenario.driver_truth()
    return SimulatedRun(record=driver.channel('accel'), board_celsius=constant, chamber_celsius=constant,
                        true_temp_code=constant, specific_force=driver.accel, truth=unit_truth.accel,
                        scenario=scenario, driver=driver, angular_rate=np.zeros_like(driver.gyro),
                        unit_truth=unit_truth)


def _effect_terms(effects: tuple[Effect, ...], inputs: np.ndarray, temperature: np.ndarray,
                  stamp_s: np.ndarray) -> np.ndarray:
    """What hidden effects add to three channels, ``(k, 3)``, driven by the true temperature."""
    extra = np.zeros((len(stamp_s), 3))
    for effect in effects:
        if effect.kind == 'input':
            extra += effect.input_counts(inputs)
        else:
            extra += effect.offsets(stamp_s, temperature)
    return extra


def hidden_terms(scenario: Scenario, force: np.ndarray, true_code: np.ndarray, stamp_s: np.ndarray,
                 time_s: np.ndarray) -> np.ndarray:
    """Counts ``(k, 3)`` that the scenario's hidden effects and supply drift add to the channels."""
    extra = _effect_terms(scenario.effect_instances(), force, true_code, stamp_s)
    if scenario.supply_voltage_drift > 0.0:
        extra += _supply_terms(scenario, time_s)
    return extra


def _supply_terms(scenario: Scenario, time_s: np.ndarray) -> np.ndarray:
    """The offset ``(k, 3)`` that the unobserved supply voltage adds."""
    return (scenario.supply_voltage_drift * supply_voltage(scenario, time_s))[:, None] * np.array(SUPPLY_AXIS_WEIGHTS)


def _effects_from_mapping(raw: Any) -> dict[str, dict[str, float]]:
    if not isinstance(raw, Mapping):
        msg = 'effects: expected a mapping of effect names to their parameters'
        raise ScenarioError(msg)
    effects: dict[str, dict[str, float]] = {}
    for name, values in raw.items():
        if not isinstance(values, Mapping):
            msg = f'effects.{name}: expected a mapping of parameter names to numbers'
            raise ScenarioError(msg)
        for parameter, value in values.items():
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                msg = f'effects.{name}.{parameter}: expected a finite number'
                raise ScenarioError(msg)
        effects[str(name)] = {str(k): float(v) for k, v in values.items()}
    return effects


def _tuple_of_floats(value: Any, key: str) -> tuple[float, ...]:
    if not isinstance(value, (list, tuple)) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        msg = f'{key}: expected a list of numbers'
        raise ScenarioError(msg)
    return tuple(float(v) for v in value)


def scenario_from_mapping(raw: Mapping[str, Any], *, base: Scenario | None = None) -> Scenario:
    """Override ``base`` (default :class:`Scenario`) with the keys of a mapping.

    :raises ScenarioError: naming an unknown or ill-typed key.
    """
    base = base or Scenario()
    if not isinstance(raw, Mapping):
        msg = 'scenario: expected a mapping of keys to values'
        raise ScenarioError(msg)
    known = {f.name: f for f in fields(Scenario)}
    changes: dict[str, Any] = {}
    for key, value in raw.items():
        if key not in known:
            msg = f'{key}: unknown scenario key (known: {", ".join(known)})'
            raise ScenarioError(msg)
        current = getattr(base, key)
        if key in ('unit', 'accel_unit', 'gyro_unit'):
            changes[key] = _unit_from_mapping(value, getattr(base, key))
        elif key in ('effects', 'gyro_effects'):
            changes[key] = _effects_from_mapping(value)
        elif key == 'magnetometer':
            changes[key] = None if value is None else truth_from_mapping(value)
        elif key == 'handheld':
            changes[key] = None if value is None else motion_from_mapping(value)
        elif key == 'positions':
            if not isinstance(value, list) or not all(isinstance(p, list) and len(p) == 3 for p in value):
                msg = 'positions: expected a list of [x, y, z] unit vectors'
                raise ScenarioError(msg)
            vectors = tuple(_tuple_of_floats(p, 'positions') for p in value)
            for p in vectors:
                if not math.isclose(math.hypot(*p), 1.0, rel_tol=1e-6):
                    msg = f'positions: {list(p)} is not a unit vector'
                    raise ScenarioError(msg)
            changes[key] = vectors
        elif isinstance(current, tuple):
            changes[key] = _tuple_of_floats(value, key)
        elif isinstance(current, str):
            if not isinstance(value, str):
                msg = f'{key}: expected a string'
                raise ScenarioError(msg)
            changes[key] = value
        elif isinstance(current, bool):
            if not isinstance(value, bool):
                msg = f'{key}: expected true or false'
                raise ScenarioError(msg)
            changes[key] = value
        elif isinstance(current, int):
            if isinstance(value, bool) or not isinstance(value, int):
                msg = f'{key}: expected an integer'
                raise ScenarioError(msg)
            changes[key] = value
        else:
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                msg = f'{key}: expected a finite number'
                raise ScenarioError(msg)
            changes[key] = float(value)
    return replace(base, **changes)


def _unit_from_mapping(raw: Any, base: tuple[AxisTruth, ...]) -> tuple[AxisTruth, ...]:
    if not isinstance(raw, Mapping):
        msg = 'unit: expected a mapping with axes x, y, z'
        raise ScenarioError(msg)
    axes = list(base)
    known = {f.name for f in fields(AxisTruth)}
    for name, values in raw.items():
        if name not in AXES:
            msg = f'unit.{name}: unknown axis (x, y or z)'
            raise ScenarioError(msg)
        if not isinstance(values, Mapping):
            msg = f'unit.{name}: expected a mapping'
            raise ScenarioError(msg)
        changes: dict[str, Any] = {}
        for key, value in values.items():
            if key not in known:
                msg = f'unit.{name}.{key}: unknown key (known: {", ".join(sorted(known))})'
                raise ScenarioError(msg)
            if key in ('offset_coeffs', 'scale_coeffs', 'gauss_markov', 'gauss_markov_time'):
                changes[key] = _tuple_of_floats(value, f'unit.{name}.{key}')
            elif isinstance(value, bool) or not isinstance(value, (int, float)):
                msg = f'unit.{name}.{key}: expected a number'
                raise ScenarioError(msg)
            else:
                changes[key] = float(value)
        axes[AXES.index(name)] = replace(axes[AXES.index(name)], **changes)
    return tuple(axes)
