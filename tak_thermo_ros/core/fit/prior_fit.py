"""A fleet's prior over both sensors, made from its units' pools, and a unit's pool fitted with it.

The fleet (:func:`fleet_from_units`): each unit's pool fitted at the fleet's orders
(:func:`unit_statistics`: the pool fit with a prior that fixes only the orders, no order choice),
reduced to its information on its curve terms; per sensor the prior of
:func:`~tak_thermo_ros.core.fit.fleet_prior.fleet_prior` in one basis (the middle of every unit's
temperatures, their half-span); the units' turn-on repeatability (its median per axis) beside.

A unit (:func:`fit_with_prior`): its pool through the same fit with the prior's rows
(:class:`~tak_thermo_ros.core.fit.prior.CurvePrior`), in the prior's basis and orders, over the
prior's temperatures and its own; where the fleet falls in groups, the group its records put it in
(a first fit without the prior's rows tells). A pool of fewer than :data:`OWN_TURN_ON_RECORDS` records
takes the fleet's turn-on repeatability. Each sensor's calibration carries its uncertainty
(:class:`~tak_thermo_ros.core.link.uncertainty.LinkUncertainty`, the section every fit writes): the
posterior's covariance of the prior's curve terms (records and prior), the share of each term's precision
the records gave, and the temperatures the records saw.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, replace
from typing import Mapping, Sequence

import numpy as np

from tak_thermo_ros.core.fit.design import Frame
from tak_thermo_ros.core.fit.fleet_prior import FEW_UNITS, MAX_GROUPS, SensorFleet, fleet_prior
from tak_thermo_ros.core.fit.handheld import HandheldSettings
from tak_thermo_ros.core.fit.pool import PoolFit, fit_pool
from tak_thermo_ros.core.fit.prior import Basis, CurvePrior, Information, SensorPrior
from tak_thermo_ros.core.link.model import AXES, TurnOn, UnitCalibration
from tak_thermo_ros.core.link.uncertainty import LinkUncertainty
from tak_thermo_ros.core.records.handheld import HandheldRecord
from tak_thermo_ros.core.values import SENSOR_NAMES
from tak_thermo_ros.errors import FitError

OWN_TURN_ON_RECORDS = 6
"""A pool of fewer records takes the fleet's turn-on repeatability (its own REML of a few records is wide)."""
SENSORS = ('accel', 'gyro')


@dataclass(frozen=True)
class UnitStatistics:
    """What a unit's pool tells a fleet: per sensor its information on its curve terms, its turn-on spread.

    :param records: the records pooled (after those left out as another unit's).
    :param turn_on: per sensor ``(repeatability (3,), rests' extra (3,))`` (``nan``: not determined).
    """

    name: str
    records: int
    information: Mapping[str, Information]
    turn_on: Mapping[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)

    @property
    def low(self) -> float:
        """The lowest temperature of the unit's rests, C."""
        return min(info.low for info in self.information.values())

    @property
    def high(self) -> float:
        """The highest, C."""
        return max(info.high for info in self.information.values())


def unit_statistics(name: str, record: HandheldRecord, settings: HandheldSettings) -> UnitStatistics:
    """A unit's pool fitted at ``settings``' orders (no order choice), reduced to what a fleet needs."""
    vague = CurvePrior(None, settings.bias_order, settings.scale_order)
    return statistics_of(name, fit_pool(record, replace(settings, prior=vague)))


def statistics_of(name: str, fitted: PoolFit) -> UnitStatistics:
    """What a pool's fit with a prior (one without rows: the orders only) tells a fleet about its unit."""
    turn_on = {sensor: (np.asarray(fit.variances.turn_on, dtype=float), np.asarray(fit.variances.rest, dtype=float))
               for sensor, fit in fitted.fit.turn_on.items()}
    return UnitStatistics(name, fitted.record.records,
                          {sensor: info.curve() for sensor, info in fitted.fit.information.items()}, turn_on)


