"""``tak_calib carrier-*``: the carrier method (docs/magnetometer.md).

- ``carrier-simulate -o record.csv [--seed N]``: the seed's three stages with its instrument errors;
- ``carrier-fit record.csv [--json F]``: the Earth field, the Poisson coefficients, the hard iron
  and the sensor offset, each with its standard uncertainty, and the condition of the problem;
- ``carrier-budget [--runs N] [--report DIR] [--json F]``: the Monte Carlo table beside the
  seed's figures and, with ``--report``, the sweeps (tilt range, step, each instrument error)
  as a PNG in an HTML page.

Every output obeys the overwrite rule (:mod:`tak_thermo_ros.formats.files`).
"""

from __future__ import annotations

import argparse
import base64
import html
import math
import sys
from typing import Any

from tak_thermo_ros.cli import options as bounds
from tak_thermo_ros.formats.files import FILE, REPORT

OUTPUTS: dict[str, tuple[tuple[str, str, str], ...]] = {
    'carrier-simulate': (('output', FILE, '-o'),),
    'carrier-fit': (('json', FILE, '--json'),),
    'carrier-budget': (('json', FILE, '--json'), ('report', REPORT, '--report')),
}
"""Each carrier command's outputs, checked by ``tak_calib`` before any work is done."""


def _model(args: argparse.Namespace):
    from tak_thermo_ros.core.magnetometer.carrier import POISSON_NAMES, CarrierModel, Gauge
    from tak_thermo_ros.errors import CarrierError
    names = tuple(POISSON_NAMES) if args.poisson == 'all' else tuple(
        part.strip() for part in args.poisson.split(',') if part.strip())
    if args.declination is None and args.magnitude is None and not args.no_gauge:
        msg = ('give --declination DEG and/or --magnitude UT (outside knowledge the record cannot replace), '
               'or --no-gauge for a record that tilts about two axes')
        raise CarrierError(msg)
    gauge = Gauge() if args.no_gauge else Gauge(args.declination, args.declination_sigma, args.magnitude,
                                                args.magnitude_sigma)
    return CarrierModel(names, gauge)


def _errors(args: argparse.Namespace):
    from tak_thermo_ros.core.magnetometer.carrier import InstrumentErrors
    return InstrumentErrors(args.field_error, args.turn_error, math.radians(args.attitude_error), args.distribution)


def cmd_carrier_simulate(args: argparse.Namespace) -> int:
    """Simulate the seed's stages into a CSV record."""
    from tak_thermo_ros.formats.files import write_text_atomic
    from tak_thermo_ros.core.simulation.carrier import CarrierScenario, record_csv, simulate_carrier
    scenario = CarrierScenario(errors=_errors(args), seed=args.seed, tilt_range_deg=args.tilt_range,
                               tilt_step_deg=args.tilt_step, second_tilt_axis=args.second_tilt)
    record, truth = simulate_carrier(scenario)
    write_text_atomic(args.output, record_csv(record))
    earth = ' '.join(f'{v:.4f}' for v in truth.earth_uT)
    print(f'{args.output}: {len(record)} readings (stages 1, 2, 3); truth: B_earth (N E D) {earth} uT, '
          f'D_zz {truth.poisson[2, 2]:g}, p {" ".join(f"{v:g}" for v in truth.hard_iron_uT)} uT')
    return 0


def cmd_carrier_fit(args: argparse.Namespace) -> int:
    """Fit Poisson's model to a CSV record; one line per parameter."""
    from tak_thermo_ros.core.magnetometer.carrier_fit import fit_carrier
    from tak_thermo_ros.formats.files import write_json
    from tak_thermo_ros.core.simulation.carrier import read_record_csv
    model = _model(args)
    fit = fit_carrier(read_record_csv(args.record), model, _errors(args))
    print(f'{args.record}: {fit.readings} readings; Poisson coefficients free: {", ".join(model.poisson) or "none"}; '
          f'gauge: {model.gauge.describe()}')
    for estimate in fit.estimates:
        unit = f' {estimate.unit}' if estimate.unit else ''
        print(f'  {estimate.name:8s} {estimate.value:+12.5f} +- {estimate.sigma:.5f}{unit}')
    print(f'condition number {fit.condition:.3g} (weighted Jacobian, unit columns); '
          f'chi2/dof {fit.chi2_per_dof:.3f} (about 1 when the stated instrument errors are right)')
    if args.json:
        document = {'record': str(args.record), 'readings': fit.readings, 'poisson_free': list(model.poisson),
                    'gauge': model.gauge.describe(), 'condition': fit.condition, 'chi2_per_dof': fit.chi2_per_dof,
                    'estimates': {e.name: {'value': e.value, 'sigma': e.sigma, 'unit': e.unit} for e in fit.estimates},
                    'covariance': fit.covariance.tolist()}
        write_json(args.json, document)
    return 0


