"""Correction and validation block by block equal one call on the whole run, effects with memory included."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from conftest import EXAMPLES
from tak_thermo_ros.core.link.correction import Corrector, OutOfRange, UnitCorrector
from tak_thermo_ros.core.effects import LIBRARY
from tak_thermo_ros.core.link.model import InputKind, UnitCalibration
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.core.link.stream_correction import BlockCorrector, BlockUnitCorrector, GravityCheck, RateCheck
from tak_thermo_ros.core.link.validate import validate_gravity, validate_rate

SPLITS = [1, 2, 999, 1000, 2500]


def _series(count: int = 3000, seed: int = 1):
    rng = np.random.default_rng(seed)
    stamps = 1.7e9 + np.cumsum(rng.uniform(0.5, 1.5, count))
    codes = np.round(8200.0 + np.cumsum(rng.normal(0.0, 3.0, count)))
    counts = np.round(rng.normal(0.0, 6000.0, (count, 3)))
    return stamps, codes, counts


def _calibration(names):
    return replace(Scenario().truth(), effects=tuple(LIBRARY[name](**EXAMPLES[name]) for name in names))


def _in_blocks(corrector, counts, codes, stamps, edges=SPLITS):
    bounds = [0, *edges, len(codes)]
    return np.vstack([corrector.correct(counts[a:b], codes[a:b], stamp_s=stamps[a:b])
                      for a, b in zip(bounds[:-1], bounds[1:])])


@pytest.mark.parametrize('names', [[name] for name in EXAMPLES] + [list(EXAMPLES), []])
@pytest.mark.parametrize('policy', list(OutOfRange))
def test_blocks_equal_one_call_bit_for_bit(names, policy):
    """Any split of the run (single samples, empty-free blocks) gives the floats of one call."""
    stamps, codes, counts = _series()
    calibration = _calibration(names)
    whole = Corrector(calibration, out_of_range=policy).correct(counts, codes, stamp_s=stamps)
    blocked = _in_blocks(BlockCorrector(calibration, out_of_range=policy), counts, codes, stamps)
    assert np.array_equal(blocked.view(np.int64), whole.view(np.int64))
    if any(name in ('thermal_lag', 'warmup', 'hysteresis') for name in names):  # the effects with memory
        # A plain Corrector restarts the effects' memory at every call: the blocks would differ.
        restarted = _in_blocks(Corrector(calibration, out_of_range=policy), counts, codes, stamps)
        assert not np.array_equal(restarted, whole)


def test_reset_starts_a_new_run():
    """After reset the next block starts the effects afresh, as a new Corrector would."""
    stamps, codes, counts = _series(500)
    calibration = _calibration(['thermal_lag', 'warmup'])
    corrector = BlockCorrector(calibration)
    corrector.correct(counts[:200], codes[:200], stamp_s=stamps[:200])
    corrector.reset()
    again = corrector.correct(counts[200:], codes[200:], stamp_s=stamps[200:])
    fresh = Corrector(calibration).correct(counts[200:], codes[200:], stamp_s=stamps[200:])
    assert np.array_equal(again, fresh)


def test_unit_corrector_six_channels_in_blocks():
    """Accelerometer and gyroscope with thermal_lag in blocks equal UnitCorrector on the whole run."""
    stamps, codes, counts = _series(2000)
    accel = _calibration(['thermal_lag'])
    gyro = _calibration(['warmup'])
    unit = UnitCalibration(InputKind.IMU, accel, gyro)
    values = np.hstack([counts, counts[::-1]])
    whole = UnitCorrector(unit).correct(values, codes, stamp_s=stamps)
    blocked = _in_blocks(BlockUnitCorrector(unit), values, codes, stamps, edges=[5, 1500])
    assert np.array_equal(blocked, whole)


def test_validation_sums_equal_the_whole_run_statistics():
    """|g| and rate error statistics from block sums equal validate_gravity / validate_rate."""
    stamps, codes, counts = _series(3000)
    calibration = _calibration(['thermal_lag'])
    codes[100:150] = calibration.temp_code_max + 100.0
    whole = validate_gravity(calibration, counts, codes, gravity=9.81, stamp_s=stamps)
    check = GravityCheck(calibration, gravity=9.81, out_of_range=OutOfRange.CLAMP)
    for a, b in ((0, 10), (10, 2000), (2000, 3000)):
        check.add(counts[a:b], codes[a:b], stamps[a:b])
    for got, expected in ((check.before.gravity_error(), whole.before), (check.after.gravity_error(), whole.after)):
        assert got.rms == pytest.approx(expected.rms, rel=1e-12)
        assert got.mean == pytest.approx(expected.mean, rel=1e-9, abs=1e-12)
        assert got.max == expected.max
    assert check.out_of_range == whole.out_of_range > 0
    reference = np.zeros((3000, 3))
    rate = validate_rate(calibration, counts, codes, reference, stamp_s=stamps)
    rate_check = RateCheck(calibration, out_of_range=OutOfRange.CLAMP)
    rate_check.add(counts[:1234], codes[:1234], reference[:1234], stamps[:1234])
    rate_check.add(counts[1234:], codes[1234:], reference[1234:], stamps[1234:])
    got = rate_check.after.rate_error()
    np.testing.assert_allclose(got.rms, rate.after.rms, rtol=1e-12)
    np.testing.assert_allclose(got.mean, rate.after.mean, rtol=1e-9)
    assert got.max == rate.after.max
