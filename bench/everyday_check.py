"""The everyday-records check: a simulated month of one unit pooled, judged on held-out records of the unit.

Per seed: a month of everyday records (:mod:`tak_thermo_ros.core.simulation.everyday`) of which
the first ``records`` are pooled and fitted (:func:`tak_thermo_ros.core.fit.pool.fit_pool`, in
memory: the rests found from each record, as ``tak_calib fit`` does) and the last ``held_out``
are the judge. Beside the pool's calibration:

- the same unit's **chamber calibration**: a rate-table run through plateaus over the month's
  temperatures (its own power-up, so its own turn-on offset), fitted by the table fit;
- **Android's straight line** (contexthub ``over_temp_cal`` fed by ``gyro_cal``): per rest of 5 s or
  more a (temperature, mean rate) point, one point per 0.75 C bin (the newest kept), an
  ordinary least-squares line per axis (its age weights make every point but the last 15
  minutes' equal; no age limit here, which can only help it, and no outlier gate);
- the **truth**, whose errors are the noise alone: the floor.

The gyroscope's bias shape at the held-out records' rests: each rest's mean corrected rate, each
record's own mean taken off (its turn-on offset), RMS over the rests; ``|f|`` at the rests:
``|mean corrected f| - g``, RMS (nothing taken off). Judged at the rests within the pool's
calibrated temperatures (a held-out day hotter than the whole month is beyond any everyday
calibration, which clamps there); over every rest beside, with how many lay outside. The
repeatability's coverage: whether the reported spread lies within two of its standard errors of
the true one, per gyroscope axis.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from tak_thermo_ros.core.fit import fit_model
from tak_thermo_ros.core.fit.handheld import HandheldSettings
from tak_thermo_ros.core.fit.pool import fit_pool
from tak_thermo_ros.core.link.correction import Corrector
from tak_thermo_ros.core.link.model import InputKind, UnitCalibration
from tak_thermo_ros.core.records.handheld import pooled
from tak_thermo_ros.core.records.record import align
from tak_thermo_ros.core.records.still import find_still
from tak_thermo_ros.core.simulation.everyday import (
    everyday_scenario,
    everyday_truth,
    second_everyday,
    simulate_everyday_record,
)
from tak_thermo_ros.core.simulation.imu import RATE_TABLE_POSITIONS, RATE_TABLE_RATES, simulate

ANDROID_BIN_C = 0.75
ANDROID_MIN_REST_S = 5.0
EDGE_S = 0.5
"""The judge's rests: the true rests without this much at each end."""


SETTINGS = ('first', 'second')
"""The everyday simulator's settings: the one the pool was built on, and a second one apart from it
(:func:`~tak_thermo_ros.core.simulation.everyday.second_everyday`: a unit drawn per seed, tilts up to 15
deg, other habits and noise)."""


def month(seed: int, *, records: int, held_out: int, minutes: float, rate_hz: float, setting: str = 'first'):
    """The scenario and habits of a month of ``records + held_out`` records in one of :data:`SETTINGS`."""
    if setting == 'second':
        return second_everyday(seed, records=records + held_out, record_minutes=minutes, rate_hz=rate_hz)
    return everyday_scenario({'sample_rate_hz': rate_hz, 'seed': seed,
                              'everyday': {'records': records + held_out, 'record_minutes': minutes}})


def pool_of(simulated: list) -> object:
    """The simulated records as a pool (each record's rests found from itself), as ``fit`` reads them."""
    from tak_thermo_ros.core.records.handheld import HandheldCollector
    from tak_thermo_ros.passes.pool import record_budgets
    budget, turn_budget = record_budgets(len(simulated))
    parts = []
    for item in simulated:
        record = item.record
        still = find_still(record.stamp_ns, np.hstack([record.accel, record.gyro]))
        collector = HandheldCollector(still, budget=budget, turn_budget=turn_budget)
        collector.add(align(record.six_channels(), use_reference=False))
        parts.append(collector.record())
    return pooled(parts, [f'rec{item.index:02d}' for item in simulated])


def chamber(scenario, habits, seed: int, rate_hz: float) -> UnitCalibration:
    """The same unit's chamber calibration: a rate table through plateaus over the month's span, its own power-up."""
    low, high = habits.temperature_span()
    rng = np.random.default_rng([seed, 77])
    units = {}
    for name, sensor in (('accel_unit', 'accel'), ('gyro_unit', 'gyro')):
        draw = rng.standard_normal(3) * habits.turn_on(sensor)
        units[name] = tuple(replace(axis, offset=axis.offset + d) for axis, d in zip(getattr(scenario, name), draw))
    plateaus = tuple(float(t) for t in np.linspace(low, high, 6))
    table = replace(scenario, **units, sample_rate_hz=rate_hz, temp_code_every=1, start_celsius=low,
                    plateaus_celsius=plateaus, plateau_hours=0.25, ramp_celsius_per_minute=1.0, board_lag_s=300.0,
                    dwell_s=20.0, positions=RATE_TABLE_POSITIONS, table_rates=RATE_TABLE_RATES,
                    seed=seed + 100_003)
    driver = simulate(table).driver
    fits = {sensor: fit_model(align(driver.channel(sensor)), bias_order=3, scale_order=2).calibration
            for sensor in ('accel', 'gyro')}
    return UnitCalibration(InputKind.IMU, fits['accel'], fits['gyro'])


