"""Issue 31 on the real cycle: the loop's advice judged on what the fit never saw, and errors that hold.

The real log (``data/tofupilot-imu-thermal``, 71 min at 2 Hz: a cooling 52 -> -17.6 C, a heating
to 74 C, a cooling to 36 C) split in time as a user would split it: the first 22.7 min (the first
cooling, down to the coldest point) and the last 48 min (the heating and the second cooling),
each imported as its own record, as ``import-csv`` of each part gives. Both sensors, through the
driver path. The diagnoses try the effects the issue found (``thermal_lag``, ``hysteresis``,
``warmup``) to keep the test short; ``docs/real_imu.md`` shows the CLI with every candidate.

(a) the loop (diagnose -> fit with the named effect -> diagnose, until it names nothing) on the last
    48 min, judged on the first 22.7 min, is no worse than the base model on any axis of either
    sensor;
(b) the effects the loop names on the whole record, fitted on the last 48 min, are no worse on the
    first 22.7 min (the gyroscope's hysteresis, which made x and z worse there, is not named, and
    the verdict says why);
(c) the effect named on the whole record, fitted on the whole record and on its last 48 min, agrees
    within 3 combined standard errors (the errors from the residual's own correlation);
and a record of one excursion says it cannot judge; ``--held-out`` judges on a second record.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from paths import REPO
from tak_thermo_ros.cli import main
from tak_thermo_ros.core.diagnose import diagnose
from tak_thermo_ros.core.diagnose.crossval import _with_range
from tak_thermo_ros.core.fit import fit_model, residual_counts
from tak_thermo_ros.core.noise.residual import model_from_residual
from tak_thermo_ros.formats.bag import Topics
from tak_thermo_ros.passes.diagnose import bounded_run
from tak_thermo_ros.passes.run import StreamOptions
from tak_thermo_ros.formats.records import open_record

REAL_LOG = REPO / 'data' / 'tofupilot-imu-thermal' / 'imu_raw_data.csv'
FIRST_ROWS = 2697
"""The first 22.7 min: rows up to the coldest point (-17.6 C), where the heating starts."""
CANDIDATES = ('thermal_lag', 'hysteresis', 'warmup')
NOMINAL = (1.0, 1.0, 1.0)
SENSORS = ('accel', 'gyro')


def _import(path: Path, bag: Path) -> None:
    assert main(['import-csv', str(path), '-o', str(bag), '--time-unit', 'us', '--acc-columns', 'imu.acc.x',
                 'imu.acc.y', 'imu.acc.z', '--temp-column', 'imu.temperature', '--gyro-columns', 'imu.gyro.x',
                 'imu.gyro.y', 'imu.gyro.z']) == 0


@pytest.fixture(scope='module')
def records(tmp_path_factory):
    """Per part (``whole``, ``first``, ``last``): the bag and its samples per sensor."""
    root = tmp_path_factory.mktemp('real_heldout')
    lines = REAL_LOG.read_text(encoding='utf-8').splitlines(keepends=True)
    parts = {'whole': lines, 'first': lines[:1 + FIRST_ROWS], 'last': lines[:1] + lines[1 + FIRST_ROWS:]}
    found = {}
    for name, part in parts.items():
        csv = root / f'{name}.csv'
        csv.write_text(''.join(part), encoding='utf-8')
        _import(csv, root / name)
        run = bounded_run(open_record(root / name, topics=Topics()), StreamOptions(topics=Topics(), progress=False))
        found[name] = (root / name, run.samples)
    return found


def _fit(samples, effects=()):
    return fit_model(samples, effects=tuple(effects), nominal_scale=NOMINAL)


def _diagnose(samples, effects=()):
    calibration = _fit(samples, effects).calibration
    noise = model_from_residual(residual_counts(calibration, samples), samples.stamp_ns)
    return diagnose(calibration, samples, noise=noise, candidates=CANDIDATES, unit='m/s^2')


def _loop(samples) -> tuple[list[str], list]:
    """The user's loop: add what the verdict names until it names nothing; the effects and each diagnosis."""
    effects: list[str] = []
    seen = []
    for _ in range(4):
        found = _diagnose(samples, effects)
        seen.append(found)
        if found.verdict in ('none', 'unexplained'):
            break
        effects.append(found.verdict)
    return effects, seen


def _heldout_rms(fitted_on, judged_on, effects) -> np.ndarray:
    """Per axis, the RMS residual on ``judged_on`` of the model fitted on ``fitted_on`` (evaluated, not clamped)."""
    calibration = _with_range(_fit(fitted_on, effects).calibration, float(judged_on.temp_code.min()),
                              float(judged_on.temp_code.max()))
    return np.sqrt(np.mean(residual_counts(calibration, judged_on) ** 2, axis=0))


def _statement(diagnosis, word: str) -> str:
    return next((s.text for s in diagnosis.statements if word in s.text), '')


