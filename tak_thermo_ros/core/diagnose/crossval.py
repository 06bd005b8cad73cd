"""Blocked cross-validation: folds of contiguous time blocks, a model's held-out scores, its null on a copy."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Callable, Sequence

import numpy as np

from tak_thermo_ros.core.diagnose.values import ModelScore
from tak_thermo_ros.core.effects import Effect
from tak_thermo_ros.core.effects.base import call_effect
from tak_thermo_ros.core.fit import FitResult, fit_model, residual_counts
from tak_thermo_ros.core.link.correction import Corrector
from tak_thermo_ros.core.link.model import Calibration
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.errors import FitError, TakError

EDGE_FRACTION = 0.01
"""A fitted shape parameter within this fraction of its search range (log scale for time
constants) of either end counts as unresolved by the run."""


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


def fit_with(samples: AlignedSamples, effects: Sequence[Any], settings: _FitSettings, *,
             train_mask: np.ndarray | None = None, errors: bool = False) -> FitResult:
    """``fit_model`` with ``effects`` and ``settings``, on the ``train_mask`` samples (default: all).

    :param errors: compute the standard errors (the refits that only predict do without).
    """
    return fit_model(samples, effects=tuple(effects), bias_order=settings.bias_order,
                     scale_order=settings.scale_order, temp_code_ref=settings.temp_code_ref,
                     nominal_scale=settings.nominal_scale, train_mask=train_mask, errors=errors)


def decimate(samples: AlignedSamples, stride: int) -> AlignedSamples:
    """Every ``stride``-th sample, in time order (white noise stays white)."""
    if stride <= 1:
        return samples
    return AlignedSamples(stamp_ns=samples.stamp_ns[::stride], counts=samples.counts[::stride],
                          temp_code=samples.temp_code[::stride],
                          reference=None if samples.reference is None else samples.reference[::stride],
                          dropped=dict(samples.dropped),
                          aux={name: values[::stride] for name, values in samples.aux.items()})


def fold_labels(time_s: np.ndarray, folds: int, blocks: int, *, split_start: bool = True) -> np.ndarray:
    """Fold of each sample: ``blocks`` contiguous equal-duration blocks dealt round-robin.

    :param split_start: cut the first block into ``folds`` equal pieces, one per fold. What
        happens only at the start of a run (a warm-up decaying within minutes of power-on) then
        lies in every fold's training data, and a held-out piece of it is interpolated from its
        neighbours instead of extrapolated from the tail of the run.
    """
    duration = max(float(time_s[-1] - time_s[0]), 1e-9)
    position = (time_s - time_s[0]) / duration * blocks
    block = np.minimum(position.astype(np.int64), blocks - 1)
    labels = block % folds
    if split_start and blocks > 1:
        first = block == 0
        labels[first] = np.minimum((position[first] * folds).astype(np.int64), folds - 1)
    return labels


def block_index(labels: np.ndarray) -> np.ndarray:
    """Contiguous block of each sample (0, 1, ...): a block ends where the fold label changes."""
    if not len(labels):
        return np.zeros(0, dtype=np.int64)
    return np.concatenate(([0], np.cumsum(labels[1:] != labels[:-1]))).astype(np.int64)


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
    """The same link with its calibrated range widened to ``low..high``.

    So held-out samples are evaluated by the fitted functions, not clamped at the training range's edge.
    """
    return replace(calibration, temp_code_min=min(low, calibration.temp_code_min),
                   temp_code_max=max(high, calibration.temp_code_max))


def cross_validate(samples: AlignedSamples, effects: Sequence[Any], labels: np.ndarray,
                   settings: _FitSettings, *, folds: int, fallback: ModelScore | None = None,
                   whiten: Callable[[np.ndarray], np.ndarray] | None = None) -> ModelScore:
    """Blocked cross-validation of base + ``effects``: fit without one fold, score on it.

    Stateful effects run over the whole series; the least squares sees only the training
    folds (``fit_model(..., train_mask=...)``).

    :param fallback: the current model's score. A fold on which the extended model cannot be
        fitted is scored with the current model instead (the effect gains nothing there), as
        long as at most half of the folds fail; otherwise the model counts as not fittable.
    :param whiten: applied to the assembled ``(k, 3)`` held-out residual before it is scored (the
        noise model's whitening filter, :func:`~tak_thermo_ros.core.diagnose.yardstick.whitener`);
        the held-out residual is then kept in the score (``heldout``).
    """
    names = tuple(_effect_name(spec) for spec in effects)
    low, high = float(samples.temp_code.min()), float(samples.temp_code.max())
    fold_sse = np.zeros((folds, 3))
    fold_samples = np.zeros(folds)
    block = block_index(labels)
    blocks = int(block[-1]) + 1 if len(block) else 0
    block_sse = np.zeros((blocks, 3))
    block_samples = np.bincount(block, minlength=blocks).astype(float)
    failures: list[str] = []
    heldout = np.zeros((len(labels), 3)) if whiten is not None else None
    for fold in range(folds):
        held_out = labels == fold
        fold_samples[fold] = np.count_nonzero(held_out)
        try:
            result = fit_with(samples, effects, settings, train_mask=~held_out)
            residual = residual_counts(_with_range(result.calibration, low, high), samples)
            part = residual[held_out]
            if not np.all(np.isfinite(part)):
                msg = 'the fitted model gives non-finite residuals on held-out data'
                raise FitError(msg)
            fold_sse[fold] = np.sum(part ** 2, axis=0)
            if heldout is not None:
                heldout[held_out] = part
            for index in np.unique(block[held_out]):
                block_sse[index] = np.sum(residual[block == index] ** 2, axis=0)
        except TakError as err:
            failures.append(f'fold {fold + 1}: {err}')
            if fallback is None or not fallback.ok or 2 * len(failures) > folds:
                return ModelScore(effects=names, fold_sse=np.zeros((0, 3)), fold_samples=np.zeros(0),
                                  error=_joined_failures(failures))
            fold_sse[fold] = fallback.fold_sse[fold]
            if heldout is not None and fallback.heldout is not None:
                heldout[held_out] = fallback.heldout[held_out]
            if fallback.block_sse is not None:
                held_blocks = np.unique(block[held_out])
                block_sse[held_blocks] = fallback.block_sse[held_blocks]
    if heldout is not None and whiten is not None:
        whitened = whiten(heldout)
        fold_sse = np.stack([np.sum(whitened[labels == fold] ** 2, axis=0) for fold in range(folds)])
        block_sse = np.stack([np.sum(whitened[block == index] ** 2, axis=0) for index in range(blocks)])
    return ModelScore(effects=names, fold_sse=fold_sse, fold_samples=fold_samples,
                      failed_folds=tuple(failures), block_sse=block_sse, block_samples=block_samples,
                      heldout=heldout)


def _joined_failures(failures: list[str]) -> str:
    """``fold k: reason`` joined; one reason said once when every failed fold gives it."""
    reasons = {failure.partition(': ')[2] for failure in failures}
    if len(reasons) == 1:
        folds = ', '.join(failure.partition(':')[0].removeprefix('fold ') for failure in failures)
        return f'fold{"s" if len(failures) > 1 else ""} {folds}: {reasons.pop()}'
    return '; '.join(failures)


def paired_block_t(before: ModelScore, after: ModelScore) -> np.ndarray:
    """Paired t per axis of the held-out MSE gain ``before - after`` over the time blocks.

    Each contiguous block gives one difference of held-out mean squared errors between the two
    models (both scored on the same samples, so the noise common to both cancels); ``t`` is the
    mean difference over the blocks divided by its standard error. ``(3,)``; zero where the two
    models do not differ or the scores lack blocks.
    """
    if before.block_sse is None or after.block_sse is None or before.block_samples is None \
            or len(before.block_sse) != len(after.block_sse) or len(before.block_sse) < 2:
        return np.zeros(3)
    count = np.maximum(before.block_samples, 1.0)[:, None]
    gain = before.block_sse / count - after.block_sse / count
    spread = gain.std(axis=0, ddof=1) / math.sqrt(len(gain))
    mean = gain.mean(axis=0)
    return np.divide(mean, spread, out=np.zeros(3), where=spread > 0.0)


def summed_block_t(before: ModelScore, after: ModelScore, floor: np.ndarray) -> float:
    """Paired t over the time blocks of the held-out gain ``before - after`` summed over the axes.

    Each block's gain is the drop of its held-out mean square per axis in units of that axis'
    ``floor^2``, summed over the axes (the ladder's excess, block by block); ``t`` is the mean
    gain over the blocks divided by its standard error. 0 when the scores lack blocks.
    """
    if before.block_sse is None or after.block_sse is None or before.block_samples is None \
            or len(before.block_sse) != len(after.block_sse) or len(before.block_sse) < 2:
        return 0.0
    count = np.maximum(before.block_samples, 1.0)[:, None]
    gain = np.sum((before.block_sse - after.block_sse) / count / np.asarray(floor) ** 2, axis=1)
    spread = float(gain.std(ddof=1)) / math.sqrt(len(gain))
    return float(gain.mean()) / spread if spread > 0.0 else 0.0


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


def null_heldout(samples: AlignedSamples, effects: Sequence[Any], labels: np.ndarray, settings: Any,
                 floor: np.ndarray, *, folds: int, seed: int = 0) -> ModelScore:
    """Cross-validation of the same model on a simulated copy of the run where that model is true.

    The copy keeps the stamps, temperature codes and reference of ``samples``; its counts are
    the model fitted on all of ``samples`` plus white noise at ``floor``. Its held-out RMS is
    what a model without missing structure shows on this run: the floor, plus the error of
    parameters estimated from the other folds (larger where held-out blocks extrapolate, e.g.
    a warm-up at the start of the run). The verdict measures the excess against it.
    """
    result = fit_with(samples, effects, settings)
    low, high = float(samples.temp_code.min()), float(samples.temp_code.max())
    corrector = Corrector(_with_range(result.calibration, low, high))
    predicted = corrector.predict_counts(samples.reference, samples.temp_code, stamp_s=samples.stamp_s,
                                         aux=samples.aux)
    noise = np.random.default_rng(seed).standard_normal(predicted.shape) * floor
    copy = replace(samples, counts=predicted + noise)
    return cross_validate(copy, tuple(effects), labels, settings, folds=folds)


def _record_folds(groups: np.ndarray, bins: np.ndarray | None, stride: int, folds: int) -> np.ndarray:
    """Each cross-validation sample's fold when whole records are held out: its record modulo ``folds``."""
    if bins is None:
        return (groups[::stride] % folds).astype(np.int64)
    kept = np.flatnonzero(bins >= 0)
    of_bin = np.zeros(int(bins.max()) + 1 if len(kept) else 0, dtype=np.int64)
    of_bin[bins[kept]] = groups[kept]
    return of_bin % folds
