"""A fleet's prior from its units' information: the REML held against MixedLM, recovery over seeds, groups, far units.

The units here are synthetic at the level of their sufficient statistics: each unit's curve drawn
around the fleet's, its records a polynomial seen at its own temperatures (some narrow, some wide)
with its own noise; the statistics are what the pool fit hands on (``H``, ``g``, ``c``). The pool
fit's own statistics are tested in test/passes/test_fleet_prior.py.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from tak_thermo_ros.core.fit.fleet_prior import GROUP_BIC, fleet_prior, offset_band
from tak_thermo_ros.core.fit.fleet_reml import MIN_UNITS, _Stats, reml
from tak_thermo_ros.core.fit.prior import Basis, Information, SensorPrior, basis_change, term_change
from tak_thermo_ros.errors import FitError

NAMES = ('x.offset', 'x.offset_T1', 'x.offset_T2')
BASIS = Basis(0.0, 1.0)


def unit_information(rng, beta: np.ndarray, *, sigma: float, count: int, span: tuple[float, float],
                     names=NAMES) -> tuple[Information, np.ndarray, np.ndarray]:
    """A unit seen at ``count`` temperatures within ``span`` (``u``): its information, design and data."""
    u = rng.uniform(*span, count)
    design = u[:, None] ** np.arange(len(beta))[None, :]
    y = design @ beta + sigma * rng.standard_normal(count)
    rows = np.column_stack([design, y]) / sigma
    return Information(tuple(names), rows.T @ rows, BASIS, float(span[0]), float(span[1]), rows=count), u, y


def fleet(rng, mean, spread, units: int, *, sigma: float = 0.05, count: int = 30, narrow_share: float = 0.3):
    """``units`` units around ``mean`` (``spread`` per term), a share of them seen over a narrow span only."""
    out, truths = {}, []
    for index in range(units):
        beta = mean + spread * rng.standard_normal(len(mean))
        span = (-0.2, 0.3) if rng.uniform() < narrow_share else (-1.0, 1.0)
        out[f'unit{index:02d}'] = unit_information(rng, beta, sigma=sigma, count=count, span=span)[0]
        truths.append(beta)
    return out, np.array(truths)


def test_the_reml_is_mixedlm_s_on_the_same_data():
    """The variance components, the mean and the noise scale from the units' statistics equal MixedLM's REML.

    statsmodels' MixedLM on the raw data (random intercept, slope and curvature as independent variance
    components, the residual variance free): the units' sufficient statistics ``X'X``, ``X'y``, ``y'y``
    and their row counts carry the same restricted likelihood (:func:`reml` with ``scale``).
    """
    from statsmodels.regression.mixed_linear_model import MixedLM
    for seed in range(3):
        rng = np.random.default_rng(seed)
        mean, spread, sigma = np.array([1.0, 0.5, -0.3]), np.array([0.4, 0.2, 0.1]), 0.3
        infos, designs, targets, groups = [], [], [], []
        for unit in range(10 + 2 * seed):
            beta = mean + spread * rng.standard_normal(3)
            u = rng.uniform(-1.0, 1.0, 25)
            design = u[:, None] ** np.arange(3)[None, :]
            y = design @ beta + sigma * rng.standard_normal(len(u))
            rows = np.column_stack([design, y])
            infos.append(Information(NAMES, rows.T @ rows, BASIS, -1.0, 1.0, rows=len(u)))
            designs.append(design)
            targets.append(y)
            groups += [unit] * len(u)
        components = {name: {unit: design[:, [k]] for unit, design in enumerate(designs)}
                      for k, name in enumerate('abc')}
        y, x = np.concatenate(targets), np.vstack(designs)
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            theirs = MixedLM(y, x, np.array(groups), exog_re=np.zeros((len(y), 0)),
                             exog_vc=components).fit(reml=True, method=['lbfgs'])
        ours = reml(_Stats.of(infos, NAMES), scale=True)
        # a component at the boundary (about 0) is flat for both: equal within a hundredth of the spreads
        np.testing.assert_allclose(ours.spread, np.sqrt(theirs.vcomp), rtol=2e-3, atol=0.01 * spread.max())
        np.testing.assert_allclose(ours.mean, theirs.fe_params, rtol=1e-4, atol=1e-6)
        assert ours.phi == pytest.approx(theirs.scale, rel=1e-3)


def test_the_spread_is_recovered_and_its_error_covers_it_over_seeds():
    """Over 200 fleets of 15 units (a third seen over a narrow span): the spread within 2 errors about 95 % of the time.

    And the estimate is not biased by more than a few percent (the mean over the fleets).
    """
    mean, spread = np.array([0.2, 1.0, -0.4]), np.array([0.3, 0.15, 0.08])
    covered, ratios = [], []
    for seed in range(200):
        rng = np.random.default_rng(1000 + seed)
        units, _ = fleet(rng, mean, spread, 15)
        fitted = reml(_Stats.of(list(units.values()), NAMES))
        covered.append(np.abs(fitted.spread - spread) <= 2.0 * fitted.spread_error)
        ratios.append(fitted.spread / spread)
    coverage = np.mean(covered, axis=0)
    assert np.all((coverage > 0.88) & (coverage < 0.99)), coverage
    assert np.all(np.abs(np.mean(ratios, axis=0) - 1.0) < 0.08), np.mean(ratios, axis=0)


def test_a_new_unit_lies_within_the_prior_s_band_about_95_percent_of_the_time():
    """The band of :func:`offset_band` (the spread widened for few units, the mean's error): a held-out unit's curve.

    Over 150 fleets of 8 units, a ninth unit's true curve at 9 temperatures within mean +- 2 sigma:
    94-97 % (the Student-t stand-in; the plain Gaussian band of 8 units covers about 91 %).
    """
    mean, spread = np.array([0.2, 1.0, -0.4]), np.array([0.3, 0.15, 0.08])
    temperatures = np.linspace(-1.0, 1.0, 9)
    inside = []
    for seed in range(150):
        rng = np.random.default_rng(5000 + seed)
        units, _ = fleet(rng, mean, spread, 8)
        prior = fleet_prior(units, 'gyro', BASIS, groups=1)
        truth = mean + spread * rng.standard_normal(3)
        band = offset_band(prior, 'x', temperatures)
        curve = (temperatures[:, None] ** np.arange(3)) @ truth
        inside += list(np.abs(curve - band.mean) <= 2.0 * band.sd)
    assert 0.93 <= np.mean(inside) <= 0.975, np.mean(inside)


def test_a_unit_of_another_part_is_named_and_left_out():
    """A unit whose slope lies 25 spreads off: named, with its term, not in the prior's units; the spread unharmed."""
    mean, spread = np.array([0.2, 1.0, -0.4]), np.array([0.3, 0.15, 0.08])
    rng = np.random.default_rng(7)
    units, _ = fleet(rng, mean, spread, 12, narrow_share=0.0)
    units['bad'] = unit_information(rng, mean + np.array([0.0, 25 * 0.15, 0.0]), sigma=0.05, count=30,
                                    span=(-1.0, 1.0))[0]
    prior = fleet_prior(units, 'gyro', BASIS)
    assert [far.name for far in prior.left_out] == ['bad']
    assert prior.left_out[0].term == 'x.offset_T1' and prior.left_out[0].sigmas > 10.0
    assert 'bad' not in prior.units and len(prior.units) == 12
    assert prior.spread[1] < 2.0 * 0.15


def test_clean_fleets_lose_no_unit():
    """Over 100 clean fleets of 12 units: no unit left out (the screen's rate is 1e-3 per fleet)."""
    mean, spread = np.array([0.2, 1.0, -0.4]), np.array([0.3, 0.15, 0.08])
    lost = 0
    for seed in range(100):
        rng = np.random.default_rng(9000 + seed)
        units, _ = fleet(rng, mean, spread, 12)
        lost += len(fleet_prior(units, 'gyro', BASIS, groups=1).left_out)
    assert lost <= 1


def test_two_groups_of_slopes_are_found_and_a_unit_placed_in_its_own():
    """Units in two groups of slopes 8 spreads apart: two groups, each unit in its own; a new unit's records place it.

    One group of the same size and spread: no second group over 20 fleets (the BIC margin holds).
    """
    mean, spread = np.array([0.2, 1.0, -0.4]), np.array([0.3, 0.15, 0.08])
    rng = np.random.default_rng(11)
    units = {}
    for index in range(24):
        shift = np.array([0.0, (-4.0 if index % 2 else 4.0) * 0.15, 0.0])
        units[f'unit{index:02d}'] = unit_information(rng, mean + shift + spread * rng.standard_normal(3), sigma=0.05,
                                                     count=30, span=(-1.0, 1.0))[0]
    prior = fleet_prior(units, 'gyro', BASIS)
    assert len(prior.groups) == 2
    slopes = sorted(group.mean[1] for group in prior.groups)
    assert slopes[0] == pytest.approx(1.0 - 0.6, abs=0.15) and slopes[1] == pytest.approx(1.0 + 0.6, abs=0.15)
    for group in prior.groups:
        parity = {int(name[-2:]) % 2 for name in group.units}
        assert len(parity) == 1 and len(group.units) >= 10
    newcomer = unit_information(rng, mean + np.array([0.0, 0.6, 0.0]), sigma=0.05, count=20, span=(0.0, 0.5))[0]
    weights = prior.membership(newcomer)
    upper = int(np.argmax([group.mean[1] for group in prior.groups]))
    assert weights[upper] > 0.95
    found = 0
    for seed in range(20):
        units, _ = fleet(np.random.default_rng(300 + seed), mean, spread, 24, narrow_share=0.0)
        found += len(fleet_prior(units, 'gyro', BASIS, groups=2).groups) > 1
    assert found <= 1, f'{found} of 20 one-group fleets split (BIC margin {GROUP_BIC})'


def test_too_few_units_and_untold_terms_are_said():
    """Fewer than MIN_UNITS: one line; a term no unit tells (all narrow, a cubic nobody sees) is left out and named."""
    rng = np.random.default_rng(3)
    units, _ = fleet(rng, np.array([0.2, 1.0, -0.4]), np.array([0.3, 0.15, 0.08]), MIN_UNITS - 1)
    with pytest.raises(FitError, match=f'needs {MIN_UNITS} units or more, got {MIN_UNITS - 1}'):
        fleet_prior(units, 'gyro', BASIS)
    names = (*NAMES, 'x.offset_T3')
    units = {}
    for index in range(6):
        info = unit_information(rng, np.array([0.2, 1.0, -0.4]), sigma=0.05, count=30, span=(-1.0, 1.0))[0]
        normal = np.zeros((5, 5))
        keep = [0, 1, 2, 4]
        normal[np.ix_(keep, keep)] = info.normal
        units[f'u{index}'] = Information(names, normal, BASIS, -1.0, 1.0)
    prior = fleet_prior(units, 'gyro', BASIS)
    assert prior.untold == ('x.offset_T3',) and prior.names == NAMES


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-2.0, 2.0), min_size=2, max_size=5), st.floats(-30.0, 60.0), st.floats(0.5, 40.0),
       st.floats(-30.0, 60.0), st.floats(0.5, 40.0))
