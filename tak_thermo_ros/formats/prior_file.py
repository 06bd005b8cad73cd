"""The prior file (``prior.yaml``, written by ``fit-fleet --everyday``): a fleet's prior, read by ``fit --prior``.

A plain YAML document (not a node's parameters: no node loads it)::

    prior:
      version: 1
      basis: {ref: 25.0, n_scale: 19.6}       # u = (T - ref) / n_scale, degrees C
      bias_order: 3                           # the offset polynomials' order
      scale_order: 2
      units: [unit00, unit01, ...]            # every unit it was made from
      records: 120
      sensors:
        gyro:                                 # accel likewise
          names: [x.offset, x.offset_T1, ...] # the curve terms (powers of u)
          units: [unit00, ...]                # the units in this sensor's prior (far ones left out)
          records: 117
          low: 5.4                            # the temperatures the units' records saw, C
          high: 44.6
          spread: [...]                       # per term the units' standard deviation about their group's mean
          spread_error: [...]                 # its standard error (null: not determined, e.g. at 0)
          scale: 1.0                          # the units' own noise scale (1: taken as the fits say)
          groups:                             # one or more
            - {weight: 1.0, mean: [...], mean_covariance: [...], units: [...]}   # covariance row-major
          left_out:                           # units far outside, named
            - {name: unit07, distance: 140.2, dof: 12, probability: 1.0e-22, term: x.offset_T1, sigmas: 9.3}
          untold: []                          # curve terms no unit's records told (not in the prior)
          turn_on: {repeatability: [...], rest: [...]}   # the units' median, sensor units (null: undetermined)

Every number finite or ``null`` where the document says so; read back by :func:`load_prior`, one line
naming the key on anything else.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from tak_thermo_ros.core.fit.fleet_outliers import FarUnit
from tak_thermo_ros.core.fit.fleet_prior import Group, SensorFleet
from tak_thermo_ros.core.fit.prior import Basis, curve_term
from tak_thermo_ros.core.fit.prior_fit import FleetPrior
from tak_thermo_ros.errors import CalibrationError
from tak_thermo_ros.formats.files import check_finite, read_yaml, write_text_atomic

PRIOR_VERSION = 1
SENSORS = ('accel', 'gyro')


def _floats(values: Any) -> list[float | None]:
    return [float(v) if math.isfinite(float(v)) else None for v in np.asarray(values, dtype=float).ravel()]


def prior_to_mapping(prior: FleetPrior) -> dict[str, Any]:
    """The file's document of a prior."""
    sensors = {}
    for sensor, fleet in prior.sensors.items():
        entry: dict[str, Any] = {
            'names': list(fleet.names), 'units': list(fleet.units), 'records': int(fleet.records),
            'low': float(fleet.low), 'high': float(fleet.high), 'spread': _floats(fleet.spread),
            'spread_error': _floats(fleet.spread_error), 'scale': float(fleet.scale),
            'groups': [{'weight': float(g.weight), 'mean': _floats(g.mean),
                        'mean_covariance': _floats(g.mean_covariance), 'units': list(g.units)} for g in fleet.groups],
            'left_out': [{'name': f.name, 'distance': float(f.distance), 'dof': int(f.dof),
                          'probability': float(f.probability), 'term': f.term, 'sigmas': float(f.sigmas)}
                         for f in fleet.left_out],
            'untold': list(fleet.untold)}
        if sensor in prior.turn_on:
            spread, rest = prior.turn_on[sensor]
            entry['turn_on'] = {'repeatability': _floats(spread), 'rest': _floats(rest)}
        sensors[sensor] = entry
    return {'prior': {'version': PRIOR_VERSION, 'basis': {'ref': float(prior.basis.ref),
                                                          'n_scale': float(prior.basis.n_scale)},
                      'bias_order': int(prior.bias_order), 'scale_order': int(prior.scale_order),
                      'units': list(prior.units), 'records': int(prior.records), 'sensors': sensors}}


