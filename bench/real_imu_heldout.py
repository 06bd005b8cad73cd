"""The real cycle split in time (issue 31): fitted on the last 48 min, judged on the first 22.7 min.

The log of ``data/tofupilot-imu-thermal`` cut where the first cooling ends (-17.6 C, 22.7 min):
each part imported as its own driver record, as ``import-csv`` of each part gives. Per axis of
both sensors, the RMS residual on the first 22.7 min (never fitted) of models fitted on the last
48 min: the base model, what the loop names on the last 48 min, what it names on the whole record
(issue 31: the excursion judgement), and what it named before (accelerometer ``thermal_lag``,
gyroscope ``hysteresis`` then ``warmup``); the whole record for in-sample figures. And the
parameters of the named effects fitted on the whole record and on its last 48 min, with the
errors the fit prints now and the white-noise errors it printed before, in combined sigmas apart.

Run: ``nice -n 10 .venv/bin/python bench/real_imu_heldout.py``. Writes ``bench/results/real_imu_heldout.json``.
"""

from __future__ import annotations

import contextlib
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchlib import REAL_LOG, machine, run_tak_calib

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))

from core.fit.test_uncertainty import white_errors  # noqa: E402

from tak_thermo_ros.core.diagnose import diagnose  # noqa: E402
from tak_thermo_ros.core.diagnose.crossval import _with_range  # noqa: E402
from tak_thermo_ros.core.fit import fit_model, residual_counts  # noqa: E402
from tak_thermo_ros.core.noise.residual import model_from_residual  # noqa: E402
from tak_thermo_ros.core.values import STANDARD_GRAVITY  # noqa: E402
from tak_thermo_ros.formats.bag import Topics  # noqa: E402
from tak_thermo_ros.passes.diagnose import bounded_run  # noqa: E402
from tak_thermo_ros.formats.records import open_record  # noqa: E402
from tak_thermo_ros.passes.run import StreamOptions  # noqa: E402

RESULTS = Path(__file__).resolve().parent / 'results'
FIRST_ROWS = 2697
"""The first 22.7 min: rows up to the coldest point, -17.6 C."""
TO_READER = {'accel': 1e3 / STANDARD_GRAVITY, 'gyro': 180.0 / math.pi * 3600.0}
"""m/s^2 -> mg, rad/s -> deg/h."""
BEFORE = {'accel': ['thermal_lag'], 'gyro': ['hysteresis', 'warmup']}
"""What the loop named on the whole record before issue 31 (docs/manual.md, "On a real IMU")."""
NOMINAL = (1.0, 1.0, 1.0)


def parts(root: Path) -> dict[str, dict]:
    """The whole log, its first 22.7 min and its last 48 min, imported: per part the samples per sensor."""
    lines = REAL_LOG.read_text(encoding='utf-8').splitlines(keepends=True)
    cuts = {'whole': lines, 'first': lines[:1 + FIRST_ROWS], 'last': lines[:1] + lines[1 + FIRST_ROWS:]}
    found = {}
    for name, part in cuts.items():
        (root / f'{name}.csv').write_text(''.join(part), encoding='utf-8')
        run_tak_calib('import-csv', str(root / f'{name}.csv'), '-o', str(root / name), '--time-unit', 'us',
                      '--acc-columns', 'imu.acc.x', 'imu.acc.y', 'imu.acc.z', '--temp-column', 'imu.temperature',
                      '--gyro-columns', 'imu.gyro.x', 'imu.gyro.y', 'imu.gyro.z')
        found[name] = bounded_run(open_record(root / name, topics=Topics()),
                                  StreamOptions(topics=Topics(), progress=False)).samples
    return found


