"""Model discovery: where the fitted model fails, and which physical effect it is missing.

Pure maths on aligned samples and a calibration; no plotting (see ``tak_thermo_ros.report``).

The steps of :func:`diagnose`:

1. **Noise floor** per axis, from the data itself: the RMS of successive differences of the
   residual divided by sqrt(2) (the Allan deviation at the shortest interval). Slow structure
   cancels in a difference, white noise does not; the code rounding (uniform, 1/12 count^2)
   is in the residual and therefore in the floor. Differences across a turntable move or a
   gap in the samples are left out, as are isolated jumps (more than 8 robust sigmas).
2. **Residual views**: the residual against time, the temperature code ``N_t``, its rate
   ``dN_t/dt``, the own input and the other axes' inputs, heating versus cooling and per
   temperature plateau; for each, the fraction of the residual variance that a binned mean
   of that quantity explains (the correlation ratio, eta^2).
3. **Blocked cross-validation** of the current model and of the current model plus each
   library effect it does not hold yet: the run is cut into contiguous time blocks, dealt
   round-robin into folds (so every fold holds early and late, hot and cold blocks); each
   model is fitted on the other folds and scored on the held-out one, with stateful effects
   run over the whole series. An effect that merely overfits scores worse, not better.
4. **Model ladder and verdict**: ``'none'`` when the held-out residual of the current model
   is at the noise floor. Otherwise the best effect joins the ladder when it removes at least
   :data:`MIN_STEP_FRACTION` of the held-out excess variance over the floor, by far more than
   noise could (:data:`SIGNIFICANCE_SIGMAS`), and the ladder climbs (current model + effect +
   next effect ...) while structure remains. The verdict is the ladder's first effect when the
   ladder removes at least :data:`MIN_TOTAL_FRACTION` of the excess and the run resolves its
   shape (a fitted time constant or width not at the edge of the range searched on this run,
   see :func:`unresolved_shapes`); ``'unexplained'`` otherwise, with what the residual still
   follows.

All residuals and RMS values are in counts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Sequence

import numpy as np

from tak_thermo_ros.core.effects import LIBRARY, Effect, resolve_effect
from tak_thermo_ros.core.effects.aux_signal import recorded_candidates
from tak_thermo_ros.core.effects.base import call_effect
from tak_thermo_ros.core.fit import fit_model, residual_counts
from tak_thermo_ros.core.model import AXES, Calibration
from tak_thermo_ros.core.record import AlignedSamples
from tak_thermo_ros.errors import FitError, TakError

VERDICT_NONE = 'none'
VERDICT_UNEXPLAINED = 'unexplained'

MIN_STEP_FRACTION = 0.5
"""An effect joins the ladder when it removes at least this share of the held-out excess
variance over the floor that the rung below leaves: less, and it leaves more structure
unexplained than it explains."""
MIN_TOTAL_FRACTION = 0.75
"""The first effect of the ladder is the verdict when the ladder as a whole removes at least
this share of the current model's held-out excess; else significant structure remains that the
library does not explain (``'unexplained'``). Single hidden effects reach 0.97-1.0 on simulated
runs, the lag on the real IMU log 0.88; a supply-voltage drift that a monotone temperature
staircase confounds with temperature lets the spline of ``temperature_shape`` reach up to 0.48."""
SIGNIFICANCE_SIGMAS = 4.0
"""How many standard errors of pure noise an excess or an improvement must exceed."""
MIN_VARIANCE_EXCESS = 0.02
"""Below this held-out variance excess (2 %, i.e. RMS 1 % above the floor) an axis counts as
at the floor however many samples there are: the floor estimate itself is not better."""
JUMP_SIGMAS = 8.0
RATE_WINDOW_S = 300.0
"""Window of the central difference that estimates ``dN_t/dt`` from the held, quantised code."""
VIEW_BINS = 40
EDGE_FRACTION = 0.01
"""A fitted shape parameter within this fraction of its search range (log scale for time
constants) of either end counts as unresolved by the run."""


# ---------------------------------------------------------------------------------- values

@dataclass(frozen=True)
class AxisSummary:
    """Residual RMS of the given calibration on this run against the noise floor, counts.

    :param rms: RMS of ``N - model`` over the whole run (the calibration as given).
    :param noise_floor: white noise plus code rounding, from successive differences.
    :param heldout_rms: held-out RMS of the same model structure refitted by cross-validation.
    :param excess_significant: whether ``heldout_rms`` lies significantly above the floor.
    """

    rms: float
    noise_floor: float
    heldout_rms: float
    excess_significant: bool


@dataclass(frozen=True)
class ModelScore:
    """Blocked cross-validation of one model.

    :param effects: effect names on top of the base model.
    :param fold_sse: ``(folds, 3)`` held-out sum of squared residuals per fold and axis.
    :param fold_samples: ``(folds,)`` held-out samples per fold.
    :param error: why the model could not be fitted (then the arrays are empty).
    :param failed_folds: folds that could not be fitted and were scored with the current model.
    """

    effects: tuple[str, ...]
    fold_sse: np.ndarray
    fold_samples: np.ndarray
    error: str | None = None
    failed_folds: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        """Whether every fold could be fitted."""
        return self.error is None

    @property
    def heldout_rms(self) -> np.ndarray:
        """``(3,)`` pooled held-out RMS per axis."""
        return np.sqrt(self.fold_sse.sum(axis=0) / self.fold_samples.sum())

    def excess(self, floor: np.ndarray) -> float:
        """Held-out variance above the floor, summed over axes in units of each axis' floor^2."""
        return float(np.sum(self.heldout_rms ** 2 / floor ** 2 - 1.0))

    @property
    def label(self) -> str:
        """``'base'`` or ``'base + a + b'``."""
        return ' + '.join(('base', *self.effects))


