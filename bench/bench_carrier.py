"""Benchmark: the carrier method's error budget beside the seed's table (issue 18, items 3-4).

Writes ``bench/results/carrier_budget.json`` (and, with ``--report DIR``, the sweeps' PNG):

- ``table``: the Monte Carlo over the seed's instrument errors and stages (``--runs``, default
  1000): RMS and 95th percentile of each relative error, the mean predicted 1-sigma, and the
  coverage of the reported uncertainties (fraction of estimates within 2 sigma);
- ``alternatives``: the same table for other gauges and designs (a known |B_earth| instead of
  the declination; both; a second tilt about roll without any gauge; all nine Poisson
  coefficients with a roll tilt and a known |B_earth|);
- ``identifiability``: the noise-free design's condition number for every (design, Poisson
  set, gauge) of docs/magnetometer.md (``inf``: a combination the design cannot determine);
- ``sweeps``: tilt range, tilt step and each instrument error (``--sweep-runs`` per point).

Run: ``.venv/bin/python bench/bench_carrier.py [--runs 1000] [--sweep-runs 50]`` (8 min on this machine, loaded).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import replace
from pathlib import Path

from benchlib import machine
from tak_thermo_ros.core.magnetometer.budget import monte_carlo, sweep, table_text
from tak_thermo_ros.core.magnetometer.carrier import POISSON_NAMES, CarrierModel, Gauge
from tak_thermo_ros.core.magnetometer.carrier_fit import design_condition
from tak_thermo_ros.formats.files import write_text_atomic
from tak_thermo_ros.core.simulation.carrier import CarrierScenario, stage_design

RESULTS = Path(__file__).resolve().parent / 'results'


def identifiability() -> list[dict[str, object]]:
    """The noise-free condition number of each design, Poisson set and gauge."""
    scenario = CarrierScenario()
    truth = scenario.truth()
    rows = []
    gauges = {'none': Gauge(), 'declination': Gauge(declination_deg=7.0), 'magnitude': Gauge(magnitude_uT=50.0),
              'declination+magnitude': Gauge(declination_deg=7.0, magnitude_uT=50.0)}
    for design, design_scenario in (('pitch', scenario), ('pitch+roll', replace(scenario, second_tilt_axis='roll'))):
        record = stage_design(design_scenario)
        for poisson in ((), ('zz',), ('xx',), ('xz',), ('zx',), ('yy',), ('xx', 'zz'), ('xx', 'xz', 'zx', 'zz'),
                        POISSON_NAMES):
            for gauge_name, gauge in gauges.items():
                condition, _, _ = design_condition(record, truth, CarrierModel(poisson, gauge))
                rows.append({'design': design, 'poisson': ','.join(poisson) if len(poisson) < 9 else 'all',
                             'gauge': gauge_name, 'condition': condition if math.isfinite(condition) else 'inf'})
    return rows


def main() -> None:
    """Run the table, the alternatives, the identifiability table and the sweeps; write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', type=int, default=1000)
    parser.add_argument('--alternative-runs', type=int, default=300)
    parser.add_argument('--sweep-runs', type=int, default=50)
    parser.add_argument('--output', type=Path, default=RESULTS / 'carrier_budget.json')
    args = parser.parse_args()
    start = time.perf_counter()
    scenario = CarrierScenario()
    model = CarrierModel()
    table = monte_carlo(scenario, model, args.runs)
    print(table_text(table), flush=True)
    alternatives = {}
    normal = replace(scenario, errors=replace(scenario.errors, distribution='normal'))
    variants = {
        'magnitude gauge (|B_earth| 50 uT known, declination free)':
            (scenario, CarrierModel(('zz',), Gauge(magnitude_uT=50.0))),
        'declination and magnitude known':
            (scenario, CarrierModel(('zz',), Gauge(declination_deg=7.0, magnitude_uT=50.0))),
        'second tilt about roll, no gauge':
            (replace(scenario, second_tilt_axis='roll'), CarrierModel(('zz',), Gauge())),
        'normal errors (+/- as 1 sigma)': (normal, model),
    }
    for name, (alt_scenario, alt_model) in variants.items():
        summary = monte_carlo(alt_scenario, alt_model, args.alternative_runs)
        print(f'\n{name}\n{table_text(summary)}', flush=True)
        alternatives[name] = summary.as_json()
    ident = identifiability()
    sweeps = sweep(scenario, model, args.sweep_runs, progress=lambda text: print(f'  sweep {text}', flush=True))
    document = {
        'benchmark': 'carrier_budget',
        'seconds': time.perf_counter() - start,
        'scenario': {'magnitude_uT': scenario.magnitude_uT, 'inclination_deg': scenario.inclination_deg,
                     'declination_deg': scenario.declination_deg, 'poisson_zz': scenario.poisson[8],
                     'hard_iron_uT': list(scenario.hard_iron_uT), 'sensor_offset_uT': list(scenario.sensor_offset_uT),
                     'heading_deg': scenario.heading_deg, 'errors': {
                         'field_uT': scenario.errors.field_uT, 'turn_rad': scenario.errors.turn_rad,
                         'attitude_deg': math.degrees(scenario.errors.attitude_rad),
                         'distribution': scenario.errors.distribution}},
        'model': {'poisson': list(model.poisson), 'gauge': model.gauge.describe()},
        'table': table.as_json(),
        'table_text': table_text(table),
        'alternatives': alternatives,
        'identifiability': ident,
        'sweeps': {name: [{'value': value, **summary.as_json()} for value, summary in points]
                   for name, points in sweeps.items()},
        'machine': machine(),
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(args.output, json.dumps(document, indent=2) + '\n')
    print(f'wrote {args.output}')


if __name__ == '__main__':
    main()