@dataclass(frozen=True)
class FleetPrior:
    """A fleet's prior over both sensors.

    :param sensors: per sensor its :class:`~tak_thermo_ros.core.fit.fleet_prior.SensorFleet`.
    :param turn_on: per sensor the units' median turn-on repeatability and rests' extra variance per axis
        (``nan``: no unit determined it).
    :param units: every unit the prior was made from (before any was left out); ``records`` theirs.
    :param label: what the prior is, for the files and lines (the prior file's name, its units).
    """

    basis: Basis
    bias_order: int
    scale_order: int
    sensors: Mapping[str, SensorFleet]
    turn_on: Mapping[str, tuple[np.ndarray, np.ndarray]]
    units: tuple[str, ...]
    records: int
    label: str = ''

    @property
    def low(self) -> float:
        """The lowest temperature any unit's records saw, C."""
        return min(fleet.low for fleet in self.sensors.values())

    @property
    def high(self) -> float:
        """The highest, C."""
        return max(fleet.high for fleet in self.sensors.values())

    @property
    def grouped(self) -> bool:
        """Whether a sensor's units fall in groups (a unit's group is chosen from its records)."""
        return any(len(fleet.groups) > 1 for fleet in self.sensors.values())

    def gives_turn_on(self, records: int, sensor: str) -> bool:
        """Whether a pool of ``records`` takes the fleet's turn-on repeatability of ``sensor``.

        It does below :data:`OWN_TURN_ON_RECORDS` records, where the fleet has one.
        """
        return records < OWN_TURN_ON_RECORDS and sensor in self.turn_on

    def vague(self) -> CurvePrior:
        """The prior's basis, orders and temperatures without its rows (a unit's first fit, its group chosen)."""
        return CurvePrior(self.basis, self.bias_order, self.scale_order, self.low, self.high)

    def curve_prior(self, information: Mapping[str, Information] | None = None) -> tuple[CurvePrior, list[str]]:
        """What a unit's fit takes (its group from its ``information``, where the fleet falls in groups).

        :returns: the prior and one statement per sensor whose group was chosen.
        """
        sensors, lines = {}, []
        for sensor, fleet in self.sensors.items():
            info = (information or {}).get(sensor)
            prior, said = fleet.prior_for(info, label=self.label)
            sensors[sensor] = prior
            if said:
                lines.append(f'{SENSOR_NAMES[sensor]}: the prior\'s {said}')
        return replace(self.vague(), sensors=sensors), lines

    def lines(self) -> list[str]:
        """What the prior is made of: units, records, temperatures; a small fleet, the units left out."""
        kept = {sensor: len(fleet.units) for sensor, fleet in self.sensors.items()}
        out = [f'prior: {len(self.units)} units, {self.records} records, {self.low:.1f}..{self.high:.1f} C, '
               f'offset order {self.bias_order}, basis T = {self.basis.ref:g} + {self.basis.n_scale:g} u']
        for sensor, fleet in self.sensors.items():
            groups = 'one group' if len(fleet.groups) == 1 else f'{len(fleet.groups)} groups'
            out.append(f'{SENSOR_NAMES[sensor]}: the prior of {kept[sensor]} units, {groups}, '
                       f'{len(fleet.names)} curve terms' + (f' (not told by any unit: {" ".join(fleet.untold)})'
                                                            if fleet.untold else ''))
            if kept[sensor] < FEW_UNITS:
                out.append(f'{SENSOR_NAMES[sensor]}: a prior from {kept[sensor]} units (fewer than {FEW_UNITS}): '
                           f'its spread is known to about +-{100.0 / math.sqrt(2.0 * (kept[sensor] - 1)):.0f} %')
        return out


def fleet_from_units(units: Sequence[UnitStatistics], *, bias_order: int, scale_order: int,
                     groups: int = MAX_GROUPS, label: str = '') -> FleetPrior:
    """The fleet's prior from its units (see the module's description).

    :raises FitError: as :func:`~tak_thermo_ros.core.fit.fleet_prior.fleet_prior` (too few units).
    """
    if not units:
        msg = 'a prior needs units: none given'
        raise FitError(msg)
    frame = Frame.of_range(min(unit.low for unit in units), max(unit.high for unit in units))
    basis = Basis.of_frame(frame)
    records = {unit.name: unit.records for unit in units}
    sensors = {}
    for sensor in SENSORS:
        given = {unit.name: unit.information[sensor] for unit in units if sensor in unit.information}
        sensors[sensor] = fleet_prior(given, sensor, basis, records=records, groups=groups)
    turn_on = {}
    for sensor in SENSORS:
        found = [unit.turn_on[sensor] for unit in units if sensor in unit.turn_on]
        if found:
            with warnings.catch_warnings():  # an axis no unit determined (its offset held): nan, said so
                warnings.simplefilter('ignore', RuntimeWarning)
                spread = np.nanmedian(np.array([f[0] for f in found]), axis=0)
                rest = np.nanmedian(np.array([f[1] for f in found]), axis=0)
            turn_on[sensor] = (spread, rest)
    return FleetPrior(basis, bias_order, scale_order, sensors, turn_on, tuple(unit.name for unit in units),
                      sum(records.values()), label)


