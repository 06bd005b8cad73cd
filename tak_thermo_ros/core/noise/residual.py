"""Noise models that ``diagnose`` and ``validate`` derive: from a run's residual, or in codes.

The given sources (a Kalibr-style file, a static run, the calibration file's noise section) come
from :func:`tak_thermo_ros.noise_run.noise_models`; here: a model expressed in a counts
calibration's codes, and, when none is given, a model fitted to the diagnosed run's own residual
at short averaging times (``source='residual'``, said as such).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.noise.allan import allan_variance, cluster_sizes, largest_cluster
from tak_thermo_ros.core.noise.model import NoiseModel, fit_noise_model
from tak_thermo_ros.errors import TakError

RESIDUAL_LONGEST_TAU_S = 30.0
"""A noise model from the diagnosed run's own residual is fitted to its Allan variance at
averaging times up to this (half a minute): a thermal effect acts over the minutes a temperature
ramp takes, so what the residual shows at shorter averaging times is the sensor's own noise;
longer, the residual holds whatever the model misses besides the wander, and no run can tell
them apart without a static run or a data sheet."""


def sample_period(stamp_ns: np.ndarray) -> float:
    """The median interval of ``stamp_ns`` in seconds (1 s for fewer than two stamps)."""
    return max(float(np.median(np.diff(stamp_ns))) * 1e-9, 1e-9) if len(stamp_ns) > 1 else 1.0


def in_counts(model: NoiseModel, axis_scales: Sequence[float]) -> NoiseModel:
    """A noise model in SI (a file) expressed in channel codes, by each axis's scale (codes per unit)."""
    scale = np.asarray(axis_scales, dtype=float)

    def scaled(name: str) -> tuple[float, float, float]:
        values = np.asarray(getattr(model, name), dtype=float) * scale
        return float(values[0]), float(values[1]), float(values[2])
    terms = ('white_noise_density', 'bias_instability', 'random_walk', 'quantization', 'rate_ramp')
    return replace(model, **{name: scaled(name) for name in terms})


def model_from_signal(signal: np.ndarray, sample_period_s: float, source: str, *,
                      longest_s: float | None = None) -> NoiseModel:
    """The five-term noise model of a ``(k, 3)`` signal.

    Its overlapping Allan variance, fitted; up to ``longest_s`` of averaging when given, two
    averaging times per octave.
    """
    signal = np.asarray(signal, dtype=float)
    largest = largest_cluster(len(signal))
    if longest_s is not None:
        largest = min(largest, int(longest_s / sample_period_s))
    allan = allan_variance(signal - signal.mean(axis=0), 1.0 / sample_period_s, clusters=cluster_sizes(largest, 2))
    return fit_noise_model(allan, source=source)


def model_from_residual(residual: np.ndarray, stamp_ns: np.ndarray) -> NoiseModel | None:
    """The noise model of the run's own residual, or ``None`` when the run is too short.

    At averaging times up to :data:`RESIDUAL_LONGEST_TAU_S` (``source='residual'``); ``None`` when
    the run is too short for five averaging times.
    """
    try:
        return model_from_signal(residual, sample_period(stamp_ns), 'residual', longest_s=RESIDUAL_LONGEST_TAU_S)
    except TakError:
        return None