@dataclass(frozen=True)
class Candidate:
    """One library effect tried on top of the current model.

    :param effect: its name.
    :param rms_after: ``(3,)`` held-out RMS with the effect added, counts.
    :param explained: share of the current model's held-out excess variance it removes.
    :param significance: that improvement in standard errors of pure noise.
    :param evidence: one paragraph for a human.
    :param summary: the effect's physics, one sentence.
    :param confirm: which test run would confirm it.
    :param parameters: its fitted parameters.
    """

    effect: str
    rms_after: tuple[float, float, float]
    explained: float
    significance: float
    evidence: str
    summary: str = ''
    confirm: str = ''
    parameters: dict[str, float] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {'effect': self.effect, 'rms_after': dict(zip(AXES, self.rms_after)),
                'explained_fraction': self.explained, 'significance_sigmas': self.significance,
                'evidence': self.evidence, 'summary': self.summary, 'confirm': self.confirm,
                'parameters': dict(self.parameters)}


@dataclass(frozen=True)
class LadderStep:
    """One rung of the model ladder: a model and its held-out RMS per axis."""

    label: str
    effects: tuple[str, ...]
    heldout_rms: tuple[float, float, float]

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {'model': self.label, 'effects': list(self.effects),
                'heldout_rms': dict(zip(AXES, self.heldout_rms))}


@dataclass(frozen=True)
class Driver:
    """How much of the residual variance a binned mean of one quantity explains (eta^2)."""

    name: str
    fraction: tuple[float, float, float]

    @property
    def largest(self) -> float:
        """The largest fraction over the axes."""
        return max(self.fraction)


@dataclass(frozen=True)
class Plateau:
    """A stretch of steady temperature code.

    :param start: index of its first sample; ``stop`` one past the last.
    :param temp_code: mean temperature code.
    :param approach: ``+1`` reached by heating, ``-1`` by cooling, ``0`` at the start.
    """

    start: int
    stop: int
    temp_code: float
    approach: int


@dataclass(frozen=True)
class Views:
    """The quantities the residual is viewed against, one value per sample.

    :param time_s: ``(k,)`` seconds since the first sample.
    :param temp_code: ``(k,)`` held temperature code.
    :param rate: ``(k,)`` ``dN_t/dt`` in codes per second (central difference over a window).
    :param direction: ``(k,)`` ``+1`` heating, ``-1`` cooling, ``0`` steady.
    :param specific_force: ``(k, 3)`` the reference input, m/s^2.
    :param plateaus: the steady stretches, in time order.
    :param breaks: ``(k,)`` True where the sample starts a new segment (turntable move, gap).
    """

    time_s: np.ndarray
    temp_code: np.ndarray
    rate: np.ndarray
    direction: np.ndarray
    specific_force: np.ndarray
    plateaus: tuple[Plateau, ...]
    breaks: np.ndarray


