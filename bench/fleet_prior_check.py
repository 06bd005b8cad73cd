"""The fleet prior's check: a new unit's first hour with a fleet's prior, judged on its later records.

Per seed: a fleet of ``units`` units of one part (:mod:`tak_thermo_ros.core.simulation.fleet`: each
unit's offset, slope, curvature and cubic term drawn around the part's), each with ``records``
everyday records (:mod:`tak_thermo_ros.core.simulation.everyday`), pooled and reduced to its
statistics as ``fit-fleet --everyday`` does (in memory: the rests found from each record); the
fleet's prior from them. A new unit of the same part: its **first hour** (``hour_records`` records
at ``hour_ambient`` C: one warm-up of the board), its **later records** at ``later_ambients`` (mostly
outside the hour's temperatures) the judge. Calibrations of the new unit side by side:

- ``hour``: the first hour alone, as ``tak_calib fit`` does today (its orders chosen by leaving records out);
- ``mean``: the fleet's mean curve alone (no record of the unit);
- ``prior``: the first hour with the prior (``fit --prior``);
- ``oracle``: the first hour with the part's true mean curve and the true spread as the prior (the best
  a prior can do; what the estimated prior loses to it is the price of estimating it from the fleet);
- ``chamber``: the unit's own chamber calibration (a rate table through plateaus, its own power-up);
- ``truth``: the simulation's truth (its errors are the noise alone: the floor).

Judged as :mod:`everyday_check` judges a pool: the gyroscope's bias shape at the later records'
rests (each rest's mean corrected rate, each record's own mean taken off, RMS over rests and
axes) and ``|f| - g`` at the rests (RMS).

**Leaving each unit out** (:func:`leave_one_out`): the prior from the other units; the left-out
unit's true offset curve on every axis the prior holds (gyroscope x y z, accelerometer x y z: see
:func:`true_curves`; its level, the mean over power-ups, is part of it) checked against the prior's
band, mean +- 2 sigma, at temperatures across the fleet's span (the coverage: about 95 % if the
spread is right); and the left-out unit's own records corrected by the prior's mean alone and by
the prior with the unit's first record (the bias shape).
"""

from __future__ import annotations

import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from everyday_check import chamber, judged_rests, pool_of, shape_rms  # noqa: E402

from tak_thermo_ros.core.fit.design import Frame  # noqa: E402
from tak_thermo_ros.core.fit.fleet_prior import offset_band  # noqa: E402
from tak_thermo_ros.core.fit.handheld import HandheldSettings  # noqa: E402
from tak_thermo_ros.core.fit.model import calibration_from  # noqa: E402
from tak_thermo_ros.core.fit.pool import fit_pool  # noqa: E402
from tak_thermo_ros.core.fit.prior_fit import fit_with_prior, fleet_from_units, unit_statistics  # noqa: E402
from tak_thermo_ros.core.link.correction import Corrector  # noqa: E402
from tak_thermo_ros.core.link.model import InputKind, UnitCalibration  # noqa: E402
from tak_thermo_ros.core.simulation.everyday import everyday_scenario, simulate_everyday_record  # noqa: E402
from tak_thermo_ros.core.simulation.fleet import Fleet, fleet_unit  # noqa: E402
from tak_thermo_ros.core.simulation.imu import exact_output  # noqa: E402

SETTINGS = {
    'default': {},
    'other': {'rest_s': [10.0, 60.0], 'motion_s': [30.0, 200.0], 'motion_heating_celsius': -2.0,
              'self_heating_celsius': 14.0, 'ambient_drift_celsius': 5.0, 'board_tau_s': 400.0, 'tilt_deg': 5.0},
}
"""Everyday habits: the simulator's defaults (what the feature was built on), another setting (the claim's judge)."""


FLEET_AMBIENT = (-5.0, 35.0)
"""The fleet's days: winter to summer (a new unit's later records at 0, 12 and 30 C lie within what the fleet saw)."""


