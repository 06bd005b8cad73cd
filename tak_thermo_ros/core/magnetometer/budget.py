"""The carrier method's error budget: a Monte Carlo over the instrument errors, beside the seed's table.

Each run simulates the seed's stages (:mod:`tak_thermo_ros.core.simulation.carrier`) with a new
seed, fits them (:func:`~tak_thermo_ros.core.magnetometer.carrier_fit.fit_carrier`) and takes three
relative errors (the seed's rows):

- Earth field: ``|b_hat - b| / |b|`` (the vector error over the magnitude, so that a small
  component, east here, is not blown up);
- Poisson coefficients: ``|D_hat - D| / |D|`` over the free coefficients (one, D[z, z], by default);
- hard iron: ``|p_hat - p| / |p|``.

The statistic reported is the root mean square over the runs (a 1-sigma figure) and the 95th
percentile (a bound, the closer reading of the seed's "+/-"); the fraction of all estimates that
lay within two of their own reported standard uncertainties checks those uncertainties.

A figure that is not defined (no free Poisson coefficient; no run the fit accepted) is ``None``
(``null`` in JSON, ``-`` in the table), never NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np

from tak_thermo_ros.core.magnetometer.carrier import AXIS_NAMES, NAV_NAMES, CarrierModel, CarrierTruth, InstrumentErrors
from tak_thermo_ros.core.magnetometer.carrier_fit import CarrierFit, fit_carrier
from tak_thermo_ros.core.simulation.carrier import CarrierScenario, simulate_carrier

QUANTITIES = ('earth', 'poisson', 'hard_iron')
LABELS = {'earth': 'Earth-field components', 'poisson': 'Poisson coefficient(s)', 'hard_iron': 'hard iron'}
SEED_FIGURES_PERCENT = {'earth': 0.5, 'poisson': 4.44, 'hard_iron': 0.35}
"""The seed's table: relative errors in %, statistic and truths not stated."""


def relative_errors(fit: CarrierFit, truth: CarrierTruth) -> dict[str, float]:
    """The three relative errors of one fit against the truth (fractions, not %)."""
    values = fit.by_name()
    earth = np.array([values[f'B_{name}'].value for name in NAV_NAMES])
    hard_iron = np.array([values[f'p_{axis}'].value for axis in AXIS_NAMES])
    rows = [(AXIS_NAMES.index(name[0]), AXIS_NAMES.index(name[1])) for name in fit.model.poisson]
    poisson_hat = np.array([values[f'D_{name}'].value for name in fit.model.poisson])
    poisson_true = np.array([truth.poisson[row, col] for row, col in rows])
    poisson = (float(np.linalg.norm(poisson_hat - poisson_true) / np.linalg.norm(poisson_true))
               if rows and np.linalg.norm(poisson_true) > 0 else math.nan)
    return {'earth': float(np.linalg.norm(earth - truth.earth_uT) / np.linalg.norm(truth.earth_uT)),
            'poisson': poisson,
            'hard_iron': float(np.linalg.norm(hard_iron - truth.hard_iron_uT) / np.linalg.norm(truth.hard_iron_uT))}


def within_two_sigma(fit: CarrierFit, truth: CarrierTruth) -> np.ndarray:
    """Per estimate, whether its error is within two of its reported standard uncertainties."""
    true = {f'B_{name}': truth.earth_uT[i] for i, name in enumerate(NAV_NAMES)}
    true |= {f'p_{axis}': truth.hard_iron_uT[i] for i, axis in enumerate(AXIS_NAMES)}
    true |= {f'o_{axis}': truth.sensor_offset_uT[i] for i, axis in enumerate(AXIS_NAMES)}
    true |= {f'D_{name}': truth.poisson[AXIS_NAMES.index(name[0]), AXIS_NAMES.index(name[1])]
             for name in fit.model.poisson}
    return np.array([abs(e.value - true[e.name]) <= 2.0 * e.sigma for e in fit.estimates])


