"""A unit's everyday records: weeks of ordinary runs, each a power-up at the day's ambient.

A robot or a drone records whenever it runs. Each record here is one power-up: the unit starts
at the day's ambient (``Everyday.start_spread_celsius`` apart when it was stored elsewhere),
warms by its own heating towards ``ambient + self_heating_celsius`` through a first-order lag
(``board_tau_s``), further while it moves (``motion_heating_celsius``: motors and load; negative
when the airflow cools it more) and follows an ambient that drifts during the record
(``ambient_drift_celsius``): a rest after power-up warms, a rest after a motion cools, so the
rests of a month meet each temperature while heating and while cooling.

A record alternates rests and motions, starting and ending at rest (pre-arm, parked, landed):
rests of ``rest_s`` (log-uniform within), motions of ``motion_s``. At rest the unit lies on
uneven ground: its up direction within ``tilt_deg`` of the mount's up (near level), at any
heading; with ``face_share`` a rest lies on another of its six faces instead (a unit set down
by hand). A motion carries the pose of one rest to the next's (a minimum-jerk turn, as
:mod:`~tak_thermo_ros.core.simulation.motion`'s turns) with a vehicle's accelerations and
vibration: a small oscillation of the attitude (so the rates still integrate to the poses) and
white vibration on the accelerometer.

Every power-up adds its own **turn-on offset** to each axis of each sensor, constant over the
record, drawn with ``turn_on_accel`` / ``turn_on_gyro`` as standard deviation (the unit's bias
repeatability); the link against temperature is the scenario's (``accel_unit``, ``gyro_unit``,
hidden ``effects`` / ``gyro_effects`` from the record's first sample: an effect with memory
starts at power-up), with its white noise, bias instability and random walk (the random walk
starts at 0 at every power-up). Everything else comes from the
:class:`~tak_thermo_ros.core.simulation.imu.Scenario` (``output: imu``): the rate, the units, the
temperature quantum, gravity, the frame.

Each record is drawn from its own streams (the scenario's seed and the record's index), so a
record is the same whether the month is simulated whole or one record at a time
(:func:`simulate_everyday_record`), and a month of 30 records never sits in memory at once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import Any, Iterator, Mapping

import numpy as np

from tak_thermo_ros.core.link.model import UnitCalibration
from tak_thermo_ros.core.records.record import DriverRecord, no_orientation, seconds_from_ns
from tak_thermo_ros.core.records.stamps import ns_from_seconds
from tak_thermo_ros.core.rotation import exp_map, log_map
from tak_thermo_ros.core.simulation.imu import AxisTruth, Scenario, _driver_channels, exact_output, first_order_lag
from tak_thermo_ros.core.simulation.mapping import (
    fields_from_mapping,
    first_failed,
    integer,
    number,
    numbers,
    whole_numbers,
)
from tak_thermo_ros.core.simulation.truth import DEFAULT_DRIVER_ACCEL, DEFAULT_DRIVER_GYRO
from tak_thermo_ros.core.simulation.motion import FACE_UP, _minimum_jerk, _posed
from tak_thermo_ros.errors import ScenarioError

DAY_S = 86400.0
FIRST_HOUR = 8.0
LAST_HOUR = 18.0
"""A record starts between these hours of its day (local time of the simulated clock)."""
VIBRATION_HZ = (8.0, 40.0)
"""The vibration's frequencies are drawn within this band (kept below 0.4 of the sample rate)."""
EDGE_S = 0.5
"""A motion's vibration and accelerations fade in and out over this long (the rests stay quiet)."""

EVERYDAY_ACCEL: tuple[AxisTruth, AxisTruth, AxisTruth] = tuple(  # type: ignore[assignment]
    replace(axis, bias_instability=4.0e-4, bias_instability_tau=100.0, random_walk=2.0e-5)
    for axis in DEFAULT_DRIVER_ACCEL)
"""The driver accelerometer of the other simulated records with coloured noise: a bias instability
of 0.04 mg (flat Allan deviation 0.027 mg around 100 s) and a random walk of 2e-5 m/s^3/sqrt(Hz)."""
EVERYDAY_GYRO: tuple[AxisTruth, AxisTruth, AxisTruth] = tuple(  # type: ignore[assignment]
    replace(axis, bias_instability=2.0e-5, bias_instability_tau=100.0, random_walk=1.0e-6)
    for axis in DEFAULT_DRIVER_GYRO)
