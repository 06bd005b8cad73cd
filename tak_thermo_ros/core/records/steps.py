"""Sudden level changes (steps) in a residual, told from slow drift and from the residual's own wander.

A step is a change of level between two samples that then holds. The scan compares, at every
moment and on several time scales ``w`` (:data:`STEP_SCALES` samples on each side), the line
fitted to the ``w`` samples before with the line fitted to the ``w`` samples after, both
extrapolated to the moment: their difference ``D_w`` is the level change there. A slope or a
kink (a temperature reversal under a lag) leaves ``D_w`` near zero; a step of size ``A`` gives
``D_w = A`` at every scale that fits between two events.

What a step must beat is the residual's own ``D_w`` at ordinary moments: the robust spread
(1.4826 MAD) of ``D_w`` over the whole record, per channel and scale. That spread holds the
white noise, the bias wander (random walk, flicker) and whatever slow structure the residual
has, with their correlation: a random walk moves the means on each side of every moment as much
as it moves them at any one, so its ``D_w`` is ordinary everywhere. A step stands out of that
spread by :data:`STEP_SIGMAS`; it must also be sudden: its size at half the scale is at least
half its size at the scale (a curve, a warm-up, makes ``D_w`` grow as ``w^2``). Isolated
outliers (one sample far from the samples on both sides) are set to their neighbours' median
first: a spike is not a level.

On simulated coloured noise (white, bias instability, random walk; ``test/core/records/test_steps.py`` and
``bench/bench_steps.py``) the scan names no step in more than 99 % of runs.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

STEP_SCALES = (8, 16, 32, 64, 128)
"""Samples on each side of a moment: the time scales of the scan."""
STEP_SIGMAS = 8.0
"""A level change is a step when it stands this many robust spreads of the record's own ``D_w`` out."""
NAME_SIGMAS = 4.0
"""At a step found on some channel, another channel (or sensor) is named when its change there stands
this many spreads out: a test at one known moment, not a search over the record."""
SUDDEN_FRACTION = 0.5
"""A step's size at half the scale is at least this share of its size at the scale (a curve's is a quarter)."""
SPIKE_SIGMAS = 8.0
"""A sample further than this many robust sigmas of the successive differences from the samples on
both sides is a spike (an outlier), replaced by their median for the scan."""
MAX_STEPS = 3
"""At most this many steps are named, largest first."""


@dataclass(frozen=True)
class LevelChange:
    """One step in a residual ``(k, c)``.

    :param index: the first sample after the change.
    :param scale: samples on each side of the scale that found it.
    :param amplitude: ``(c,)`` the change per channel (after minus before), the residual's unit.
    :param sigma: ``(c,)`` the record's own spread of such a change at that scale.
    """

    index: int
    scale: int
    amplitude: np.ndarray
    sigma: np.ndarray

    @property
    def z(self) -> np.ndarray:
        """``(c,)`` the change in units of the record's own spread."""
        return self.amplitude / np.where(self.sigma > 0.0, self.sigma, np.inf)

    @property
    def named(self) -> tuple[int, ...]:
        """The channels that change at the step (:data:`NAME_SIGMAS`)."""
        return tuple(int(c) for c in np.flatnonzero(np.abs(self.z) >= NAME_SIGMAS))


def despiked(residual: np.ndarray) -> np.ndarray:
    """``residual`` with isolated outliers set to the median of the two samples on each side."""
    values = np.array(residual, dtype=float, copy=True)
    if len(values) < 5:
        return values
    differences = np.diff(values, axis=0)
    sigma = 1.4826 * np.median(np.abs(differences - np.median(differences, axis=0)), axis=0) / np.sqrt(2.0)
    sigma = np.where(sigma > 0.0, sigma, np.inf)
    edge = np.full((2, values.shape[1]), np.nan)
    padded = np.concatenate([edge, values, edge])
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', RuntimeWarning)
        before = np.nanmean(np.stack([padded[:-4], padded[1:-3]]), axis=0)
        after = np.nanmean(np.stack([padded[3:-1], padded[4:]]), axis=0)
        neighbours = np.nanmedian(np.stack([padded[:-4], padded[1:-3], padded[3:-1], padded[4:]]), axis=0)
    # The first and last samples have one side only: judged on it.
    before[:2] = np.where(np.isnan(before[:2]), after[:2], before[:2])
    after[-2:] = np.where(np.isnan(after[-2:]), before[-2:], after[-2:])
    far = (np.abs(values - before) > SPIKE_SIGMAS * sigma) & (np.abs(values - after) > SPIKE_SIGMAS * sigma)
    values[far] = neighbours[far]
    return values


def _line_ends(values: np.ndarray, scale: int) -> tuple[np.ndarray, np.ndarray]:
    """Moments ``p`` (between samples ``p-1`` and ``p``) and ``D_w(p)`` ``(m, c)``.

    ``D_w(p)``: the line through the ``w`` samples after ``p`` minus the line through the ``w`` before, both at ``p``.
    """
    count = len(values)
    positions = np.arange(scale, count - scale + 1)
    index = np.arange(count, dtype=float)
    total = np.concatenate([np.zeros((1, values.shape[1])), np.cumsum(values, axis=0)])
    moment = np.concatenate([np.zeros((1, values.shape[1])), np.cumsum(values * index[:, None], axis=0)])

    def line_at(low: np.ndarray, at: np.ndarray) -> np.ndarray:
        # The least-squares line through samples low .. low + scale - 1, evaluated at ``at``.
        high = low + scale
        mean_x = (low + high - 1) / 2.0
        sum_y = total[high] - total[low]
        sum_xy = moment[high] - moment[low]
        sxx = scale * (scale * scale - 1) / 12.0
        slope = (sum_xy - mean_x[:, None] * sum_y) / sxx
        return sum_y / scale + slope * (at - mean_x)[:, None]

    at = positions - 0.5
    return positions, line_at(positions, at) - line_at(positions - scale, at)