@dataclass(frozen=True)
class PriorFit:
    """A unit's pool fitted with its fleet's prior.

    :param pool: the pool's fit (its calibrations carry their uncertainty, the notes what came from where).
    :param lines: what a person reads: the group, the turn-on repeatability taken, each axis's +-.
    :param uncertainty: per sensor the calibration's :class:`~tak_thermo_ros.core.link.uncertainty.LinkUncertainty`.
    """

    pool: PoolFit
    prior: CurvePrior
    lines: tuple[str, ...]
    uncertainty: Mapping[str, LinkUncertainty]


def fit_with_prior(record: HandheldRecord, settings: HandheldSettings, fleet: FleetPrior) -> PriorFit:
    """A unit's pool fitted with the fleet's prior (see the module's description)."""
    information = None
    if fleet.grouped:
        information = fit_pool(record, replace(settings, prior=fleet.vague())).fit.information
    prior, lines = fleet.curve_prior(information)
    given = None
    if record.records < OWN_TURN_ON_RECORDS and fleet.turn_on:
        given = {sensor: (np.where(np.isfinite(spread), spread, 1.0), np.where(np.isfinite(rest), rest, 0.0))
                 for sensor, (spread, rest) in fleet.turn_on.items()}
        lines.append(f'turn-on repeatability: the fleet\'s ({len(fleet.units)} units; this pool holds '
                     f'{record.records} record{"s" if record.records != 1 else ""})')
    fitted = fit_pool(record, replace(settings, prior=prior, variances=given))
    uncertainty = {}
    for sensor, result in fitted.fit.results.items():
        sensor_prior = prior.sensors.get(sensor)
        if sensor_prior is None:
            continue
        records = fitted.fit.information[sensor].curve()
        if fitted.record.records < 2 and sensor in fleet.turn_on:  # one power-up: its level holds its turn-on
            spread = fleet.turn_on[sensor][0]
            records = records.with_level_spread({axis: float(sd) for axis, sd in zip(AXES, spread)
                                                 if np.isfinite(sd)})
        uncertainty[sensor] = _uncertainty(records, sensor_prior, fleet, result.calibration)
    results = {}
    for sensor, result in fitted.fit.results.items():
        calibration = result.calibration
        if sensor in uncertainty:
            calibration = replace(calibration, uncertainty=uncertainty[sensor])
        if fleet.gives_turn_on(record.records, sensor):
            calibration = _fleet_turn_on(calibration, fleet, sensor)
        results[sensor] = replace(result, calibration=calibration)
    pool = replace(fitted, fit=replace(fitted.fit, results=results))
    return PriorFit(pool, prior, tuple(lines), uncertainty)


def _fleet_turn_on(calibration, fleet: FleetPrior, sensor: str):
    """The calibration with the fleet's turn-on repeatability (where every axis has one), said in a note."""
    spread = fleet.turn_on[sensor][0]
    if not np.all(np.isfinite(spread)):
        return replace(calibration, turn_on=None)
    turn_on = TurnOn(repeatability=tuple(float(v) for v in spread),  # type: ignore[arg-type]
                     repeatability_error=(0.0, 0.0, 0.0), records=max(fleet.records, 2))
    note = f'turn_on: the fleet\'s median repeatability over {len(fleet.units)} units ({fleet.records} records)'
    own = tuple(said for said in calibration.notes if not said.startswith('turn_on not'))  # the records' own, replaced
    return replace(calibration, turn_on=turn_on, notes=(*own, note))


def _uncertainty(records: Information, prior: SensorPrior, fleet: FleetPrior, calibration) -> LinkUncertainty:
    """The calibration's uncertainty with the prior: the posterior's covariance of the prior's curve terms.

    ``(H + P)^-1`` over the prior's terms in its basis (``temperature_scale`` its ``n_scale``; cross-axis
    terms kept), the records' share of each term's precision (``1 - posterior variance / prior variance``),
    the temperatures the records saw; a term the fit held is said held (its spread the prior's); the
    spread of the offset's slope beyond the calibrated range is the fit's own (``calibration``'s section).
    """
    posterior_normal = records.aligned(prior.names)[0] + np.linalg.inv(prior.covariance)
    covariance = np.linalg.inv(posterior_normal)
    share = np.clip(1.0 - np.diag(covariance) / np.diag(prior.covariance), 0.0, 1.0)
    held = tuple(name for name in prior.names if name in records.held)
    own = calibration.uncertainty
    return replace(LinkUncertainty.of(prior.names, covariance, fleet.basis.n_scale, held, ('prior',) * len(held),
                                      own.beyond if own is not None else ()),
                   source='records and prior', prior=fleet.label, records_share=tuple(float(v) for v in share),
                   records_min=float(records.low), records_max=float(records.high))