"""Its gyroscope: a bias instability of 2e-5 rad/s (4 deg/h) and a random walk of 1e-6 rad/s^2/sqrt(Hz)."""
EVERYDAY_SCENARIO = Scenario(output='imu', sample_rate_hz=50.0, temp_code_every=10, reference_celsius=20.0,
                             accel_unit=EVERYDAY_ACCEL, gyro_unit=EVERYDAY_GYRO, frame_id='imu_link',
                             start_time_s=1_700_000_000.0)
"""The scenario a scenario file with an ``everyday:`` section starts from (its other keys override it)."""


@dataclass(frozen=True)
class Everyday:
    """How a unit lives through its everyday records (scenario key ``everyday``, every key optional).

    :param records: how many records (power-ups).
    :param days: the records are spread over this many days, in order.
    :param record_minutes: each record's length (it ends at the rest that reaches it).
    :param ambient_celsius: ``(low, high)``: each day's ambient is drawn uniformly within.
    :param ambient_drift_celsius: the ambient moves by up to +- this over a record (linearly).
    :param start_spread_celsius: at power-up the unit is within +- this of the day's ambient.
    :param self_heating_celsius: the unit at rest settles this much above the ambient.
    :param board_tau_s: the unit's first-order lag towards its settled temperature.
    :param motion_heating_celsius: moving raises the settled temperature by this much (negative: lowers it).
    :param rest_s: ``(shortest, longest)`` rest, seconds (log-uniform).
    :param motion_s: ``(shortest, longest)`` motion between rests, seconds (log-uniform).
    :param tilt_deg: at rest the mount's up lies within this of the vertical (uneven ground).
    :param face_share: the share of rests on another face (set down on a side): 0 = always on the mount.
    :param mount_up: the mount's up direction in the sensor frame.
    :param vibration_rate: RMS of the attitude's vibration rate while moving, rad/s.
    :param vibration_accel: RMS of the white vibration on the accelerometer while moving, m/s^2.
    :param vehicle_accel: RMS of the vehicle's slow accelerations while moving, m/s^2.
    :param turn_on_accel: per axis the standard deviation of the accelerometer's turn-on offset, m/s^2.
    :param turn_on_gyro: per axis the gyroscope's, rad/s.
    """

    records: int = 16
    days: float = 30.0
    record_minutes: float = 30.0
    ambient_celsius: tuple[float, float] = (5.0, 30.0)
    ambient_drift_celsius: float = 3.0
    start_spread_celsius: float = 0.0
    self_heating_celsius: float = 10.0
    board_tau_s: float = 600.0
    motion_heating_celsius: float = 6.0
    rest_s: tuple[float, float] = (5.0, 120.0)
    motion_s: tuple[float, float] = (20.0, 300.0)
    tilt_deg: float = 3.0
    face_share: float = 0.0
    mount_up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    vibration_rate: float = 0.05
    vibration_accel: float = 0.5
    vehicle_accel: float = 0.3
    turn_on_accel: tuple[float, float, float] = (0.003, 0.003, 0.004)
    turn_on_gyro: tuple[float, float, float] = (3.0e-4, 3.0e-4, 4.0e-4)

    def __post_init__(self) -> None:
        def finite(*values: float) -> bool:
            return all(math.isfinite(v) for v in values)

        def pair(values: tuple[float, float], positive: bool) -> bool:
            return (len(values) == 2 and finite(*values) and values[0] <= values[1]
                    and (values[0] > 0.0 if positive else True))

        checks = (
            (isinstance(self.records, int) and not isinstance(self.records, bool) and self.records >= 1,
             'records', 'must be a whole number >= 1'),
            (finite(self.days) and self.days > 0.0, 'days', 'must be > 0'),
            (finite(self.record_minutes) and self.record_minutes > 0.0, 'record_minutes', 'must be > 0'),
            (pair(self.ambient_celsius, False), 'ambient_celsius', 'expected [low, high], low <= high'),
            (pair(self.rest_s, True), 'rest_s', 'expected [shortest, longest] > 0, shortest <= longest'),
            (pair(self.motion_s, True), 'motion_s', 'expected [shortest, longest] > 0, shortest <= longest'),
            (finite(self.ambient_drift_celsius, self.start_spread_celsius, self.self_heating_celsius,
                    self.motion_heating_celsius) and min(self.ambient_drift_celsius, self.start_spread_celsius) >= 0,
             'ambient_drift_celsius, start_spread_celsius', 'must be finite numbers >= 0'),
            (finite(self.board_tau_s) and self.board_tau_s > 0.0, 'board_tau_s', 'must be > 0'),
            (finite(self.tilt_deg) and 0.0 <= self.tilt_deg < 45.0, 'tilt_deg', 'must lie within 0..45'),
            (finite(self.face_share) and 0.0 <= self.face_share <= 1.0, 'face_share', 'must lie within 0..1'),
            (len(self.mount_up) == 3 and finite(*self.mount_up) and math.hypot(*self.mount_up) > 0.0,
             'mount_up', 'expected a non-zero [x, y, z]'),
            (finite(self.vibration_rate, self.vibration_accel, self.vehicle_accel)
             and min(self.vibration_rate, self.vibration_accel, self.vehicle_accel) >= 0.0,
             'vibration_rate, vibration_accel, vehicle_accel', 'must be finite numbers >= 0'),
            *((len(getattr(self, key)) == 3 and finite(*getattr(self, key)) and min(getattr(self, key)) >= 0.0,
               key, 'expected three finite numbers >= 0 (x y z)') for key in ('turn_on_accel', 'turn_on_gyro')),
        )
        first_failed(checks, 'everyday')

    def turn_on(self, sensor: str) -> np.ndarray:
        """``(3,)`` the standard deviation of a sensor's turn-on offset per axis (its true repeatability)."""
        return np.asarray(self.turn_on_accel if sensor == 'accel' else self.turn_on_gyro, dtype=float)

    def temperature_span(self) -> tuple[float, float]:
        """The lowest and highest temperature a record can reach, degrees C."""
        low, high = self.ambient_celsius
        spread = max(self.ambient_drift_celsius, self.start_spread_celsius)
        heating = (self.self_heating_celsius, self.self_heating_celsius + self.motion_heating_celsius)
        return low - spread + min(0.0, *heating), high + spread + max(0.0, *heating)