def _sweep_figure(results: dict[str, Any]) -> bytes:
    """The sweeps as one PNG: each figure's RMS relative error against the varied value."""
    import io

    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from tak_thermo_ros.core.magnetometer.budget import LABELS, QUANTITIES, SEED_FIGURES_PERCENT, SWEEPS
    figure, axes = plt.subplots(1, len(SWEEPS), figsize=(4.0 * len(SWEEPS), 3.6), sharey=True)
    colours = {'earth': '#1f77b4', 'poisson': '#d62728', 'hard_iron': '#2ca02c'}
    for ax, item in zip(axes, SWEEPS):
        for name in QUANTITIES:  # a point not defined (every run refused, no free coefficient) is left out
            points = [(value, summary.rms_percent[name]) for value, summary in results[item.name]
                      if summary.rms_percent[name] is not None]
            ax.plot([value for value, _ in points], [rms for _, rms in points], 'o-', color=colours[name],
                    label=LABELS[name])
            ax.axhline(SEED_FIGURES_PERCENT[name], color=colours[name], linestyle=':', linewidth=0.8)
        ax.axvline(item.seed_value, color='#777777', linestyle='--', linewidth=0.8)
        if item.log_x:
            ax.set_xscale('log')
        ax.set_yscale('log')
        ax.set_xlabel(item.label)
        ax.grid(True, which='both', alpha=0.3)
    axes[0].set_ylabel('RMS relative error, %')
    axes[0].legend(fontsize=8)
    figure.suptitle("carrier method: errors against the design and the instrument errors "
                    "(dashed: the seed's value; dotted: the seed's figures)", fontsize=10)
    figure.tight_layout()
    buffer = io.BytesIO()
    figure.savefig(buffer, format='png', dpi=100)
    plt.close(figure)
    return buffer.getvalue()