@pytest.fixture(scope='module')
def whole_loop(records):
    """The loop on the whole record, per sensor: the effects it names and its diagnoses."""
    return {sensor: _loop(records['whole'][1][sensor]) for sensor in SENSORS}


def test_a_the_loop_on_the_last_48_min_is_no_worse_on_the_first_22_7(records):
    """(a) per axis of either sensor, the loop's model is no worse than the base on the part it never saw."""
    last, first = records['last'][1], records['first'][1]
    named = {}
    for sensor in SENSORS:
        named[sensor], _ = _loop(last[sensor])
        base = _heldout_rms(last[sensor], first[sensor], ())
        loop = _heldout_rms(last[sensor], first[sensor], named[sensor])
        assert np.all(loop <= base), (sensor, named[sensor], base, loop)
    # the accelerometer's lag is named there and holds on the first 22.7 min (|g| 7.8 -> 2.6 mg in the issue)
    assert named['accel'] == ['thermal_lag']


def test_b_what_the_whole_record_names_holds_on_the_first_22_7(records, whole_loop):
    """(b) fitted on the last 48 min, the whole record's named effects are no worse on the first 22.7 min."""
    last, first = records['last'][1], records['first'][1]
    assert whole_loop['accel'][0] == ['thermal_lag']
    for sensor in SENSORS:
        effects = whole_loop[sensor][0]
        base = _heldout_rms(last[sensor], first[sensor], ())
        named = _heldout_rms(last[sensor], first[sensor], effects)
        assert np.all(named <= base), (sensor, effects, base, named)
    accel = whole_loop['accel'][1][0]
    assert _statement(accel, 'thermal_lag holds on held-out excursions: better on 2 of 2')
    # The gyroscope's hysteresis (named by interleaved blocks before issue 31) is not named, and why.
    gyro = whole_loop['gyro'][1][0]
    assert gyro.verdict == 'unexplained' and whole_loop['gyro'][0] == []
    why = _statement(gyro, 'hysteresis does not hold on held-out excursions')
    assert 'worse on z' in why and 'not recommended' in why, gyro.message
    # ... and it does make z worse there, fitted on the last 48 min
    assert _heldout_rms(last['gyro'], first['gyro'], ('hysteresis',))[2] > \
        _heldout_rms(last['gyro'], first['gyro'], ())[2]
    # Its z amplitude is within its noise of zero, but the gate takes no second look on 1 of 2
    # excursions better: held at zero on z it would still make x worse on the first 22.7 min.
    assert 'judged as hysteresis[xy]' not in gyro.message
    assert _heldout_rms(last['gyro'], first['gyro'], ('hysteresis[xy]',))[0] > \
        _heldout_rms(last['gyro'], first['gyro'], ())[0]


def test_c_the_named_effect_agrees_between_the_whole_record_and_its_last_48_min(records, whole_loop):
    """(c) within 3 combined standard errors, each parameter (the errors hold the residual's correlation)."""
    effects = whole_loop['accel'][0]
    whole = _fit(records['whole'][1]['accel'], effects)
    last = _fit(records['last'][1]['accel'], effects)
    assert not whole.error_basis.white and not last.error_basis.white
    checked = 0
    for effect in whole.calibration.effects:
        other = next(e for e in last.calibration.effects if e.name == effect.name)
        for name, value in effect.values.items():
            key = f'{effect.name}.{name}'
            combined = math.hypot(whole.parameter_errors[key], last.parameter_errors[key])
            assert abs(value - other[name]) <= 3.0 * combined, (key, value, other[name], combined)
            checked += 1
    assert checked == 4  # tau_s and the three slopes


def test_one_excursion_says_it_cannot_judge(records):
    """The first 22.7 min are one cooling: the verdict says in one line that excursions cannot judge it."""
    found = _diagnose(records['first'][1]['accel'])
    lines = [s.text for s in found.statements if 'cannot be held out' in s.text]
    assert len(lines) == 1 and 'one thermal excursion (cooling 51.6..-17.6 C)' in lines[0], found.message
    assert found.excursions is not None and not found.excursions.can_judge


def test_held_out_judges_on_a_second_record(records, capsys):
    """``diagnose LAST --params P --held-out FIRST``: each rung is judged on the first record's excursion."""
    last_bag, first_bag = records['last'][0], records['first'][0]
    params = last_bag.parent / 'last_base.yaml'
    assert main(['fit', str(last_bag), '-o', str(params), '--no-progress']) == 0
    capsys.readouterr()
    assert main(['diagnose', str(last_bag), '--params', str(params), '--held-out', str(first_bag), '--candidates',
                 'thermal_lag', '--no-progress']) == 0
    said = capsys.readouterr().out
    assert f'held out: {first_bag}, 2,697 samples' in said
    assert "thermal_lag holds on the second record's excursions: better on 1 of 1" in said
    assert max(len(line) for line in said.splitlines()) <= 100
