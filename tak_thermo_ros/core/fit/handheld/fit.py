"""The fit of a hand-held record, :func:`fit_handheld`, and what it gives (:class:`HandheldFit`).

It takes the record's rests, fits the accelerometer (:mod:`~tak_thermo_ros.core.fit.handheld.accel`),
then the gyroscope in the frame the accelerometer defines (:mod:`~tak_thermo_ros.core.fit.handheld.gyro`),
a pool's variances in turn (:mod:`~tak_thermo_ros.core.fit.handheld.pooled`), the effects' shapes on
the still samples, and builds each sensor's calibration, its uncertainty and the lines that say
what was held (:mod:`~tak_thermo_ros.core.fit.handheld.held`). :func:`gauge_rotation` and
:func:`sensitivity` relate a unit's matrices to the frame the fit corrects into.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.effects import CrossAxis, Effect, resolve_effect
from tak_thermo_ros.core.effects.base import INPUT, checked_basis, effect_input
from tak_thermo_ros.core.fit.design import Frame, subset
from tak_thermo_ros.core.fit.handheld.accel import GAUGE, AccelProblem, fit_accel
from tak_thermo_ros.core.fit.handheld.gyro import GyroProblem, fit_gyro
from tak_thermo_ros.core.fit.handheld.held import (
    SPAN_PER_ORDER_C,
    held_lines,
    one_orientation,
    order_holds,
    orders_for_span,
)
from tak_thermo_ros.core.fit.handheld.layout import Layout, Terms
from tak_thermo_ros.core.fit.handheld.plateau import PlateauRow, plateau_table
from tak_thermo_ros.core.fit.handheld.pooled import (
    TurnOnFit,
    pooled_accel,
    pooled_gyro,
    turn_on_determined,
    turn_on_fit,
    with_turn_on,
)
from tak_thermo_ros.core.fit.handheld.rests import Rests
from tak_thermo_ros.core.fit.handheld.settings import HandheldSettings
from tak_thermo_ros.core.fit.handheld.system import BOUNDS, Solved, System
from tak_thermo_ros.core.fit.link_uncertainty import link_uncertainty
from tak_thermo_ros.core.fit.model import FitResult, calibration_from, finish_fit, fitted_effects, residual_counts
from tak_thermo_ros.core.fit.prior import Basis, CurvePrior, Information
from tak_thermo_ros.core.fit.random_effects import RecordSystem, Variances
from tak_thermo_ros.core.link.model import AXES, Calibration
from tak_thermo_ros.core.link.uncertainty import LinkUncertainty
from tak_thermo_ros.core.records.handheld import (
    HandheldRecord,
    TurnClosure,
    merged_samples,
    numbered_rests,
    rest_records,
    sensor_samples,
)
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.errors import FitError


ONE_TEMPERATURE_HALF_RANGE_C = 0.5
"""A calibration at one temperature states the range ``T +- this`` (a file needs a range)."""


@dataclass(frozen=True)
class HandheldFit:
    """Both sensors fitted from a hand-held record.

    :param results: per sensor the fit (calibration, residual statistics, ``parameter_errors``:
        ``'x.scale'``, ``'x.offset'`` at the reference temperature, the couplings and effect terms).
    :param lines: what the record determined and what was held, one statement each.
    :param up: ``(k, 3)`` each still interval's up direction in the corrected frame.
    :param closure: the turns' closure after the fit; ``closure_before`` with the driver's values.
    :param plus_minus: the paper's quantities per plateau (empty unless the faces came in opposite pairs).
    :param orders: the bias and scale orders fitted (after the span rule).
    """

    results: dict[str, FitResult]
    lines: tuple[str, ...]
    up: np.ndarray
    closure: TurnClosure
    closure_before: TurnClosure
    plus_minus: tuple[PlateauRow, ...]
    orders: tuple[int, int]
    turn_on: dict[str, TurnOnFit] = field(default_factory=dict)
    """A pool's records (several power-ups): per sensor the turn-on offsets and their spread."""
    information: dict[str, Information] = field(default_factory=dict)
    """With a prior (one without rows too: a fleet's first pass), per sensor what the records say about every
    term the fit did not hold by construction, the prior's rows left out (:mod:`~tak_thermo_ros.core.fit.prior`)."""