def cmd_carrier_budget(args: argparse.Namespace) -> int:
    """The Monte Carlo error budget beside the seed's table; with --report, the sweeps."""
    from tak_thermo_ros.core.magnetometer.budget import SWEEPS, monte_carlo, sweep, table_text
    from tak_thermo_ros.errors import CarrierError
    from tak_thermo_ros.formats.files import atomic_directory, json_text, write_text_atomic
    from tak_thermo_ros.core.simulation.carrier import CarrierScenario
    model = _model(args)
    scenario = CarrierScenario(errors=_errors(args), tilt_range_deg=args.tilt_range, tilt_step_deg=args.tilt_step,
                               second_tilt_axis=args.second_tilt)
    summary = monte_carlo(scenario, model, args.runs, args.first_seed)
    if summary.failed == summary.runs:
        msg = (f'carrier-budget: the fit refused every one of the {args.runs} runs, so there is no figure; '
               f'the first: {summary.first_refusal}')
        raise CarrierError(msg)
    table = table_text(summary)
    heading = (f'carrier method, {args.runs} runs; model: Poisson {", ".join(model.poisson) or "none"}, gauge '
               f'{model.gauge.describe()}; errors +/- read as {scenario.errors.distribution} '
               f'(dT {scenario.errors.field_uT:g} uT, dA {scenario.errors.turn_rad:g} rad, '
               f'dG {math.degrees(scenario.errors.attitude_rad):g} deg)')
    print(heading)
    print(table)
    sweeps: dict[str, Any] = {}
    if args.report:
        runs = max(args.runs // 4, 2)

        def progress(text: str) -> None:
            print(f'  sweep: {text} ({runs} runs)', file=sys.stderr)

        sweeps = sweep(scenario, model, runs, progress=None if args.quiet else progress)
    if args.json:  # checked before the report is written: one refusal writes neither
        text = json_text({'heading': heading, 'table': summary.as_json(),
                          'sweeps': {name: [{'value': value, **s.as_json()} for value, s in points]
                                     for name, points in sweeps.items()}}, args.json)
    if args.report:
        png = _sweep_figure(sweeps)
        rows = ''.join(
            f'<tr><td>{html.escape(item.label)}</td><td>{value:g}</td>'
            + ''.join(f'<td>{"-" if s.rms_percent[name] is None else f"{s.rms_percent[name]:.3f}"}</td>'
                      for name in ('earth', 'poisson', 'hard_iron'))
            + '</tr>' for item in SWEEPS for value, s in sweeps[item.name])
        page = (f'<!DOCTYPE html><html><head><meta charset="utf-8"><title>carrier method error budget</title></head>'
                f'<body><h1>Carrier method: error budget</h1><p>{html.escape(heading)}</p>'
                f'<pre>{html.escape(table)}</pre><h2>Sweeps ({runs} runs per point)</h2>'
                f'<img alt="sweeps" src="data:image/png;base64,{base64.b64encode(png).decode()}">'
                f'<table border="1" cellpadding="3"><tr><th>varied</th><th>value</th><th>Earth field RMS %</th>'
                f'<th>Poisson RMS %</th><th>hard iron RMS %</th></tr>{rows}</table></body></html>\n')
        with atomic_directory(args.report) as directory:
            (directory / 'sweeps.png').write_bytes(png)
            (directory / 'report.html').write_text(page, encoding='utf-8')
        print(f'report: {args.report}/report.html')
    if args.json:
        write_text_atomic(args.json, text)
    return 0


def _common(parser: argparse.ArgumentParser, *, model: bool) -> None:
    group = parser.add_argument_group("instrument errors (the seed's by default)")
    group.add_argument('--field-error', type=bounds.float_within(0.0, 100.0, 'uT'), default=0.001, metavar='UT',
                       help='magnetometer error dT, +/- microtesla (default 0.001)')
    group.add_argument('--turn-error', type=bounds.float_within(0.0, 0.5, 'rad'), default=3e-3, metavar='RAD',
                       help='turn-angle error dA, +/- rad (default 3e-3)')
    group.add_argument('--attitude-error', type=bounds.float_within(0.0, 10.0, 'deg'), default=0.1, metavar='DEG',
                       help='attitude error dG of roll, pitch and heading, +/- degrees (default 0.1)')
    group.add_argument('--distribution', choices=['uniform', 'normal'], default='uniform',
                       help='+/- as uniform bounds (default) or as one standard deviation')
    if model:
        group = parser.add_argument_group('model and gauge (docs/magnetometer.md: what a record can determine)')
        group.add_argument('--poisson', default='zz', metavar='NAME[,NAME...]',
                           help="free Poisson coefficients D[row, col] as 'zz', 'xz', ... or 'all' "
                                "(the others held at zero; default zz, the seed's one)")
        group.add_argument('--declination', type=bounds.float_within(-180.0, 180.0, 'deg'), metavar='DEG',
                           help='known declination of the Earth field, degrees east of north')
        group.add_argument('--declination-sigma', type=bounds.float_within(0.0, 90.0, 'deg'), default=0.0,
                           metavar='DEG', help='its standard uncertainty (default 0)')
        group.add_argument('--magnitude', type=bounds.float_within(1.0, 2000.0, 'uT'), metavar='UT',
                           help='known total intensity |B_earth|, microtesla')
        group.add_argument('--magnitude-sigma', type=bounds.float_within(0.0, 100.0, 'uT'), default=0.0,
                           metavar='UT', help='its standard uncertainty (default 0)')
        group.add_argument('--no-gauge', action='store_true',
                           help='no outside datum (a record that tilts about two axes can do without)')
    parser.add_argument('--force', action='store_true', help='replace an existing output')
    parser.add_argument('--debug', action='store_true', default=argparse.SUPPRESS,
                        help='show the traceback of an error')


def _design(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("the stages (the seed's by default)")
    group.add_argument('--tilt-range', type=bounds.float_within(0.1, 45.0, 'deg'), default=10.0, metavar='DEG',
                       help='stage 3 tilts the carrier from -DEG to +DEG (default 10)')
    group.add_argument('--tilt-step', type=bounds.float_within(0.01, 10.0, 'deg'), default=0.2, metavar='DEG',
                       help='in steps of DEG (default 0.2)')
    group.add_argument('--second-tilt', choices=['roll'], help='stage 3 also tilts about roll (default: pitch only)')


def add_parsers(commands: Any) -> None:
    """Add ``carrier-simulate``, ``carrier-fit`` and ``carrier-budget`` (their outputs: :data:`OUTPUTS`)."""
    sim = commands.add_parser('carrier-simulate', help="simulate the carrier method's three stages into a CSV record")
    sim.add_argument('-o', '--output', required=True, metavar='RECORD.csv')
    sim.add_argument('--seed', type=bounds.seed, default=0, help='random seed (default 0)')
    _design(sim)
    _common(sim, model=False)
    sim.set_defaults(handler=cmd_carrier_simulate)

    fit = commands.add_parser('carrier-fit', help="estimate the Earth field, Poisson coefficients and hard iron "
                                                  "from a carrier record (CSV)")
    fit.add_argument('record', metavar='RECORD.csv')
    fit.add_argument('--json', metavar='OUT.json', help='also write the estimates and covariance as JSON')
    _common(fit, model=True)
    fit.set_defaults(handler=cmd_carrier_fit)

    budget = commands.add_parser('carrier-budget', help="Monte Carlo error budget of the carrier method beside "
                                                        "the seed's table")
    budget.add_argument('--runs', type=bounds.int_within(2, 1_000_000), default=200,
                        help='Monte Carlo runs (default 200)')
    budget.add_argument('--first-seed', type=bounds.seed, default=0, help='seed of the first run (default 0)')
    budget.add_argument('--report', metavar='DIR', help='also run the sweeps (runs/4 per point) into DIR/report.html')
    budget.add_argument('--json', metavar='OUT.json', help='write the figures as JSON')
    budget.add_argument('--quiet', action='store_true', help='no sweep progress on stderr')
    _design(budget)
    _common(budget, model=True)
    budget.set_defaults(handler=cmd_carrier_budget, declination=7.0)
