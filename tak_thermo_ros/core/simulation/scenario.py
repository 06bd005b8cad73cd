"""A simulated run's numbers: :class:`Scenario`, its temperature profiles, and reading it from a mapping.

Effects beyond the paper's model can be hidden in a run (all off by default): ``effects`` maps
library effect names (``tak_thermo_ros.core.effects``) to their true parameters, and the SAME
effect classes that fit and correct add their forward contribution, driven by the true
(unrounded) temperature code and the sample stamps (power-on = the first sample).
``supply_voltage_drift`` adds an offset that follows an unobserved, slowly varying supply
voltage (not in the bag, not correlated with temperature): the case no library effect explains.
``record_supply`` records that voltage on a topic (then it is observed: ``aux:TOPIC``).

Every number lives in a :class:`Scenario`, loadable from YAML (all keys optional):
:func:`scenario_from_mapping` reads one (:func:`tak_thermo_ros.formats.scenario.load_scenario`
reads the file); :func:`tak_thermo_ros.core.simulation.imu.simulate` runs it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Mapping

from tak_thermo_ros.core.effects import resolve_effect
from tak_thermo_ros.core.effects.base import Effect

from tak_thermo_ros.core.link.model import AXES, Calibration, InputKind, UnitCalibration
from tak_thermo_ros.core.noise.model import NoiseModel, floor_tau, model_floor_tau
from tak_thermo_ros.core.simulation.motion import HandheldMotion, motion_from_mapping
from tak_thermo_ros.core.simulation.magnetometer import MagnetometerTruth, truth_from_mapping
from tak_thermo_ros.core.simulation.mapping import (
    fields_from_mapping,
    first_failed,
    flag,
    integer,
    number,
    numbers,
    string,
)
from tak_thermo_ros.core.simulation.truth import (
    DEFAULT_DRIVER_ACCEL,
    DEFAULT_DRIVER_GYRO,
    DEFAULT_POSITIONS,
    DEFAULT_UNIT,
    AxisTruth,
)
from tak_thermo_ros.core.values import STANDARD_GRAVITY
from tak_thermo_ros.errors import CalibrationError, FitError, ScenarioError

SUPPLY_TYPES = ('battery_state', 'float64')
"""The message types a recorded supply voltage can take (``record_supply_type``)."""

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
        first_failed(checks)

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


def _effects_from_mapping(raw: Any) -> dict[str, dict[str, float]]:
    if not isinstance(raw, Mapping):
        msg = 'effects: expected a mapping of effect names to their parameters'
        raise ScenarioError(msg)
    effects: dict[str, dict[str, float]] = {}
    for name, values in raw.items():
        if not isinstance(values, Mapping):
            msg = f'effects.{name}: expected a mapping of parameter names to numbers'
            raise ScenarioError(msg)
        effects[str(name)] = {str(k): number(v, f'effects.{name}.{k}', finite=True) for k, v in values.items()}
    return effects


def scenario_from_mapping(raw: Mapping[str, Any], *, base: Scenario | None = None) -> Scenario:
    """Override ``base`` (default :class:`Scenario`) with the keys of a mapping.

    :raises ScenarioError: naming an unknown or ill-typed key.
    """
    base = base or Scenario()

    def read(key: str, value: Any) -> Any:
        current = getattr(base, key)
        if key in ('unit', 'accel_unit', 'gyro_unit'):
            return _unit_from_mapping(value, getattr(base, key))
        if key in ('effects', 'gyro_effects'):
            return _effects_from_mapping(value)
        if key == 'magnetometer':
            return None if value is None else truth_from_mapping(value)
        if key == 'handheld':
            return None if value is None else motion_from_mapping(value)
        if key == 'positions':
            if not isinstance(value, list) or not all(isinstance(p, list) and len(p) == 3 for p in value):
                msg = 'positions: expected a list of [x, y, z] unit vectors'
                raise ScenarioError(msg)
            vectors = tuple(numbers(p, 'positions') for p in value)
            for p in vectors:
                if not math.isclose(math.hypot(*p), 1.0, rel_tol=1e-6):
                    msg = f'positions: {list(p)} is not a unit vector'
                    raise ScenarioError(msg)
            return vectors
        if isinstance(current, tuple):
            return numbers(value, key)
        if isinstance(current, str):
            return string(value, key)
        if isinstance(current, bool):
            return flag(value, key)
        if isinstance(current, int):
            return integer(value, key)
        return number(value, key, finite=True)

    changes = fields_from_mapping(raw, Scenario, '', read, noun='scenario key',
                                  not_a_mapping='scenario: expected a mapping of keys to values')
    return replace(base, **changes)


def _unit_from_mapping(raw: Any, base: tuple[AxisTruth, ...]) -> tuple[AxisTruth, ...]:
    if not isinstance(raw, Mapping):
        msg = 'unit: expected a mapping with axes x, y, z'
        raise ScenarioError(msg)
    axes = list(base)
    for name, values in raw.items():
        if name not in AXES:
            msg = f'unit.{name}: unknown axis (x, y or z)'
            raise ScenarioError(msg)

        def read(key: str, value: Any) -> float | tuple[float, ...]:
            if key in ('offset_coeffs', 'scale_coeffs', 'gauss_markov', 'gauss_markov_time'):
                return numbers(value, f'unit.{name}.{key}')
            return number(value, f'unit.{name}.{key}')

        changes = fields_from_mapping(values, AxisTruth, f'unit.{name}.', read,
                                      not_a_mapping=f'unit.{name}: expected a mapping', sort_known=True)
        axes[AXES.index(name)] = replace(axes[AXES.index(name)], **changes)
    return tuple(axes)