@dataclass(frozen=True)
class Diagnosis:
    """What :func:`diagnose` found.

    :param verdict: an effect name, ``'none'`` or ``'unexplained'``.
    :param message: the verdict in two or three sentences.
    :param axes: per axis x, y, z.
    :param candidates: effects tried on the current model, best first.
    :param skipped: effect -> why it could not be tried on this run.
    :param ladder: the current model, then each effect added while it explained the rest.
    :param drivers: what the final residual follows (eta^2 per quantity), largest first.
    :param base_drivers: the same for the current model's residual.
    :param residual: ``(k, 3)`` residual of the given calibration.
    :param residual_after: ``(k, 3)`` residual after the ladder's effects, or ``None``.
    :param calibration: the calibration as given.
    :param calibration_after: the calibration refitted with the ladder's effects, or ``None``.
    :param views: the quantities the residual is viewed against.
    :param folds: cross-validation folds; ``blocks`` contiguous time blocks in all.
    :param cv_stride: every this many samples were used in the cross-validation fits.
    :param present_effects: the effects the given calibration holds already.
    :param explained: share of the current model's held-out excess that the ladder removes.
    :param unresolved: ladder effect -> its shape parameters fitted at the edge of the searched
        range (the run does not identify it; it is then not the verdict).
    """

    verdict: str
    message: str
    axes: tuple[AxisSummary, AxisSummary, AxisSummary]
    candidates: tuple[Candidate, ...]
    skipped: dict[str, str]
    ladder: tuple[LadderStep, ...]
    drivers: tuple[Driver, ...]
    base_drivers: tuple[Driver, ...]
    residual: np.ndarray
    residual_after: np.ndarray | None
    calibration: Calibration
    calibration_after: Calibration | None
    views: Views
    folds: int
    blocks: int
    cv_stride: int
    present_effects: tuple[str, ...] = ()
    explained: float = 0.0
    unresolved: dict[str, str] = field(default_factory=dict)

    @property
    def noise_floor(self) -> np.ndarray:
        """``(3,)`` the noise floor per axis, counts."""
        return np.array([axis.noise_floor for axis in self.axes])

    def as_dict(self) -> dict[str, Any]:
        """The JSON document of ``tak_calib diagnose --json``."""
        return {
            'verdict': self.verdict,
            'message': self.message,
            'axes': {name: {'rms': a.rms, 'noise_floor': a.noise_floor, 'heldout_rms': a.heldout_rms,
                            'excess_significant': a.excess_significant}
                     for name, a in zip(AXES, self.axes)},
            'candidates': [c.as_dict() for c in self.candidates],
            'skipped': dict(self.skipped),
            'unresolved': dict(self.unresolved),
            'ladder': [step.as_dict() for step in self.ladder],
            'residual_follows': [{'quantity': d.name, 'variance_fraction': dict(zip(AXES, d.fraction))}
                                 for d in self.drivers],
            'ladder_explained_fraction': self.explained,
            'model_effects': list(self.present_effects),
            'cross_validation': {'folds': self.folds, 'blocks': self.blocks, 'stride': self.cv_stride},
            'samples': int(len(self.views.time_s)),
        }


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