def fleet_scenario(seed: int, *, rate_hz: float, minutes: float, records: int, setting: str):
    """The part's scenario and the units' habits."""
    return everyday_scenario({'sample_rate_hz': rate_hz, 'seed': seed,
                              'everyday': {'records': records, 'record_minutes': minutes,
                                           'ambient_celsius': list(FLEET_AMBIENT), **SETTINGS[setting]}})


def unit_records(scenario, habits, *, ambient: tuple[float, float] | None, count: int, first: int):
    """``count`` records of a unit (its record numbers from ``first``), at an ambient when given."""
    own = habits if ambient is None else replace(habits, ambient_celsius=ambient, ambient_drift_celsius=1.0)
    own = replace(own, records=max(own.records, first + count))
    return [simulate_everyday_record(scenario, own, index) for index in range(first, first + count)]


def mean_calibration(prior) -> UnitCalibration:
    """The fleet's mean curves as a calibration (scales held at 1; the axes outside the prior at 0)."""
    frame = Frame(ref=prior.basis.ref, low=prior.low, high=prior.high, n_scale=prior.basis.n_scale)
    links = {}
    for sensor in ('accel', 'gyro'):
        fleet = prior.sensors[sensor]
        mean = fleet.mean
        betas = []
        for axis in 'xyz':
            beta = np.zeros(prior.bias_order + 1)
            for index, name in enumerate(fleet.names):
                if name.startswith(f'{axis}.offset'):
                    power = int(name.split('_T')[1]) if '_T' in name else 0
                    beta[power] = mean[index]
            betas.append(beta)
        links[sensor] = calibration_from(frame, betas, bias_order=prior.bias_order, scale_order=0,
                                         held_scales=(1.0, 1.0, 1.0))
    return UnitCalibration(InputKind.IMU, links['accel'], links['gyro'])


def _corrector(unit: UnitCalibration, sensor: str):
    corrector = Corrector(unit.sensor(sensor))
    return lambda values, temperature: corrector.correct(values, temperature)


def judge(units: dict[str, UnitCalibration], later: list) -> dict[str, dict[str, float]]:
    """Each calibration's gyroscope bias shape (RMS over rests and axes) and ``|f| - g`` RMS on the later records."""
    out = {}
    for name, unit in units.items():
        shapes, gravity = [], []
        for simulated in later:
            rates, magnitude, counts = judged_rests(simulated, _corrector(unit, 'accel'), _corrector(unit, 'gyro'))
            shapes.append((rates, counts))
            gravity.append(magnitude)
        per_axis = shape_rms(shapes)
        out[name] = {'gyro_shape_rms': float(np.sqrt(np.mean(per_axis ** 2))),
                     'gyro_shape_rms_axes': per_axis.tolist(),
                     'gravity_rms': float(np.sqrt(np.mean(np.concatenate(gravity) ** 2)))}
    return out


def true_curves(scenario, temperature: np.ndarray) -> dict[str, np.ndarray]:
    """A unit's true offset curves as the pool fit holds them, ``(k, 3)`` per sensor, a column per axis.

    The gyroscope's x y z at rest; the accelerometer's at 1 g along z, the gravity taken off: x and y their
    offsets (the tilts of the rests tell them apart from their scales), z its offset with its scale's error
    and drift at 1 g (the rests near level cannot tell them apart).
    """
    n = np.asarray(temperature, dtype=float) - scenario.reference_celsius
    gyro = exact_output(scenario.gyro_unit, np.zeros((len(n), 3)), n)
    force = np.zeros((len(n), 3))
    force[:, 2] = scenario.gravity
    return {'gyro': gyro, 'accel': exact_output(scenario.accel_unit, force, n) - force}


def fleet_of(seed: int, fleet: Fleet, *, rate_hz: float, minutes: float, records: int, setting: str):
    """The part's scenario, the habits, and each unit's statistics (and its scenario)."""
    scenario, habits = fleet_scenario(seed, rate_hz=rate_hz, minutes=minutes, records=records, setting=setting)
    units = []
    for index in range(fleet.units):
        own = fleet_unit(scenario, fleet, index)
        pool = pool_of([simulate_everyday_record(own, habits, i) for i in range(records)])
        units.append((own, unit_statistics(f'unit{index:02d}', pool, HandheldSettings())))
    return scenario, habits, units