def everyday_from_mapping(raw: Any) -> Everyday:
    """An :class:`Everyday` from a scenario's ``everyday`` mapping.

    :raises ScenarioError: naming the key.
    """
    return section_from_mapping(Everyday, raw, 'everyday')


def section_from_mapping(cls: type, raw: Any, section: str, *, whole_lists: tuple[str, ...] = ()) -> Any:
    """A scenario section's dataclass (every key optional) from its mapping, each value of its default's kind.

    A tuple default takes a list of as many numbers (an empty default: any number of them; ``whole_lists``:
    whole numbers), an ``int`` a whole number, a ``float`` a number
    (:func:`~tak_thermo_ros.core.simulation.mapping.fields_from_mapping`).

    :raises ScenarioError: naming the key.
    """
    def read(key: str, value: Any) -> Any:
        default, where = getattr(cls(), key), f'{section}.{key}'
        if isinstance(default, tuple):
            length = len(default) if default else None
            what = f'a list of {length or "any"} {"whole numbers" if key in whole_lists else "numbers"}'
            if key in whole_lists:
                return whole_numbers(value, where, what=what, length=length)
            return numbers(value, where, what=what, length=length)
        if isinstance(default, int):
            return integer(value, where, what='a whole number')
        return number(value, where)

    names = ', '.join(f.name for f in fields(cls))
    return cls(**fields_from_mapping(raw, cls, f'{section}.', read,
                                     not_a_mapping=f'{section}: expected a mapping (every key optional: {names})'))


def everyday_scenario(raw: Mapping[str, Any] | None = None) -> tuple[Scenario, Everyday]:
    """The scenario and the habits of a scenario mapping with an ``everyday`` section.

    The other keys override :data:`EVERYDAY_SCENARIO` (``output`` must stay ``imu``; no
    ``handheld``, ``rotation`` or ``magnetometer``).

    :raises ScenarioError: naming the key; a ``raw`` that is no mapping (``scenario: expected a mapping ...``).
    """
    from tak_thermo_ros.core.simulation.scenario import scenario_from_mapping
    if not isinstance(raw or {}, Mapping):  # the words of scenario_from_mapping
        msg = 'scenario: expected a mapping of keys to values'
        raise ScenarioError(msg)
    raw = dict(raw or {})
    habits = everyday_from_mapping(raw.pop('everyday', {}) or {})
    for key in ('handheld', 'rotation', 'magnetometer'):
        if key in raw and raw[key] not in (None, ''):
            msg = f'{key}: not with everyday (an everyday record is a unit in use, its rests found from the record)'
            raise ScenarioError(msg)
    scenario = scenario_from_mapping(raw, base=EVERYDAY_SCENARIO)
    if scenario.output != 'imu':
        msg = 'everyday: needs output: imu (a driver\'s records)'
        raise ScenarioError(msg)
    return scenario, habits