def save_prior(path: str | os.PathLike[str], prior: FleetPrior, *, header: str = '') -> None:
    """Write the prior file atomically (``header``: comment lines first)."""
    document = prior_to_mapping(prior)
    check_finite(document, path)  # an unknown is null in the document, never .nan or .inf
    text = yaml.safe_dump(document, sort_keys=False, default_flow_style=None, width=120)
    comments = ''.join(f'# {line}\n' for line in header.splitlines())
    write_text_atomic(path, comments + text)


class _Reader:
    """Checked reads of the document's keys, each error one line naming the key."""

    def __init__(self, where: str) -> None:
        self.where = where

    def fail(self, key: str, problem: str) -> None:
        msg = f'{self.where}: {key}: {problem}'
        raise CalibrationError(msg)

    def mapping(self, raw: Any, key: str, required: tuple[str, ...], optional: tuple[str, ...] = ()) -> Mapping:
        if not isinstance(raw, Mapping):
            self.fail(key, 'expected a mapping')
        for name in required:
            if name not in raw:
                self.fail(f'{key}.{name}', 'missing')
        unknown = sorted(str(name) for name in set(raw) - set(required) - set(optional))
        if unknown:
            self.fail(f'{key}.{unknown[0]}', 'unknown key')
        return raw

    def number(self, raw: Any, key: str, *, positive: bool = False) -> float:
        if isinstance(raw, bool) or not isinstance(raw, (int, float)) or not math.isfinite(raw) or (
                positive and raw <= 0):
            self.fail(key, f'expected a finite number{" > 0" if positive else ""}, got {raw!r}')
        return float(raw)

    def whole(self, raw: Any, key: str, low: int = 0) -> int:
        if isinstance(raw, bool) or not isinstance(raw, int) or raw < low:
            self.fail(key, f'expected a whole number >= {low}, got {raw!r}')
        return int(raw)

    def numbers(self, raw: Any, key: str, count: int, *, nullable: bool = False) -> np.ndarray:
        if not isinstance(raw, list) or len(raw) != count:
            self.fail(key, f'expected a list of {count} numbers')
        out = []
        for index, value in enumerate(raw):
            if value is None and nullable:
                out.append(math.nan)
            else:
                out.append(self.number(value, f'{key}[{index}]'))
        return np.array(out, dtype=float)

    def strings(self, raw: Any, key: str) -> tuple[str, ...]:
        if not isinstance(raw, list) or not all(isinstance(v, str) for v in raw):
            self.fail(key, 'expected a list of strings')
        return tuple(raw)