def unit_with_prior(unit: UnitCalibration, statistics: UnitStatistics, fleet: FleetPrior) -> PriorUnit:
    """A fleet's unit, fitted at the fleet's orders (its ``statistics``' fit), solved again with the prior's rows.

    The unit's records are its statistics (:class:`~tak_thermo_ros.core.fit.prior.Information`: its pool fit's
    system as a normal matrix, the nuisance terms integrated out); the prior's rows add their precision and
    pull: the curve terms are ``(H + P)^-1 (g + P mean)``, what :func:`fit_with_prior` solves from the records'
    rows (one Gauss-Newton step from the unit's own solution, which the unit's many records make exact
    within its noise). Each axis's curve is rebuilt in the prior's basis over the prior's temperatures and
    the unit's; its scales held as the unit's fit held them, its effects, residuals and turn-on repeatability
    its fit's (the fleet's when its pool holds fewer than :data:`OWN_TURN_ON_RECORDS` records).
    """
    prior, lines = fleet.curve_prior(statistics.information)
    sensors, uncertainty = {}, {}
    for sensor, calibration in unit.sensors:
        sensor_prior = prior.sensors.get(sensor)
        records = statistics.information.get(sensor)
        if sensor_prior is None or records is None:
            sensors[sensor] = calibration
            continue
        records = records.in_basis(fleet.basis)
        theta = _posterior_mean(records, sensor_prior)
        calibration = _rebuilt(calibration, theta, fleet, records.low, records.high)
        uncertainty[sensor] = _uncertainty(records, sensor_prior, fleet, calibration)
        calibration = replace(calibration, uncertainty=uncertainty[sensor])
        if fleet.gives_turn_on(statistics.records, sensor):
            calibration = _fleet_turn_on(calibration, fleet, sensor)
        sensors[sensor] = calibration
    return PriorUnit(replace(unit, **sensors), tuple(lines), uncertainty)


@dataclass(frozen=True)
class PriorUnit:
    """A fleet's unit with the prior: its calibration, the statements on its group, each sensor's uncertainty."""

    unit: UnitCalibration
    lines: tuple[str, ...]
    uncertainty: Mapping[str, LinkUncertainty]


def _posterior_mean(records: Information, prior: SensorPrior) -> dict[str, float]:
    """The curve terms ``(H + P)^-1 (g + P mean)`` over the records' terms (a term the fit held keeps its value)."""
    names = [name for name in records.names if name not in records.held]
    hessian, gradient, _ = records.aligned(names)
    precision = np.zeros_like(hessian)
    pull = np.zeros(len(names))
    index = [names.index(name) for name in prior.names if name in names]
    inside = [i for i, name in enumerate(prior.names) if name in names]
    inverse = np.linalg.inv(prior.covariance)
    block = inverse[np.ix_(inside, inside)]
    precision[np.ix_(index, index)] = block
    pull[index] = block @ prior.mean[inside]
    solved = np.linalg.lstsq(hessian + precision, gradient + pull, rcond=1e-12)[0]
    values = dict(zip(names, (float(v) for v in solved)))
    values.update({name: (1.0 if '.scale' in name and '_T' not in name else 0.0) for name in records.held})
    return values


def _rebuilt(calibration, theta: Mapping[str, float], fleet: FleetPrior, low: float, high: float):
    """A sensor's calibration with its curves ``theta`` (the prior's basis) over the prior's and its own range."""
    from tak_thermo_ros.core.fit.model import calibration_from
    frame = Frame(ref=fleet.basis.ref, low=min(low, fleet.low, calibration.temp_code_min),
                  high=max(high, fleet.high, calibration.temp_code_max), n_scale=fleet.basis.n_scale)
    betas, held_scales = [], []
    for name, axis in zip(AXES, calibration.axes):
        offset = [theta.get(f'{name}.offset' + (f'_T{k}' if k else ''), 0.0) for k in range(fleet.bias_order + 1)]
        if axis.scale_observable and f'{name}.scale' in theta:
            scale = [theta.get(f'{name}.scale' + (f'_T{k}' if k else ''), 0.0) for k in range(fleet.scale_order + 1)]
            betas.append(np.array([*scale, *offset]))
            held_scales.append(None)
        else:
            betas.append(np.array(offset))
            held_scales.append(axis.scale)
    rebuilt = calibration_from(frame, betas, bias_order=fleet.bias_order, scale_order=fleet.scale_order,
                               held_scales=held_scales, notes=calibration.notes, effects=calibration.effects)
    axes = tuple(replace(new, residual_rms=old.residual_rms) for new, old in zip(rebuilt.axes, calibration.axes))
    return replace(calibration, temp_code_ref=rebuilt.temp_code_ref, temp_code_min=rebuilt.temp_code_min,
                   temp_code_max=rebuilt.temp_code_max, axes=axes)