@dataclass(frozen=True)
class EverydayRecord:
    """One simulated everyday record: what the bag holds, and the hidden truth.

    :param index: the record's number in the month, from 0.
    :param record: the driver record (both sensors in every Imu message).
    :param board_celsius: ``(k,)`` the true temperature at each sample.
    :param rest: ``(k,)`` the true rest each sample lies in (0, 1, ...), ``-1`` while moving.
    :param up: ``(r, 3)`` each rest's up direction in the sensor frame.
    :param turn_on: per sensor ``(3,)`` this power-up's turn-on offset (m/s^2, rad/s).
    :param ambient_celsius: the day's ambient at power-up.
    :param specific_force: ``(k, 3)`` the true specific force, m/s^2.
    :param rate: ``(k, 3)`` the true angular rate, rad/s.
    :param scenario: the scenario it was drawn from (the record's own seed).
    """

    index: int
    record: DriverRecord
    board_celsius: np.ndarray
    rest: np.ndarray
    up: np.ndarray
    turn_on: dict[str, np.ndarray]
    ambient_celsius: float
    specific_force: np.ndarray
    rate: np.ndarray
    scenario: Scenario = field(repr=False, default_factory=Scenario)

    @property
    def duration_s(self) -> float:
        """From the first stamp to the last, seconds."""
        return float(self.record.stamp_ns[-1] - self.record.stamp_ns[0]) * 1e-9

    def true_offsets(self, sensor: str) -> np.ndarray:
        """``(k, 3)``: the link's offset against temperature at each sample (no turn-on offset, no noise).

        What the sensor gives without noise at its true input minus the input with the unit's
        scale: ``b(T)`` plus the scale's drift times the input (zero for the gyroscope at rest).
        """
        unit = self.scenario.sensor_unit(sensor)
        inputs = self.specific_force if sensor == 'accel' else self.rate
        n = self.board_celsius - self.scenario.reference_celsius
        nominal = np.array([a.scale for a in unit])
        return exact_output(unit, inputs, n) - inputs * nominal


def record_seed(seed: int, index: int) -> int:
    """The scenario seed of record ``index`` of a month drawn with ``seed`` (63 bits, its own streams)."""
    words = np.random.SeedSequence([int(seed), int(index), 41]).generate_state(2, dtype=np.uint32)
    return int((int(words[0]) << 31) ^ int(words[1])) & ((1 << 63) - 1)