def gauge_rotation(matrix: np.ndarray) -> np.ndarray:
    """``Q`` with ``matrix = L Q``, ``L`` lower triangular with a positive diagonal (the accelerometer's gauge).

    A unit whose accelerometer's sensitivity matrix is ``M`` (sensor frame to channels) is
    corrected by a hand-held fit into the frame ``Q`` times the sensor frame; its accelerometer
    reads ``L`` there, its gyroscope ``M_g Q^T``.
    """
    orthogonal, upper = np.linalg.qr(np.asarray(matrix, dtype=float).T)  # M^T = Q^T L^T
    signs = np.sign(np.diag(upper))
    return (orthogonal * signs[None, :]).T


def sensitivity(calibration: Calibration, temperature: float) -> np.ndarray:
    """The sensor's matrix ``diag(K0 F_c(T)) + C`` at one temperature (channels per unit input)."""
    n = float(np.clip(temperature, calibration.temp_code_min, calibration.temp_code_max)) - calibration.temp_code_ref
    matrix = np.diag([axis.scale * float(axis.scale_factor(n)) for axis in calibration.axes])
    for effect in calibration.effects:
        if isinstance(effect, CrossAxis):
            matrix = matrix + np.array(effect.matrix())
    return matrix


def _offset_effects(specs: Sequence, sensor: str) -> tuple[type[Effect], ...]:
    """The effects asked for one sensor: offset effects only (the misalignment is always fitted)."""
    classes = []
    for spec in specs:
        cls = resolve_effect(spec)
        if cls is CrossAxis:
            continue
        if cls.kind == INPUT:
            msg = (f'effect {cls.name}: not fitted from a hand-held record (the {sensor} misalignment, cross_axis, '
                   f'is; a scale nonlinearity needs a table)')
            raise FitError(msg)
        classes.append(cls)
    return tuple(classes)


