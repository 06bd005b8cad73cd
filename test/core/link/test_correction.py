"""The correction link: two paths that agree bit for bit, and the inverse of the forward model."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tak_thermo_ros.core.link.correction import Corrector, OutOfRange, acceleration_variance
from tak_thermo_ros.core.link.model import AxisModel, Calibration, horner_no_constant
from tak_thermo_ros.core.simulation.scenario import Scenario


@pytest.fixture
def calibration() -> Calibration:
    """The default simulated unit's true link."""
    return Scenario().truth()


def _random_inputs(calibration: Calibration, count: int, seed: int = 3):
    rng = np.random.default_rng(seed)
    counts = np.round(rng.uniform(-30000, 30000, size=(count, 3)))
    codes = rng.uniform(calibration.temp_code_min - 200, calibration.temp_code_max + 200, size=count)
    return counts, np.round(codes)


@pytest.mark.parametrize('policy', list(OutOfRange))
def test_vectorised_and_per_sample_paths_agree(calibration, policy):
    """correct() and correct_sample() agree to 1e-12 relative; in fact they are bit-identical."""
    counts, codes = _random_inputs(calibration, 2000)
    corrector = Corrector(calibration, out_of_range=policy)
    bulk = corrector.correct(counts, codes)
    single = np.array([corrector.correct_sample(*row, code) for row, code in zip(counts.tolist(), codes.tolist())])
    np.testing.assert_allclose(single, bulk, rtol=1e-12, atol=0.0)
    assert np.array_equal(single, bulk)


def test_correction_inverts_the_forward_model(calibration):
    """f_hat(N(f, N_t), N_t) = f inside the calibrated range, to rounding error."""
    rng = np.random.default_rng(5)
    force = rng.uniform(-20.0, 20.0, size=(5000, 3))
    codes = rng.uniform(calibration.temp_code_min, calibration.temp_code_max, size=5000)
    counts = calibration.forward(force, codes)
    recovered = Corrector(calibration).correct(counts, codes)
    np.testing.assert_allclose(recovered, force, rtol=0.0, atol=1e-11)


def test_code_at_reference_matches_the_paper(calibration):
    """N_hat(0) = (N - dNs(n)) / F_c(n) + dNs0 equals the code the same input gives at n = 0."""
    rng = np.random.default_rng(7)
    force = rng.uniform(-9.8, 9.8, size=(1000, 3))
    codes = rng.uniform(calibration.temp_code_min, calibration.temp_code_max, size=1000)
    counts = calibration.forward(force, codes)
    at_reference = calibration.forward(force, np.full(1000, calibration.temp_code_ref))
    np.testing.assert_allclose(Corrector(calibration).code_at_reference(counts, codes), at_reference,
                               rtol=0.0, atol=1e-9)


def test_clamp_uses_the_range_edge_and_extrapolate_does_not(calibration):
    """Out of range: clamp equals the value at the edge; extrapolate differs and follows the polynomial."""
    counts = np.array([[2500.0, -40.0, 7.0]])
    beyond = np.array([calibration.temp_code_max + 500.0])
    edge = np.array([calibration.temp_code_max])
    clamp = Corrector(calibration, out_of_range=OutOfRange.CLAMP)
    extrapolate = Corrector(calibration, out_of_range=OutOfRange.EXTRAPOLATE)
    assert np.array_equal(clamp.correct(counts, beyond), clamp.correct(counts, edge))
    assert not np.allclose(extrapolate.correct(counts, beyond), clamp.correct(counts, edge), rtol=1e-9, atol=0)
    force = extrapolate.correct(counts, beyond)
    np.testing.assert_allclose(calibration.forward(force, beyond), counts, atol=1e-9)
    assert clamp.out_of_range_count(np.array([calibration.temp_code_min - 1, 8000.0, beyond[0]])) == 2


def test_nominal_turns_every_temperature_term_off(calibration):
    """The nominal link corrects with scale and offset only."""
    nominal = Corrector(calibration.nominal())
    counts = np.array([[1000.0, 2000.0, -3000.0]])
    expected = (counts[0] - [a.offset for a in calibration.axes]) / [a.scale for a in calibration.axes]
    np.testing.assert_allclose(nominal.correct(counts, np.array([calibration.temp_code_max]))[0], expected, rtol=1e-15)


def test_horner_matches_powers():
    """Horner without constant term evaluates c1 n + c2 n^2 + c3 n^3."""
    n = np.linspace(-700.0, 700.0, 11)
    coeffs = (0.05, 1.5e-5, 2.0e-8)
    np.testing.assert_allclose(horner_no_constant(coeffs, n), sum(c * n ** (k + 1) for k, c in enumerate(coeffs)),
                               rtol=1e-13, atol=1e-12)


def test_offset_shape_is_normalised_to_unit_maximum(calibration):
    """`max` |F_s| over the calibrated range is 1 and D is the largest offset change."""
    low, high = calibration.code_offset_range()
    grid = np.linspace(low, high, 4001)
    for axis in calibration.axes:
        shape = horner_no_constant(axis.offset_shape, grid)
        assert np.max(np.abs(shape)) == pytest.approx(1.0, abs=1e-6)


def test_variance_from_residual_rms():
    """The Imu covariance diagonal is (residual RMS / K0)^2, zero where unknown."""
    axis = AxisModel(scale=200.0, offset=0.0, offset_span=0.0, offset_shape=(0.0,), residual_rms=2.0)
    unknown = AxisModel(scale=200.0, offset=0.0, offset_span=0.0, offset_shape=(0.0,))
    calibration = Calibration(temp_code_ref=0.0, temp_code_min=-1.0, temp_code_max=1.0, axes=(axis, unknown, axis))
    assert acceleration_variance(calibration) == (1e-4, 0.0, 1e-4)


@pytest.mark.parametrize('policy', list(OutOfRange))
def test_the_polynomials_run_once_per_temperature_and_give_the_vectorised_bits(calibration, policy, monkeypatch):
    """A temperature every 50 samples (as a driver batches them): each axis's polynomials once per temperature.

    The samples in between take the held offsets and gains; the result is still the vectorised
    path's, bit for bit, and an equal temperature of another sign of zero is evaluated afresh.
    """
    from tak_thermo_ros.core.link import correction
    calls = []
    evaluate = correction.offset_and_gain
    monkeypatch.setattr(correction, 'offset_and_gain', lambda *args: calls.append(args[0]) or evaluate(*args))
    counts, codes = _random_inputs(calibration, 2000)
    codes = np.repeat(codes[::50], 50)  # 40 temperatures, each held for 50 samples
    corrector = Corrector(calibration, out_of_range=policy)
    single = []
    for start in range(0, len(codes), 50):
        temperature = float(codes[start])  # one float per temperature message, as the online core holds it
        single += [corrector.correct_sample(*row, temperature) for row in counts[start:start + 50].tolist()]
    assert len(calls) == 3 * 40
    assert np.array_equal(np.array(single), corrector.correct(counts, codes))
    zero = Corrector(replace(calibration, temp_code_ref=0.0, temp_code_min=-10.0, temp_code_max=10.0))
    calls.clear()
    plus, minus = zero.correct_sample(-0.0, 1.0, 2.0, 0.0), zero.correct_sample(-0.0, 1.0, 2.0, -0.0)
    assert len(calls) == 6
    bulk = zero.correct(np.array([[-0.0, 1.0, 2.0]] * 2), np.array([0.0, -0.0]))
    assert np.array_equal(np.array([plus, minus]).view(np.uint64), bulk.view(np.uint64))
