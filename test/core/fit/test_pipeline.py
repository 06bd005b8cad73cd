"""The fit's pipeline: the blocked solve equals the in-memory one; columns are read back by their labels."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from tak_thermo_ros.core.effects import LIBRARY, resolve_effect
from tak_thermo_ros.core.fit.design import Frame, axis_design
from tak_thermo_ros.core.fit.model import amplitude_errors, fitted_effects
from tak_thermo_ros.core.fit.solve import BlockedQR, least_squares


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2 ** 31), cuts=st.lists(st.integers(1, 299), max_size=6))
def test_blocked_solve_equals_the_in_memory_solve(seed, cuts):
    """Any cut of the rows into blocks: the same coefficients and residual sum of squares."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1.0, 1.0, 300)
    design = np.column_stack([u ** j * scale for j, scale in enumerate((1.0, 1e3, 1e-2, 5.0))])
    target = design @ rng.normal(size=4) + rng.normal(scale=0.1, size=300)
    whole = least_squares(design.copy(), target)
    blocked = BlockedQR(5)
    for rows in np.split(np.column_stack([design, target]), sorted(set(cuts))):
        blocked.add(rows)
    solution = blocked.solution()
    np.testing.assert_allclose(solution.coefficients, whole.coefficients, rtol=1e-9)
    assert abs(solution.rss - whole.rss) <= 1e-9 * whole.rss
    assert solution.rank == whole.rank == 4


def test_each_coefficient_lands_in_the_amplitude_its_column_names():
    """Base columns, then the input effects', then the offset effects': read back by label, per axis."""
    cross, lag = LIBRARY['cross_axis'](), resolve_effect('warmup_per_axis')()
    rows = 50
    force = np.ones((rows, 3))
    codes = np.linspace(-5.0, 5.0, rows)
    powers = Frame.of_range(-5.0, 5.0).powers(codes, 3)
    basis = np.ones((rows, 3))
    designs = [axis_design(i, powers, force, np.zeros((rows, 3)), bias_order=3, scale_order=2,
                           held_scale=1.0 if i == 2 else None, input_effects=[cross], offset_bases=[(lag, basis)])
               for i in range(3)]
    coefficients = [100.0 * i + np.arange(len(design.columns)) for i, design in enumerate(designs)]
    fitted = dict((e.name, e) for e in fitted_effects([cross, lag], [d.columns for d in designs], coefficients))
    for i, design in enumerate(designs):
        base = 4 if i == 2 else 7  # a held axis has the offset polynomial only
        assert design.matrix.shape == (rows, base + 2 + 1)
        first, second = (name for name, _ in cross.input_columns(i, force[:1]))
        assert fitted['cross_axis'][first] == 100.0 * i + base
        assert fitted['cross_axis'][second] == 100.0 * i + base + 1
        assert fitted['warmup_per_axis'][f'amplitude_{"xyz"[i]}'] == 100.0 * i + base + 2
    errors = amplitude_errors(designs[0].columns, np.arange(10.0))
    assert errors['warmup_per_axis.amplitude_x'] == 9.0 and len(errors) == 3
