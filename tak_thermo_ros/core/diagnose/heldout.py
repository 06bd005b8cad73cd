"""The ladder judged on whole thermal excursions the fit never saw (see :mod:`.excursions`).

:func:`judge_ladder` takes the models the ladder climbed (the current model, then each effect
added) and keeps the rungs that hold on held-out excursions: each model is fitted without one
excursion (or fold of excursions) and its residual taken on that excursion, where it
interpolates; with a second record (``held_out``), each model is fitted on the whole diagnosed
record and its residual taken on the second record's excursions. A rung is kept when its gain
over the rung below, summed over the excursions and axes, stands beyond its noise and no
axis gets worse over them beyond its noise; the first rung that fails ends the ladder. A rung that
too few excursions can judge (none lies within what its fits saw) stands on the interleaved blocks
alone, and says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Callable, Sequence

import numpy as np
from scipy.stats import chi2, norm

from tak_thermo_ros.core.diagnose.crossval import _effect_name, _with_range, fit_with
from tak_thermo_ros.core.diagnose.excursions import (
    GAIN_SIGMAS,
    GAP_FRACTION,
    MAX_FOLDS,
    MIN_JUDGED,
    WORSE_ALPHA,
    WORSE_MIN,
    Excursion,
    excursion_labels,
    excursions,
)
from tak_thermo_ros.core.effects import held_form, resolve_effect
from tak_thermo_ros.core.effects.base import INPUT, checked_basis, effect_input
from tak_thermo_ros.core.fit import residual_counts
from tak_thermo_ros.core.fit.uncertainty import ResidualNoise, noise_product, weighted_sum_error
from tak_thermo_ros.core.link.model import AXES
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.errors import TakError


@dataclass(frozen=True)
class HeldOut:
    """One model's residual on the held-out excursions: ``(k, 3)``, NaN where a sample is not judged.

    A sample is judged when its excursion was held out of the fit, the fit succeeded, and its
    temperature and every offset effect's signal lie within what the fitted samples saw.
    """

    label: str
    residual: np.ndarray

    @property
    def judged(self) -> np.ndarray:
        """``(k,)`` which samples are judged."""
        return np.all(np.isfinite(self.residual), axis=1)


@dataclass(frozen=True)
class RungJudgement:
    """One rung of the ladder against the rung below, on held-out excursions.

    :param effect: the effect the rung adds (or the per-axis form it puts in place).
    :param better: excursions on which the held-out mean square fell (summed over the axes).
    :param judged: excursions with judged samples under both models.
    :param sigmas: the gain summed over the excursions and axes, in its standard errors.
    :param worse: ``(excursion description, axis)``: on an axis whose gain over the excursions is
        below zero beyond its noise, the excursions where it fell.
    :param rms_before: ``(3,)`` held-out RMS of the rung below on the judged samples; ``rms_after`` of this rung.
    :param kept: whether the rung holds (or could not be judged: too few excursions lie within what
        its fits saw; then the interleaved blocks decide alone, and the line says so).
    :param decided: whether enough excursions were judged to decide.
    :param slightly_worse: axes worse beyond their noise but by less than the floor's variance
        (:data:`~tak_thermo_ros.core.diagnose.excursions.WORSE_MIN`): said, not refused.
    :param narrowed_to: a rung refused for the axes it made worse where its fit cannot tell its
        amplitudes from zero: the held form judged in its place (``thermal_lag[xz]``,
        :func:`narrowed`); ``''`` otherwise.
    :param second_look: the rung is a held form, chosen after its effect was judged on these
        excursions: it holds only where it is better on most of them besides.
    """

    effect: str
    better: int
    judged: int
    sigmas: float
    worse: tuple[tuple[str, str], ...]
    rms_before: tuple[float, float, float]
    rms_after: tuple[float, float, float]
    kept: bool
    decided: bool = True
    slightly_worse: tuple[str, ...] = ()
    narrowed_to: str = ''
    second_look: bool = False

    def line(self, where: str, unit: str = '') -> str:
        """``'thermal_lag holds on held-out excursions: better on 2 of 2, gain 7.4 sigmas'`` (one sentence).

        ``unit``: the temperature's, after its numbers (``' C'``; a counts record's codes: none).
        """
        groups: dict[tuple[str, ...], list[str]] = {}
        for axis in AXES:
            places = tuple(what + unit for what, worse_axis in self.worse if worse_axis == axis)
            if places:
                groups.setdefault(places, []).append(axis)
        worse = '; '.join(f'{", ".join(axes)} ({", ".join(places)})' for places, axes in groups.items())
        if not self.decided:
            return (f'{self.effect} cannot be judged on {where}: too few of them ({self.judged}) lie within what '
                    f'its fits saw (the temperatures and its signals); named on interleaved time blocks only.')
        verb = 'holds' if self.kept else 'does not hold'
        slightly = f'; slightly worse on {", ".join(self.slightly_worse)}' if self.slightly_worse and not worse else ''
        said = (f'{self.effect} {verb} on {where}: better on {self.better} of {self.judged}, gain '
                f'{self.sigmas:.1f} sigmas{"; worse on " + worse if worse else slightly}.')
        if self.narrowed_to:
            held = sorted({axis for _, axis in self.worse})
            said += (f' On {", ".join(held)} its fit cannot tell its amplitude from zero: held at zero there, '
                     f'judged as {self.narrowed_to}.')
        if self.second_look and not self.kept and 2 * self.better <= self.judged and not worse:
            said = said[:-1] + ('; a held form, chosen after its effect was judged on these excursions, must be '
                                'better on most of them.')
        return said

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        def finite(value: float) -> float | None:
            return float(value) if math.isfinite(value) else None
        return {'effect': self.effect, 'better': self.better, 'judged': self.judged, 'gain_sigmas': finite(self.sigmas),
                'worse': [{'excursion': what, 'axis': axis} for what, axis in self.worse],
                'rms_before': {axis: finite(v) for axis, v in zip(AXES, self.rms_before)},
                'rms_after': {axis: finite(v) for axis, v in zip(AXES, self.rms_after)},
                'kept': self.kept, 'decided': self.decided, 'slightly_worse': list(self.slightly_worse),
                'narrowed_to': self.narrowed_to, 'second_look': self.second_look}


@dataclass(frozen=True)
class ExcursionVerdict:
    """What the held-out excursions say of the ladder.

    :param excursions: the excursions judged on (of the diagnosed record, or of the second one).
    :param second_record: whether they are a second record's.
    :param rungs: per rung the judgement, in the ladder's order, up to the first that failed (a rung
        narrowed to its held form: its refusal, then the held form's judgement).
    :param reason: why nothing could be judged ('' when it could).
    :param models: per ladder rung judged, ``(effect added, the model's specs)`` as judged (a
        narrowed rung's held form in place of the effect, there and above).
    """

    excursions: tuple[Excursion, ...]
    second_record: bool
    rungs: tuple[RungJudgement, ...]
    reason: str = ''
    models: tuple[tuple[str, tuple[Any, ...]], ...] = ()

    @property
    def ladder_rungs(self) -> tuple[RungJudgement, ...]:
        """The judgements of the ladder's rungs (without the refusals a held form replaced)."""
        return tuple(rung for rung in self.rungs if not rung.narrowed_to)

    @property
    def can_judge(self) -> bool:
        """Whether the excursions could judge the ladder."""
        return not self.reason

    @property
    def kept(self) -> int:
        """How many of the rungs judged hold (a rung too few excursions could decide counts as holding).

        0 when no rung is listed: nothing could be judged (see :attr:`can_judge`) or the ladder has no rung.
        """
        return sum(1 for rung in self.rungs if rung.kept)

    @property
    def where(self) -> str:
        """``'held-out excursions'`` or ``'the second record's excursions'``."""
        return 'the second record\'s excursions' if self.second_record else 'held-out excursions'

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {'excursions': [{'kind': e.kind, 'first': e.first, 'last': e.last, 'samples': e.stop - e.start}
                               for e in self.excursions],
                'second_record': self.second_record, 'reason': self.reason,
                'models': [name for name, _ in self.models],
                'rungs': [rung.as_dict() for rung in self.rungs]}


def worse_sigmas(records: int = 1) -> float:
    """How far below zero an axis's held-out gain must lie, in its standard errors, to count as worse.

    Bonferroni over the three axes (of ``records`` records), :data:`WORSE_ALPHA` in all.
    """
    return float(norm.isf(WORSE_ALPHA / max(3 * records, 1)))


def compare(before: HeldOut, after: HeldOut, labels: np.ndarray, found: Sequence[Excursion], floor: np.ndarray,
            effect: str, *, least: int = 2, noise: Sequence[ResidualNoise] | None = None) -> RungJudgement:
    """Rung ``after`` against rung ``before`` on the samples both judge (at least ``least`` excursions).

    :param noise: per axis the sensor's noise at the samples' period (:func:`sensor_noise`); ``None``:
        the noise model of the rung's own held-out residual (all its structure counted as noise).
    """
    both = before.judged & after.judged
    floor2 = np.maximum(np.asarray(floor, dtype=float), 1e-300) ** 2
    gain = (before.residual ** 2 - after.residual ** 2) / floor2
    better, judged = 0, 0
    worse_where: list[list[str]] = [[], [], []]
    for index, excursion in enumerate(found):
        inside = both & (labels == index)
        if np.count_nonzero(inside) < MIN_JUDGED:
            continue
        judged += 1
        part = gain[inside]
        better += float(part.sum()) > 0.0
        for axis in range(3):
            if part[:, axis].mean() < 0.0:
                worse_where[axis].append(excursion.describe())
    # The gain over every judged sample, in time order. With d = b - a the change the rung makes
    # to the prediction, a^2 - b^2 = 2 b d + d^2: its mean is uncertain by what the sensor's noise
    # in the rung's held-out residual b makes of 2 sum(b d) / n, with the noise's correlation (the
    # d^2 part is what the rung changes, not noise).
    scored = both & np.isin(labels, [index for index in range(len(found))
                                     if np.count_nonzero(both & (labels == index)) >= MIN_JUDGED])
    count = int(np.count_nonzero(scored))
    worse: list[tuple[str, str]] = []
    slightly: list[str] = []
    sigmas = 0.0
    if count:
        series = gain[scored]
        change = (after.residual[scored] - before.residual[scored])
        if noise is not None:
            errors = np.array([2.0 * math.sqrt(max(float(noise_product(change[:, [axis]] / count, noise[axis])[0, 0]),
                                                   0.0)) for axis in range(3)]) / floor2
        else:
            errors = np.array([2.0 * weighted_sum_error(after.residual[scored, axis], change[:, axis] / count)
                               for axis in range(3)]) / floor2
        total = float(series.sum(axis=1).mean())
        spread = float(np.sqrt(np.sum(errors ** 2)))
        sigmas = total / spread if spread > 0.0 else (math.inf if total > 0.0 else 0.0)
        # An axis is worse when its gain lies below zero beyond its noise (Bonferroni over the axes)
        # and by more than WORSE_MIN of the floor squared; an axis the rung leaves as it was (an
        # effect held at zero there) only by rounding is neither.
        moved = np.max(np.abs(change), axis=0) > 1e-9 * np.max(np.abs(before.residual[scored]), axis=0)
        for axis in np.flatnonzero(moved):
            mean = float(series[:, axis].mean())
            if mean < -max(worse_sigmas() * errors[axis], WORSE_MIN):
                worse += [(where, AXES[axis]) for where in worse_where[axis]]
            elif mean < -worse_sigmas() * errors[axis]:
                slightly.append(AXES[axis])
    rms_before = np.sqrt(np.nanmean(np.where(both[:, None], before.residual, np.nan) ** 2, axis=0)) \
        if both.any() else np.full(3, np.nan)
    rms_after = np.sqrt(np.nanmean(np.where(both[:, None], after.residual, np.nan) ** 2, axis=0)) \
        if both.any() else np.full(3, np.nan)
    decided = judged >= least
    kept = not decided or sigmas >= GAIN_SIGMAS and not worse
    return RungJudgement(effect=effect, better=int(better), judged=judged, sigmas=float(sigmas), worse=tuple(worse),
                         rms_before=tuple(float(v) for v in rms_before),  # type: ignore[arg-type]
                         rms_after=tuple(float(v) for v in rms_after), kept=bool(kept),  # type: ignore[arg-type]
                         decided=decided, slightly_worse=tuple(slightly))


def covered(temperature: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Where a temperature lies among those a fit saw: within :data:`GAP_FRACTION` of their range from one of them.

    Not merely between their extremes: a held-out ramp across a gap between two plateaus the fit saw
    is an extrapolation for a curve with knots in the gap.
    """
    known = np.unique(np.asarray(seen, dtype=float))
    if not len(known):
        return np.zeros(len(temperature), dtype=bool)
    gap = GAP_FRACTION * max(float(known[-1] - known[0]), 1e-12)
    values = np.asarray(temperature, dtype=float)
    at = np.clip(np.searchsorted(known, values), 1, max(len(known) - 1, 1))
    nearest = np.minimum(np.abs(values - known[at - 1]), np.abs(values - known[np.minimum(at, len(known) - 1)]))
    return (values >= known[0]) & (values <= known[-1]) & (nearest <= gap)


def _signals_within(calibration: Any, judged: AlignedSamples, fitted: AlignedSamples | None = None,
                    train: np.ndarray | None = None) -> np.ndarray:
    """``(k,)`` where every offset effect's signal on ``judged`` lies within what the fit saw.

    The fit saw ``fitted`` (default: ``judged`` itself), its ``train`` samples (default: all of them).
    """
    fitted = judged if fitted is None else fitted

    def signal(effect: Any, run: AlignedSamples) -> np.ndarray:
        codes = np.clip(run.temp_code, calibration.temp_code_min, calibration.temp_code_max)
        return checked_basis(effect, run.stamp_s, effect_input(effect, codes, run.aux))
    inside = np.ones(len(judged), dtype=bool)
    for effect in calibration.effects:
        if effect.kind == INPUT:
            continue
        try:
            basis = signal(effect, judged)
            seen = basis if fitted is judged else signal(effect, fitted)
        except TakError:
            return np.zeros(len(judged), dtype=bool)
        if train is not None:
            seen = seen[train]
        if not len(seen):
            return np.zeros(len(judged), dtype=bool)
        slack = 1e-9 * np.maximum(np.abs(seen).max(axis=0), 1e-300)
        inside &= np.all((basis >= seen.min(axis=0) - slack) & (basis <= seen.max(axis=0) + slack), axis=1)
    return inside


def heldout_residual(samples: AlignedSamples, specs: Sequence[Any], settings: Any, folds: np.ndarray,
                     fold_count: int, found: Sequence[Excursion], labels: np.ndarray) -> HeldOut:
    """The model ``specs`` fitted without each fold of excursions, its residual on that fold where it interpolates.

    An excursion is judged only by a fit that saw one of its kind (a heating by a model fitted on
    a heating too: a lag fitted on coolings alone cannot tell itself from the polynomials).
    """
    out = np.full((len(samples), 3), np.nan)
    low, high = float(samples.temp_code.min()), float(samples.temp_code.max())
    fold_of = np.array([index % fold_count for index in range(len(found))])
    for fold in range(fold_count):
        train = folds != fold
        seen = {excursion.kind for index, excursion in enumerate(found) if fold_of[index] != fold}
        judgeable = [index for index, excursion in enumerate(found)
                     if fold_of[index] == fold and excursion.kind in seen]
        if not judgeable:
            continue
        held = np.isin(labels, judgeable)
        try:
            result = fit_with(samples, specs, settings, train_mask=train)
            calibration = _with_range(result.calibration, low, high)
            residual = residual_counts(calibration, samples)
        except TakError:
            continue
        within = covered(samples.temp_code, samples.temp_code[train])
        seen_signals = _signals_within(result.calibration, samples, train=train)
        judged = held & within & seen_signals & np.all(np.isfinite(residual), 1)
        out[judged] = residual[judged]
    return HeldOut(label=' + '.join(('base', *(_effect_name(s) for s in specs))), residual=out)


def second_record_residual(samples: AlignedSamples, second: AlignedSamples, specs: Sequence[Any],
                           settings: Any) -> HeldOut:
    """The model ``specs`` fitted on all of ``samples``, its residual on ``second`` where it interpolates."""
    out = np.full((len(second), 3), np.nan)
    try:
        result = fit_with(samples, specs, settings)
        low, high = float(second.temp_code.min()), float(second.temp_code.max())
        residual = residual_counts(_with_range(result.calibration, low, high), second)
    except TakError:
        return HeldOut(label='', residual=out)
    within = covered(second.temp_code, samples.temp_code)
    seen = _signals_within(result.calibration, second, samples)
    judged = within & seen & np.all(np.isfinite(residual), axis=1)
    out[judged] = residual[judged]
    return HeldOut(label=' + '.join(('base', *(_effect_name(s) for s in specs))), residual=out)


def sensor_noise(noise: Any, white_floor: np.ndarray, raw_period: float, period: float,
                 duration: float, *, averaged: bool = False) -> list[ResidualNoise]:
    """Per axis the sensor's noise model as the held-out residual at ``period`` carries it.

    White noise at the measured floor (per sample at ``raw_period``; ``averaged``: the samples are
    means over ``period``, else every so many samples kept as they are), the
    model's bias instability as the simulator draws it (Gauss-Markov processes around its time,
    at most a tenth of the record), its random walk and Gauss-Markov processes; without a model,
    white noise at the floor (as the rest of the verdict takes it then).
    """
    from tak_thermo_ros.core.simulation.noise import bias_instability_poles, bias_instability_variance
    shrink = raw_period / max(period, raw_period) if averaged else 1.0
    if noise is None:
        return [ResidualNoise.white_only(float(white_floor[axis]) ** 2 * shrink, period) for axis in range(3)]

    def triple(name: str) -> np.ndarray:
        values = np.asarray(getattr(noise, name, 0.0), dtype=float).reshape(-1)
        return np.broadcast_to(values, (3,)) if values.size in (1, 3) else values[:3]
    found = []
    longest = max(duration / 10.0, 2.0 * period)
    for axis in range(3):
        markov = []
        bias, tau = float(triple('bias_instability')[axis]), float(triple('bias_instability_tau')[axis])
        if bias > 0.0:
            centre = min(max(tau, 2.0 * period), longest) if math.isfinite(tau) else longest
            variance = bias_instability_variance(bias, centre)
            markov += [(variance, float(time)) for time in bias_instability_poles(centre)]
        for sigma, time in zip(getattr(noise, 'gauss_markov', ()), getattr(noise, 'gauss_markov_time', ())):
            if float(sigma[axis]) > 0.0:
                markov.append((float(sigma[axis]) ** 2, float(time[axis])))
        white = float(white_floor[axis]) ** 2 * shrink
        walk = float(triple('random_walk')[axis]) ** 2 * period
        found.append(ResidualNoise(white=white, markov=tuple(markov), walk=walk, period=period, longest_s=duration))
    return found


NARROW_LEVEL = 0.05
"""A worse axis is held at zero when its fitted amplitudes lie within their noise of zero: their
chi-square (with the sandwich errors) below its ``1 - NARROW_LEVEL`` quantile."""


NARROW_JUDGED = 3
"""A held form is a second look at the excursions its effect was refused on: only a rung judged on at
least this many, better on most of them and with its gain beyond its noise, is narrowed."""


def narrowed(samples: AlignedSamples, settings: Any, below: tuple[Any, ...], specs: tuple[Any, ...],
             rung: RungJudgement) -> tuple[Any, type] | None:
    """The effect a refused rung adds, and its form held at zero on the axes it made worse; or ``None``.

    A unit's effect may sit on two axes and not the third. Fitted on all three, the third's
    amplitude takes whatever slow wander of that channel looks most like the effect's signal, and a
    held-out excursion finds that axis worse while the others gain. When on every worse axis the
    fit on all samples cannot tell the amplitudes from zero (:data:`NARROW_LEVEL`, the sandwich
    errors), the effect is judged again held at zero there (:mod:`~tak_thermo_ros.core.effects.held`).
    Where the fit finds an amplitude the held-out excursions refuse, the effect is not what it
    seems there, and nothing is narrowed. The held form is chosen after the excursions were seen,
    so the rung must have left something to judge it on (:data:`NARROW_JUDGED`), and the held form
    must be better on most of them besides holding (``second_look``).
    """
    worse = sorted({AXES.index(axis) for _, axis in rung.worse})
    added = [spec for spec in specs if not any(spec is other for other in below)]
    if not worse or len(worse) == 3 or len(added) != 1 or len(specs) != len(below) + 1:
        return None
    if rung.judged < NARROW_JUDGED or 2 * rung.better <= rung.judged or rung.sigmas < GAIN_SIGMAS:
        return None
    try:
        cls = resolve_effect(added[0])
        form = held_form(cls, [axis for axis in cls.fitted_axes if axis not in worse])
        result = fit_with(samples, specs, settings, errors=True)
    except TakError:  # no held form of this kind of effect, or the fit fails
        return None
    effect = next((e for e in result.calibration.effects if e.name == cls.name), None)
    if effect is None:
        return None
    errors = result.parameter_errors
    for axis in worse:
        names = effect.amplitude_names()[axis]
        sigmas = [errors.get(f'{cls.name}.{name}') for name in names]
        if not names or any(sigma is None or not sigma > 0.0 for sigma in sigmas):
            return None
        statistic = sum((effect[name] / sigma) ** 2 for name, sigma in zip(names, sigmas))
        if statistic > chi2.isf(NARROW_LEVEL, len(names)):
            return None
    return added[0], form


def judge_ladder(samples: AlignedSamples, rungs: Sequence[tuple[str, tuple[Any, ...]]], settings: Any,
                 floor: np.ndarray, *, held_out: AlignedSamples | None = None,
                 temperature_unit: str = '', noise: Sequence[ResidualNoise] | None = None,
                 whiten: Callable[[np.ndarray], np.ndarray] | None = None, narrow: bool = True) -> ExcursionVerdict:
    """Keep the ladder's rungs that hold on held-out excursions (see the module docstring).

    :param rungs: ``(effect added, the model's specs)`` per rung, the current model first (effect '').
    :param floor: ``(3,)`` the axes' noise floor the gains are measured in.
    :param held_out: a second record to judge on instead of the diagnosed record's own excursions.
    :param temperature_unit: after a temperature in a message (``' C'``; codes: ``''``).
    :param noise: per axis the sensor's noise (:func:`sensor_noise`) the gains are judged against.
    :param whiten: the noise model's whitening filter over ``samples`` (judged against a noise model
        from a file or a static run, as the cross-validation is): the held-out residuals are
        whitened before they are compared, so that what the model's bias wander explains (a slow
        amplitude fitted to wander on an axis without the effect) is not counted; ``noise`` is
        then the whitened residual's white level.
    :param narrow: a rung refused only for axes where its fit cannot tell the effect from zero is
        judged again held at zero there (:func:`narrowed`); its held form then takes the rung.
    """
    target = held_out if held_out is not None else samples
    found = excursions(target.time_s, target.temp_code)
    if held_out is None and len(found) < 2:
        return ExcursionVerdict(found, False, (), reason=(
            f'one thermal excursion ({found[0].describe(temperature_unit) if found else "none"}): whole '
            f'excursions cannot be held out; judge on a second record (--held-out) or validate on one'))
    labels = excursion_labels(len(target), found)
    fold_count = min(len(found), MAX_FOLDS)
    folds = labels % fold_count
    if held_out is None:
        kinds = [excursion.kind for excursion in found]
        judgeable = [index for index, kind in enumerate(kinds)
                     if any(other == kind and other_index % fold_count != index % fold_count
                            for other_index, other in enumerate(kinds))]
        if len(judgeable) < 2:
            listed = ', '.join(excursion.describe(temperature_unit) for excursion in found[:4])
            return ExcursionVerdict(found, False, (), reason=(
                f'no two excursions of a kind ({listed}): none can be held out and judged by a fit that saw '
                f'its kind; judge on a second record (--held-out) or validate on one'))
    if len(rungs) < 2:
        return ExcursionVerdict(found, held_out is not None, ())

    def residual_of(specs: tuple[Any, ...]) -> HeldOut:
        if held_out is not None:
            return second_record_residual(samples, held_out, specs, settings)
        return heldout_residual(samples, specs, settings, folds, fold_count, found, labels)

    def judge(below: HeldOut, above: HeldOut, effect: str) -> RungJudgement:
        if whiten is not None and held_out is None:
            # Both rungs whitened over the samples both judge: an axis a rung leaves as it was
            # keeps the same whitened residual.
            both = below.judged & above.judged

            def whitened(rung: HeldOut) -> HeldOut:
                filtered = whiten(np.where(both[:, None], rung.residual, 0.0))
                return HeldOut(rung.label, np.where(both[:, None], filtered, np.nan))
            below, above = whitened(below), whitened(above)
        return compare(below, above, labels, found, floor, effect, least=least, noise=noise)

    least = 1 if held_out is not None else 2
    judged: list[RungJudgement] = []
    models: list[tuple[str, tuple[Any, ...]]] = []
    specs_below = rungs[0][1]
    below = residual_of(specs_below)
    swaps: list[tuple[Any, Any]] = []
    for effect, specs in rungs[1:]:
        for old, new in swaps:
            specs = tuple(new if spec is old else spec for spec in specs)
        above = residual_of(specs)
        rung = judge(below, above, effect)
        swap = narrowed(samples, settings, specs_below, specs, rung) if (
            narrow and not rung.kept and rung.worse) else None
        if swap is not None:
            judged.append(replace(rung, narrowed_to=swap[1].name))
            swaps.append(swap)
            effect, specs = swap[1].name, tuple(swap[1] if spec is swap[0] else spec for spec in specs)
            above = residual_of(specs)
            rung = replace(judge(below, above, effect), second_look=True)
            if rung.kept and rung.decided and 2 * rung.better <= rung.judged:
                rung = replace(rung, kept=False)
        judged.append(rung)
        if not rung.kept:
            break
        models.append((effect, specs))
        below, specs_below = above, specs
    return ExcursionVerdict(found, held_out is not None, tuple(judged), models=tuple(models))


def held_out_like(held_out: AlignedSamples | None, cv_samples: AlignedSamples, binned: bool, averaging_s: float,
                  max_samples: int) -> AlignedSamples | None:
    """The second record as the cross-validation sees the diagnosed one: averaged over the same bins, or decimated."""
    if held_out is None:
        return None
    from tak_thermo_ros.core.diagnose.crossval import decimate
    from tak_thermo_ros.core.diagnose.views import segment_breaks
    from tak_thermo_ros.core.diagnose.yardstick import bin_labels, bin_samples
    if binned and len(held_out) > 1:
        period = max(float(np.median(np.diff(held_out.time_s))), 1e-9)
        return bin_samples(held_out, bin_labels(held_out.time_s, segment_breaks(held_out), averaging_s, period))
    return decimate(held_out, max(1, math.ceil(len(held_out) / max_samples)))


def excursion_statements(statements: list, verdict: ExcursionVerdict, temperature_unit: str = '') -> list:
    """The verdict's message with what the held-out excursions say (one sentence per rung judged, or why none).

    When the ladder's first rung does not hold, the sentence that named the best library effect
    says so instead.
    """
    from tak_thermo_ros.core.diagnose.verdict import Statement
    if not verdict.can_judge:
        return [*statements[:1], Statement(f'Judged on interleaved time blocks only: {verdict.reason}.'),
                *statements[1:]]
    lines = [Statement(rung.line(verdict.where, temperature_unit)
                       + ('' if rung.kept or rung.narrowed_to else ' It is not recommended.'))
             for rung in verdict.rungs]
    ladder = verdict.ladder_rungs
    rejected_first = bool(ladder) and not ladder[0].kept
    out = []
    for statement in statements:
        text = statement.text
        if rejected_first and text.startswith(('The best library effect', 'No library effect lowers')):
            continue
        if rejected_first:
            text = text.replace('that no library effect explains with parameters this run resolves',
                                f'that no library effect explains on {verdict.where}')
        out.append(Statement(text, statement.detail) if text != statement.text else statement)
    return [*out[:1], *lines, *out[1:]]
