"""Thermal-chamber simulator: the paper's protocol, seeded and deterministic.

The chamber holds plateaus joined by ramps; the board (ADC and temperature sensor) follows
the chamber through a first-order lag; the temperature code is a rounded affine function of
board temperature; a turntable cycles through the six +/-g positions and tilted ones, so
every axis also sees 0 g and mixed inputs; the channel codes follow the paper's model with
white noise, rounded to 16-bit two's complement with saturation.

A run's numbers are a :class:`~tak_thermo_ros.core.simulation.scenario.Scenario`; the true
axes it draws its channels from are in :mod:`.truth`. Effects beyond the paper's model are
hidden by the SAME effect classes that fit and correct; ``supply_voltage_drift`` adds an
offset that follows an unobserved supply voltage (:func:`supply_voltage`), recorded on a
topic with ``record_supply``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from tak_thermo_ros.core.effects.base import Effect

import numpy as np

from tak_thermo_ros.core.link.model import Calibration, UnitCalibration
from tak_thermo_ros.core.simulation.noise import bias_wander, filtered_white
from tak_thermo_ros.core.records.drops import COUNTS_MAX, COUNTS_MIN
from tak_thermo_ros.core.records.record import ChannelRecord, DriverRecord, hold_last_index, no_orientation
from tak_thermo_ros.core.records.stamps import ns_from_seconds, seconds_from_ns
from tak_thermo_ros.core.simulation.motion import Trajectory, hand_trajectory
from tak_thermo_ros.core.simulation.magnetometer import rotation_record, table_field
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.core.simulation.truth import AxisTruth, exact_output


SUPPLY_AXIS_WEIGHTS: tuple[float, float, float] = (1.0, -0.7, 0.5)
"""Sensitivity of axes x, y, z to the unobserved supply voltage, relative to x."""
SUPPLY_PERIODS_HOURS: tuple[float, float] = (0.4, 2.0)
"""The supply voltage is three sinusoids with periods drawn from this range and random phases."""
SUPPLY_NOMINAL_VOLTS = 12.0
SUPPLY_VOLTS_RMS = 0.2
"""A recorded supply voltage is ``SUPPLY_NOMINAL_VOLTS + SUPPLY_VOLTS_RMS * supply_voltage()``."""


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