def android_line(record) -> tuple[np.ndarray, np.ndarray]:
    """Android's over-temperature line per gyroscope axis from a pool's rests: ``(slope (3,), intercept (3,))``."""
    from tak_thermo_ros.core.records.handheld import numbered_rests
    interval, count, _, _ = numbered_rests(record)
    samples = np.bincount(interval, minlength=count).astype(float)
    stamps = record.still.stamp_s
    first = np.full(count, np.inf)
    last = np.full(count, -np.inf)
    np.minimum.at(first, interval, stamps)
    np.maximum.at(last, interval, stamps)
    temperature = np.bincount(interval, weights=record.still.temp_code, minlength=count) / samples
    bias = np.column_stack([np.bincount(interval, weights=record.still.counts[:, 3 + axis], minlength=count)
                            for axis in range(3)]) / samples[:, None]
    long_enough = (last - first) >= ANDROID_MIN_REST_S
    points: dict[int, tuple[float, float, np.ndarray]] = {}
    for rest in np.argsort(last):  # in time order: a bin keeps its newest point
        if long_enough[rest]:
            points[int(math.floor(temperature[rest] / ANDROID_BIN_C))] = (last[rest], temperature[rest], bias[rest])
    kept = list(points.values())
    t = np.array([p[1] for p in kept])
    b = np.array([p[2] for p in kept])
    design = np.column_stack([t, np.ones_like(t)])
    solution, *_ = np.linalg.lstsq(design, b, rcond=None)
    return solution[0], solution[1]