@dataclass(frozen=True)
class BudgetSummary:
    """The Monte Carlo's figures: per quantity, RMS and 95th percentile of the relative error, in %.

    A figure is ``None`` where it is not defined: every run refused, or (Poisson) no free coefficient.

    :param first_refusal: the fit's message for the first run it refused, or ``None``.
    """

    runs: int
    failed: int
    rms_percent: dict[str, float | None]
    p95_percent: dict[str, float | None]
    mean_sigma_percent: dict[str, float | None]
    coverage_two_sigma: float | None
    condition_median: float | None
    first_refusal: str | None = None

    def as_json(self) -> dict[str, object]:
        """The figures as a JSON-ready mapping (``null`` where not defined)."""
        return {'runs': self.runs, 'failed': self.failed, 'rms_percent': self.rms_percent,
                'p95_percent': self.p95_percent, 'mean_predicted_sigma_percent': self.mean_sigma_percent,
                'coverage_two_sigma': self.coverage_two_sigma, 'condition_median': self.condition_median,
                'seed_percent': SEED_FIGURES_PERCENT}


def _predicted_relative_sigma(fit: CarrierFit, truth: CarrierTruth) -> dict[str, float]:
    """The reported uncertainties as relative errors (root of the summed variances over the norm)."""
    values = fit.by_name()

    def norm_sigma(names: Sequence[str]) -> float:
        return math.sqrt(sum(values[name].sigma ** 2 for name in names))

    poisson_norm = float(np.linalg.norm([truth.poisson[AXIS_NAMES.index(n[0]), AXIS_NAMES.index(n[1])]
                                         for n in fit.model.poisson])) if fit.model.poisson else 0.0
    return {'earth': norm_sigma([f'B_{n}' for n in NAV_NAMES]) / float(np.linalg.norm(truth.earth_uT)),
            'poisson': (norm_sigma([f'D_{n}' for n in fit.model.poisson]) / poisson_norm
                        if poisson_norm > 0 else math.nan),
            'hard_iron': norm_sigma([f'p_{a}' for a in AXIS_NAMES]) / float(np.linalg.norm(truth.hard_iron_uT))}


def monte_carlo(scenario: CarrierScenario, model: CarrierModel | None = None, runs: int = 200,
                first_seed: int = 0, progress: Callable[[int, int], None] | None = None) -> BudgetSummary:
    """Simulate and fit ``runs`` seeded runs of ``scenario``; summarise the relative errors.

    The fit is weighted with the scenario's own instrument errors. A run the fit refuses
    (:class:`~tak_thermo_ros.errors.FitError`) is counted in ``failed``.
    """
    from tak_thermo_ros.errors import FitError

    model = model or CarrierModel()
    errors: dict[str, list[float]] = {name: [] for name in QUANTITIES}
    sigmas: dict[str, list[float]] = {name: [] for name in QUANTITIES}
    covered: list[float] = []
    conditions: list[float] = []
    failed = 0
    first_refusal = None
    for run in range(runs):
        record, truth = simulate_carrier(replace(scenario, seed=first_seed + run))
        try:
            fit = fit_carrier(record, model, scenario.errors)
        except FitError as err:
            failed += 1
            first_refusal = first_refusal or str(err)
            continue
        for name, value in relative_errors(fit, truth).items():
            if math.isfinite(value):  # NaN: not defined (no free Poisson coefficient)
                errors[name].append(value)
        for name, value in _predicted_relative_sigma(fit, truth).items():
            if math.isfinite(value):
                sigmas[name].append(value)
        covered.append(float(np.mean(within_two_sigma(fit, truth))))
        conditions.append(fit.condition)
        if progress is not None:
            progress(run + 1, runs)

    def rms(values: list[float]) -> float | None:
        return 100.0 * float(np.sqrt(np.mean(np.square(values)))) if values else None

    def p95(values: list[float]) -> float | None:
        return 100.0 * float(np.percentile(values, 95)) if values else None

    return BudgetSummary(runs, failed, {name: rms(errors[name]) for name in QUANTITIES},
                         {name: p95(errors[name]) for name in QUANTITIES},
                         {name: 100.0 * float(np.mean(sigmas[name])) if sigmas[name] else None
                          for name in QUANTITIES},
                         float(np.mean(covered)) if covered else None,
                         float(np.median(conditions)) if conditions else None, first_refusal)


