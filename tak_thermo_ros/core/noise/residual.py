"""Noise models that ``diagnose`` and ``validate`` derive: from a run's residual, or in codes.

The given sources (a Kalibr-style file, a static run, the calibration file's noise section) come
from :func:`tak_thermo_ros.passes.noise.noise_models`; here: a model expressed in a counts
calibration's codes, and, when none is given, a model fitted to the diagnosed run's own residual
at short averaging times (``source='residual'``, said as such).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.noise.allan import AllanVariance, allan_variance, cluster_sizes, largest_cluster
from tak_thermo_ros.core.noise.fit import fit_noise_model
from tak_thermo_ros.core.noise.model import NoiseModel
from tak_thermo_ros.errors import TakError

RESIDUAL_LONGEST_TAU_S = 30.0
"""A noise model from the diagnosed run's own residual is fitted to its Allan variance at
averaging times up to this (half a minute): a thermal effect acts over the minutes a temperature
ramp takes, so what the residual shows at shorter averaging times is the sensor's own noise;
longer, the residual holds whatever the model misses besides the wander, and no run can tell
them apart without a static run or a data sheet."""
RESIDUAL_TERMS = ('quantization', 'white_noise_density', 'bias_instability')
"""The terms of a model fitted to a run's own residual: those that half a minute of averaging
identifies. A random walk or a ramp rises slowly; fitted at short averaging times it would be a
guess that then extrapolates unchecked to the long averaging times at which ``diagnose`` judges
the residual, where it could hide the very drift the verdict is to find."""


def sample_period(stamp_ns: np.ndarray) -> float:
    """The median interval of ``stamp_ns`` in seconds (1 s for fewer than two stamps)."""
    return max(float(np.median(np.diff(stamp_ns))) * 1e-9, 1e-9) if len(stamp_ns) > 1 else 1.0


def in_counts(model: NoiseModel, axis_scales: Sequence[float]) -> NoiseModel:
    """A noise model in SI (a file) expressed in channel codes, by each axis's scale (codes per unit)."""
    scale = np.asarray(axis_scales, dtype=float)

    def scaled(name: str) -> tuple[float, float, float]:
        values = np.asarray(getattr(model, name), dtype=float) * scale
        return float(values[0]), float(values[1]), float(values[2])
    terms = ('white_noise_density', 'bias_instability', 'random_walk', 'quantization', 'rate_ramp',
             'random_walk_bound')
    bumps = tuple(tuple(float(v) for v in np.asarray(sigma) * scale) for sigma in model.gauss_markov)
    return replace(model, gauss_markov=bumps, **{name: scaled(name) for name in terms})


def short_term_model(allan: AllanVariance) -> NoiseModel:
    """The model of a residual's own short-term noise from its Allan variance (``source='residual'``).

    The terms :data:`RESIDUAL_TERMS`, fitted at averaging times up to :data:`RESIDUAL_LONGEST_TAU_S`.

    :raises NoiseError: fewer than five usable averaging times there.
    """
    short = allan.select(allan.taus <= RESIDUAL_LONGEST_TAU_S * (1.0 + 1e-9))
    return fit_noise_model(short, source='residual', terms=RESIDUAL_TERMS)


def model_from_residual(residual: np.ndarray, stamp_ns: np.ndarray) -> NoiseModel | None:
    """The noise model of the run's own residual, or ``None`` when the run is too short.

    At averaging times up to :data:`RESIDUAL_LONGEST_TAU_S`, the terms :data:`RESIDUAL_TERMS`
    (``source='residual'``); ``None`` when the run is too short for five averaging times.
    """
    period = sample_period(stamp_ns)
    residual = np.asarray(residual, dtype=float)
    largest = min(largest_cluster(len(residual)), int(RESIDUAL_LONGEST_TAU_S / period))
    try:
        allan = allan_variance(residual - residual.mean(axis=0), 1.0 / period, clusters=cluster_sizes(largest, 2))
        return short_term_model(allan)
    except TakError:
        return None