def check_seed(seed: int, *, units: int = 8, records: int = 5, minutes: float = 30.0, rate_hz: float = 25.0,
               hour_records: int = 2, hour_ambient: float = 22.0, later_ambients=(0.0, 12.0, 30.0),
               setting: str = 'default', fleet: Fleet | None = None) -> dict[str, object]:
    """One seed's figures: the new unit side by side, and the fleet's leave-one-unit-out (see the module)."""
    fleet = fleet or Fleet(units=units + 1)
    scenario, habits, drawn = fleet_of(seed, replace(fleet, units=units), rate_hz=rate_hz, minutes=minutes,
                                       records=records, setting=setting)
    prior = fleet_from_units([stats for _, stats in drawn], bias_order=3, scale_order=2)
    new = fleet_unit(scenario, replace(fleet, units=units + 1), units)  # a unit the prior never saw
    hour = unit_records(new, habits, ambient=(hour_ambient, hour_ambient), count=hour_records, first=0)
    hour_pool = pool_of(hour)
    later = [record for k, ambient in enumerate(later_ambients)
             for record in unit_records(new, habits, ambient=(ambient, ambient), count=1, first=100 + k)]
    own = fit_pool(hour_pool, HandheldSettings()).fit
    borrowed = fit_with_prior(hour_pool, HandheldSettings(), prior)
    with_prior = borrowed.pool.fit
    oracle = fit_with_prior(hour_pool, HandheldSettings(), oracle_prior(scenario, fleet, prior)).pool.fit
    calibrations = {
        'hour': UnitCalibration(InputKind.IMU, own.results['accel'].calibration, own.results['gyro'].calibration),
        'mean': mean_calibration(prior),
        'prior': UnitCalibration(InputKind.IMU, with_prior.results['accel'].calibration,
                                 with_prior.results['gyro'].calibration),
        'oracle': UnitCalibration(InputKind.IMU, oracle.results['accel'].calibration,
                                  oracle.results['gyro'].calibration),
        'chamber': chamber(new, replace(habits, ambient_celsius=(min(later_ambients), max(later_ambients))), seed,
                           10.0),
        'truth': UnitCalibration(InputKind.IMU, *(
            replace(link, temp_code_min=-40.0, temp_code_max=85.0) for link in
            (_truth(new, 'accel'), _truth(new, 'gyro')))),
    }
    figures = judge(calibrations, later)
    hour_span = (float(hour_pool.still.temp_code.min()), float(hour_pool.still.temp_code.max()))
    later_t = np.concatenate([np.interp(r.record.stamp_ns.astype(float), r.record.temp_stamp_ns.astype(float),
                                        r.record.temperature)[r.rest >= 0] for r in later])
    outside = float(np.mean((later_t < hour_span[0]) | (later_t > hour_span[1])))
    return {'seed': seed, 'setting': setting, 'units': units, 'records': records, 'figures': figures,
            'hour_span': hour_span, 'later_rest_share_outside_hour': outside,
            'fleet_span': (prior.low, prior.high),
            'left_out': [f.name for s in prior.sensors.values() for f in s.left_out],
            'groups': {s: len(f.groups) for s, f in prior.sensors.items()},
            'new_unit_group': [line for line in borrowed.lines if 'group' in line],
            'new_unit_slope_shift': 'up' if units % max(fleet.groups, 1) else 'down',
            'loo': leave_one_out(drawn, habits, prior_span=(prior.low, prior.high))}