def _cell(value: float | None, width: int, form: str) -> str:
    """A figure in the table, ``-`` where it is not defined."""
    return f'{"-":>{width}s}' if value is None else f'{value:{width}{form}}'


def table_text(summary: BudgetSummary) -> str:
    """The seed's table beside the Monte Carlo's, as aligned text (``-``: not defined)."""
    lines = [f'{"relative error, %":28s} {"seed":>7s} {"RMS":>8s} {"95th pct":>9s} {"predicted 1-sigma":>18s}']
    for name in QUANTITIES:
        lines.append(f'{LABELS[name]:28s} {SEED_FIGURES_PERCENT[name]:7.2f} '
                     f'{_cell(summary.rms_percent[name], 8, ".3f")} {_cell(summary.p95_percent[name], 9, ".3f")} '
                     f'{_cell(summary.mean_sigma_percent[name], 18, ".3f")}')
    coverage, condition = summary.coverage_two_sigma, summary.condition_median
    lines.append(f'runs {summary.runs} ({summary.failed} refused); estimates within 2 reported sigma: '
                 f'{"-" if coverage is None else f"{100.0 * coverage:.1f} %"} (normal: 95.4 %); median condition '
                 f'number {"-" if condition is None else f"{condition:.3g}"}')
    if summary.rms_percent['earth'] is not None and summary.rms_percent['poisson'] is None:
        lines.append('Poisson coefficient(s): none free, so no figure (-)')
    return '\n'.join(lines)


@dataclass(frozen=True)
class Sweep:
    """One design or instrument figure varied over ``values`` with everything else at the seed's."""

    name: str
    label: str
    values: tuple[float, ...]
    seed_value: float
    apply: Callable[[CarrierScenario, float], CarrierScenario]
    log_x: bool = False


def _errors_with(scenario: CarrierScenario, **changes: float) -> CarrierScenario:
    return replace(scenario, errors=replace(scenario.errors, **changes))


SWEEPS: tuple[Sweep, ...] = (
    Sweep('tilt_range_deg', 'tilt range +/- (deg)', (2.5, 5.0, 10.0, 15.0, 20.0), 10.0,
          lambda s, v: replace(s, tilt_range_deg=v)),
    Sweep('tilt_step_deg', 'tilt step (deg)', (0.1, 0.2, 0.5, 1.0, 2.0), 0.2,
          lambda s, v: replace(s, tilt_step_deg=v), log_x=True),
    Sweep('field_uT', 'magnetometer error dT (uT)', (1e-4, 1e-3, 1e-2, 1e-1), 1e-3,
          lambda s, v: _errors_with(s, field_uT=v), log_x=True),
    Sweep('turn_rad', 'turn-angle error dA (rad)', (3e-4, 1e-3, 3e-3, 1e-2), 3e-3,
          lambda s, v: _errors_with(s, turn_rad=v), log_x=True),
    Sweep('attitude_deg', 'attitude error dG (deg)', (0.01, 0.03, 0.1, 0.3), 0.1,
          lambda s, v: _errors_with(s, attitude_rad=math.radians(v)), log_x=True),
)
"""The sweeps of the budget: tilt range, tilt step, and each instrument error."""


def sweep(scenario: CarrierScenario, model: CarrierModel | None, runs: int,
          sweeps: Sequence[Sweep] = SWEEPS,
          progress: Callable[[str], None] | None = None) -> dict[str, list[tuple[float, BudgetSummary]]]:
    """Each sweep's summaries: ``{sweep name: [(value, summary), ...]}``."""
    results: dict[str, list[tuple[float, BudgetSummary]]] = {}
    for item in sweeps:
        results[item.name] = []
        for value in item.values:
            if progress is not None:
                progress(f'{item.label} = {value:g}')
            results[item.name].append((value, monte_carlo(item.apply(scenario, value), model, runs)))
    return results


def default_errors() -> InstrumentErrors:
    """The seed's instrument errors (dT 0.001 uT, dA 3e-3 rad, dG 0.1 deg; +/- read as uniform bounds)."""
    return InstrumentErrors()
