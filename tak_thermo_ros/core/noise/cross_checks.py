"""Two readings of a measured Allan variance beside the noise model's fit: a step in the record, IEEE 952's slope lines.

:func:`find_step` finds a jump in the record (the largest term of the estimator far beyond what
Gaussian noise gives); :func:`slope_lines` reads the tangents of slope -1, -1/2, 0, +1/2, +1
under the curve, each an upper bound of its term. :func:`~tak_thermo_ros.core.noise.fit.fit_noise`
reports both beside its fit (:class:`~tak_thermo_ros.core.noise.fit.NoiseFit`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from tak_thermo_ros.core.noise.model import TERMS, allan_terms

SLOPE_LINE_EDF = 5.0
"""IEEE 952's slope lines are read at averaging times with at least this many degrees of freedom."""
STEP_ALPHA = 0.001
"""False-alarm probability of the step test per axis (Bonferroni over averaging times and terms)."""


@dataclass(frozen=True)
class Step:
    """A jump in the record: one term of the estimator far beyond what Gaussian noise gives.

    :param time_s: where in the record (s from its start).
    :param size: the difference of the averages before and after it, units, at ``tau``.
    :param tau: the averaging time where it stands out most, s.
    :param sigmas: how many standard deviations of that difference it is.
    :param low: the shortest averaging time at which it stands out, s.
    :param high: the longest, s.
    """

    time_s: float
    size: float
    tau: float
    sigmas: float
    low: float
    high: float


@dataclass(frozen=True)
class SlopeLines:
    """IEEE 952's slope-line reading of the measured Allan deviation, per axis: each an upper bound.

    The largest line of each slope that stays under the measured curve (at averaging times of
    two samples and longer): ``quantization`` (slope -1, ``Q = sigma tau / sqrt(3)``),
    ``white_noise_density`` (-1/2, ``N = sigma sqrt(tau)``), ``bias_instability`` (0, ``B =
    min sigma / 0.664``), ``random_walk`` (+1/2, ``K = sigma sqrt(3 / tau)``), ``rate_ramp``
    (+1, ``R = sigma sqrt(2) / tau``), and where each touches (``*_tau``). A term equals its
    line where it dominates the curve; no fitted term can lie above its line by more than the
    measurement's own scatter.
    """

    values: dict[str, tuple[float, float, float]]
    taus: dict[str, tuple[float, float, float]]

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return _finite({name: {'value': list(value), 'tau_s': list(self.taus[name])}
                        for name, value in self.values.items()})


def _finite(value: Any) -> Any:
    """``value`` with every non-finite float as ``None`` (strict JSON), lists and mappings followed."""
    if isinstance(value, dict):
        return {key: _finite(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(item) for item in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def find_step(allan: Any, axis: int, usable: np.ndarray | None = None) -> Step | None:
    """A jump in the record: the largest term of the estimator far beyond what Gaussian noise gives.

    For Gaussian noise of any spectrum the difference of two adjacent ``m``-sample averages is
    Gaussian with variance ``2 avar``; of the estimator's ``n`` such differences the largest
    exceeds ``z`` standard deviations with probability at most ``n * 2 Phi(-z)``. A
    step of size ``D`` gives a difference ``D`` however small its share of the Allan variance.
    Tested at every averaging time with the estimator's :attr:`AllanVariance.peak` (Bonferroni:
    :data:`STEP_ALPHA` over averaging times and differences); ``None`` when none stands out.
    """
    from scipy.stats import norm
    peak = getattr(allan, 'peak', None)
    if peak is None:
        return None
    keep = (allan.counts >= 2) & np.isfinite(peak[:, axis]) & (allan.avar[:, axis] > 0.0)
    if usable is not None:
        keep &= usable
    if not np.any(keep):
        return None
    m = allan.clusters.astype(float)
    with np.errstate(divide='ignore', invalid='ignore'):
        sigmas = peak[:, axis] / (m * np.sqrt(2.0 * allan.avar[:, axis]))
    # Bonferroni over every difference (overlapping, so conservative) and every averaging time.
    terms = np.maximum(allan.counts * np.maximum(allan.strides, 1), 1.0)
    critical = norm.isf(STEP_ALPHA / (2.0 * terms * int(np.count_nonzero(keep))))
    flagged = keep & (sigmas > critical)
    if not np.any(flagged):
        return None
    best = int(np.argmax(np.where(flagged, sigmas / critical, -np.inf)))
    index = int(allan.peak_index[best, axis])
    return Step(time_s=float((index + m[best]) / allan.rate), size=float(peak[best, axis] / m[best]),
                tau=float(allan.taus[best]), sigmas=float(sigmas[best]), low=float(allan.taus[flagged].min()),
                high=float(allan.taus[flagged].max()))


def slope_lines(allan: Any, keep: np.ndarray) -> SlopeLines:
    """IEEE 952's slope lines under the measured Allan deviation (see :class:`SlopeLines`).

    Read where the curve is known: averaging times in ``keep`` with at least
    :data:`SLOPE_LINE_EDF` degrees of freedom (a walk's, the fewest), not the last few points
    whose estimate can fall to a tenth of its value.
    """
    from tak_thermo_ros.core.noise.allan import equivalent_degrees_of_freedom
    keep = keep & (equivalent_degrees_of_freedom(allan, -2) >= SLOPE_LINE_EDF)
    taus = allan.taus[keep][:, None]
    # A term alone at its unit Allan variance (allan_terms): its value is sqrt(avar / unit) at each tau.
    unit = allan_terms(allan.taus[keep])
    readings = {name: np.sqrt(allan.avar[keep] / unit[:, [i]]) for i, name in enumerate(TERMS)}
    values, where = {}, {}
    for name, reading in readings.items():
        if not len(reading):
            values[name], where[name] = (math.nan,) * 3, (math.nan,) * 3
            continue
        best = np.argmin(reading, axis=0)
        values[name] = tuple(float(reading[b, i]) for i, b in enumerate(best))
        where[name] = tuple(float(taus[b, 0]) for b in best)
    return SlopeLines(values=values, taus=where)  # type: ignore[arg-type]
