"""The noise floor and the residual views: what the residual follows, plateaus, directions."""

from __future__ import annotations

import math

import numpy as np

from tak_thermo_ros.core.diagnose.values import Driver, Plateau, Views
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.errors import FitError

JUMP_SIGMAS = 8.0
RATE_WINDOW_S = 300.0
"""Window of the central difference that estimates ``dN_t/dt`` from the held, quantised code."""
VIEW_BINS = 40


# ------------------------------------------------------------------------------ noise floor

def segment_breaks(samples: AlignedSamples) -> np.ndarray:
    """``(k,)`` True where a sample begins a new segment: a reference change or a time gap.

    A gap is a step longer than three times the median sampling step.
    """
    count = len(samples)
    breaks = np.zeros(count, dtype=bool)
    if count == 0:
        return breaks
    breaks[0] = True
    if count > 1:
        steps = np.diff(samples.stamp_ns).astype(float)
        breaks[1:] |= steps > 3.0 * max(float(np.median(steps)), 1.0)
        if samples.reference is not None:
            breaks[1:] |= np.any(samples.reference[1:] != samples.reference[:-1], axis=1)
    return breaks


def noise_floor(residual: np.ndarray, breaks: np.ndarray | None = None, *,
                least_spread: float = 0.5) -> tuple[np.ndarray, int]:
    """Per-axis noise floor (white noise plus code rounding) from successive differences.

    ``floor = sqrt(mean(d^2) / 2)`` with ``d = r[k+1] - r[k]`` inside segments, after leaving
    out isolated jumps beyond :data:`JUMP_SIGMAS` robust sigmas of ``d``.

    :param residual: ``(k, 3)`` residual in counts, in time order.
    :param breaks: ``(k,)`` True where a segment starts (no difference taken into it).
    :param least_spread: the smallest robust sigma of the differences the jump limit assumes:
        half a code for the paper's whole-number codes (rounding alone spreads them), 0 for a
        driver's values in SI units (a spread in counts would reject nothing there).
    :returns: ``(3,)`` floor in counts and the number of differences used (for its
        standard error: the relative standard error of ``floor^2`` is about ``sqrt(3 / m)``).
    """
    residual = np.asarray(residual, dtype=float)
    if len(residual) < 3:
        msg = f'too few samples ({len(residual)}) to estimate the noise floor'
        raise FitError(msg)
    diffs = np.diff(residual, axis=0)
    keep = np.ones(len(diffs), dtype=bool) if breaks is None else ~np.asarray(breaks[1:], dtype=bool)
    diffs = diffs[keep]
    if len(diffs) < 2:
        msg = 'too few samples between turntable moves to estimate the noise floor'
        raise FitError(msg)
    floor = np.empty(diffs.shape[1])
    used = len(diffs)
    for i in range(diffs.shape[1]):
        column = diffs[:, i]
        robust = 1.4826 * float(np.median(np.abs(column - np.median(column))))
        limit = JUMP_SIGMAS * max(robust, least_spread)
        inside = np.abs(column) <= limit if limit > 0.0 else np.ones(len(column), dtype=bool)
        floor[i] = math.sqrt(float(np.mean(column[inside] ** 2)) / 2.0)
        used = min(used, int(np.count_nonzero(inside)))
    return floor, used


# ------------------------------------------------------------------------------------ views

def temperature_rate(time_s: np.ndarray, temp_code: np.ndarray, window_s: float) -> np.ndarray:
    """``dN_t/dt`` in codes per second: central difference of the held code over ``window_s``."""
    if len(time_s) < 2 or window_s <= 0.0:
        return np.zeros(len(time_s))
    half = window_s / 2.0
    ahead = np.minimum(time_s + half, time_s[-1])
    behind = np.maximum(time_s - half, time_s[0])
    span = np.maximum(ahead - behind, 1e-9)
    return (np.interp(ahead, time_s, temp_code) - np.interp(behind, time_s, temp_code)) / span


