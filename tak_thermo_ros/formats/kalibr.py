"""Kalibr-style ``imu.yaml``: read a user's noise file, write the fitted noise models.

Kalibr reads one number per key::

    accelerometer_noise_density: 2.0e-3   # m/s^2/sqrt(Hz)   white noise (velocity random walk)
    accelerometer_random_walk:   3.0e-4   # m/s^3/sqrt(Hz)   bias random walk
    gyroscope_noise_density:     1.7e-4   # rad/s/sqrt(Hz)   white noise (angle random walk)
    gyroscope_random_walk:       2.0e-5   # rad/s^2/sqrt(Hz) bias random walk
    rostopic:                    /imu/data_raw
    update_rate:                 200.0    # Hz

and refuses (``kalibr_common/ConfigReader.py``, ``ImuParameters``) a ``rostopic`` that is not a
string, an ``update_rate <= 0`` and any of the four values ``<= 0`` ("invalid
accelerometer_random_walk"). OpenVINS reads the same four keys under ``imu0:`` of its
``kalibr_imu_chain.yaml``; VINS-Fusion the same numbers as ``acc_n``, ``acc_w``, ``gyr_n``,
``gyr_w`` of its own configuration (a walk of 0 there leaves the bias without process noise: its
covariance is then singular). :func:`write_kalibr` writes every one of them positive:

- the four keys hold the **largest axis** (what Kalibr can use); the per-axis values go under
  extra keys that Kalibr ignores: ``<sensor>_<term>_xyz`` (three numbers, x y z) for the two
  Kalibr terms, the bias instability (IEEE 952's ``B``), the floor (``allan_floor``: the Allan
  deviation's minimum, the data-sheet convention) and its averaging time
  (``bias_instability_tau``; ``null`` on an axis where the record shows no floor: its Allan
  deviation still falls at the longest averaging time), the quantisation, the rate ramp and the
  driver's filter;
  ``<sensor>_gauss_markov_sigma`` / ``_time`` (three numbers per process); ``<sensor>_noise_source``;
- where the record shows **no random walk**, the walk written is the largest the record allows
  (``random_walk_bound``, from its longest averaging times), said in a comment and under
  ``<sensor>_random_walk_bound_xyz`` (0 where the walk is measured);
- a white noise density of 0 (a fit that put all of it into quantisation) is written as the
  density of white noise with the model's Allan variance at one sample period (what the
  node's covariance uses), said in a comment.

:func:`read_kalibr` gives a :class:`~tak_thermo_ros.core.noise.model.NoiseModel` per sensor
found (``source='file'``): the ``_xyz`` keys when present (their largest value must equal the
single key, so that an edited single number is never silently ignored), else the single
number on all three axes. A Kalibr file has no bias instability: it is 0 (the model is
white noise and random walk; its Allan deviation floor is where the two cross,
``bias_instability_tau = sqrt(3) N / K``), unless ``<sensor>_bias_instability_xyz`` is given.
An axis with a ``random_walk_bound`` reads as a model without a walk and with that bound.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Mapping


from tak_thermo_ros.core.noise.model import NoiseModel, model_floor_tau
from tak_thermo_ros.errors import NoiseError

KALIBR_SENSORS = {'accel': 'accelerometer', 'gyro': 'gyroscope'}
"""Our sensor names and Kalibr's key prefixes."""
KALIBR_TERMS = {'white_noise_density': 'noise_density', 'random_walk': 'random_walk'}
"""Our term names and Kalibr's key suffixes."""
UNITS = {'accel': {'noise_density': 'm/s^2/sqrt(Hz)', 'random_walk': 'm/s^3/sqrt(Hz)'},
         'gyro': {'noise_density': 'rad/s/sqrt(Hz)', 'random_walk': 'rad/s^2/sqrt(Hz)'}}
_EXTRA_TERMS = ('white_noise_density', 'random_walk', 'random_walk_bound', 'bias_instability', 'allan_floor',
                'bias_instability_tau', 'quantization', 'rate_ramp', 'filter_time_constant', 'filter_share')
_PROCESS_KEYS = {'gauss_markov_sigma': 'gauss_markov', 'gauss_markov_time': 'gauss_markov_time'}
"""Per Gauss-Markov process three numbers (x y z, x y z, ...): the key's suffix, the model's field."""
_OTHER_KEYS = ('rostopic', 'update_rate')


def _key(sensor: str, term: str) -> str:
    return f'{KALIBR_SENSORS[sensor]}_{KALIBR_TERMS.get(term, term)}'