def loop(samples, unit: str) -> tuple[list[str], list[dict]]:
    """The user's loop, every library effect a candidate: what it names, each verdict and its excursion lines."""
    effects: list[str] = []
    steps = []
    for _ in range(4):
        calibration = fit_model(samples, effects=tuple(effects), nominal_scale=NOMINAL).calibration
        noise = model_from_residual(residual_counts(calibration, samples), samples.stamp_ns)
        found = diagnose(calibration, samples, noise=noise, unit=unit)
        steps.append({'model': ['base', *effects], 'verdict': found.verdict,
                      'ladder': [step.label for step in found.ladder],
                      'excursions': [s.text for s in found.statements
                                     if 'excursions' in s.text or 'excursion (' in s.text]})
        if found.verdict in ('none', 'unexplained') or found.verdict in effects:
            break
        effects.append(found.verdict)
    return effects, steps


def rms_on(fitted_on, judged_on, effects) -> list[float]:
    """Per axis the RMS residual on ``judged_on`` of the model fitted on ``fitted_on``."""
    calibration = fit_model(fitted_on, effects=tuple(effects), nominal_scale=NOMINAL).calibration
    calibration = _with_range(calibration, float(judged_on.temp_code.min()), float(judged_on.temp_code.max()))
    return np.sqrt(np.mean(residual_counts(calibration, judged_on) ** 2, axis=0)).tolist()


def agreement(whole, last, effects) -> dict[str, dict]:
    """Per parameter: value and error fitted on each, combined sigmas apart, now and with white errors."""
    out = {}
    for label, context in (('reported', contextlib.nullcontext), ('white', white_errors)):
        with context():
            on_whole = fit_model(whole, effects=tuple(effects), nominal_scale=NOMINAL)
            on_last = fit_model(last, effects=tuple(effects), nominal_scale=NOMINAL)
        for effect in on_whole.calibration.effects:
            other = next(e for e in on_last.calibration.effects if e.name == effect.name)
            for name, value in effect.values.items():
                key = f'{effect.name}.{name}'
                errors = (on_whole.parameter_errors[key], on_last.parameter_errors[key])
                entry = out.setdefault(key, {'whole': value, 'last': other[name]})
                entry[label] = {'errors': list(errors),
                                'sigmas_apart': abs(value - other[name]) / math.hypot(*errors)}
        if label == 'reported':
            out['assumes'] = {'whole': on_whole.error_basis.text(), 'last': on_last.error_basis.text()}
    return out


def main() -> int:
    start = time.perf_counter()
    result: dict = {'machine': machine(), 'first_rows': FIRST_ROWS}
    with tempfile.TemporaryDirectory() as directory:
        samples = parts(Path(directory))
    for sensor, unit in (('accel', 'm/s^2'), ('gyro', 'rad/s')):
        whole, first, last = (samples[name][sensor] for name in ('whole', 'first', 'last'))
        on_last, last_steps = loop(last, unit)
        on_whole, whole_steps = loop(whole, unit)
        models = {'base': [], 'loop on the last 48 min': on_last, 'loop on the whole record': on_whole,
                  'named before issue 31': BEFORE[sensor]}
        scale = TO_READER[sensor]
        result[sensor] = {
            'loop_last': {'effects': on_last, 'steps': last_steps},
            'loop_whole': {'effects': on_whole, 'steps': whole_steps},
            'heldout_rms_first': {name: [v * scale for v in rms_on(last, first, effects)]
                                  for name, effects in models.items()},
            'in_sample_rms_whole': {name: [v * scale for v in rms_on(whole, whole, effects)]
                                    for name, effects in models.items()},
            'unit': 'mg' if sensor == 'accel' else 'deg/h',
            'agreement': {', '.join(effects): agreement(whole, last, effects)
                          for effects in ({tuple(on_whole), tuple(BEFORE[sensor][:1])} - {()})},
        }
        print(f'{sensor}: loop on the last 48 min {on_last or "nothing"}; on the whole record {on_whole or "nothing"}')
        for name, values in result[sensor]['heldout_rms_first'].items():
            print(f'  first 22.7 min, fitted on the last 48, {name}: {" ".join(f"{v:.4g}" for v in values)} '
                  f'{result[sensor]["unit"]}')
    result['seconds'] = time.perf_counter() - start
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / 'real_imu_heldout.json').write_text(json.dumps(result, indent=2) + '\n')
    print(f'wrote {RESULTS / "real_imu_heldout.json"} in {result["seconds"]:.0f} s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