def test_a_basis_change_keeps_the_curve(coefficients, ref_a, scale_a, ref_b, scale_b):
    """Any polynomial in one basis equals its change in another at every temperature; the way back is the inverse."""
    beta = np.array(coefficients)
    a, b = Basis(ref_a, scale_a), Basis(ref_b, scale_b)
    order = len(beta) - 1
    gamma = basis_change(a, b, order) @ beta
    temperatures = np.linspace(-20.0, 50.0, 7)
    before = a.powers(temperatures, order) @ beta
    after = b.powers(temperatures, order) @ gamma
    np.testing.assert_allclose(after, before, rtol=1e-8, atol=1e-8 * (1 + np.max(np.abs(before))))
    np.testing.assert_allclose(basis_change(b, a, order) @ gamma, beta, rtol=1e-6, atol=1e-8)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.floats(-20.0, 40.0), st.floats(1.0, 30.0))
def test_information_carries_to_another_basis_and_integrates_nuisance_out(seed, ref, scale):
    """A unit's estimate in another basis is its estimate carried there; a nuisance integrated out gives the block.

    The curve's covariance from :meth:`Information.marginal` is the curve's block of the full inverse
    (the nuisance term integrated out with a flat prior); the same curve values in either basis.
    """
    rng = np.random.default_rng(seed)
    names = (*NAMES, 'x.turn_on.r0')
    design = np.column_stack([rng.uniform(-1, 1, 40)[:, None] ** np.arange(3), rng.integers(0, 2, 40)])
    y = design @ rng.standard_normal(4) + 0.1 * rng.standard_normal(40)
    rows = np.column_stack([design, y])
    info = Information(names, rows.T @ rows, BASIS, -1.0, 1.0)
    curve = info.curve()
    assert curve.names == NAMES
    full = np.linalg.inv(info.hessian)
    estimate, covariance = curve.estimate()
    np.testing.assert_allclose(covariance, full[:3, :3], rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(estimate, (full @ info.gradient)[:3], rtol=1e-6, atol=1e-9)
    moved = curve.in_basis(Basis(ref, scale))
    moved_estimate, _ = moved.estimate()
    temperatures = np.linspace(-1.0, 1.0, 5)
    np.testing.assert_allclose(Basis(ref, scale).powers(temperatures, 2) @ moved_estimate,
                               BASIS.powers(temperatures, 2) @ estimate, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(term_change(NAMES, BASIS, Basis(ref, scale)) @ estimate, moved_estimate,
                               rtol=1e-6, atol=1e-8)


def test_prior_rows_are_the_prior_s_information():
    """The rows a fit takes, ``R (theta - mean)``, have the prior's precision and pull to its mean."""
    rng = np.random.default_rng(2)
    root = rng.standard_normal((3, 3))
    covariance = root @ root.T + 0.1 * np.eye(3)
    prior = SensorPrior(NAMES, np.array([0.5, -1.0, 2.0]), covariance)
    layout = ('x.scale', *NAMES, 'x.turn_on.r0')
    rows = prior.rows(layout)
    normal = rows.T @ rows
    np.testing.assert_allclose(normal[1:4, 1:4], np.linalg.inv(covariance), rtol=1e-8)
    assert np.all(normal[[0, 4], :-1] == 0.0)
    np.testing.assert_allclose(np.linalg.solve(normal[1:4, 1:4], normal[1:4, -1]), prior.mean, rtol=1e-8)
    with pytest.raises(FitError, match='the prior holds x.offset_T2'):
        prior.rows(('x.scale', 'x.offset', 'x.offset_T1'))


def test_the_spread_of_a_unit_never_seen_at_the_edges_stays_the_prior_s():
    """A unit seen near one temperature only: its curve's +- far from it is the prior's, given the level it saw.

    The posterior's variance at the edge equals the prior's conditioned on the curve's value where the
    records lie (Gaussian conditioning), within 10 %: the records add nothing they did not see.
    """
    rng = np.random.default_rng(4)
    units, _ = fleet(rng, np.array([0.2, 1.0, -0.4]), np.array([0.3, 0.15, 0.08]), 40, narrow_share=0.0)
    prior = fleet_prior(units, 'gyro', BASIS, groups=1)
    seen = unit_information(rng, np.array([0.2, 1.0, -0.4]), sigma=0.01, count=200, span=(0.0, 0.002))[0]
    sensor_prior, _ = prior.prior_for(seen)
    covariance = np.linalg.inv(seen.hessian + np.linalg.inv(sensor_prior.covariance))
    c = sensor_prior.covariance
    here, edge = np.array([1.0, 0.001, 1e-6]), np.array([1.0, 1.0, 1.0])
    conditioned = edge @ c @ edge - (edge @ c @ here) ** 2 / (here @ c @ here)
    assert math.sqrt(here @ covariance @ here) < 0.05 * math.sqrt(here @ c @ here)
    assert edge @ covariance @ edge == pytest.approx(conditioned, rel=0.1)