def oracle_prior(scenario, fleet: Fleet, prior):
    """The part's true curves and the fleet's true spread as a prior in ``prior``'s basis (its other parts kept)."""
    from tak_thermo_ros.core.fit.fleet_prior import Group
    from tak_thermo_ros.core.fit.prior import Basis, term_change
    raw = Basis(scenario.reference_celsius, 1.0)
    sensors = {}
    for sensor, estimated in prior.sensors.items():
        names = estimated.names
        mean = np.zeros(len(names))
        spread = np.zeros(len(names))
        for index, name in enumerate(names):
            axis, power = 'xyz'.index(name[0]), int(name.split('_T')[1]) if '_T' in name else 0
            truth = (scenario.gyro_unit if sensor == 'gyro' else scenario.accel_unit)[axis]
            scale = [truth.scale - 1.0, *(truth.scale * a for a in truth.scale_coeffs), 0.0, 0.0][:4]
            if name[1:].startswith('.scale'):  # the accelerometer's x and y scales (the units share the part's)
                mean[index] = 1.0 + np.polyval(scale[::-1], prior.basis.ref - scenario.reference_celsius)
                spread[index] = 1e-6
                continue
            coefficients = [truth.offset, *truth.offset_coeffs, 0.0, 0.0, 0.0][:4]
            if sensor == 'accel' and name[0] == 'z':  # z's offset curve at 1 g (true_curves): the scale's in it
                coefficients = [c + scenario.gravity * k for c, k in zip(coefficients, scale)]
            mean[index] = coefficients[power]
            spread[index] = (fleet.gyro if sensor == 'gyro' else fleet.accel)[power]
        change = term_change(names, raw, prior.basis)
        covariance = change @ np.diag(spread ** 2) @ change.T
        group = Group(1.0, change @ mean, covariance, ('truth',))
        sensors[sensor] = replace(estimated, groups=(group,), spread=np.full(len(names), 1e-15),
                                  units=tuple(f'truth{i}' for i in range(1000)))
    return replace(prior, sensors=sensors)


def _truth(scenario, sensor: str):
    from tak_thermo_ros.core.simulation.everyday import everyday_truth
    from tak_thermo_ros.core.simulation.everyday import Everyday
    return everyday_truth(scenario, Everyday(ambient_celsius=(-20.0, 60.0))).sensor(sensor)


def leave_one_out(drawn: list, habits, *, prior_span: tuple[float, float], grid: int = 9) -> dict[str, object]:
    """Each unit left out in turn: its true curves within the others' prior band (2 sigma), per sensor.

    :returns: per sensor the share of (unit, axis, temperature) points covered, the RMS of the
        left-out units' true curve about the prior's mean in units of the band's sigma (1 if right),
        the share covered per axis, and how many units were left out as far.
    """
    temperatures = np.linspace(prior_span[0], prior_span[1], grid)
    covered = {'accel': [], 'gyro': []}
    per_axis = {'accel': {}, 'gyro': {}}
    plain = {'accel': [], 'gyro': []}
    z = {'accel': [], 'gyro': []}
    for index, (scenario, _) in enumerate(drawn):
        others = [stats for k, (_, stats) in enumerate(drawn) if k != index]
        prior = fleet_from_units(others, bias_order=3, scale_order=2, groups=1)
        truth = true_curves(scenario, temperatures)
        for sensor, fleet in prior.sensors.items():
            axes = [a for a in 'xyz' if any(n.startswith(f'{a}.offset') for n in fleet.names)]
            for axis in axes:
                band = offset_band(fleet, axis, temperatures)
                column = 'xyz'.index(axis)
                score = (truth[sensor][:, column] - band.mean) / band.sd
                covered[sensor] += list(np.abs(score) <= 2.0)
                per_axis[sensor].setdefault(axis, []).extend(np.abs(score) <= 2.0)
                z[sensor] += list(score)
                # the band without the widening for few units (its spread's variance / inflation)
                index = [i for i, name in enumerate(fleet.names) if name.startswith(f'{axis}.offset')]
                powers = fleet.basis.powers(temperatures, len(index) - 1)
                unwidened = np.einsum('kp,pq,kq->k', powers, np.diag(fleet.spread[index] ** 2)
                                      + fleet.groups[0].mean_covariance[np.ix_(index, index)], powers)
                plain[sensor] += list(np.abs(truth[sensor][:, column] - band.mean) <= 2.0 * np.sqrt(unwidened))
    return {sensor: {'coverage_2sigma': float(np.mean(covered[sensor])),
                     'coverage_2sigma_unwidened': float(np.mean(plain[sensor])),
                     'coverage_2sigma_axes': {axis: float(np.mean(inside))
                                              for axis, inside in per_axis[sensor].items()},
                     'z_rms': float(np.sqrt(np.mean(np.square(z[sensor])))), 'points': len(covered[sensor])}
            for sensor in covered}