def prior_from_mapping(document: Any, where: str, label: str = '') -> FleetPrior:
    """A :class:`~tak_thermo_ros.core.fit.prior_fit.FleetPrior` from the file's document.

    :raises CalibrationError: one line naming the file and the key.
    """
    read = _Reader(where)
    top = read.mapping(document, 'document', ('prior',))
    raw = read.mapping(top['prior'], 'prior', ('version', 'basis', 'bias_order', 'scale_order', 'units', 'records',
                                               'sensors'))
    if raw['version'] != PRIOR_VERSION:
        read.fail('prior.version', f'expected {PRIOR_VERSION}, got {raw["version"]!r}')
    basis_raw = read.mapping(raw['basis'], 'prior.basis', ('ref', 'n_scale'))
    basis = Basis(read.number(basis_raw['ref'], 'prior.basis.ref'),
                  read.number(basis_raw['n_scale'], 'prior.basis.n_scale', positive=True))
    bias_order = read.whole(raw['bias_order'], 'prior.bias_order', 1)
    scale_order = read.whole(raw['scale_order'], 'prior.scale_order', 0)
    units = read.strings(raw['units'], 'prior.units')
    records = read.whole(raw['records'], 'prior.records')
    sensors_raw = read.mapping(raw['sensors'], 'prior.sensors', (), SENSORS)
    if not sensors_raw:
        read.fail('prior.sensors', 'holds no sensor')
    sensors, turn_on = {}, {}
    for sensor, entry in sensors_raw.items():
        key = f'prior.sensors.{sensor}'
        item = read.mapping(entry, key, ('names', 'units', 'records', 'low', 'high', 'spread', 'spread_error', 'scale',
                                         'groups', 'left_out', 'untold'), ('turn_on',))
        names = read.strings(item['names'], f'{key}.names')
        for name in names:
            term = curve_term(name)
            if term is None or term[2] > (bias_order if term[1] == 'offset' else scale_order):
                read.fail(f'{key}.names', f'{name!r} is no curve term of the orders {bias_order} and {scale_order}')
        size = len(names)
        spread = read.numbers(item['spread'], f'{key}.spread', size)
        if np.any(spread <= 0.0):
            read.fail(f'{key}.spread', 'expected numbers > 0')
        groups = []
        if not isinstance(item['groups'], list) or not item['groups']:
            read.fail(f'{key}.groups', 'expected a list of one group or more')
        for index, group in enumerate(item['groups']):
            gkey = f'{key}.groups[{index}]'
            g = read.mapping(group, gkey, ('weight', 'mean', 'mean_covariance', 'units'))
            covariance = read.numbers(g['mean_covariance'], f'{gkey}.mean_covariance', size * size).reshape(size, size)
            if not np.allclose(covariance, covariance.T, rtol=1e-6, atol=0.0) or np.any(np.diag(covariance) < 0):
                read.fail(f'{gkey}.mean_covariance', 'expected a symmetric covariance')
            weight = read.number(g['weight'], f'{gkey}.weight', positive=True)
            groups.append(Group(weight, read.numbers(g['mean'], f'{gkey}.mean', size), covariance,
                                read.strings(g['units'], f'{gkey}.units')))
        left = []
        if not isinstance(item['left_out'], list):
            read.fail(f'{key}.left_out', 'expected a list')
        for index, far in enumerate(item['left_out']):
            fkey = f'{key}.left_out[{index}]'
            f = read.mapping(far, fkey, ('name', 'distance', 'dof', 'probability', 'term', 'sigmas'))
            if not isinstance(f['name'], str) or not isinstance(f['term'], str):
                read.fail(fkey, 'name and term: expected strings')
            left.append(FarUnit(f['name'], sensor, read.number(f['distance'], f'{fkey}.distance'),
                                read.whole(f['dof'], f'{fkey}.dof'),
                                read.number(f['probability'], f'{fkey}.probability'),
                                f['term'], read.number(f['sigmas'], f'{fkey}.sigmas')))
        fleet_units = read.strings(item['units'], f'{key}.units')
        low, high = read.number(item['low'], f'{key}.low'), read.number(item['high'], f'{key}.high')
        if not low <= high:
            read.fail(f'{key}.low', f'must not exceed high ({low} > {high})')
        sensors[sensor] = SensorFleet(
            sensor, names, basis, tuple(groups), spread,
            read.numbers(item['spread_error'], f'{key}.spread_error', size, nullable=True), fleet_units, low, high,
            read.whole(item['records'], f'{key}.records'), tuple(left), read.strings(item['untold'], f'{key}.untold'),
            read.number(item['scale'], f'{key}.scale', positive=True))
        if 'turn_on' in item:
            t = read.mapping(item['turn_on'], f'{key}.turn_on', ('repeatability', 'rest'))
            turn_on[sensor] = (read.numbers(t['repeatability'], f'{key}.turn_on.repeatability', 3, nullable=True),
                               read.numbers(t['rest'], f'{key}.turn_on.rest', 3, nullable=True))
    return FleetPrior(basis, bias_order, scale_order, sensors, turn_on, units, records, label)


def load_prior(path: str | os.PathLike[str]) -> FleetPrior:
    """Read a prior file (its label: the file's name, units and records).

    :raises CalibrationError: one line naming the file (missing, not YAML, a bad key).
    """
    document = read_yaml(path, 'prior file', CalibrationError)
    prior = prior_from_mapping(document, str(path))
    label = f'{Path(path).name}: {len(prior.units)} units, {prior.records} records'
    from dataclasses import replace
    return replace(prior, label=label)