def _number(value: Any, where: str, *, positive: bool = False, allow_inf: bool = False,
            allow_nan: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        msg = f'{where}: expected a number, got {type(value).__name__} {value!r}'
        raise NoiseError(msg)
    number = float(value)
    if allow_nan and math.isnan(number):
        return number
    bad = math.isnan(number) or (math.isinf(number) and not (allow_inf and number > 0)) or number < 0.0 \
        or (positive and number == 0.0)
    if bad:
        msg = f'{where}: expected a {"positive" if positive else "non-negative"} finite number, got {number}'
        raise NoiseError(msg)
    return number


_NO_FLOOR_TERMS = ('allan_floor', 'bias_instability_tau')
"""Per-axis terms that are not defined where the record shows no floor: ``null`` there."""
_NO_FLOOR_WORDS = 'null: no floor (still falling at the longest averaging time)'


def _axis_number(value: Any, where: str, term: str) -> float:
    """One axis of a ``_xyz`` key; ``null`` (or the ``.inf``/``.nan`` of older files) where there is no floor."""
    if term == 'bias_instability_tau':
        return math.inf if value is None else _number(value, where, positive=True, allow_inf=True)
    if term == 'allan_floor':
        return math.nan if value is None else _number(value, where, allow_nan=True)
    return _number(value, where)


def kalibr_from_mapping(raw: Any, where: str = 'imu.yaml') -> tuple[dict[str, NoiseModel], str]:
    """The noise models (``'accel'``, ``'gyro'``, whichever the file holds) and the ``rostopic`` ('' if none).

    :raises NoiseError: not a mapping, an unknown key, a sensor with only one of its two Kalibr
        keys, a missing or non-positive ``update_rate``, a bad number, or no sensor at all.
    """
    if not isinstance(raw, Mapping):
        msg = f'{where}: expected a Kalibr-style mapping (accelerometer_noise_density: ..., update_rate: ...)'
        raise NoiseError(msg)
    known = set(_OTHER_KEYS)
    for sensor in KALIBR_SENSORS:
        known |= {_key(sensor, term) for term in KALIBR_TERMS}
        known |= {f'{_key(sensor, term)}_xyz' for term in _EXTRA_TERMS}
        known |= {f'{KALIBR_SENSORS[sensor]}_{suffix}' for suffix in _PROCESS_KEYS}
        known.add(f'{KALIBR_SENSORS[sensor]}_noise_source')
    unknown = sorted(str(k) for k in raw if k not in known)
    if unknown:
        if str(unknown[0]).endswith('compensator'):
            msg = f'{where}: a calibration file, not a noise model (give it with --params)'
        else:
            msg = f'{where}: {unknown[0]}: unknown key (not a Kalibr key: docs/noise.md lists them)'
        raise NoiseError(msg)
    if 'update_rate' not in raw:
        msg = f'{where}: update_rate: missing (Hz; the rate the noise densities were measured at)'
        raise NoiseError(msg)
    rate = _number(raw['update_rate'], f'{where}: update_rate', positive=True)
    topic = raw.get('rostopic', '')
    if not isinstance(topic, str):
        msg = f'{where}: rostopic: expected a topic name, got {topic!r}'
        raise NoiseError(msg)
    models = {}
    for sensor, prefix in KALIBR_SENSORS.items():
        present = [term for term in KALIBR_TERMS if _key(sensor, term) in raw]
        if not present:
            stray = [k for k in raw if str(k).startswith(prefix)]
            if stray:
                msg = f'{where}: {stray[0]}: given without {_key(sensor, "white_noise_density")}'
                raise NoiseError(msg)
            continue
        if len(present) < len(KALIBR_TERMS):
            missing = next(_key(sensor, t) for t in KALIBR_TERMS if t not in present)
            msg = f'{where}: {missing}: missing ({prefix} needs both its noise density and its random walk)'
            raise NoiseError(msg)
        values: dict[str, tuple[float, float, float]] = {}
        for term in _EXTRA_TERMS:
            extra = f'{_key(sensor, term)}_xyz'
            if extra in raw:
                items = raw[extra]
                if not isinstance(items, list) or len(items) != 3:
                    msg = f'{where}: {extra}: expected three numbers [x, y, z], got {items!r}'
                    raise NoiseError(msg)
                values[term] = tuple(_axis_number(v, f'{where}: {extra}[{a}]', term)
                                     for a, v in zip('xyz', items))  # type: ignore[assignment]
        values.pop('allan_floor', None)  # written for people: the model gives it again
        processes: dict[str, Any] = {}
        for suffix, name in _PROCESS_KEYS.items():
            key = f'{prefix}_{suffix}'
            if key in raw:
                items = raw[key]
                if not isinstance(items, list) or len(items) % 3:
                    msg = f'{where}: {key}: expected three numbers (x, y, z) per process, got {items!r}'
                    raise NoiseError(msg)
                times = suffix.endswith('time')
                processes[name] = tuple(tuple(_number(v, f'{where}: {key}[{i * 3 + a}]', positive=times)
                                              for a, v in enumerate(items[i * 3:i * 3 + 3]))
                                        for i in range(len(items) // 3))
        if len(processes.get('gauss_markov', ())) != len(processes.get('gauss_markov_time', ())):
            msg = f'{where}: {prefix}_gauss_markov_sigma and {prefix}_gauss_markov_time: as many processes in each'
            raise NoiseError(msg)
        for term in KALIBR_TERMS:
            single = _number(raw[_key(sensor, term)], f'{where}: {_key(sensor, term)}')
            if term in values:
                largest = max(values[term])
                if not math.isclose(largest, single, rel_tol=1e-6, abs_tol=0.0):
                    msg = (f'{where}: {_key(sensor, term)} {single:g} is not the largest of '
                           f'{_key(sensor, term)}_xyz {list(values[term])}: edit both, or remove the _xyz key')
                    raise NoiseError(msg)
            else:
                values[term] = (single, single, single)
        zero = (0.0, 0.0, 0.0)
        for term in ('bias_instability', 'quantization', 'rate_ramp'):
            values.setdefault(term, zero)
        if 'random_walk_bound' in values:
            # The walk written where the record shows none is its bound: the model has no walk there.
            bound, written = values['random_walk_bound'], values['random_walk']
            for a, (b, w) in enumerate(zip(bound, written)):
                if b > 0.0 and not math.isclose(b, w, rel_tol=1e-6):
                    msg = (f'{where}: {_key(sensor, "random_walk")}_xyz[{"xyz"[a]}] {w:g} is not the bound '
                           f'{b:g} of {_key(sensor, "random_walk_bound")}_xyz: edit both')
                    raise NoiseError(msg)
            values['random_walk'] = tuple(0.0 if b > 0.0 else w for b, w in zip(bound, written))  # type: ignore
        try:
            model = NoiseModel(update_rate=rate, source='file', **{'bias_instability_tau': (1.0, 1.0, 1.0),
                                                                   **values, **processes})
        except NoiseError as err:
            msg = f'{where}: {prefix}: {err}'
            raise NoiseError(msg) from None
        if 'bias_instability_tau' not in values:
            from dataclasses import replace
            model = replace(model, bias_instability_tau=model_floor_tau(model))
        models[sensor] = model
    if not models:
        msg = f'{where}: no accelerometer_* or gyroscope_* noise keys'
        raise NoiseError(msg)
    return models, topic


def read_kalibr(path: str | os.PathLike[str]) -> dict[str, NoiseModel]:
    """The noise models of a Kalibr-style imu.yaml (see :func:`kalibr_from_mapping`).

    :raises NoiseError: a missing or unreadable file, or a bad one (one line naming the file and key).
    """
    from tak_thermo_ros.formats.files import read_yaml
    return kalibr_from_mapping(read_yaml(path, 'noise file', NoiseError), str(Path(path)))[0]


def kalibr_values(model: NoiseModel) -> dict[str, tuple[float, float, float]]:
    """Per axis what a Kalibr file gets: ``noise_density`` and ``random_walk``, every one positive where it can be.

    The white density, or where it is 0 the density of white noise with the model's Allan
    variance at one sample period; the random walk, or where it is 0 its bound.
    """
    per_sample = model.sample_variance()
    density = tuple(n if n > 0.0 else math.sqrt(v / model.update_rate)
                    for n, v in zip(model.white_noise_density, per_sample))
    walk = tuple(k if k > 0.0 else b for k, b in zip(model.random_walk, model.random_walk_bound))
    return {'noise_density': density, 'random_walk': walk}  # type: ignore[dict-item]


def kalibr_text(models: Mapping[str, NoiseModel], *, rostopic: str, update_rate: float | None = None,
                header: str = '') -> str:
    """The imu.yaml text: Kalibr's keys (largest axis, positive) and the per-axis ``_xyz`` keys.

    :param update_rate: Hz (default: the first model's).
    :param header: comment lines written first (without ``#``).
    :raises NoiseError: no model, or a sensor whose density or walk is 0 on every axis with no
        bound to write instead (Kalibr refuses a value ``<= 0``).
    """
    if not models:
        msg = 'imu.yaml: no noise model to write'
        raise NoiseError(msg)
    rate = update_rate if update_rate is not None else next(iter(models.values())).update_rate
    lines = [f'# {line}' for line in header.splitlines()]
    for sensor in ('accel', 'gyro'):
        if sensor not in models:
            continue
        model = models[sensor]
        prefix = KALIBR_SENSORS[sensor]
        written = kalibr_values(model)
        lines.append(f'# {prefix} (largest axis; per axis x y z under *_xyz)')
        for term, suffix in KALIBR_TERMS.items():
            value = max(written[suffix])
            if not value > 0.0:
                msg = (f'imu.yaml: {_key(sensor, term)}: the {prefix} model has none on any axis and no bound: '
                       f'Kalibr refuses a value <= 0')
                raise NoiseError(msg)
            note = ''
            if term == 'random_walk' and any(model.random_walk_bound):
                axes = ' '.join(a for a, b in zip('xyz', model.random_walk_bound) if b > 0.0)
                note = f'; on {axes} an upper bound, the record shows no walk there'
            if term == 'white_noise_density' and not all(model.white_noise_density):
                axes = ' '.join(a for a, n in zip('xyz', model.white_noise_density) if n == 0.0)
                note = f'; on {axes} from the Allan variance at one sample (no white term fitted)'
            lines.append(f'{_key(sensor, term)}: {_yaml_float(value)}   # {UNITS[sensor][suffix]}{note}')
        for term in _EXTRA_TERMS:
            if term in ('filter_time_constant', 'filter_share') and not any(model.filter_share):
                continue
            if term == 'random_walk_bound' and not any(model.random_walk_bound):
                continue
            numbers = {'white_noise_density': written['noise_density'], 'random_walk': written['random_walk'],
                       'allan_floor': model.floor()}.get(term) or getattr(model, term)
            undefined = term in _NO_FLOOR_TERMS and not all(math.isfinite(v) for v in numbers)
            lines.append(f'{_key(sensor, term)}_xyz: '
                         f'[{", ".join(_yaml_float(v, undefined=term in _NO_FLOOR_TERMS) for v in numbers)}]'
                         f'{"   # " + _NO_FLOOR_WORDS if undefined else ""}')
        for suffix, name in _PROCESS_KEYS.items():
            processes = getattr(model, name)
            if any(any(sigma) for sigma in model.gauss_markov):
                numbers = ', '.join(_yaml_float(v) for triple in processes for v in triple)
                lines.append(f'{prefix}_{suffix}: [{numbers}]')
        lines.append(f'{prefix}_noise_source: {model.source}')
    lines.append('# OpenVINS reads the four Kalibr keys above under imu0: of its kalibr_imu_chain.yaml')
    if 'accel' in models and 'gyro' in models:
        vins = {name: max(kalibr_values(models[sensor])[suffix]) for name, sensor, suffix in
                (('acc_n', 'accel', 'noise_density'), ('acc_w', 'accel', 'random_walk'),
                 ('gyr_n', 'gyro', 'noise_density'), ('gyr_w', 'gyro', 'random_walk'))}
        lines.append('# VINS-Fusion takes them as ' + ', '.join(f'{k}: {v:.4e}' for k, v in vins.items()))
    lines.append(f'rostopic: {json.dumps(rostopic)}')
    lines.append(f'update_rate: {float(rate)!r}   # Hz')
    return '\n'.join(lines) + '\n'


def _yaml_float(value: float, *, undefined: bool = False) -> str:
    """A number as YAML: ``null`` for a non-finite one where that means "not defined", else ``.nan``/``.inf``.

    (which :func:`~tak_thermo_ros.formats.files.check_finite_yaml` refuses to write).
    """
    if not math.isfinite(value):
        return 'null' if undefined else '.inf' if math.isinf(value) else '.nan'
    return f'{value:.6e}'


def write_kalibr(path: str | os.PathLike[str], models: Mapping[str, NoiseModel], *, rostopic: str,
                 update_rate: float | None = None, header: str = '', force: bool = False) -> None:
    """Write :func:`kalibr_text` atomically (the overwrite rule of ``formats/files.py``)."""
    from tak_thermo_ros.formats.files import check_finite_yaml, check_output, write_text_atomic
    check_output(path, force=force)
    text = kalibr_text(models, rostopic=rostopic, update_rate=update_rate, header=header)
    check_finite_yaml(text, path)
    write_text_atomic(path, text)


__all__ = ['KALIBR_SENSORS', 'kalibr_from_mapping', 'kalibr_text', 'kalibr_values', 'read_kalibr', 'write_kalibr']