def summary(rows: list[dict]) -> dict[str, object]:
    """Over seeds: each calibration's pooled figures and their ratios to the floor and to the chamber."""
    names = list(rows[0]['figures'])
    pooled = {name: {'gyro_shape_rms': float(np.sqrt(np.mean([r['figures'][name]['gyro_shape_rms'] ** 2
                                                              for r in rows]))),
                     'gravity_rms': float(np.sqrt(np.mean([r['figures'][name]['gravity_rms'] ** 2 for r in rows])))}
              for name in names}
    floor = pooled['truth']['gyro_shape_rms']
    per_seed = {name: [r['figures'][name]['gyro_shape_rms'] / r['figures']['truth']['gyro_shape_rms'] for r in rows]
                for name in names}
    loo = {sensor: {'coverage_2sigma': float(np.mean([r['loo'][sensor]['coverage_2sigma'] for r in rows])),
                    'coverage_2sigma_unwidened': float(np.mean([r['loo'][sensor]['coverage_2sigma_unwidened']
                                                                for r in rows])),
                    'coverage_2sigma_axes': {axis: float(np.mean([r['loo'][sensor]['coverage_2sigma_axes'][axis]
                                                                  for r in rows]))
                                             for axis in rows[0]['loo'][sensor]['coverage_2sigma_axes']},
                    'z_rms': float(np.sqrt(np.mean([r['loo'][sensor]['z_rms'] ** 2 for r in rows])))}
           for sensor in ('accel', 'gyro')}
    return {'seeds': len(rows), 'pooled': pooled,
            'gyro_shape_over_floor': {name: pooled[name]['gyro_shape_rms'] / floor for name in names},
            'gyro_shape_over_floor_median_seed': {name: float(np.median(v)) for name, v in per_seed.items()},
            'gravity_over_chamber': {name: pooled[name]['gravity_rms'] / pooled['chamber']['gravity_rms']
                                     for name in names},
            'leave_one_out': loo,
            'later_rest_share_outside_hour': float(np.mean([r['later_rest_share_outside_hour'] for r in rows]))}


def show(result: dict) -> list[str]:
    """The summary as a person reads it."""
    lines = [f'{result["seeds"]} seeds; later rests outside the hour\'s temperatures: '
             f'{100 * result["later_rest_share_outside_hour"]:.0f} %']
    for name, value in result['gyro_shape_over_floor'].items():
        pooled = result['pooled'][name]
        lines.append(f'  {name:8s} gyro shape {pooled["gyro_shape_rms"] * 180 / math.pi * 3600:7.1f} deg/h = '
                     f'{value:5.2f} x floor (median seed {result["gyro_shape_over_floor_median_seed"][name]:5.2f}); '
                     f'|f| {pooled["gravity_rms"] * 1e3 / 9.80665:6.3f} mg = '
                     f'{result["gravity_over_chamber"][name]:5.2f} x chamber')
    for sensor, values in result['leave_one_out'].items():
        lines.append(f'  leave one unit out, {sensor}: true curve within the prior\'s 2-sigma band '
                     f'{100 * values["coverage_2sigma"]:.1f} % '
                     f'(unwidened {100 * values["coverage_2sigma_unwidened"]:.1f} %), z RMS {values["z_rms"]:.2f}')
        shares = values['coverage_2sigma_axes'].items()
        lines.append('    per axis: ' + ', '.join(f'{axis} {100 * share:.1f} %' for axis, share in shares))
    return lines
