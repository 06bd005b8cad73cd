"""The steps of :func:`diagnose` put together: floor, views, cross-validated ladder, verdict."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Callable, Sequence

import numpy as np

from tak_thermo_ros.core.diagnose.crossval import (
    _effect_name,
    _effect_parameters,
    _effect_specs,
    _record_folds,
    _settings_of,
    _with_range,
    block_index,
    cross_validate,
    decimate,
    fit_with,
    fold_labels,
    null_heldout,
    paired_block_t,
    summed_block_t,
    unresolved_shapes,
)
from tak_thermo_ros.core.diagnose.heldout import excursion_statements, held_out_like as _held_out_like, judge_ladder
from tak_thermo_ros.core.diagnose.heldout import sensor_noise
from tak_thermo_ros.core.diagnose.values import AxisSummary, Candidate, Diagnosis, ModelScore
from tak_thermo_ros.core.diagnose.verdict import (
    MIN_STEP_FRACTION,
    MIN_TOTAL_FRACTION,
    MIN_VARIANCE_EXCESS,
    SIGNIFICANCE_SIGMAS,
    VERDICT_NONE,
    VERDICT_UNEXPLAINED,
    _describe_rms,
    _noise_sigma,
    _paired_sigma,
    _percent,
    _rung,
    _verdict_message,
    Statement,
    message_text,
    gain_t_threshold,
    per_axis_t_threshold,
    rms_text,
    step_statements,
)
from tak_thermo_ros.core.diagnose.views import EFFECT_VIEWS, build_views, noise_floor, residual_drivers
from tak_thermo_ros.core.diagnose.yardstick import (
    BINS_PER_BLOCK,
    NULL_REPLICATES,
    AllanCheck,
    NullYardstick,
    _rung_allan,
    averaging_time,
    bin_labels,
    bin_samples,
    null_under_noise,
    sample_period,
    wander_explains,
    whitener,
)
from tak_thermo_ros.core.effects import (
    LIBRARY,
    PER_AXIS,
    PER_AXIS_SUFFIX,
    Effect,
    PerAxisEffect,
    held_of,
    resolve_effect,
)
from tak_thermo_ros.core.effects.aux_signal import recorded_candidates
from tak_thermo_ros.core.effects.step import Step
from tak_thermo_ros.core.records.steps import find_steps
from tak_thermo_ros.core.fit import residual_counts
from tak_thermo_ros.core.link.model import AXES, Calibration
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.errors import FitError, TakError


@dataclass(frozen=True)
class _Step:
    """Candidates scored against one rung of the ladder: ``(candidate, score, model)`` best first."""

    current: ModelScore
    ranked: tuple[tuple[Candidate, ModelScore, tuple[Any, ...]], ...]
    skipped: dict[str, str]
    refused: frozenset[str] = frozenset()


def _shared_form(spec: Any) -> Any | None:
    """The shared class of a per-axis form, or ``None``."""
    return getattr(spec, 'shared', None) if isinstance(spec, type) and issubclass(spec, PerAxisEffect) else None


def _per_axis_of(spec: Any) -> Any | None:
    """The per-axis form of a shared library effect, or ``None``."""
    return PER_AXIS.get(_effect_name(spec) + PER_AXIS_SUFFIX) if isinstance(spec, type) else None


def _replaced(model: tuple[Any, ...], old: Any, new: Any) -> tuple[Any, ...]:
    return tuple(new if spec is old else spec for spec in model)


def diagnose(calibration: Calibration, samples: AlignedSamples, *,
             candidates: Sequence[Any] | None = None, folds: int = 5, blocks_per_fold: int = 4,
             max_cv_samples: int = 40_000, max_ladder: int = 3,
             bias_order: int | None = None, scale_order: int | None = None,
             rate_window_s: float | None = None,
             progress: Callable[[str], None] | None = None, per_axis: bool = True,
             noise: Any | None = None, seed: int = 0, unit: str = 'counts', unit_scale: float = 1.0,
             groups: np.ndarray | None = None, temperature_unit: str = '', start_s: float | None = None,
             excursions: bool = True, held_out: AlignedSamples | None = None) -> Diagnosis:
    """Compare the calibration with a run, find where it fails and which effect it misses.

    :param calibration: the model to diagnose (base model, possibly with effects).
    :param samples: an aligned run with its reference stream, in time order.
    :param candidates: effects to try: library names, ``'module:Class'`` specs or classes;
        default every library effect and every recorded signal of the run
        (:func:`~tak_thermo_ros.core.effects.aux_signal.recorded_candidates`). Effects the
        calibration holds already are not tried.
    :param folds: cross-validation folds.
    :param blocks_per_fold: contiguous time blocks per fold (dealt round-robin); the first block
        is cut into one piece per fold besides (:func:`fold_labels`).
    :param max_cv_samples: the cross-validation fits use every m-th sample so that at most
        this many remain (the noise floor and the views use all samples).
    :param max_ladder: at most this many effects are added one after the other.
    :param bias_order: ``q`` of the refits; default that of ``calibration``.
    :param scale_order: ``p`` of the refits; default that of ``calibration``.
    :param rate_window_s: window of ``dN_t/dt`` (see :func:`build_views`).
    :param progress: called with a short text before each model is cross-validated.
    :param per_axis: also try the per-axis form (``<name>_per_axis``) of an effect whose shape
        parameters can differ between axes: in place of the shared form when that joins the
        ladder, and in place of a shared form the calibration holds.
    :param noise: the sensor's noise model (:class:`~tak_thermo_ros.core.noise.model.NoiseModel`):
        from a file or a static run (``source`` ``'file'`` or ``'static_run'``), the verdict is
        judged against it (:mod:`~tak_thermo_ros.core.diagnose.yardstick`: averaging bins, the
        held-out score of copies of the run under the noise model, the Allan test); fitted to
        this run's residual (``'residual'``) or ``None``, against the white floor, and the Allan
        deviation against the model is reported.
    :param seed: seed of the simulated copies of the run.
    :param unit: the residual's unit in the verdict's message, ``unit_scale`` the factor from the
        residual to it (a magnetometer's tesla in uT: ``'uT'``, 1e6).
    :param groups: ``(k,)`` per sample its record in a pool of records (0, 1, ...): the folds then hold
        whole records out (record ``r`` in fold ``r % folds``) instead of time blocks; ``None``: time blocks.
    :param temperature_unit: the temperature's unit in messages (``'C'``); ``''``: codes.
    :param start_s: the record's first stamp, seconds: a step's moment is counted from it (default:
        the first sample's, which differs when samples at the start were left out).
    :param excursions: judge the ladder on whole thermal excursions held out of the fit (not for a pool:
        its folds already hold whole records out)
        (:mod:`~tak_thermo_ros.core.diagnose.heldout`): a rung that does not hold there ends it.
    :param held_out: a second record of the same unit (aligned, with its reference) to judge the
        ladder on instead of the diagnosed record's own excursions.
    :raises FitError: when the run has no reference or too few samples.

    Before the ladder, the residual of the calibration as given is scanned for steps (sudden
    level changes, :func:`~tak_thermo_ros.core.records.steps.find_steps`): a step found is
    named with its moment and temperature before any word on a slow drift, and the library's
    ``step`` effect joins the candidates (only then: without a step it would split a slow
    wander into two levels).
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
    whole_codes = bool(np.all(samples.counts == np.round(samples.counts)))
    floor, differences = noise_floor(residual, views.breaks, least_spread=0.5 if whole_codes else 0.0)
    floor = np.maximum(floor, 1e-12)
    white_floor = floor
    period = sample_period(samples)
    blocks = folds * blocks_per_fold
    judged = noise is not None and getattr(noise, 'source', 'residual') != 'residual'

    stride = max(1, math.ceil(len(samples) / max_cv_samples))
    averaging_s = period * stride
    bins = None
    if judged:
        duration = float(samples.time_s[-1]) if len(samples) else 0.0
        starts = np.flatnonzero(views.breaks)
        # Bins fit inside the turntable's dwells (a bin never straddles a move).
        segment_s = float(np.median(np.diff(np.append(samples.time_s[starts], duration + period))))
        averaging_s = averaging_time(noise, white_floor, period, min(duration / blocks, BINS_PER_BLOCK * segment_s))
        averaging_s = max(averaging_s, duration / max_cv_samples)
        if averaging_s > 1.5 * period:
            bins = bin_labels(samples.time_s, views.breaks, averaging_s, period)
            cv_samples = bin_samples(samples, bins)
        else:
            averaging_s, stride = period, 1
            cv_samples = samples
    else:
        cv_samples = decimate(samples, stride)
    labels = fold_labels(cv_samples.time_s, folds, blocks) if groups is None else _record_folds(
        np.asarray(groups), bins, stride, folds)
    if np.bincount(labels, minlength=folds).min() < 10:
        msg = f'too few samples ({len(cv_samples)}) for {folds}-fold cross-validation in {blocks} blocks'
        raise FitError(msg)
    yardstick: NullYardstick | None = None
    whiten = None
    if judged:
        counts = np.bincount(bins[bins >= 0]) if bins is not None else np.ones(len(cv_samples))
        whiten = whitener(noise, cv_samples.time_s, (white_floor ** 2)[None, :] / counts[:, None])
        say(f'the model on {NULL_REPLICATES} simulated copies of this run under the noise model')
        try:
            yardstick = null_under_noise(samples, bins if bins is not None else np.arange(len(samples)),
                                         cv_samples, labels, present, settings, noise, white_floor,
                                         folds=folds, seed=seed, whiten=whiten)
        except TakError as err:
            msg = f'the model cannot be fitted to simulated copies of this run under the noise model: {err}'
            raise FitError(msg) from err
        floor = np.maximum(yardstick.floor, 1e-12)

    steps = find_steps(residual, breaks=views.breaks)
    # By default every library effect and every recorded auxiliary signal (aux:TOPIC) in the run;
    # the step only where the scan found one.
    specs = list(candidates) if candidates is not None else [
        *(name for name in LIBRARY if name != Step.name or steps), *recorded_candidates(samples.aux)]
    pool = [resolve_effect(type(spec) if isinstance(spec, Effect) else spec) for spec in specs]
    related = set(present_names) | {_effect_name(_shared_form(spec)) for spec in present if _shared_form(spec)}
    related |= {held_of(spec).name for spec in present if isinstance(spec, type)}  # thermal_lag for thermal_lag[xz]
    pool = [cls for cls in pool if cls.name not in related]
    pool_names = {cls.name for cls in pool}

    cache: dict[frozenset[str], ModelScore] = {}

    def score(effects: tuple[Any, ...], fallback: ModelScore | None = None) -> ModelScore:
        key = frozenset(_effect_name(e) for e in effects)
        if key not in cache:
            say(' + '.join(('base', *(_effect_name(e) for e in effects))))
            cache[key] = cross_validate(cv_samples, effects, labels, settings, folds=folds, fallback=fallback,
                                        whiten=whiten)
        found = cache[key]
        names = tuple(_effect_name(e) for e in effects)
        return found if found.effects == names else replace(found, effects=names)

    def sigma_of(model: ModelScore) -> np.ndarray:
        held = float(model.fold_samples.sum())
        white = np.array([_noise_sigma(differences, held) for _ in range(3)])
        if yardstick is not None:
            # The yardstick is a mean over simulated copies: its spread replaces the floor's error.
            return np.maximum(yardstick.sigma, np.sqrt(2.0 / max(held, 1.0)))
        return white

    def sigma_total(model: ModelScore) -> float:
        return float(np.sqrt(np.sum(sigma_of(model) ** 2)))

    null_ratio = np.zeros(3)

    def significant_axes(model: ModelScore, *, paired: bool = True) -> np.ndarray:
        ratio = model.heldout_rms ** 2 / floor ** 2 - 1.0
        sigma = sigma_of(model)
        if paired and yardstick is None:
            held = float(model.fold_samples.sum())
            sigma = np.array([_paired_sigma(differences, held) for _ in range(3)])
        threshold = np.maximum(SIGNIFICANCE_SIGMAS * sigma, MIN_VARIANCE_EXCESS)
        return ratio - (null_ratio if paired else 0.0) > threshold

    base_drivers = residual_drivers(residual, views)

    def candidate_of(name: str, spec: Any, current: ModelScore, model: ModelScore, note: str = '') -> Candidate:
        excess_now = current.excess(floor)
        gain = excess_now - model.excess(floor)
        explained = gain / excess_now if excess_now > 0.0 else 0.0
        total = sigma_total(current)
        significance = gain / total if total > 0.0 else 0.0
        view = EFFECT_VIEWS.get(_effect_name(_shared_form(spec) or spec))
        view_text = ''
        if view is not None:
            driver = next(d for d in base_drivers if d.name == view)
            axis = int(np.argmax(driver.fraction))
            view_text = (f' In the current residual, {view} explains {_percent(driver.fraction[axis])} '
                         f'of the variance on {AXES[axis]}.')
        evidence = (f'{note}held-out RMS {_describe_rms(current.heldout_rms, model.heldout_rms)} '
                    f'(floor {", ".join(rms_text(v) for v in floor)}); removes {_percent(explained)} of '
                    f'the held-out excess variance over the floor, {significance:.1f} noise sigmas.'
                    f'{view_text}')
        if model.failed_folds:
            evidence += (f' Not fittable on {len(model.failed_folds)} of {folds} folds (scored there with '
                         f'the current model): {model.failed_folds[0]}')
        rms_after = (float(model.heldout_rms[0]), float(model.heldout_rms[1]), float(model.heldout_rms[2]))
        return Candidate(effect=name, rms_after=rms_after, explained=float(explained),
                         significance=float(significance), evidence=evidence,
                         summary=str(spec.summary or ''), confirm=str(spec.confirm or ''))

    def per_axis_evidence(shared: ModelScore, form: ModelScore) -> tuple[bool, str]:
        """Whether held-out blocks prefer the per-axis form over the shared one, and why.

        The per-axis form costs two shape parameters more. It must lower the held-out excess
        summed over the axes by more than white noise could (:data:`SIGNIFICANCE_SIGMAS`). That
        standard error holds when what the per-axis form leaves is white noise at the floor;
        when significant structure remains, the gain varies from block to block far more than
        noise makes it, and on at least one axis the paired gain over the time blocks must then
        stand out against its own spread as well (paired t beyond :func:`per_axis_t_threshold`).
        """
        t = paired_block_t(shared, form)
        count = 0 if form.block_sse is None else len(form.block_sse)
        threshold = per_axis_t_threshold(count)
        gain = shared.excess(floor) - form.excess(floor)
        noise_ok = gain > SIGNIFICANCE_SIGMAS * sigma_total(shared)
        at_floor = not significant_axes(form).any()
        blocks_ok = bool(np.max(t) > threshold)
        text = (f'paired t over the {count} held-out blocks against the shared form '
                f'{", ".join(f"{n} {v:.1f}" for n, v in zip(AXES, t))} (threshold {threshold:.2f}'
                f'{", not needed: what the per-axis form leaves is at the floor" if at_floor else ""}); ')
        return noise_ok and (at_floor or blocks_ok), text

    def rank(current: ModelScore, effects_so_far: tuple[Any, ...]) -> _Step:
        scored: list[tuple[Candidate, ModelScore, tuple[Any, ...]]] = []
        skipped: dict[str, str] = {}
        refused: set[str] = set()
        held = {_effect_name(e) for e in effects_so_far}
        held |= {_effect_name(_shared_form(e)) for e in effects_so_far if _shared_form(e)}
        trials: list[tuple[str, Any, tuple[Any, ...], str]] = []
        for spec in pool:
            name = _effect_name(spec)
            if name not in held:
                trials.append((name, spec, (*effects_so_far, spec), ''))
        if per_axis:
            # A shared form the model holds already may be replaced by its per-axis form.
            for spec in effects_so_far:
                form = _per_axis_of(spec)
                if form is not None and (candidates is None or _effect_name(spec) in pool_names
                                         or _effect_name(spec) in present_names):
                    trials.append((form.name, form, _replaced(effects_so_far, spec, form),
                                   f'In place of {_effect_name(spec)}: '))
        for name, spec, model_specs, note in trials:
            model = score(model_specs, current)
            if not model.ok:
                skipped[name] = model.error or 'fit failed'
                continue
            if note and _shared_form(spec) is not None:
                # In place of a shared form the model holds: the same evidence as on the ladder.
                preferred, text = per_axis_evidence(current, model)
                note += text
                if not preferred:
                    refused.add(name)
            scored.append((candidate_of(name, spec, current, model, note), model, model_specs))
        scored.sort(key=lambda item: item[1].excess(floor))
        return _Step(current=current, ranked=tuple(scored), skipped=skipped, refused=frozenset(refused))

    base_score = score(present)
    if not base_score.ok:
        msg = f'the model cannot be refitted on this run: {base_score.error}'
        raise FitError(msg)
    null_score: ModelScore | None = None
    if yardstick is None and significant_axes(base_score, paired=False).any():
        say('base model on a simulated copy of this run (the held-out error of a complete model)')
        try:
            null_score = null_heldout(cv_samples, present, labels, settings, floor, folds=folds)
        except TakError:
            null_score = None
        if null_score is not None and null_score.ok:
            null_ratio = np.maximum(null_score.heldout_rms ** 2 / floor ** 2 - 1.0, 0.0)
    base_significant = significant_axes(base_score)
    null_rms = null_score.heldout_rms if null_score is not None and null_score.ok else floor
    axes = tuple(AxisSummary(rms=float(math.sqrt(np.mean(residual[:, i] ** 2))), noise_floor=float(floor[i]),
                             heldout_rms=float(base_score.heldout_rms[i]),
                             excess_significant=bool(base_significant[i]),
                             null_heldout_rms=float(null_rms[i]), white_floor=float(white_floor[i]))
                 for i in range(3))

    first_step: _Step | None = None
    skipped: dict[str, str] = {}
    per_axis_tried: list[tuple[int, Candidate]] = []
    held_tried: list[Candidate] = []  # held forms judged in place of a refused rung's effect
    model_specs: tuple[Any, ...] = present
    current = base_score
    changes = 0
    gain_threshold = gain_t_threshold(blocks, len(pool))
    if base_significant.any() or judged:
        # Judged against a noise model, the ladder is tried whatever the base's excess: bias wander
        # makes that excess a poor gate; each step must beat the blocks' own spread instead.
        while changes < max_ladder and (judged or significant_axes(current).any()):
            step = rank(current, model_specs)
            if first_step is None:
                first_step = step
                skipped = dict(step.skipped)
            admissible = [item for item in step.ranked if item[0].effect not in step.refused]
            if not admissible:
                break
            best, best_score, best_model = admissible[0]
            if best.explained < MIN_STEP_FRACTION or best.significance < SIGNIFICANCE_SIGMAS:
                break
            if judged and summed_block_t(current, best_score, floor) < gain_threshold:
                break
            added_spec = best_model[-1] if len(best_model) > len(model_specs) else None
            form = _per_axis_of(added_spec) if per_axis and added_spec is not None else None
            if form is not None:
                # The per-axis form costs parameters: it takes the rung only when held-out
                # blocks prefer it by more than noise and the blocks' own spread could.
                alternative = _replaced(best_model, added_spec, form)
                form_score = score(alternative, best_score)
                if form_score.ok:
                    preferred, text = per_axis_evidence(best_score, form_score)
                    per_axis_tried.append((changes, candidate_of(form.name, form, current, form_score,
                                                                 f'In place of {_effect_name(added_spec)}: {text}')))
                    if preferred:
                        best_model, best_score = alternative, form_score
            model_specs, current = best_model, best_score
            changes += 1

    # Backward: an effect that the ladder took early may have stood in for two others taken
    # later (a lag mimics part of a warm-up and of a hysteresis); drop every added effect
    # whose removal the held-out blocks do not notice.
    pruned: list[str] = []
    while True:
        added_now = [spec for spec in model_specs if spec not in present]
        if len(model_specs) - len(present) < 2 or len(added_now) < 2:
            break
        trials = []
        for spec in added_now:
            without = tuple(s for s in model_specs if s is not spec)
            trial = score(without, current)
            if trial.ok:
                trials.append((trial.excess(floor) - current.excess(floor), _effect_name(spec), without, trial))
        if not trials:
            break
        loss, name, without, trial = min(trials, key=lambda item: item[0])
        excess_without = trial.excess(floor)
        share = loss / excess_without if excess_without > 0.0 else 0.0
        if loss >= SIGNIFICANCE_SIGMAS * sigma_total(current) and share >= MIN_STEP_FRACTION:
            break
        pruned.append(name)
        model_specs, current = without, trial

    # The effects the final model adds or upgrades, in the order of their single merit.
    first_rank = {item[0].effect: index for index, item in enumerate(first_step.ranked)} if first_step else {}

    def merit(spec: Any) -> int:
        name = _effect_name(spec)
        shared = _shared_form(spec)
        options = [first_rank.get(name, len(first_rank))]
        if shared is not None:
            options.append(first_rank.get(_effect_name(shared), len(first_rank)))
        return min(options)

    changed_specs = sorted((spec for spec in model_specs if spec not in present), key=merit)
    rung_models: list[tuple[str, tuple[Any, ...]]] = [('', present)]
    for spec in changed_specs:
        shared = _shared_form(spec)
        specs_below = rung_models[-1][1]
        rung_models.append((_effect_name(spec), _replaced(specs_below, shared, spec) if shared in specs_below
                            else (*specs_below, spec)))
    # The rungs are judged on whole thermal excursions the fit never saw (or a second record's):
    # the first that does not hold there ends the ladder.
    excursion_verdict = None
    after_temperature = '' if unit == 'counts' else ' C'  # after a temperature in the excursions' lines
    if excursions and groups is None:
        if len(rung_models) > 1:
            say('the ladder on held-out excursions')
        judged_on = _held_out_like(held_out, cv_samples, bins is not None, averaging_s, max_cv_samples)
        whitened = whiten is not None and judged_on is None
        excursion_verdict = judge_ladder(cv_samples, rung_models, settings, floor, held_out=judged_on,
                                         temperature_unit=after_temperature,
                                         noise=sensor_noise(None if whitened else noise, white_floor, period,
                                                            sample_period(judged_on if judged_on is not None
                                                                          else cv_samples),
                                                            float(samples.time_s[-1]) if len(samples) else 1.0,
                                                            averaged=bins is not None),
                                         whiten=whiten if whitened else None)
        if excursion_verdict.can_judge and excursion_verdict.models != tuple(rung_models[1:]):
            # The rungs that hold, a narrowed one's held form in place of its effect.
            rung_models = [rung_models[0], *excursion_verdict.models]
            changed_specs = [next(spec for spec in specs if not any(spec is other for other in below))
                             for (_, below), (_, specs) in zip(rung_models, rung_models[1:])]
            model_specs = rung_models[-1][1]
            current = score(model_specs, base_score)
            narrowed = {rung.narrowed_to for rung in excursion_verdict.rungs if rung.narrowed_to}
            for spec, (_, below), (name, specs) in zip(changed_specs, rung_models, rung_models[1:]):
                if name not in narrowed:
                    continue
                below_score = score(below, base_score)
                held_score = score(specs, below_score)
                if held_score.ok:
                    held_tried.append(candidate_of(name, spec, below_score, held_score,
                                                   f'In place of {held_of(spec).name} (held at zero where its fit '
                                                   f'cannot tell it from zero): '))
    ladder = [_rung(base_score)]
    for _, rung_specs in rung_models[1:]:
        rung_score = score(rung_specs, base_score)
        if rung_score.ok:
            ladder.append(_rung(rung_score))
    added = tuple(changed_specs)

    verdict = VERDICT_NONE if not base_significant.any() else VERDICT_UNEXPLAINED
    base_excess = base_score.excess(floor)
    explained_total = (base_excess - current.excess(floor)) / base_excess if base_excess > 0.0 else 0.0
    if added and (explained_total >= MIN_TOTAL_FRACTION or judged):
        verdict = _effect_name(added[0])

    calibration_after = None
    residual_after = None
    parameters: dict[str, float] = {}
    unresolved: dict[str, str] = {}
    if added:
        say('refit with ' + ', '.join(_effect_name(e) for e in added))
        try:
            result = fit_with(cv_samples, model_specs, settings, errors=True)
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
    allan: tuple[tuple[str, AllanCheck], ...] = ()
    if noise is not None:
        allan = _rung_allan(samples, cv_samples, ladder, model_specs, present, residual, residual_after, settings,
                            noise, white_floor, period)
    final_allan = allan[-1][1] if allan else None
    if judged and final_allan is not None and verdict in (VERDICT_NONE, VERDICT_UNEXPLAINED):
        verdict = VERDICT_NONE if final_allan.consistent else VERDICT_UNEXPLAINED
    wander = False
    if (not judged and allan and verdict == VERDICT_UNEXPLAINED and not (added and _effect_name(added[0]) in unresolved)
            and wander_explains(allan[0][1])):
        # No effect is named and the excess over the white floor is what this run's own
        # short-term noise model predicts at every averaging time, those beyond its fit included.
        verdict, wander, final_allan = VERDICT_NONE, True, allan[0][1]
    elif not judged and allan and verdict == VERDICT_UNEXPLAINED:
        final_allan = allan[0][1]  # no effect is named: the calibration as given is what remains

    ranked = [item[0] for item in first_step.ranked] if first_step is not None else []
    for candidate in (*(candidate for _, candidate in per_axis_tried), *held_tried):
        # A per-axis form tried in place of a shared form that joined the ladder (or a held form in
        # place of an effect refused on held-out excursions) is listed with the candidates when it is
        # the verdict; the per-axis ones are all in ``per_axis_forms``.
        if candidate.effect not in {r.effect for r in ranked} and candidate.effect == verdict:
            ranked.append(candidate)
    candidates_out = []
    for candidate in ranked:
        if candidate.effect == verdict and parameters:
            own = {key.split('.', 1)[1]: value for key, value in parameters.items()
                   if key.split('.', 1)[0] == candidate.effect}
            text = ', '.join(f'{key} {value:.4g}' for key, value in own.items())
            candidate = replace(candidate, parameters=own,
                                evidence=candidate.evidence + (f' Fitted: {text}.' if text else ''))
        candidates_out.append(candidate)

    statements = _verdict_message(verdict, axes, ladder, candidates_out, drivers, base_drivers,
                                  significant_axes(current), explained_total, unresolved,
                                  allan=final_allan, judged=judged, averaging_s=averaging_s if judged else 0.0,
                                  wander=wander, unit=unit, scale=unit_scale)
    if excursion_verdict is not None:
        statements = excursion_statements(statements, excursion_verdict, after_temperature)
    if pruned and verdict not in (VERDICT_NONE, VERDICT_UNEXPLAINED):
        statements.append(Statement(f'Not needed once the others are in: {", ".join(pruned)} (held-out blocks do '
                                    f'not notice its removal).'))
    # The first sample's time after the record's start (the steps' moments count from the record's start).
    offset_s = float(samples.stamp_s[0]) - (float(samples.stamp_s[0]) if start_s is None else float(start_s))
    if steps:
        statements = step_statements(statements, steps, views, final_residual, unit=unit, scale=unit_scale,
                                     temperature_unit=temperature_unit, named=Step.name in parameters_names(added),
                                     offset_s=offset_s)
    return Diagnosis(verdict=verdict, message=message_text(statements), axes=axes,  # type: ignore[arg-type]
                     statements=tuple(statements),
                     candidates=tuple(candidates_out), skipped=skipped, ladder=tuple(ladder), drivers=drivers,
                     base_drivers=base_drivers,
                     residual=residual, residual_after=residual_after, calibration=calibration,
                     calibration_after=calibration_after, views=views, folds=folds,
                     blocks=int(block_index(labels)[-1]) + 1,
                     cv_stride=stride, present_effects=present_names, explained=float(explained_total),
                     unresolved=unresolved, pruned=tuple(pruned),
                     per_axis_forms=tuple(candidate for _, candidate in per_axis_tried),
                     noise=noise, allan=allan, averaging_time_s=float(averaging_s) if judged else 0.0,
                     yardstick_replicates=yardstick.replicates if yardstick is not None else 0,
                     steps=steps, steps_offset_s=offset_s,
                     excursions=excursion_verdict)


def parameters_names(specs: Sequence[Any]) -> set[str]:
    """The names of effect specs."""
    return {_effect_name(spec) for spec in specs}
