"""A pool's shared terms' covariance when a bias wanders within each record (``system.record_robust``)."""

from __future__ import annotations

import numpy as np

from tak_thermo_ros.core.fit.handheld.system import MIN_ROBUST_RECORDS, record_robust, solve
from tak_thermo_ros.core.fit.random_effects import RecordColumns, RecordSystem

CURVE = np.array([0.0, 2.0, -1.0, 0.5])
"""The shared curve's coefficients over ``u^0 .. u^3``."""
EDGES = np.array([-0.9, 0.9])
"""The contrast judged: the curve at the range's upper edge less at its lower one."""


def _pool(seed: int, records: int = 16, rests: int = 12, walk: float = 0.3, white: float = 0.05):
    """A pool's solve: per record a turn-on offset, rests on a warm-up, a bias that wanders between them.

    The rows weigh each rest as independent but for its record's offset (the model's view); the
    random walk moves a record's rests together. :returns: the solve and the contrast's truth.
    """
    rng = np.random.default_rng(seed)
    width = 4 + records
    columns = RecordColumns(np.arange(4, width)[:, None], width)
    system = RecordSystem(columns)
    rows, owner = [], []
    for record in range(records):
        start, end = rng.uniform(-1.0, 0.2), rng.uniform(0.3, 1.0)
        u = start + (end - start) * (1.0 - np.exp(-np.arange(rests) / 4.0))
        bias = rng.normal(0.0, 1.0) + np.cumsum(rng.normal(0.0, walk, rests)) + rng.normal(0.0, white, rests)
        powers = u[:, None] ** np.arange(4)[None, :]
        row = np.zeros((rests, width + 1))
        row[:, :4] = powers
        row[:, 4 + record] = 1.0
        row[:, -1] = powers @ CURVE + bias
        rows.append(row / white)
        owner.append(np.full(rests, record))
    system.add(np.vstack(rows), np.concatenate(owner))
    system.add_prior(np.array([1.0]))
    solved = solve(system, {}, width)
    contrast = EDGES[1] ** np.arange(4) - EDGES[0] ** np.arange(4)
    return solved, contrast


def _z(solved, contrast: np.ndarray) -> float:
    where = [solved.free.index(j) for j in range(4)]
    error = float(contrast @ (solved.theta[:4] - CURVE))
    return error / float(np.sqrt(contrast @ solved.covariance[np.ix_(where, where)] @ contrast))


def test_leaving_records_out_covers_a_curve_that_wanders_within_records():
    """Over 200 pools the model's 2-sigma band holds the edge-to-edge contrast rarely; the robust one about 95 %."""
    model, robust = [], []
    for seed in range(200):
        solved, contrast = _pool(seed)
        model.append(abs(_z(solved, contrast)) <= 2.0)
        robust.append(abs(_z(record_robust(solved), contrast)) <= 2.0)
    assert np.mean(model) < 0.8
    assert 0.88 <= np.mean(robust) <= 0.995


def test_without_wander_the_covariance_stays_near_the_models():
    """Rests independent within a record: the robust band is never narrower, and about as wide (median within 1.3x)."""
    ratios = []
    for seed in range(40):
        solved, contrast = _pool(seed, walk=0.0)
        where = [solved.free.index(j) for j in range(4)]
        before = contrast @ solved.covariance[np.ix_(where, where)] @ contrast
        after = contrast @ record_robust(solved).covariance[np.ix_(where, where)] @ contrast
        ratios.append(np.sqrt(after / before))
    assert min(ratios) >= 1.0 - 1e-9
    assert np.median(ratios) <= 1.3


def test_few_records_keep_the_models_covariance():
    """Fewer than MIN_ROBUST_RECORDS records: the solve comes back as it is."""
    solved, _ = _pool(1, records=MIN_ROBUST_RECORDS - 1)
    assert record_robust(solved) is solved
