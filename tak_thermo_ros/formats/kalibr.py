"""Kalibr-style ``imu.yaml``: read a user's noise file, write the fitted noise models.

Kalibr (and OpenVINS, VINS-Fusion, ORB-SLAM3 through it) reads one number per key::

    accelerometer_noise_density: 2.0e-3   # m/s^2/sqrt(Hz)   white noise (velocity random walk)
    accelerometer_random_walk:   3.0e-4   # m/s^3/sqrt(Hz)   bias random walk
    gyroscope_noise_density:     1.7e-4   # rad/s/sqrt(Hz)   white noise (angle random walk)
    gyroscope_random_walk:       2.0e-5   # rad/s^2/sqrt(Hz) bias random walk
    rostopic:                    /imu/data_raw
    update_rate:                 200.0    # Hz

:func:`write_kalibr` writes these keys with the **largest axis** (what Kalibr can use), and
the per-axis values under extra keys that Kalibr ignores: ``<sensor>_<term>_xyz`` (three
numbers, x y z) for the four Kalibr terms and for the bias instability, its averaging time,
the quantisation and the rate ramp, plus ``<sensor>_noise_source``.

:func:`read_kalibr` gives a :class:`~tak_thermo_ros.core.noise.model.NoiseModel` per sensor
found (``source='file'``): the ``_xyz`` keys when present (their largest value must equal the
single key, so that an edited single number is never silently ignored), else the single
number on all three axes. A Kalibr file has no bias instability: it is 0 (the model is
white noise and random walk; its Allan deviation floor is where the two cross,
``bias_instability_tau = sqrt(3) N / K``), unless ``<sensor>_bias_instability_xyz`` is given.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Mapping


from tak_thermo_ros.core.noise.model import NoiseModel, floor_tau
from tak_thermo_ros.errors import NoiseError

KALIBR_SENSORS = {'accel': 'accelerometer', 'gyro': 'gyroscope'}
"""Our sensor names and Kalibr's key prefixes."""
KALIBR_TERMS = {'white_noise_density': 'noise_density', 'random_walk': 'random_walk'}
"""Our term names and Kalibr's key suffixes."""
UNITS = {'accel': {'noise_density': 'm/s^2/sqrt(Hz)', 'random_walk': 'm/s^3/sqrt(Hz)'},
         'gyro': {'noise_density': 'rad/s/sqrt(Hz)', 'random_walk': 'rad/s^2/sqrt(Hz)'}}
_EXTRA_TERMS = ('white_noise_density', 'random_walk', 'bias_instability', 'bias_instability_tau',
                'quantization', 'rate_ramp')
_OTHER_KEYS = ('rostopic', 'update_rate')


def _key(sensor: str, term: str) -> str:
    return f'{KALIBR_SENSORS[sensor]}_{KALIBR_TERMS.get(term, term)}'


def _number(value: Any, where: str, *, positive: bool = False, allow_inf: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        msg = f'{where}: expected a number, got {type(value).__name__} {value!r}'
        raise NoiseError(msg)
    number = float(value)
    bad = math.isnan(number) or (math.isinf(number) and not (allow_inf and number > 0)) or number < 0.0 \
        or (positive and number == 0.0)
    if bad:
        msg = f'{where}: expected a {"positive" if positive else "non-negative"} finite number, got {number}'
        raise NoiseError(msg)
    return number


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
        known.add(f'{KALIBR_SENSORS[sensor]}_noise_source')
    unknown = sorted(str(k) for k in raw if k not in known)
    if unknown:
        msg = f'{where}: {unknown[0]}: unknown key (Kalibr keys: {", ".join(sorted(known))})'
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
                values[term] = tuple(_number(v, f'{where}: {extra}[{a}]', allow_inf=term == 'bias_instability_tau',
                                             positive=term == 'bias_instability_tau')
                                     for a, v in zip('xyz', items))  # type: ignore[assignment]
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
        if 'bias_instability_tau' not in values:
            values['bias_instability_tau'] = floor_tau(values['white_noise_density'], values['bias_instability'],
                                                       values['random_walk'], values['quantization'],
                                                       values['rate_ramp'])
        models[sensor] = NoiseModel(update_rate=rate, source='file', **values)
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


def kalibr_text(models: Mapping[str, NoiseModel], *, rostopic: str, update_rate: float | None = None,
                header: str = '') -> str:
    """The imu.yaml text: Kalibr's keys (largest axis) and the per-axis ``_xyz`` keys.

    :param update_rate: Hz (default: the first model's).
    :param header: comment lines written first (without ``#``).
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
        lines.append(f'# {KALIBR_SENSORS[sensor]} (largest axis; per axis x y z under *_xyz)')
        for term, suffix in KALIBR_TERMS.items():
            lines.append(f'{_key(sensor, term)}: {max(getattr(model, term)):.6e}   # {UNITS[sensor][suffix]}')
        for term in _EXTRA_TERMS:
            values = ', '.join(_yaml_float(v) for v in getattr(model, term))
            lines.append(f'{_key(sensor, term)}_xyz: [{values}]')
        lines.append(f'{KALIBR_SENSORS[sensor]}_noise_source: {model.source}')
    lines.append(f'rostopic: {json.dumps(rostopic)}')
    lines.append(f'update_rate: {float(rate)!r}   # Hz')
    return '\n'.join(lines) + '\n'


def _yaml_float(value: float) -> str:
    return '.inf' if math.isinf(value) else f'{value:.6e}'


def write_kalibr(path: str | os.PathLike[str], models: Mapping[str, NoiseModel], *, rostopic: str,
                 update_rate: float | None = None, header: str = '', force: bool = False) -> None:
    """Write :func:`kalibr_text` atomically (the overwrite rule of ``formats/files.py``)."""
    from tak_thermo_ros.formats.files import check_output, write_text_atomic
    check_output(path, force=force)
    write_text_atomic(path, kalibr_text(models, rostopic=rostopic, update_rate=update_rate, header=header))


__all__ = ['KALIBR_SENSORS', 'kalibr_from_mapping', 'kalibr_text', 'read_kalibr', 'write_kalibr']