def _log_uniform(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    low, high = bounds
    return float(math.exp(rng.uniform(math.log(low), math.log(high))))


def _schedule(habits: Everyday, rng: np.random.Generator) -> list[float]:
    """The lengths of rest, motion, rest, ..., rest (seconds) that fill the record."""
    target = habits.record_minutes * 60.0
    lengths = [_log_uniform(rng, habits.rest_s)]
    while sum(lengths) < target:
        lengths += [_log_uniform(rng, habits.motion_s), _log_uniform(rng, habits.rest_s)]
    return lengths


def _rest_poses(habits: Everyday, count: int, rng: np.random.Generator) -> np.ndarray:
    """``(count, 3, 3)``: each rest's pose, its up within ``tilt_deg`` of the mount's (or of another face)."""
    mount = np.asarray(habits.mount_up, dtype=float)
    mount = mount / np.linalg.norm(mount)
    faces = np.array(FACE_UP)
    other = rng.uniform(size=count) < habits.face_share
    up = np.where(other[:, None], faces[rng.integers(0, len(faces), count)], mount)
    tilt = math.radians(habits.tilt_deg) * np.sqrt(rng.uniform(size=count))
    axis = np.cross(up, rng.standard_normal((count, 3)))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    return _posed(np.einsum('kab,kb->ka', exp_map(tilt[:, None] * axis), up), rng)


def _fade(time_s: np.ndarray, length: float) -> np.ndarray:
    """A window from 0 to 1 and back to 0 over :data:`EDGE_S` at each end of a motion of ``length``."""
    edge = min(EDGE_S, 0.25 * length)
    rise = np.clip(time_s / edge, 0.0, 1.0)
    fall = np.clip((length - time_s) / edge, 0.0, 1.0)
    return np.sin(0.5 * math.pi * np.minimum(rise, fall)) ** 2


def _trajectory(habits: Everyday, lengths: list[float], rate_hz: float, gravity: float,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Time, specific force, rate, rest number per sample, and each rest's up direction."""
    edges = np.concatenate([[0.0], np.cumsum(lengths)])
    count = int(math.floor(edges[-1] * rate_hz)) + 1
    time_s = np.arange(count) / rate_hz
    segment = np.minimum(np.searchsorted(edges, time_s, side='right') - 1, len(lengths) - 1)
    poses = _rest_poses(habits, (len(lengths) + 1) // 2, rng)
    rotation = poses[segment // 2].copy()
    moving = segment % 2 == 1
    force_extra = np.zeros((count, 3))
    top = min(VIBRATION_HZ[1], 0.4 * rate_hz)
    bottom = min(VIBRATION_HZ[0], 0.5 * top)
    for motion in range(len(lengths) // 2):
        rows = np.flatnonzero(segment == 2 * motion + 1)
        if not len(rows):
            continue
        before, after = poses[motion], poses[motion + 1]
        length = lengths[2 * motion + 1]
        local = time_s[rows] - edges[2 * motion + 1]
        s, _, _ = _minimum_jerk(np.clip(local / length, 0.0, 1.0))
        phi = log_map(before.T @ after)
        fade = _fade(local, length)
        # Vibration: a small oscillation of the attitude about a random axis per frequency, so that
        # the rate (the attitude's derivative) integrates back to the poses at the rests.
        angle = np.zeros((len(rows), 3))
        for _ in range(3):
            frequency = rng.uniform(bottom, top)
            axis = rng.standard_normal(3)
            axis /= np.linalg.norm(axis)
            amplitude = habits.vibration_rate / (2.0 * math.pi * frequency) * math.sqrt(2.0 / 3.0)
            angle += (amplitude * np.sin(2.0 * math.pi * frequency * local + rng.uniform(0.0, 2.0 * math.pi))
                      * fade)[:, None] * axis
        rotation[rows] = before @ exp_map(s[:, None] * phi) @ exp_map(angle)
        # The vehicle's slow accelerations (level frame) and the white vibration (sensor frame).
        slow = np.zeros((len(rows), 3))
        for _ in range(2):
            period = rng.uniform(5.0, 30.0)
            slow += np.sin(2.0 * math.pi * local / period + rng.uniform(0.0, 2.0 * math.pi, 3)[:, None]).T
        slow *= habits.vehicle_accel * fade[:, None]  # two sinusoids of RMS 1/sqrt(2) per axis: RMS 1
        level_to_sensor = np.swapaxes(rotation[rows], 1, 2)
        force_extra[rows] = (np.einsum('kab,kb->ka', level_to_sensor, slow)
                             + rng.standard_normal((len(rows), 3)) * habits.vibration_accel * fade[:, None])
    # The rate as the attitude's derivative: each step's rotation over its length, averaged at the samples.
    steps = log_map(np.swapaxes(rotation[:-1], 1, 2) @ rotation[1:]) * rate_hz
    rate = np.zeros((count, 3))
    if count > 1:
        rate[:-1] += 0.5 * steps
        rate[1:] += 0.5 * steps
        rate[0] += 0.5 * steps[0]
        rate[-1] += 0.5 * steps[-1]
    rate[~moving] = 0.0
    force = gravity * rotation[:, 2, :] + force_extra
    rest = np.where(moving, -1, segment // 2)
    return time_s, force, rate, rest, poses[:, 2, :]


def _temperature(habits: Everyday, time_s: np.ndarray, moving: np.ndarray,
                 rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """The unit's true temperature at each sample, and the day's ambient at power-up."""
    low, high = habits.ambient_celsius
    ambient = rng.uniform(low, high)
    drift = rng.uniform(-habits.ambient_drift_celsius, habits.ambient_drift_celsius)
    start = ambient + rng.uniform(-habits.start_spread_celsius, habits.start_spread_celsius)
    # On a 1 s grid (the lag is minutes), then onto the samples.
    duration = float(time_s[-1]) if len(time_s) else 0.0
    grid = np.arange(0.0, duration + 1.0, 1.0)
    moving_grid = np.interp(grid, time_s, moving.astype(float)) > 0.5
    settled = (ambient + drift * grid / max(duration, 1.0) + habits.self_heating_celsius
               + habits.motion_heating_celsius * moving_grid)
    board = first_order_lag(settled, grid, habits.board_tau_s, start)
    return np.interp(time_s, grid, board), float(ambient)


def simulate_everyday_record(scenario: Scenario, habits: Everyday, index: int) -> EverydayRecord:
    """Record ``index`` (from 0) of the month (deterministic for the scenario's seed and the index)."""
    if not 0 <= index < habits.records:
        msg = f'everyday: record {index} of {habits.records} (0 .. {habits.records - 1})'
        raise ScenarioError(msg)
    own = replace(scenario, seed=record_seed(scenario.seed, index))
    rng = np.random.default_rng([own.seed, 1])
    lengths = _schedule(habits, rng)
    time_s, force, rate, rest, up = _trajectory(habits, lengths, scenario.sample_rate_hz, scenario.gravity,
                                                np.random.default_rng([own.seed, 2]))
    board, ambient = _temperature(habits, time_s, rest < 0, np.random.default_rng([own.seed, 3]))
    day = math.floor(index * habits.days / habits.records)
    start = scenario.start_time_s + day * DAY_S + rng.uniform(FIRST_HOUR, LAST_HOUR) * 3600.0
    stamps = ns_from_seconds(start + time_s)
    stamp_s = seconds_from_ns(stamps)
    turn_rng = np.random.default_rng([own.seed, 4])
    turn_on = {sensor: turn_rng.standard_normal(3) * habits.turn_on(sensor) for sensor in ('accel', 'gyro')}
    noise_rng = np.random.default_rng([own.seed, 5])
    accel = _driver_channels(own, own.accel_unit, 'effects', force, board, stamp_s, time_s, noise_rng)
    gyro = _driver_channels(own, own.gyro_unit, 'gyro_effects', rate, board, stamp_s, time_s, noise_rng)
    temp_rows = np.arange(0, len(time_s), scenario.temp_code_every)
    quantum = scenario.temperature_resolution_celsius
    orientation, covariance = no_orientation(len(time_s))
    driver = DriverRecord(stamp_ns=stamps, accel=accel + turn_on['accel'], gyro=gyro + turn_on['gyro'],
                          orientation=orientation, orientation_covariance=covariance,
                          temp_stamp_ns=stamps[temp_rows], temperature=np.round(board[temp_rows] / quantum) * quantum,
                          frame_id=scenario.frame_id)
    return EverydayRecord(index=index, record=driver, board_celsius=board, rest=rest, up=up, turn_on=turn_on,
                          ambient_celsius=ambient, specific_force=force, rate=rate, scenario=own)


def simulate_everyday(scenario: Scenario, habits: Everyday) -> Iterator[EverydayRecord]:
    """The month's records in order, one at a time."""
    for index in range(habits.records):
        yield simulate_everyday_record(scenario, habits, index)


def everyday_truth(scenario: Scenario, habits: Everyday) -> UnitCalibration:
    """The unit's true links (degrees C from ``reference_celsius``) over the temperatures a month can reach."""
    low, high = habits.temperature_span()
    return replace(scenario, start_celsius=low, plateaus_celsius=(high,)).driver_truth()


# -- a second everyday setting: a unit drawn per seed, other habits, other noise -------------------

SECOND_HABITS: dict[str, Any] = {
    'ambient_celsius': [0.0, 35.0], 'ambient_drift_celsius': 4.0, 'start_spread_celsius': 3.0,
    'self_heating_celsius': 7.0, 'board_tau_s': 450.0, 'motion_heating_celsius': -2.0,
    'rest_s': [3.0, 90.0], 'motion_s': [15.0, 240.0], 'tilt_deg': 15.0,
    'vibration_rate': 0.08, 'vibration_accel': 0.8, 'vehicle_accel': 0.5,
    'turn_on_accel': [0.004, 0.004, 0.005], 'turn_on_gyro': [3.4e-4, 2.4e-4, 4.4e-4]}
"""The second setting's habits (an ``everyday`` section): rests on ground tilted up to 15 deg at any
heading, 3 s to 1.5 min; the ambient 0 to 35 C, drifting by up to 4 C over a record, the unit up
to 3 C apart from it at power-up, warming by 7 C over 7.5 minutes at rest, cooled by the airflow
while it moves (the first setting: heated while it moves); other turn-on repeatabilities."""
SECOND_BOUNDS = {'accel_offset': 0.147, 'accel_scale': 0.006, 'accel_slope': 3.0e-3,
                 'accel_curvature': (0.5e-5, 2.0e-5), 'accel_cubic': (0.5e-7, 2.0e-7),
                 'gyro_offset': 5.0e-3, 'gyro_scale': 0.006, 'gyro_slope': 4.0e-4,
                 'gyro_curvature': (1.0e-6, 4.0e-6), 'gyro_cubic': (2.0e-8, 6.0e-8), 'gyro_coupling': 3.0e-3}
"""Within what the second setting draws its unit, per seed (SI: m/s^2, rad/s, per degree C from 20 C):
offsets up to 15 mg and 0.29 deg/s, scale errors up to 0.6 %, a slope, and on every axis a curvature
and a cubic term of either sign whose sizes lie within the pairs; the gyroscope misaligned by up to
3 mrad (the accelerometer's triad orthogonal: its offsets are the truth the pool's are judged by)."""


def drawn_unit(seed: int, bounds: Mapping[str, Any] = SECOND_BOUNDS) -> dict[str, Any]:
    """The scenario keys of a unit drawn within ``bounds`` (:data:`SECOND_BOUNDS`): its links and its noise.

    The noise is coloured otherwise than the first setting's: beside white noise, bias instability
    and random walk, a Gauss-Markov process on every axis (5 minutes on the accelerometer, 3 on the
    gyroscope).
    """
    rng = np.random.default_rng([int(seed), 39])

    def sized(pair: tuple[float, float]) -> float:
        return float(rng.choice((-1.0, 1.0)) * rng.uniform(*pair))

    def axes(sensor: str, noise: dict[str, Any]) -> dict[str, dict[str, Any]]:
        out = {}
        for name in 'xyz':
            offset = (rng.uniform(-1.0, 1.0) * bounds[f'{sensor}_offset'])
            slope = rng.uniform(-1.0, 1.0) * bounds[f'{sensor}_slope']
            curve = [slope, sized(bounds[f'{sensor}_curvature']), sized(bounds[f'{sensor}_cubic'])]
            out[name] = {'scale': 1.0 + rng.uniform(-1.0, 1.0) * bounds[f'{sensor}_scale'], 'offset': offset,
                         'offset_coeffs': curve,
                         'scale_coeffs': [rng.uniform(-1.5e-4, 1.5e-4), rng.uniform(-2.0e-6, 2.0e-6)], **noise}
        return out

    accel = axes('accel', {'noise_counts': 0.003, 'bias_instability': 3.0e-4, 'random_walk': 3.0e-5,
                           'gauss_markov': [1.0e-4], 'gauss_markov_time': [300.0]})
    gyro = axes('gyro', {'noise_counts': 0.0007, 'bias_instability': 1.5e-5, 'random_walk': 1.5e-6,
                         'gauss_markov': [1.0e-5], 'gauss_markov_time': [180.0]})
    coupling = bounds['gyro_coupling']
    couplings = {f'c_{a}{b}': float(rng.uniform(-coupling, coupling)) for a in 'xyz' for b in 'xyz' if a != b}
    return {'accel_unit': accel, 'gyro_unit': gyro, 'gyro_effects': {'cross_axis': couplings}}


def second_everyday(seed: int, *, records: int = 16, record_minutes: float = 30.0, rate_hz: float = 50.0
                    ) -> tuple[Scenario, Everyday]:
    """The second everyday setting of a seed: a unit drawn by :func:`drawn_unit`, :data:`SECOND_HABITS`."""
    raw = {'sample_rate_hz': rate_hz, 'seed': int(seed), **drawn_unit(seed),
           'everyday': {**SECOND_HABITS, 'records': records, 'record_minutes': record_minutes}}
    return everyday_scenario(raw)
