"""The vectorised correction runs in blocks: block edges change no bit of the result."""

from __future__ import annotations

import numpy as np
import pytest

from tak_thermo_ros.core.link.correction import BLOCK_SAMPLES, Corrector, OutOfRange
from tak_thermo_ros.core.simulation.scenario import Scenario


def _inputs(count: int):
    calibration = Scenario().truth()
    rng = np.random.default_rng(11)
    counts = np.round(rng.uniform(-30000, 30000, size=(count, 3)))
    codes = np.round(rng.uniform(calibration.temp_code_min - 300, calibration.temp_code_max + 300, size=count))
    return calibration, counts, codes


@pytest.mark.parametrize('policy', list(OutOfRange))
def test_blocks_agree_bit_for_bit_with_the_per_sample_path(policy):
    """Over two full blocks and a partial one, correct() equals correct_sample() bit for bit."""
    calibration, counts, codes = _inputs(2 * BLOCK_SAMPLES + 5)
    corrector = Corrector(calibration, out_of_range=policy)
    bulk = corrector.correct(counts, codes)
    single = np.array([corrector.correct_sample(x, y, z, code)
                       for (x, y, z), code in zip(counts.tolist(), codes.tolist())])
    assert np.array_equal(bulk.view(np.int64), single.view(np.int64))


def test_block_results_do_not_depend_on_layout_or_length():
    """A Fortran-ordered copy, a prefix and the whole array give the same rows."""
    calibration, counts, codes = _inputs(BLOCK_SAMPLES + 7)
    corrector = Corrector(calibration)
    whole = corrector.correct(counts, codes)
    assert np.array_equal(corrector.correct(np.asfortranarray(counts), codes), whole)
    assert np.array_equal(corrector.correct(counts[:BLOCK_SAMPLES + 1], codes[:BLOCK_SAMPLES + 1]),
                          whole[:BLOCK_SAMPLES + 1])
    assert corrector.correct(np.zeros((0, 3)), np.zeros(0)).shape == (0, 3)


def test_a_non_finite_temperature_code_gives_nan_in_both_paths():
    """`NaN` in the temperature code propagates to all three axes, in blocks and per sample."""
    calibration, counts, codes = _inputs(10)
    codes[4] = np.nan
    corrector = Corrector(calibration)
    bulk = corrector.correct(counts, codes)
    assert np.isnan(bulk[4]).all() and np.isfinite(np.delete(bulk, 4, axis=0)).all()
    assert all(np.isnan(corrector.correct_sample(*counts[4].tolist(), float('nan'))))