def noise_floor(residual: np.ndarray, breaks: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Per-axis noise floor (white noise plus code rounding) from successive differences.

    ``floor = sqrt(mean(d^2) / 2)`` with ``d = r[k+1] - r[k]`` inside segments, after leaving
    out isolated jumps beyond :data:`JUMP_SIGMAS` robust sigmas of ``d``.

    :param residual: ``(k, 3)`` residual in counts, in time order.
    :param breaks: ``(k,)`` True where a segment starts (no difference taken into it).
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
        limit = JUMP_SIGMAS * max(robust, 0.5)
        inside = np.abs(column) <= limit
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


# ------------------------------------------------------------------------- cross-validation

@dataclass(frozen=True)
class _FitSettings:
    bias_order: int
    scale_order: int
    temp_code_ref: float
    nominal_scale: tuple[float, float, float]


def _settings_of(calibration: Calibration, bias_order: int | None, scale_order: int | None) -> _FitSettings:
    if bias_order is None:
        bias_order = max(len(axis.offset_shape) for axis in calibration.axes)
    if scale_order is None:
        flat = all(tuple(axis.scale_shape) == (0.0,) for axis in calibration.axes)
        scale_order = 0 if flat else max(len(axis.scale_shape) for axis in calibration.axes)
    nominal = tuple(float(axis.scale) for axis in calibration.axes)
    return _FitSettings(bias_order=int(bias_order), scale_order=int(scale_order),
                        temp_code_ref=float(calibration.temp_code_ref),
                        nominal_scale=nominal)  # type: ignore[arg-type]


def decimate(samples: AlignedSamples, stride: int) -> AlignedSamples:
    """Every ``stride``-th sample, in time order (white noise stays white)."""
    if stride <= 1:
        return samples
    return AlignedSamples(stamp_ns=samples.stamp_ns[::stride], counts=samples.counts[::stride],
                          temp_code=samples.temp_code[::stride],
                          reference=None if samples.reference is None else samples.reference[::stride],
                          dropped=dict(samples.dropped),
                          aux={name: values[::stride] for name, values in samples.aux.items()})


def fold_labels(time_s: np.ndarray, folds: int, blocks: int) -> np.ndarray:
    """Fold of each sample: ``blocks`` contiguous equal-duration blocks dealt round-robin."""
    duration = max(float(time_s[-1] - time_s[0]), 1e-9)
    block = np.minimum(((time_s - time_s[0]) / duration * blocks).astype(np.int64), blocks - 1)
    return block % folds


def _effect_specs(calibration: Calibration) -> tuple[Any, ...]:
    """The effects the calibration already holds, as ``fit_model`` takes them (their classes)."""
    return tuple(type(effect) for effect in getattr(calibration, 'effects', ()) or ())


def _effect_name(spec: Any) -> str:
    if isinstance(spec, str):
        return spec
    return str(getattr(spec, 'name', getattr(spec, '__name__', repr(spec))))


def _effect_parameters(calibration: Calibration) -> dict[str, float]:
    """Fitted parameter values of the calibration's effects, ``effect.parameter`` -> value."""
    values: dict[str, float] = {}
    for effect in getattr(calibration, 'effects', ()) or ():
        for key, value in effect.values.items():
            values[f'{effect.name}.{key}'] = float(value)
    return values


def _with_range(calibration: Calibration, low: float, high: float) -> Calibration:
    """The same link with its calibrated range widened to ``low..high``, so held-out samples
    are evaluated by the fitted functions, not clamped at the training range's edge."""
    return replace(calibration, temp_code_min=min(low, calibration.temp_code_min),
                   temp_code_max=max(high, calibration.temp_code_max))


def cross_validate(samples: AlignedSamples, effects: Sequence[Any], labels: np.ndarray,
                   settings: _FitSettings, *, folds: int, fallback: ModelScore | None = None) -> ModelScore:
    """Blocked cross-validation of base + ``effects``: fit without one fold, score on it.

    Stateful effects run over the whole series; the least squares sees only the training
    folds (``fit_model(..., train_mask=...)``).

    :param fallback: the current model's score. A fold on which the extended model cannot be
        fitted is scored with the current model instead (the effect gains nothing there), as
        long as at most half of the folds fail; otherwise the model counts as not fittable.
    """
    names = tuple(_effect_name(spec) for spec in effects)
    low, high = float(samples.temp_code.min()), float(samples.temp_code.max())
    fold_sse = np.zeros((folds, 3))
    fold_samples = np.zeros(folds)
    failures: list[str] = []
    for fold in range(folds):
        held_out = labels == fold
        fold_samples[fold] = np.count_nonzero(held_out)
        try:
            result = fit_model(samples, effects=tuple(effects), bias_order=settings.bias_order,
                               scale_order=settings.scale_order, temp_code_ref=settings.temp_code_ref,
                               nominal_scale=settings.nominal_scale, train_mask=~held_out)
            residual = residual_counts(_with_range(result.calibration, low, high), samples)
            part = residual[held_out]
            if not np.all(np.isfinite(part)):
                msg = 'the fitted model gives non-finite residuals on held-out data'
                raise FitError(msg)
            fold_sse[fold] = np.sum(part ** 2, axis=0)
        except TakError as err:
            failures.append(f'fold {fold + 1}: {err}')
            if fallback is None or not fallback.ok or 2 * len(failures) > folds:
                return ModelScore(effects=names, fold_sse=np.zeros((0, 3)), fold_samples=np.zeros(0),
                                  error='; '.join(failures))
            fold_sse[fold] = fallback.fold_sse[fold]
    return ModelScore(effects=names, fold_sse=fold_sse, fold_samples=fold_samples,
                      failed_folds=tuple(failures))


def unresolved_shapes(effect: Effect, samples: AlignedSamples) -> tuple[str, ...]:
    """Shape parameters that the fit drove to the edge of the range it searches on this run.

    A time constant at twice the run's length, or a play as wide as half the code range, means
    the data prefer a shape the run cannot resolve (a lag longer than the run is an integral of
    the temperature, not a lag): the effect is then not identified by this run.

    :returns: ``'tau_s 2.07e+04 (edge of 3..2.07e+04)'`` texts, empty when all are inside.
    """
    space = call_effect(effect, 'search_space', type(effect).search_space, samples.stamp_s, samples.temp_code)
    varies = effect.shape_varies()
    found = []
    for name in effect.shape_names():
        if not varies.get(name, True) or name not in space:
            continue
        low, high, logarithmic = space[name]
        value = effect[name]
        if not (math.isfinite(low) and math.isfinite(high)) or high <= low:
            continue
        if logarithmic and low > 0.0 and value > 0.0:
            position = math.log(value / low) / math.log(high / low)
        else:
            position = (value - low) / (high - low)
        if position <= EDGE_FRACTION or position >= 1.0 - EDGE_FRACTION:
            found.append(f'{name} {value:.3g} (edge of the searched {low:.3g}..{high:.3g})')
    return tuple(found)


# ---------------------------------------------------------------------------------- verdict

def _noise_sigma(floor_differences: int, heldout_samples: float) -> float:
    """Standard error of ``heldout_mse / floor^2`` for one axis of pure white noise."""
    return math.sqrt(2.0 / max(heldout_samples, 1.0) + 3.0 / max(floor_differences, 1))


def _describe_rms(before: np.ndarray, after: np.ndarray) -> str:
    return ', '.join(f'{name} {b:.2f}->{a:.2f}' for name, b, a in zip(AXES, before, after))


def _percent(value: float) -> str:
    return f'{round(100.0 * value) + 0:.0f}%'


def _driver_sentence(drivers: Sequence[Driver], *, exclude: Sequence[str] = ()) -> str:
    """``'time (62% on y), temperature code (8% on x)'`` for the leading quantities."""
    parts = []
    for driver in drivers:
        if driver.name in exclude:
            continue
        axis = int(np.argmax(driver.fraction))
        parts.append(f'{driver.name} ({_percent(driver.fraction[axis])} of the variance on {AXES[axis]})')
        if len(parts) == 3:
            break
    return ', '.join(parts)


def _unexplained_sentence(drivers: Sequence[Driver]) -> str:
    """What a residual that no library effect explains still follows, and what that suggests.

    Called only when no library effect explains the structure: the temperature effects (a
    spline in ``N_t``, a lag, hysteresis, warm-up) have then failed on held-out blocks, which is
    the evidence that a residual sorted by time is not a function of temperature or its history.
    """
    by_name = {d.name: d for d in drivers}
    lead = drivers[0]
    text = f'the residual still follows {_driver_sentence(drivers)}'
    if lead.name in ('time', 'time at fixed temperature'):
        text += ('; it is a slow drift in time that no function of the temperature code or of its history in '
                 'the library predicts on held-out time blocks: look for a quantity that is not in the bag '
                 '(supply voltage, humidity, mechanical stress, a reference that moves)')
        code = by_name['temperature code'].largest
        if code > 0.2:
            text += (f'. The temperature code sorts {_percent(code)} of it as well, because temperature and time '
                     f'move together over parts of the run; yet no function of temperature predicts it on '
                     f'held-out blocks. A run that holds one temperature for hours would show the drift alone')
    elif lead.name in ('temperature rate', 'heating vs cooling'):
        text += ('; it follows the temperature history, but neither the library lag nor its hysteresis '
                 'models it: consider a user-defined effect (docs/effects.md)')
    elif lead.name == 'temperature code':
        text += ('; it follows the temperature code in a way neither the power series nor the spline of '
                 'temperature_shape predicts on held-out blocks: try higher orders (--bias-order, --scale-order)')
    elif lead.name in ('own input', 'other inputs'):
        text += '; it depends on the input: check the reference stream and the turntable positions'
    return text


def _rung(model: ModelScore) -> LadderStep:
    rms = model.heldout_rms
    return LadderStep(label=model.label, effects=model.effects,
                      heldout_rms=(float(rms[0]), float(rms[1]), float(rms[2])))


@dataclass(frozen=True)
class _Step:
    """Candidates scored against one rung of the ladder."""

    current: ModelScore
    ranked: tuple[tuple[Candidate, ModelScore], ...]
    skipped: dict[str, str]


def diagnose(calibration: Calibration, samples: AlignedSamples, *,
             candidates: Sequence[Any] | None = None, folds: int = 5, blocks_per_fold: int = 4,
             max_cv_samples: int = 40_000, max_ladder: int = 3,
             bias_order: int | None = None, scale_order: int | None = None,
             rate_window_s: float | None = None,
             progress: Callable[[str], None] | None = None) -> Diagnosis:
    """Compare the calibration with a run, find where it fails and which effect it misses.

    :param calibration: the model to diagnose (base model, possibly with effects).
    :param samples: an aligned run with its reference stream, in time order.
    :param candidates: effects to try: library names, ``'module:Class'`` specs or classes;
        default every library effect and every recorded signal of the run
        (:func:`~tak_thermo_ros.core.effects.aux_signal.recorded_candidates`). Effects the
        calibration holds already are not tried.
    :param folds: cross-validation folds.
    :param blocks_per_fold: contiguous time blocks per fold (dealt round-robin).
    :param max_cv_samples: the cross-validation fits use every m-th sample so that at most
        this many remain (the noise floor and the views use all samples).
    :param max_ladder: at most this many effects are added one after the other.
    :param bias_order: ``q`` of the refits; default that of ``calibration``.
    :param scale_order: ``p`` of the refits; default that of ``calibration``.
    :param rate_window_s: window of ``dN_t/dt`` (see :func:`build_views`).
    :param progress: called with a short text before each model is cross-validated.
    :raises FitError: when the run has no reference or too few samples.
    """
    if samples.reference is None:
        msg = 'diagnose needs the reference stream (the true specific force) in the run'
        raise FitError(msg)
    if folds < 2 or blocks_per_fold < 1:
        msg = f'cross-validation needs at least 2 folds and 1 block per fold, got {folds} and {blocks_per_fold}'
        raise FitError(msg)
    say = progress or (lambda text: None)
    settings = _settings_of(calibration, bias_order, scale_order)
    present = _effect_specs(calibration)
    present_names = tuple(_effect_name(spec) for spec in present)

    residual = residual_counts(calibration, samples)
    views = build_views(samples, rate_window_s=rate_window_s)
    floor, differences = noise_floor(residual, views.breaks)
    floor = np.maximum(floor, 1e-12)

    stride = max(1, math.ceil(len(samples) / max_cv_samples))
    cv_samples = decimate(samples, stride)
    blocks = folds * blocks_per_fold
    labels = fold_labels(cv_samples.time_s, folds, blocks)
    if np.bincount(labels, minlength=folds).min() < 10:
        msg = f'too few samples ({len(cv_samples)}) for {folds}-fold cross-validation in {blocks} blocks'
        raise FitError(msg)

    # By default every library effect and every recorded auxiliary signal (aux:TOPIC) in the run.
    specs = list(candidates) if candidates is not None else [*LIBRARY, *recorded_candidates(samples.aux)]
    pool = [resolve_effect(type(spec) if isinstance(spec, Effect) else spec) for spec in specs]
    pool = [cls for cls in pool if cls.name not in present_names]

    def score(effects: tuple[Any, ...], fallback: ModelScore | None = None) -> ModelScore:
        say(' + '.join(('base', *(_effect_name(e) for e in effects))))
        return cross_validate(cv_samples, effects, labels, settings, folds=folds, fallback=fallback)

    def sigma_of(model: ModelScore) -> np.ndarray:
        held = float(model.fold_samples.sum())
        return np.array([_noise_sigma(differences, held) for _ in range(3)])

    def significant_axes(model: ModelScore) -> np.ndarray:
        ratio = model.heldout_rms ** 2 / floor ** 2 - 1.0
        threshold = np.maximum(SIGNIFICANCE_SIGMAS * sigma_of(model), MIN_VARIANCE_EXCESS)
        return ratio > threshold

    base_drivers = residual_drivers(residual, views)

    def rank(current: ModelScore, effects_so_far: tuple[Any, ...]) -> _Step:
        scored: list[tuple[Candidate, ModelScore]] = []
        skipped: dict[str, str] = {}
        excess_now = current.excess(floor)
        sigma_total = float(np.sqrt(np.sum(sigma_of(current) ** 2)))
        for spec in pool:
            name = _effect_name(spec)
            if name in (_effect_name(e) for e in effects_so_far):
                continue
            model = score((*effects_so_far, spec), current)
            if not model.ok:
                skipped[name] = model.error or 'fit failed'
                continue
            gain = excess_now - model.excess(floor)
            explained = gain / excess_now if excess_now > 0.0 else 0.0
            significance = gain / sigma_total if sigma_total > 0.0 else 0.0
            summary = str(spec.summary or '')
            confirm = str(spec.confirm or '')
            view = EFFECT_VIEWS.get(name)
            view_text = ''
            if view is not None:
                driver = next(d for d in base_drivers if d.name == view)
                axis = int(np.argmax(driver.fraction))
                view_text = (f' In the current residual, {view} explains {_percent(driver.fraction[axis])} '
                             f'of the variance on {AXES[axis]}.')
            evidence = (f'held-out RMS {_describe_rms(current.heldout_rms, model.heldout_rms)} counts '
                        f'(floor {", ".join(f"{v:.2f}" for v in floor)}); removes {_percent(explained)} of '
                        f'the held-out excess variance over the floor, {significance:.1f} noise sigmas.'
                        f'{view_text}')
            if model.failed_folds:
                evidence += (f' Not fittable on {len(model.failed_folds)} of {folds} folds (scored there with '
                             f'the current model): {model.failed_folds[0]}')
            rms_after = (float(model.heldout_rms[0]), float(model.heldout_rms[1]), float(model.heldout_rms[2]))
            scored.append((Candidate(effect=name, rms_after=rms_after, explained=float(explained),
                                     significance=float(significance), evidence=evidence, summary=summary,
                                     confirm=confirm), model))
        scored.sort(key=lambda pair: pair[1].excess(floor))
        return _Step(current=current, ranked=tuple(scored), skipped=skipped)

    base_score = score(present)
    if not base_score.ok:
        msg = f'the model cannot be refitted on this run: {base_score.error}'
        raise FitError(msg)
    base_significant = significant_axes(base_score)
    axes = tuple(AxisSummary(rms=float(math.sqrt(np.mean(residual[:, i] ** 2))), noise_floor=float(floor[i]),
                             heldout_rms=float(base_score.heldout_rms[i]),
                             excess_significant=bool(base_significant[i])) for i in range(3))

    ladder = [_rung(base_score)]
    first_step: _Step | None = None
    skipped: dict[str, str] = {}
    added: tuple[Any, ...] = ()
    current = base_score
    verdict = VERDICT_NONE
    if base_significant.any():
        verdict = VERDICT_UNEXPLAINED
        effects_so_far = present
        while len(added) < max_ladder and significant_axes(current).any():
            step = rank(current, effects_so_far)
            if first_step is None:
                first_step = step
                skipped = dict(step.skipped)
            if not step.ranked:
                break
            best, best_score = step.ranked[0]
            if best.explained < MIN_STEP_FRACTION or best.significance < SIGNIFICANCE_SIGMAS:
                break
            spec = next(s for s in pool if _effect_name(s) == best.effect)
            added = (*added, spec)
            effects_so_far = (*effects_so_far, spec)
            current = best_score
            ladder.append(_rung(best_score))

    base_excess = base_score.excess(floor)
    explained_total = (base_excess - current.excess(floor)) / base_excess if base_excess > 0.0 else 0.0
    if added and explained_total >= MIN_TOTAL_FRACTION:
        verdict = _effect_name(added[0])

    calibration_after = None
    residual_after = None
    parameters: dict[str, float] = {}
    unresolved: dict[str, str] = {}
    if added:
        say('refit with ' + ', '.join(_effect_name(e) for e in added))
        try:
            result = fit_model(cv_samples, effects=(*present, *added), bias_order=settings.bias_order,
                               scale_order=settings.scale_order, temp_code_ref=settings.temp_code_ref,
                               nominal_scale=settings.nominal_scale)
        except TakError as err:
            skipped['refit'] = f'the ladder\'s model could not be refitted on all samples: {err}'
        else:
            low, high = float(samples.temp_code.min()), float(samples.temp_code.max())
            calibration_after = _with_range(result.calibration, low, high)
            residual_after = residual_counts(calibration_after, samples)
            parameters = _effect_parameters(calibration_after)
            for effect in calibration_after.effects:
                if effect.name in (_effect_name(e) for e in added):
                    edges = unresolved_shapes(effect, cv_samples)
                    if edges:
                        unresolved[effect.name] = ', '.join(edges)
    if added and _effect_name(added[0]) in unresolved:
        verdict = VERDICT_UNEXPLAINED
    final_residual = residual if residual_after is None else residual_after
    drivers = residual_drivers(final_residual, views) if residual_after is not None else base_drivers

    ranked = list(first_step.ranked) if first_step is not None else []
    candidates_out = []
    for candidate, _ in ranked:
        if candidate.effect == verdict and parameters:
            own = {key.split('.', 1)[1]: value for key, value in parameters.items()
                   if key.split('.', 1)[0] == candidate.effect}
            text = ', '.join(f'{key} {value:.4g}' for key, value in own.items())
            candidate = replace(candidate, parameters=own,
                                evidence=candidate.evidence + (f' Fitted: {text}.' if text else ''))
        candidates_out.append(candidate)

    message = _verdict_message(verdict, axes, ladder, candidates_out, drivers, base_drivers,
                               significant_axes(current), explained_total, unresolved)
    return Diagnosis(verdict=verdict, message=message, axes=axes,  # type: ignore[arg-type]
                     candidates=tuple(candidates_out), skipped=skipped, ladder=tuple(ladder), drivers=drivers,
                     base_drivers=base_drivers,
                     residual=residual, residual_after=residual_after, calibration=calibration,
                     calibration_after=calibration_after, views=views, folds=folds, blocks=blocks,
                     cv_stride=stride, present_effects=present_names, explained=float(explained_total),
                     unresolved=unresolved)


def _verdict_message(verdict: str, axes: Sequence[AxisSummary], ladder: Sequence[LadderStep],
                     candidates: Sequence[Candidate], drivers: Sequence[Driver],
                     base_drivers: Sequence[Driver], still_significant: np.ndarray,
                     explained_total: float, unresolved: dict[str, str]) -> str:
    ratios = ', '.join(f'{name} {a.heldout_rms / a.noise_floor:.2f}x' for name, a in zip(AXES, axes))
    if verdict == VERDICT_NONE:
        text = (f'The residual is at the noise floor (held-out RMS / floor: {ratios}): '
                f'no structure left for an effect to explain.')
        refit = [name for name, a in zip(AXES, axes) if a.rms > 1.1 * a.heldout_rms]
        if refit:
            text += (f' The calibration as given fits this run worse than a refit of the same model '
                     f'(axes {", ".join(refit)}): refit it on this run.')
        return text
    if verdict == VERDICT_UNEXPLAINED:
        first = ladder[1].effects[-1] if len(ladder) > 1 else ''
        if first in unresolved:
            best = (f' {ladder[-1].label} removes {_percent(explained_total)} of the held-out excess, but the '
                    f'fit of {first} runs to the edge of what this run resolves ({unresolved[first]}): the run '
                    f'does not identify it, so it is not named (a longer run, or longer plateaus, would tell).')
            follows = f'the residual follows {_driver_sentence(base_drivers)}'
        elif len(ladder) > 1:
            best = (f' {ladder[-1].label} removes {_percent(explained_total)} of the held-out excess, '
                    f'too little to name it the cause.')
            follows = _unexplained_sentence(drivers)
        else:
            if candidates and candidates[0].explained > 0.0:
                best = (f' The best library effect, {candidates[0].effect}, removes only '
                        f'{_percent(candidates[0].explained)} of the held-out excess.')
            else:
                best = ' No library effect lowers the held-out error.'
            follows = _unexplained_sentence(base_drivers)
        return (f'Significant structure remains above the noise floor (held-out RMS / floor: {ratios}) '
                f'that no library effect explains with parameters this run resolves.{best} '
                f'{follows[0].upper()}{follows[1:]}.')
    best = candidates[0]
    text = (f'The model misses {verdict}: it removes {_percent(best.explained)} of the held-out excess '
            f'over the noise floor (held-out RMS / floor before: {ratios}). {best.summary}')
    if len(ladder) > 2:
        text += (' Then: ' + ', '.join(step.effects[-1] for step in ladder[2:])
                 + f' ({_percent(explained_total)} of the excess in all).')
    for name, edges in unresolved.items():
        text += f' The fit of {name} runs to the edge of what this run resolves ({edges}).'
    if still_significant.any():
        text += (f' Structure remains on {", ".join(n for n, s in zip(AXES, still_significant) if s)}: '
                 f'{_unexplained_sentence(drivers)}.')
    return text