def judged_rests(simulated, correct_accel, correct_gyro, within: tuple[float, float] | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A held-out record's rests: mean corrected rate ``(k, 3)``, ``|f| - g`` ``(k,)``, samples ``(k,)``.

    :param within: only the rests whose mean temperature lies within this range (``None``: all).
    """
    record = simulated.record
    temperature = np.interp(record.stamp_ns.astype(float), record.temp_stamp_ns.astype(float), record.temperature)
    gyro = correct_gyro(record.gyro, temperature)
    accel = correct_accel(record.accel, temperature) if correct_accel is not None else None
    rates, gravity, counts = [], [], []
    margin = int(round(EDGE_S * simulated.scenario.sample_rate_hz))
    for rest in range(len(simulated.up)):
        rows = np.flatnonzero(simulated.rest == rest)[margin:-margin or None]
        if len(rows) < 2:
            continue
        if within is not None and not within[0] <= temperature[rows].mean() <= within[1]:
            continue
        rates.append(gyro[rows].mean(axis=0))
        if accel is not None:
            gravity.append(float(np.linalg.norm(accel[rows].mean(axis=0))) - simulated.scenario.gravity)
        counts.append(len(rows))
    return np.array(rates), np.array(gravity), np.array(counts, dtype=float)


def shape_rms(per_record: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """``(3,)`` RMS over the rests of each rest's mean minus its record's (samples-weighted) mean."""
    residuals = []
    for means, counts in per_record:
        if len(means):
            residuals.append(means - np.average(means, axis=0, weights=counts))
    return np.sqrt(np.mean(np.vstack(residuals) ** 2, axis=0))


def _corrector(unit: UnitCalibration, sensor: str):
    corrector = Corrector(unit.sensor(sensor))
    return lambda values, temperature: corrector.correct(values, temperature)


def offset_errors(calibration) -> np.ndarray:
    """``(3,)`` the accelerometer offsets' standard errors from the file's ``uncertainty``, given its couplings.

    The file's covariance of the offsets at the reference temperature, conditional on the couplings'
    errors (the Schur complement): near level a coupling into the gravity axis acts as an offset
    (``g c_zx u_x`` as ``b_x u_x``), so the offsets are stated for the couplings the file holds
    (the simulated triad is orthogonal: its couplings are 0). ``nan`` without the section.
    """
    uncertainty = calibration.uncertainty
    if uncertainty is None:
        return np.full(3, np.nan)
    names = uncertainty.terms
    offsets = [names.index(f'{axis}.offset') for axis in 'xyz']
    couplings = [j for j, name in enumerate(names) if name.startswith('c_')]
    matrix = uncertainty.covariance
    conditional = matrix[np.ix_(offsets, offsets)]
    if couplings:
        across = matrix[np.ix_(offsets, couplings)]
        conditional = conditional - across @ np.linalg.pinv(matrix[np.ix_(couplings, couplings)]) @ across.T
    return np.sqrt(np.maximum(np.diag(conditional), 0.0))


def offset_coverage(calibration, truth: UnitCalibration) -> dict[str, list]:
    """The accelerometer offsets x y z at the file's reference temperature: value, standard error, truth (m/s^2)."""
    reference = calibration.temp_code_ref
    return {'fitted': [float(axis.offset) for axis in calibration.axes],
            'error': offset_errors(calibration).tolist(),
            'truth': [float(axis.offset + axis.offset_drift(reference - truth.accel.temp_code_ref))
                      for axis in truth.accel.axes]}


def _orders(calibration) -> dict[str, list[int]]:
    """The orders a pool's file notes say were chosen (``offset order ... x y z 3 3 3``)."""
    found = {}
    for note in calibration.notes:
        if 'offset order' in note:
            sensor = 'gyro' if note.startswith('gyroscope') else 'accel'
            found[sensor] = [int(word) for word in note.split(',')[0].split()[-3:]]
    return found


def check_seed(seed: int, *, records: int = 16, held_out: int = 4, minutes: float = 30.0, rate_hz: float = 50.0,
               chamber_rate_hz: float = 10.0, setting: str = 'first', pool_file=None) -> dict[str, object]:
    """One seed's figures (see the module's description).

    :param pool_file: the pool's calibration file as ``tak_calib fit`` wrote it (``None``: fitted here, in memory).
    """
    from tak_thermo_ros.formats.calibration_file import load_unit
    scenario, habits = month(seed, records=records, held_out=held_out, minutes=minutes, rate_hz=rate_hz,
                             setting=setting)
    training = [simulate_everyday_record(scenario, habits, index) for index in range(records)]
    record = pool_of(training)
    truth_offsets = np.array([item.turn_on['gyro'] for item in training])
    del training
    if pool_file is None:
        fitted = fit_pool(record, HandheldSettings())
        ours = UnitCalibration(InputKind.IMU, fitted.fit.results['accel'].calibration,
                               fitted.fit.results['gyro'].calibration)
    else:
        ours = load_unit(pool_file)
    slope, intercept = android_line(record)
    units = {'pool': ours, 'chamber': chamber(scenario, habits, seed, chamber_rate_hz),
             'truth': everyday_truth(scenario, habits)}
    # Judged where the pool has been (a record hotter than any of the month's is beyond every everyday
    # calibration: clamped); the figures over every rest are kept beside.
    span = (ours.gyro.temp_code_min, ours.gyro.temp_code_max)
    gyro: dict[str, list] = {name: [] for name in (*units, 'android')}
    gyro_all: dict[str, list] = {name: [] for name in (*units, 'android')}
    gravity: dict[str, list] = {name: [] for name in units}
    outside = total = 0
    android = lambda g, t: g - (slope[None, :] * t[:, None] + intercept)  # noqa: E731
    for index in range(records, records + held_out):
        simulated = simulate_everyday_record(scenario, habits, index)
        for name, unit in (*units.items(), ('android', None)):
            accel = None if unit is None else _corrector(unit, 'accel')
            correct = android if unit is None else _corrector(unit, 'gyro')
            for within, into in ((span, gyro), (None, gyro_all)):
                rates, magnitude, counts = judged_rests(simulated, accel, correct, within)
                into[name].append((rates, counts))
                if within is not None and unit is not None:
                    gravity[name].append(magnitude)
        total += len(simulated.up)
        outside += len(simulated.up) - len(gyro['pool'][-1][0])
    turn_on = ours.gyro.turn_on
    spread, spread_error = np.array(turn_on.repeatability), np.array(turn_on.repeatability_error)
    true_spread = habits.turn_on('gyro')
    covered = np.abs(spread - true_spread) <= 2.0 * spread_error
    return {
        'seed': seed,
        'gyro_shape_rms': {name: shape_rms(values).tolist() for name, values in gyro.items()},
        'gyro_shape_rms_all_rests': {name: shape_rms(values).tolist() for name, values in gyro_all.items()},
        'rests_outside_pool_range': outside, 'rests': total,
        'gravity_rms': {name: float(np.sqrt(np.mean(np.concatenate(values) ** 2))) for name, values in gravity.items()},
        'repeatability': spread.tolist(), 'repeatability_error': spread_error.tolist(),
        'true_repeatability': true_spread.tolist(),
        'sample_spread': truth_offsets.std(axis=0, ddof=1).tolist(),
        'covered': covered.tolist(),
        'orders': _orders(ours.gyro),
        'accel_offsets': offset_coverage(ours.accel, units['truth']),
        'left_out': [note.split(':')[0] for note in ours.gyro.notes if 'left out' in note],
    }