@dataclass(frozen=True)
class _Scale:
    scale: int
    positions: np.ndarray
    change: np.ndarray  # (m, c)
    sigma: np.ndarray   # (c,)

    def at(self, position: int) -> np.ndarray | None:
        row = position - self.scale
        if 0 <= row < len(self.positions) and self.positions[row] == position:
            return self.change[row]
        return None


def _scales(residual: np.ndarray, breaks: np.ndarray | None) -> list[_Scale]:
    values = despiked(residual)
    segment = np.cumsum(breaks) if breaks is not None and len(breaks) == len(values) else np.zeros(len(values))
    found = []
    for scale in STEP_SCALES:
        if len(values) < 4 * scale:
            break
        positions, change = _line_ends(values, scale)
        # Neither window may straddle a turntable move or a gap, unless the segments are shorter
        # than the windows (a turntable's short dwells): then the moves' own level changes are part of
        # the record's spread that a step must beat.
        same = segment[positions - scale] == segment[positions + scale - 1]
        if same.mean() >= 0.5:
            positions, change = positions[same], change[same]
        if len(positions) < 4 * scale:
            continue
        sigma = 1.4826 * np.median(np.abs(change - np.median(change, axis=0)), axis=0)
        found.append(_Scale(scale, positions, change, sigma))
    return found


def find_steps(residual: np.ndarray, *, breaks: np.ndarray | None = None, threshold: float = STEP_SIGMAS,
               max_steps: int = MAX_STEPS) -> tuple[LevelChange, ...]:
    """The steps of a residual ``(k, c)``, largest first (at most ``max_steps``).

    :param breaks: ``(k,)`` True where a sample starts a new segment (a turntable move, a gap):
        no window straddles one.
    :param threshold: how many of the record's own spreads a change must stand out by.
    """
    residual = np.asarray(residual, dtype=float)
    if residual.ndim == 1:
        residual = residual[:, None]
    scales = _scales(residual, breaks)
    candidates: list[tuple[float, int, _Scale]] = []
    for level in scales:
        z = np.abs(level.change) / np.where(level.sigma > 0.0, level.sigma, np.inf)
        strongest = z.max(axis=1)
        order = np.argsort(-strongest)
        taken: list[int] = []
        for row in order:
            if strongest[row] < threshold:
                break
            position = int(level.positions[row])
            if any(abs(position - other) < 2 * level.scale for other in taken):
                continue
            taken.append(position)
            candidates.append((float(strongest[row]), position, level))
            if len(taken) >= 4 * max_steps:
                break
    steps: list[LevelChange] = []
    for strength, position, level in sorted(candidates, key=lambda item: -item[0]):
        if any(abs(position - step.index) < 2 * max(level.scale, step.scale) for step in steps):
            continue
        step = _sudden(position, level, scales)
        if step is not None:
            steps.append(step)
        if len(steps) >= max_steps:
            break
    return tuple(steps)


def _sudden(position: int, level: _Scale, scales: list[_Scale]) -> LevelChange | None:
    """The change at ``position`` when it is sudden: its moment refined on the finer scales, its size."""
    change = level.at(position)
    channel = int(np.argmax(np.abs(change) / np.where(level.sigma > 0.0, level.sigma, np.inf)))
    finer = [other for other in scales if other.scale < level.scale]
    if finer:
        half = finer[-1]
        # Refined: the moment within the finer scale's reach where its change is largest on that channel.
        rows = [position + shift for shift in range(-half.scale, half.scale + 1)
                if half.at(position + shift) is not None]
        if rows:
            sign = float(np.sign(change[channel]))
            best = max(rows, key=lambda p: sign * float(half.at(p)[channel]))
            small = half.at(best)
            if small[channel] * change[channel] <= 0.0 or abs(small[channel]) < SUDDEN_FRACTION * abs(change[channel]):
                return None
            if level.at(best) is not None:
                position = best
    return LevelChange(index=position, scale=level.scale, amplitude=np.array(level.at(position)),
                       sigma=np.array(level.sigma))


def step_scales(residual: np.ndarray, *, breaks: np.ndarray | None = None) -> list[_Scale]:
    """The level changes of ``residual`` ``(k, c)`` on every scale, for :func:`change_at` at several moments."""
    residual = np.asarray(residual, dtype=float)
    return _scales(residual[:, None] if residual.ndim == 1 else residual, breaks)


def change_at(residual: np.ndarray, index: int, *, breaks: np.ndarray | None = None,
              scale: int | None = None, scales: list[_Scale] | None = None) -> LevelChange | None:
    """The level change of ``residual`` ``(k, c)`` at sample ``index`` (another sensor at a step's moment).

    :param scale: the scale to measure it on (default: the largest that fits); ``None`` when none fits there.
    :param scales: :func:`step_scales` of ``residual`` (computed here when not given).
    """
    if scales is None:
        scales = step_scales(residual, breaks=breaks)
    fitting = [level for level in scales if level.at(index) is not None
               and (scale is None or level.scale <= scale)]
    if not fitting:
        return None
    level = fitting[-1]
    return LevelChange(index=index, scale=level.scale, amplitude=np.array(level.at(index)), sigma=np.array(level.sigma))