def _union_bases(effects: Sequence[Effect], frame: Frame, record: HandheldRecord
                 ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Each effect's basis over the still and turn samples together, in time order (effects with memory)."""
    if not effects:
        return [], []
    series, still_rows, turn_rows = merged_samples(record)
    still_bases, turn_bases = [], []
    for effect in effects:
        inputs = effect_input(effect, np.clip(series.temp_code, frame.low, frame.high), series.aux)
        basis = checked_basis(effect, series.stamp_s, inputs)
        still_bases.append(basis[still_rows])
        turn_bases.append(basis[turn_rows])
    return still_bases, turn_bases


def _calibration(solved: Solved, layout: Layout, terms: Terms, notes: tuple[str, ...]) -> Calibration:
    """The correction link of a solve: the axes, the misalignment when any coupling was fitted, the effects."""
    betas = [layout.axis_part(solved.theta, axis) for axis in range(3)]
    fitted_couplings = any(layout.kinds[j] == 'coupling' for j in solved.free)
    effects = fitted_effects([CrossAxis(), *terms.effects], layout.columns, betas)
    if not fitted_couplings:
        effects = effects[1:]
    calibration = calibration_from(terms.frame, betas, bias_order=terms.bias_order, scale_order=terms.scale_order,
                                   held_scales=(None, None, None), notes=notes, effects=effects)
    held_scale = [layout.index(f'{name}.scale') in solved.held for name in AXES]
    axes = tuple(replace(axis, scale_observable=False) if held else axis
                 for axis, held in zip(calibration.axes, held_scale))
    return replace(calibration, axes=axes)  # type: ignore[arg-type]


def fit_handheld(record: HandheldRecord, settings: HandheldSettings = HandheldSettings()) -> HandheldFit:
    """Fit both sensors of a hand-held record (see the package's description).

    :raises FitError: no still interval, too few samples, an effect that cannot be fitted so.
    """
    if not len(record.still):
        msg = ('no still interval: the unit never rested for 2 s or more (rest 5-10 s in each orientation, '
               'docs/handheld.md)')
        raise FitError(msg)
    temperature = record.still.temp_code
    low, high = float(temperature.min()), float(temperature.max())
    prior = settings.prior
    bias_order, scale_order = orders_for_span(high - low, settings.bias_order, settings.scale_order)
    if prior is not None:  # the prior tells what the span cannot: its orders
        bias_order, scale_order = prior.bias_order, prior.scale_order
    lines: list[str] = []
    notes: list[str] = []
    if (bias_order, scale_order) != (settings.bias_order, settings.scale_order) and prior is None:
        if bias_order == 0 and scale_order == 0:
            said = (f'temperature span {high - low:.2g} C ({low:.1f}..{high:.1f} C): offsets, scales and '
                    f'misalignment at {0.5 * (low + high):.1f} C, their temperature terms held at 0 (a fit against '
                    f'temperature needs {SPAN_PER_ORDER_C:g} C per order)')
        else:
            said = (f'temperature span {high - low:.3g} C ({low:.1f}..{high:.1f} C): bias order {bias_order} and '
                    f'scale order {scale_order} (asked {settings.bias_order} and {settings.scale_order}; '
                    f'{SPAN_PER_ORDER_C:g} C per order)')
        lines.append(said)
        notes.append(said)
    if high - low < 2.0 * ONE_TEMPERATURE_HALF_RANGE_C:
        middle = 0.5 * (low + high)
        low, high = middle - ONE_TEMPERATURE_HALF_RANGE_C, middle + ONE_TEMPERATURE_HALF_RANGE_C
    frame = Frame.of_range(low, high, settings.temp_code_ref) if prior is None else prior.frame(
        low, high, settings.temp_code_ref)
    effects = {sensor: _offset_effects(settings.effects.get(sensor, ()), sensor) for sensor in ('accel', 'gyro')}
    if any(effects.values()) and bias_order == 0:
        msg = 'effects need a temperature span: this record was taken at one temperature'
        raise FitError(msg)
    interval, count, turn_interval, used = numbered_rests(record)
    pool = record.records
    still_record = record.still_record
    rest_record = rest_records(record)
    noise = record.intervals.noise
    accel_counts = record.still.counts[:, :3]
    means = np.zeros((count, 3))
    np.add.at(means, interval, accel_counts)
    kept = np.bincount(interval, minlength=count)
    up = means / np.linalg.norm(means, axis=1, keepdims=True)
    measured = up  # the rests' orientation as recorded: one orientation or not, whatever the fit makes of it

    accel_terms = Terms(frame, bias_order, scale_order, records=pool)
    level_line, level = one_orientation(measured, kept, accel_terms.layout())
    if level_line:
        lines.append(level_line)
        notes.append(level_line)
    axis_orders = settings.axis_orders or {}

    def accel_holds(layout: Layout) -> dict[int, float]:
        """The gauge, one orientation's holds and the chosen orders' on a layout of the accelerometer."""
        held = {layout.index(f'cross_axis.{name}'): 0.0 for name in GAUGE}
        if level_line:
            held.update(one_orientation(measured, kept, layout)[1])
        held.update(order_holds(layout, axis_orders.get('accel')))
        return held

    def gyro_holds(layout: Layout) -> dict[int, float]:
        """The chosen orders' holds on a layout of the gyroscope; one orientation holds its scales and couplings.

        Its frame is the accelerometer's, whose tilts take up the other axes' offsets: its misalignment
        is not told, nor its scale by motions closed on those tilts (the motions are not integrated).
        """
        held = order_holds(layout, axis_orders.get('gyro'))
        if level_line:
            held.update({j: (1.0 if kind == 'scale' else 0.0) for j, kind in enumerate(layout.kinds)
                         if kind in ('coupling', 'scale', 'scale_T')})
        return held

    gauge = accel_holds(accel_terms.layout())
    problem = AccelProblem(accel_counts, temperature, interval, accel_terms, [], settings.gravity, noise[:3],
                           still_record)
    problem.turn_on_sigma = np.full(3, BOUNDS['offset', 'accel'])  # weak, until the pool's own spread is known
    _set_prior(problem, prior, 'accel')
    given = settings.variances or {}
    if 'accel' in given:
        problem.turn_on_sigma, problem.rest_variance = given['accel'][0], np.asarray(given['accel'][1]) ** 2
    accel, up = fit_accel(problem, up, gauge)
    turn_on: dict[str, TurnOnFit] = {}
    if pool > 1 and 'accel' not in given:
        accel, up, turn_on['accel'] = pooled_accel(problem, up, gauge, accel)
    shapes: dict[str, FitResult] = {}
    if effects['accel']:
        reference = settings.gravity * up[interval]
        samples = sensor_samples(record.still, 'accel', reference)
        if 'accel' in turn_on:  # a pool: each record's own offset off, the shapes searched on the rest
            samples = replace(samples, counts=samples.counts - turn_on['accel'].offsets[still_record])
        shaped = _shapes(samples, effects['accel'], accel, problem.layout, accel_terms, frame)
        shapes['accel'] = shaped
        offsets = tuple(effect for effect in shaped.calibration.effects if not isinstance(effect, CrossAxis))
        accel_terms = Terms(frame, bias_order, scale_order, offsets, records=pool)
        still_bases, _ = _union_bases(accel_terms.effects, frame, record)
        gauge = accel_holds(accel_terms.layout())
        variances = problem.turn_on_sigma, problem.rest_variance
        problem = AccelProblem(accel_counts, temperature, interval, accel_terms, still_bases, settings.gravity,
                               problem.sigma, still_record)
        problem.turn_on_sigma, problem.rest_variance = variances
        _set_prior(problem, prior, 'accel')
        accel, up = fit_accel(problem, up, gauge)
        if pool > 1 and 'accel' not in given:
            accel, up, turn_on['accel'] = pooled_accel(problem, up, gauge, accel)
    level = one_orientation(measured, kept, problem.layout)[1] if level_line else {}
    accel_layout = problem.layout
    accel_sigma = problem.sigma

    up_noise = float(np.sqrt(np.mean(accel_sigma ** 2))) / (settings.gravity * np.sqrt(np.maximum(kept, 1)))
    if not settings.turns or level:  # one orientation: see the gyroscope's holds below
        used = np.zeros(len(turn_interval), dtype=bool)
    turns_record = _with_turns(record, turn_interval, used)
    gyro_terms = Terms(frame, bias_order, scale_order, records=pool)
    turn_record = (rest_record[turns_record.turns[turns_record.turn_index, 0]] if len(turns_record.turn_index)
                   else np.zeros(0, dtype=np.int64))
    gyro_problem = GyroProblem(turns_record, interval, gyro_terms, [], [], up, noise[3:6], up_noise, settings.latitude,
                               records=(still_record, turn_record))
    gyro_problem.rests.turn_on_sigma = np.full(3, BOUNDS['offset', 'gyro'])
    _set_prior(gyro_problem.rests, prior, 'gyro')
    if 'gyro' in given:
        gyro_problem.rests.turn_on_sigma = given['gyro'][0]
        gyro_problem.rests.rest_variance = np.asarray(given['gyro'][1]) ** 2
    gyro_orders = gyro_holds(gyro_problem.layout)
    gyro, turns, turn_scale = fit_gyro(gyro_problem, gyro_orders)
    if pool > 1 and 'gyro' not in given:
        gyro, turns, turn_scale, turn_on['gyro'] = pooled_gyro(gyro_problem, gyro, turns, turn_scale, gyro_orders)
    if effects['gyro']:
        # The Earth rate (1e-4 rad/s at most) taken off at nominal scale: the scale's error (1e-3) leaves 1e-7.
        at_rest = record.still.counts[:, 3:6] - gyro_problem.reference
        if 'gyro' in turn_on:  # a pool: each record's own offset off, the shapes searched on the rest
            at_rest = at_rest - turn_on['gyro'].offsets[still_record]
        samples = replace(sensor_samples(record.still, 'gyro', np.zeros((len(interval), 3))), counts=at_rest)
        shaped = _shapes(samples, effects['gyro'], gyro, gyro_problem.layout, gyro_terms, frame)
        shapes['gyro'] = shaped
        gyro_terms = Terms(frame, bias_order, scale_order, tuple(shaped.calibration.effects), records=pool)
        still_bases, turn_bases = _union_bases(gyro_terms.effects, frame, turns_record)
        variances = gyro_problem.rests.turn_on_sigma, gyro_problem.rests.rest_variance
        gyro_problem = GyroProblem(turns_record, interval, gyro_terms, still_bases, turn_bases, up, noise[3:6],
                                   up_noise, settings.latitude, records=(still_record, turn_record))
        gyro_problem.rests.turn_on_sigma, gyro_problem.rests.rest_variance = variances
        _set_prior(gyro_problem.rests, prior, 'gyro')
        gyro_orders = gyro_holds(gyro_problem.layout)
        gyro, turns, turn_scale = fit_gyro(gyro_problem, gyro_orders)
        if pool > 1 and 'gyro' not in given:
            gyro, turns, turn_scale, turn_on['gyro'] = pooled_gyro(gyro_problem, gyro, turns, turn_scale,
                                                                   gyro_orders)
    through_frame = gyro_problem.frame_covariance(turns, gyro, accel, problem.sensitivity(accel.theta, up))
    gyro = replace(gyro, covariance=gyro.covariance + through_frame)
    closure = replace(turns.closure, seconds=turns_record.turn_seconds())

    gauge_line = 'accelerometer: gauge c_xy = c_xz = c_yz = 0: corrected x along its x axis, y in its x-y plane'
    source = 'this record' if pool < 2 else 'these records'
    chosen = order_holds(accel_layout, axis_orders.get('accel'))  # the orders' holds are said by the pool
    accel_held = held_lines('accel', accel, accel_layout, gauge=GAUGE, source=source, said=[*level, *chosen])
    gyro_held = held_lines('gyro', gyro, gyro_problem.layout, source=source, said=list(gyro_orders))
    if level:
        gyro_held.insert(0, 'gyroscope: scales and misalignment held, the motions not integrated: its frame is the '
                            'accelerometer\'s, which one orientation does not fix')
    coupled = any(accel_layout.kinds[j] == 'coupling' for j in accel.free)
    said_gauge = [gauge_line] if coupled or not level else []  # no coupling fitted: no gauge to say
    lines += [*said_gauge, *accel_held, *gyro_held]
    accel_cal = _calibration(accel, accel_layout, accel_terms, tuple(notes + said_gauge + accel_held))
    gyro_cal = _calibration(gyro, gyro_problem.layout, gyro_terms, tuple(notes + gyro_held))
    accel_cal = replace(accel_cal, uncertainty=_uncertainty(accel, accel_layout, 'accel', frame, settings))
    gyro_cal = replace(gyro_cal, uncertainty=_uncertainty(gyro, gyro_problem.layout, 'gyro', frame, settings))
    for sensor, solved, layout in (('accel', accel, accel_layout), ('gyro', gyro, gyro_problem.layout)):
        if pool > 1 and sensor not in turn_on:  # the variances were given
            spread, extra = given[sensor]
            determined = turn_on_determined(layout, solved.held)
            variances = Variances(np.where(determined, spread, np.nan), np.full(3, np.nan), np.asarray(extra),
                                  determined)
            turn_on[sensor] = turn_on_fit(solved, layout, variances, pool)
    # A pool's residual at the rests: each record's own turn-on offset taken off
    own = {sensor: (turn_on[sensor].offsets[still_record] if sensor in turn_on else 0.0)
           for sensor in ('accel', 'gyro')}
    accel_samples = sensor_samples(record.still, 'accel', settings.gravity * up[interval])
    gyro_samples = sensor_samples(record.still, 'gyro', gyro_problem.reference)
    if pool > 1:
        accel_samples = replace(accel_samples, counts=accel_samples.counts - own['accel'])
        gyro_samples = replace(gyro_samples, counts=gyro_samples.counts - own['gyro'])
        accel_cal, gyro_cal = (with_turn_on(calibration, turn_on[sensor], pool)
                               for sensor, calibration in (('accel', accel_cal), ('gyro', gyro_cal)))
    results = {
        'accel': _result(accel_cal, accel, accel_layout, accel_samples, record, shapes),
        'gyro': _result(gyro_cal, gyro, gyro_problem.layout, gyro_samples, record, shapes),
    }
    before = replace(gyro_problem.turn_rows(gyro_problem.layout.initial(), rows_needed=False).closure,
                     seconds=closure.seconds)
    if turn_scale > 1.0:
        lines.append(f'gyroscope: the turns close {math.sqrt(turn_scale):.2f}x worse than the noise predicts; '
                     f'their weight is lowered by that much')
    table = plateau_table(record.still, interval, up, accel_cal, settings.gravity)
    information = {}
    if prior is not None:  # what a fleet's prior is made of, or chooses a unit's group by
        span = (float(temperature.min()), float(temperature.max()))
        gyro_system = gyro_problem.still_system().plus(turns.rows, gyro_problem.turn_row_record)
        information = {'accel': _information(problem.system(accel.theta, up), problem, gauge, accel, frame, span),
                       'gyro': _information(gyro_system, gyro_problem.rests, gyro_orders, gyro, frame, span)}
    return HandheldFit(results=results, lines=tuple(lines), up=up, closure=closure, closure_before=before,
                       plus_minus=table, orders=(bias_order, scale_order), turn_on=turn_on, information=information)


def _set_prior(rests: Rests, prior: CurvePrior | None, sensor: str) -> None:
    """A sensor's rests take a prior's rows on their curve terms (none without a prior)."""
    if prior is not None:
        rests.curve_rows = prior.rows(sensor, rests.layout.names)


def _information(system: System | RecordSystem, rests: Rests, structural: dict[int, float], solved: Solved,
                 frame: Frame, span: tuple[float, float]) -> Information:
    """What the records say about every term not held by construction: the system's normal matrix, its prior rows out.

    ``structural``: the terms held by construction (the gauge, one orientation, the orders) go in at their values.
    """
    layout = rests.layout
    normal = system.normal() - rests.curve_rows.T @ rests.curve_rows
    free = [j for j in range(layout.width) if j not in structural]
    carry = np.zeros((layout.width + 1, len(free) + 1))  # [theta; -1] = carry [theta_free; -1]
    carry[free, np.arange(len(free))] = 1.0
    for j, value in structural.items():
        carry[j, -1] = -value
    carry[-1, -1] = 1.0
    held = tuple(layout.names[j] for j in solved.held if j not in structural)
    return Information(tuple(layout.names[j] for j in free), carry.T @ normal @ carry, Basis.of_frame(frame),
                       span[0], span[1], rows=system.count, held=held)


def _uncertainty(solved: Solved, layout: Layout, sensor: str, frame: Frame,
                 settings: HandheldSettings) -> LinkUncertainty:
    """The link's own uncertainty (:mod:`~tak_thermo_ros.core.fit.link_uncertainty`), held terms included.

    The gauge is no error (it defines the corrected frame: ``|f|`` and the rates at rest do not
    see it); the gyroscope's carries its offsets only (at rest its scales and couplings multiply
    the Earth rate alone: a few hundredths of a deg/h).
    """
    whole = solved.normal  # built from the system's factors: once
    normal = whole[:-1, :-1]
    gradient = whole[:-1, -1] - normal @ solved.theta
    names = layout.names
    held = [j for j in solved.held if names[j].split('.')[-1] not in GAUGE]
    offsets = [j for j in [*solved.free, *held] if layout.kinds[j] in ('offset', 'offset_T')]
    carried = None if sensor == 'accel' else offsets
    return link_uncertainty(names, layout.kinds, normal, gradient, solved.free, solved.covariance,
                            _held_variance(solved, layout), held, sensor=sensor,
                            temperature_scale=frame.n_scale, spreads=settings.held_spreads, carried=carried)


def _held_variance(solved: Solved, layout: Layout) -> np.ndarray:
    """Per column the variance scale a held term's error from the records takes.

    The model's (the solve's residual scale), times per axis how far the records' scatter widened
    its fitted offset terms' variances (:func:`~tak_thermo_ros.core.fit.handheld.system.record_robust`,
    their mean ratio; at least 1): a term held beside them is known no better than they are.
    """
    variance = np.full(layout.width, solved.variance)
    if solved.widening is None:
        return variance
    for axis in range(3):
        span = range(layout.starts[axis], layout.starts[axis] + len(layout.columns[axis]))
        widened = [solved.widening[i] for i, j in enumerate(solved.free)
                   if j in span and layout.kinds[j] in ('offset', 'offset_T') and np.isfinite(solved.widening[i])]
        if widened:
            variance[list(span)] *= max(1.0, float(np.mean(widened)))
    return variance


def _with_turns(record: HandheldRecord, pairs: np.ndarray, used: np.ndarray) -> HandheldRecord:
    """The record with its turns' intervals counted among the kept ones, turns without both left out."""
    if used.all():
        return replace(record, turns=pairs.reshape(-1, 2))
    keep_turn = np.flatnonzero(used)
    mapping = np.full(len(used), -1)
    mapping[keep_turn] = np.arange(len(keep_turn))
    rows = used[record.turn_index]
    return replace(record, turns=pairs[used], turn=subset(record.turn, rows),
                   turn_index=mapping[record.turn_index[rows]])


def _shapes(samples: AlignedSamples, effects: Sequence[type[Effect]], solved: Solved, layout: Layout,
            terms: Terms, frame: Frame) -> FitResult:
    """The effects' shapes, searched by :func:`fit_model` on the still samples with the hand-held reference."""
    from tak_thermo_ros.core.fit import fit_model
    nominal = tuple(float(solved.theta[layout.index(f'{name}.scale')]) for name in AXES)
    try:
        return fit_model(samples, effects=tuple(effects), bias_order=max(terms.bias_order, 1),
                         scale_order=terms.scale_order, temp_code_ref=frame.ref, nominal_scale=nominal)
    except FitError as err:
        msg = f'the effects\' shapes on the still intervals: {err}'
        raise FitError(msg) from None


def _result(calibration: Calibration, solved: Solved, layout: Layout, samples: AlignedSamples,
            record: HandheldRecord, shapes: dict[str, FitResult]) -> FitResult:
    """The sensor's :class:`FitResult`: residual at the still samples through the correction path, the errors."""
    residual = residual_counts(calibration, samples)
    parameters = [sum(1 for j in solved.free if layout.starts[axis] <= j < layout.starts[axis]
                      + len(layout.columns[axis])) for axis in range(3)]
    errors = solved.errors(layout)
    for shaped in shapes.values():
        for effect in calibration.effects:
            for name in effect.shape_names():
                key = f'{effect.name}.{name}'
                if key in shaped.parameter_errors:
                    errors[key] = shaped.parameter_errors[key]
    return finish_fit(calibration, residual, parameters, dropped=record.dropped, parameter_errors=errors)