def build_views(samples: AlignedSamples, *, rate_window_s: float | None = None) -> Views:
    """The quantities the residual is viewed against (see :class:`Views`).

    The rate window defaults to :data:`RATE_WINDOW_S`, shortened to a fiftieth of the run for
    short runs. A sample is *steady* when its rate is below both two codes per window
    (quantisation alone moves the code by one) and 5 % of the run's typical ramp rate (so an
    exponential approach to a plateau counts as steady after about three board time
    constants); a plateau is a steady stretch at least two windows long; its approach is the
    direction of the last ramp before it.
    """
    time_s = samples.time_s
    temp_code = np.asarray(samples.temp_code, dtype=float)
    duration = float(time_s[-1]) if len(time_s) else 0.0
    window = rate_window_s if rate_window_s is not None else min(RATE_WINDOW_S, max(duration / 50.0, 1e-3))
    rate = temperature_rate(time_s, temp_code, window)
    ramp = float(np.percentile(np.abs(rate), 99.0)) if len(rate) else 0.0
    dead_band = max(2.0 / window, 0.05 * ramp)
    direction = np.where(rate > dead_band, 1, np.where(rate < -dead_band, -1, 0)).astype(np.int8)
    plateaus = _plateaus(time_s, temp_code, direction, 2.0 * window)
    force = samples.reference if samples.reference is not None else np.zeros((len(time_s), 3))
    return Views(time_s=time_s, temp_code=temp_code, rate=rate, direction=direction,
                 specific_force=np.asarray(force, dtype=float), plateaus=plateaus,
                 breaks=segment_breaks(samples))


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` of the runs of True in a boolean array."""
    padded = np.concatenate(([False], mask, [False]))
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist()))


def _plateaus(time_s: np.ndarray, temp_code: np.ndarray, direction: np.ndarray,
              min_length_s: float) -> tuple[Plateau, ...]:
    plateaus = []
    for start, stop in _runs(direction == 0):
        if time_s[stop - 1] - time_s[start] < min_length_s:
            continue
        moving = np.flatnonzero(direction[:start] != 0)
        approach = int(direction[moving[-1]]) if len(moving) else 0
        plateaus.append(Plateau(start=start, stop=stop, temp_code=float(np.mean(temp_code[start:stop])),
                                approach=approach))
    return tuple(plateaus)


def binned_means(values: np.ndarray, key: np.ndarray, bins: int, *,
                 edges: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Means of ``values`` in bins of ``key``: ``(centres, means, counts)``, empty bins dropped.

    :param bins: number of equal-width bins over the range of ``key`` (ignored with ``edges``).
    """
    key = np.asarray(key, dtype=float)
    if edges is None:
        low, high = float(np.min(key)), float(np.max(key))
        if high <= low:
            high = low + 1.0
        edges = np.linspace(low, high, bins + 1)
    index = np.clip(np.searchsorted(edges, key, side='right') - 1, 0, len(edges) - 2)
    counts = np.bincount(index, minlength=len(edges) - 1)
    sums = np.bincount(index, weights=values, minlength=len(edges) - 1)
    key_sums = np.bincount(index, weights=key, minlength=len(edges) - 1)
    filled = counts > 0
    return key_sums[filled] / counts[filled], sums[filled] / counts[filled], counts[filled]


def explained_fraction(values: np.ndarray, labels: np.ndarray) -> float:
    """Correlation ratio eta^2: share of the variance of ``values`` explained by group means.

    :param labels: ``(k,)`` non-negative integer group of each value.
    """
    values = np.asarray(values, dtype=float)
    centred = values - values.mean()
    total = float(np.dot(centred, centred))
    if total <= 0.0:
        return 0.0
    counts = np.bincount(labels)
    sums = np.bincount(labels, weights=centred)
    filled = counts > 0
    between = float(np.sum(sums[filled] ** 2 / counts[filled]))
    return between / total


def _quantile_labels(key: np.ndarray, bins: int) -> np.ndarray:
    """Integer labels of ``bins`` equal-count bins of ``key`` (ties stay together)."""
    edges = np.unique(np.quantile(key, np.linspace(0.0, 1.0, bins + 1)[1:-1]))
    return np.searchsorted(edges, key, side='right')


def _level_labels(key: np.ndarray, bins: int) -> np.ndarray:
    """Labels of the distinct levels of ``key`` (turntable inputs), or quantile bins if many."""
    levels, labels = np.unique(np.round(key, 6), return_inverse=True)
    return labels if len(levels) <= 4 * bins else _quantile_labels(key, bins)


def residual_drivers(residual: np.ndarray, views: Views, *, bins: int = VIEW_BINS) -> tuple[Driver, ...]:
    """What the residual follows: eta^2 per axis for each viewed quantity, largest first.

    Quantities: ``time`` (equal-duration bins), ``time at fixed temperature`` (time bins of
    what is left after the temperature-code bin means, as a share of the whole variance),
    ``temperature code``, ``temperature rate`` (equal-count bins), ``heating vs cooling``
    (temperature-code bins split by direction, less the temperature code alone), ``own input``
    and ``other inputs`` (turntable levels).
    """
    k = len(views.time_s)
    if k < 2 * bins:
        bins = max(2, k // 4)
    time_labels = np.minimum((views.time_s / max(views.time_s[-1], 1e-9) * bins).astype(np.int64), bins - 1)
    code_labels = _quantile_labels(views.temp_code, bins)
    rate_labels = _quantile_labels(views.rate, bins)
    split_labels = code_labels * 3 + (views.direction.astype(np.int64) + 1)
    inputs = [_level_labels(views.specific_force[:, i], bins) for i in range(3)]
    rows: dict[str, list[float]] = {name: [] for name in (
        'time', 'time at fixed temperature', 'temperature code', 'temperature rate', 'heating vs cooling',
        'own input', 'other inputs')}
    code_counts = np.maximum(np.bincount(code_labels), 1)
    for i in range(residual.shape[1]):
        column = residual[:, i]
        rows['time'].append(explained_fraction(column, time_labels))
        by_code = explained_fraction(column, code_labels)
        # What time explains once the temperature code's share is removed, as a share of the
        # whole variance: large for a drift in time, near zero for a function of temperature.
        centred = column - column.mean()
        within = centred - (np.bincount(code_labels, weights=centred) / code_counts)[code_labels]
        share = float(np.dot(within, within) / max(float(np.dot(centred, centred)), 1e-300))
        rows['time at fixed temperature'].append(explained_fraction(within, time_labels) * share)
        rows['temperature code'].append(by_code)
        rows['temperature rate'].append(explained_fraction(column, rate_labels))
        rows['heating vs cooling'].append(max(explained_fraction(column, split_labels) - by_code, 0.0))
        rows['own input'].append(explained_fraction(column, inputs[i]))
        others = [inputs[j] for j in range(3) if j != i]
        rows['other inputs'].append(max(explained_fraction(column, others[0]),
                                        explained_fraction(column, others[1])))
    drivers = [Driver(name, (vals[0], vals[1], vals[2])) for name, vals in rows.items()]
    return tuple(sorted(drivers, key=lambda d: d.largest, reverse=True))


EFFECT_VIEWS: dict[str, str] = {
    'thermal_lag': 'temperature rate',
    'hysteresis': 'heating vs cooling',
    'scale_nonlinearity': 'own input',
    'cross_axis': 'other inputs',
    'warmup': 'time',
    'temperature_shape': 'temperature code',
}
"""The residual view in which each library effect shows first."""
