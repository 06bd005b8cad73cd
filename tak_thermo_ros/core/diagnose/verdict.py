"""The verdict: the rule that names an effect, ``'none'`` or ``'unexplained'``, and its messages."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from tak_thermo_ros.core.diagnose.values import AxisSummary, Candidate, Driver, LadderStep, ModelScore, step_time_s
from tak_thermo_ros.core.diagnose.yardstick import tau_text
from tak_thermo_ros.core.noise.residual import RESIDUAL_LONGEST_TAU_S
from tak_thermo_ros.core.link.model import AXES
from tak_thermo_ros.core.values import random_walk_unit

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
PER_AXIS_ALPHA = 0.01
"""A per-axis form replaces its shared form only when, on at least one axis, the paired t over
the held-out time blocks (:func:`~tak_thermo_ros.core.diagnose.crossval.paired_block_t`) lies
beyond the one-sided quantile ``1 - PER_AXIS_ALPHA / 3`` of Student's t with ``blocks - 1``
degrees of freedom: a 1 % chance over the three axes that a per-axis form that gains nothing
is taken (t 3.05 with 20 blocks)."""


def student_t_quantile(probability: float, dof: int) -> float:
    """Quantile of Student's t distribution with ``dof`` degrees of freedom (``scipy.stats.t.ppf``)."""
    from scipy.stats import t as student_t
    return float(student_t.ppf(probability, dof))


@functools.lru_cache(maxsize=16)
def per_axis_t_threshold(blocks: int) -> float:
    """The paired-t threshold of :data:`PER_AXIS_ALPHA` for ``blocks`` held-out time blocks."""
    return student_t_quantile(1.0 - PER_AXIS_ALPHA / 3.0, max(blocks - 1, 1))


GAIN_ALPHA = 0.02
"""Judged against a noise model, an effect joins the ladder only when the paired t of its
held-out gain over the time blocks (summed over the axes,
:func:`~tak_thermo_ros.core.diagnose.crossval.summed_block_t`) lies beyond the one-sided quantile
``1 - GAIN_ALPHA / candidates`` of Student's t with ``blocks - 1`` degrees of freedom: bias
wander moves the held-out error of every model from block to block, and an effect that only
absorbs some wander gains on a few blocks and loses on others (2 % over the candidates tried)."""


@functools.lru_cache(maxsize=64)
def gain_t_threshold(blocks: int, candidates: int) -> float:
    """The paired-t threshold of :data:`GAIN_ALPHA` for ``blocks`` time blocks and ``candidates`` effects."""
    return student_t_quantile(1.0 - GAIN_ALPHA / max(candidates, 1), max(blocks - 1, 1))


def _noise_sigma(floor_differences: int, heldout_samples: float) -> float:
    """Standard error of ``heldout_mse / floor^2`` for one axis of pure white noise."""
    return math.sqrt(2.0 / max(heldout_samples, 1.0) + 3.0 / max(floor_differences, 1))


def _paired_sigma(floor_differences: int, heldout_samples: float) -> float:
    """Standard error of ``heldout_mse / floor^2`` less that of a simulated copy of the run.

    The copy has white noise at the floor (:func:`~tak_thermo_ros.core.diagnose.crossval.null_heldout`):
    both held-out means carry their own noise (``2 / n`` each), the floor estimate its own (``3 / m``).
    """
    return math.sqrt(4.0 / max(heldout_samples, 1.0) + 3.0 / max(floor_differences, 1))


def rms_text(value: float) -> str:
    """An RMS in a message: two decimals for codes, three digits for a driver's small SI values."""
    return f'{value:.2f}' if abs(value) >= 0.1 else f'{value:.3g}'


def _describe_rms(before: np.ndarray, after: np.ndarray) -> str:
    return ', '.join(f'{name} {rms_text(b)}->{rms_text(a)}' for name, b, a in zip(AXES, before, after))


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


@dataclass(frozen=True)
class Statement:
    """One sentence of a verdict's message; ``detail``: printed with ``--verbose`` only (the JSON holds all)."""

    text: str
    detail: bool = False


def message_text(statements: Sequence[Statement]) -> str:
    """The statements as one paragraph (the JSON's and the report's ``message``)."""
    return ' '.join(statement.text for statement in statements)


_OWN_MODEL = ('No noise model was given (--noise, --noise-run): the one here is white noise and bias '
              'instability fitted to this run\'s own residual at averaging times up to half a minute, where '
              'no thermal effect acts')


def _walk_statements(allan: Any, unit: str, scale: float) -> list[Statement]:
    """The rate random walk that would explain an excess over a short-term model, with its unit, and what to do."""
    walk = ' '.join(f'{value * scale:.2g}' for value in allan.walk_to_explain(RESIDUAL_LONGEST_TAU_S))
    return [Statement(f'The sensor\'s own rate random walk, which half a minute does not show, would explain the '
                      f'excess only if it were at least {walk} (x y z, {random_walk_unit(unit)}).'),
            Statement('If the part\'s data sheet or a static run at constant temperature (--noise-run BAG) gives '
                      'less, the cause is not in the bag; if as much, it is the sensor\'s own noise (give that '
                      'model with --noise imu.yaml to judge it).', detail=True)]


def _wander_statements(allan: Any, unit: str, scale: float, *, excess_said: bool = False) -> list[Statement]:
    """What a noise model fitted to the run's own residual can and cannot say.

    ``excess_said``: the message already names the excess over it (not repeated).
    """
    tau, axis, ratio = allan.worst()
    if allan.consistent:
        return [Statement(f'{_OWN_MODEL}; what remains is consistent with it at every averaging time (Allan '
                          f'deviation at most {ratio:.3g}x it, at tau {tau_text(tau)} on {AXES[axis]}).', detail=True),
                Statement('This run alone cannot tell the sensor\'s own bias wander from a cause that is not in '
                          'the bag: give the sensor\'s noise model (--noise imu.yaml) or a static run at constant '
                          'temperature (--noise-run BAG) to judge it.', detail=True)]
    against = '' if excess_said else f'; against it, {allan.describe()}, beyond its bound {allan.worst_bound():.3g}x'
    return [Statement(f'{_OWN_MODEL}{against}.', detail=excess_said), *_walk_statements(allan, unit, scale)]


def _wander_none_statements(allan: Any, ratios: str) -> list[Statement]:
    """``none`` because the excess over the white floor is this run's own bias wander."""
    tau, axis, ratio = allan.worst()
    return [Statement('The residual is consistent with this sensor\'s own noise at every averaging time: bias '
                      'wander, which no temperature model can or should follow; no structure left for an effect '
                      'to explain.'),
            Statement(f'It stands above the white floor ({ratios}) and no library effect explains that on '
                      f'held-out blocks; its Allan deviation stays within the bound of a noise model fitted to '
                      f'this run\'s residual at averaging times up to half a minute (white noise and bias '
                      f'instability, where no thermal effect acts), up to tau {tau_text(float(allan.taus.max()))} '
                      f'(at most {ratio:.3g}x the model, at tau {tau_text(tau)} on {AXES[axis]}).'),
            Statement('The noise model comes from this run itself: give the sensor\'s noise model (--noise '
                      'imu.yaml) or a static run at constant temperature (--noise-run BAG) to judge the residual '
                      'against an independent one.', detail=True)]


def _unexplained_statements(drivers: Sequence[Driver], *, judged: bool = False,
                            lead_in: str = 'The residual still follows') -> list[Statement]:
    """What a residual that no library effect explains still follows, and what that suggests.

    Called only when no library effect explains the structure: the temperature effects (a
    spline in ``N_t``, a lag, hysteresis, warm-up) have then failed on held-out blocks, which is
    the evidence that a residual sorted by time is not a function of temperature or its history.
    """
    by_name = {d.name: d for d in drivers}
    lead = drivers[0]
    found = [Statement(f'{lead_in} {_driver_sentence(drivers)}.')]
    look = ('look for a quantity that is not in the bag (supply voltage, humidity, mechanical stress, a '
            'reference that moves)')
    if lead.name in ('time', 'time at fixed temperature') and judged:
        found.append(Statement(f'It is a drift in time beyond the bias wander the noise model predicts, that no '
                               f'function of the temperature code or of its history in the library predicts on '
                               f'held-out time blocks: {look}.'))
    elif lead.name in ('time', 'time at fixed temperature'):
        found.append(Statement(f'It is a slow drift in time that no function of the temperature code or of its '
                               f'history in the library predicts on held-out time blocks: {look}.'))
        code = by_name['temperature code'].largest
        if code > 0.2:
            found.append(Statement(f'The temperature code sorts {_percent(code)} of it as well, because temperature '
                                   f'and time move together over parts of the run; yet no function of temperature '
                                   f'predicts it on held-out blocks. A run that holds one temperature for hours '
                                   f'would show the drift alone.', detail=True))
    elif lead.name in ('temperature rate', 'heating vs cooling'):
        found.append(Statement('It follows the temperature history, but neither the library lag nor its '
                               'hysteresis models it: consider a user-defined effect (docs/effects.md).'))
    elif lead.name == 'temperature code':
        found.append(Statement('It follows the temperature code in a way neither the power series nor the spline '
                               'of temperature_shape predicts on held-out blocks: try higher orders '
                               '(--bias-order, --scale-order).'))
    elif lead.name in ('own input', 'other inputs'):
        found.append(Statement('It depends on the input: check the reference stream and the turntable positions.'))
    return found


def _rung(model: ModelScore) -> LadderStep:
    rms = model.heldout_rms
    return LadderStep(label=model.label, effects=model.effects,
                      heldout_rms=(float(rms[0]), float(rms[1]), float(rms[2])))


def _verdict_message(verdict: str, axes: Sequence[AxisSummary], ladder: Sequence[LadderStep],
                     candidates: Sequence[Candidate], drivers: Sequence[Driver],
                     base_drivers: Sequence[Driver], still_significant: np.ndarray,
                     explained_total: float, unresolved: dict[str, str], *, allan: Any = None,
                     judged: bool = False, averaging_s: float = 0.0, wander: bool = False,
                     unit: str = 'counts', scale: float = 1.0) -> list[Statement]:
    """The verdict's message, one statement per sentence, each saying what its numbers say.

    ``unit`` and ``scale``: the residual's unit in the message and the factor to it (a
    magnetometer's tesla in uT: ``'uT'``, 1e6). ``allan``: the Allan test the message speaks of
    (the final rung's, or the calibration's as given when no effect is named).
    """
    ratios = ', '.join(f'{name} {a.heldout_rms / a.noise_floor:.2f}x' for name, a in zip(AXES, axes))
    if judged:
        ratios = f'held-out RMS of {tau_text(averaging_s)} means / the noise model\'s: {ratios}'
    else:
        ratios = f'held-out RMS / floor: {ratios}'

    def rms(values: Sequence[float]) -> str:
        return ', '.join(rms_text(v * scale) for v in values)
    beyond_own = allan is not None and not judged and allan.source == 'residual' and not allan.consistent
    if verdict == VERDICT_NONE:
        if judged:
            tau, axis, ratio = allan.worst()
            found = [Statement(f'The residual is consistent with the noise model ({allan.source}) at every averaging '
                               f'time ({ratios}; Allan deviation at most {ratio:.3g}x the model, at tau '
                               f'{tau_text(tau)} on {AXES[axis]}, within the bound): no structure left for an '
                               f'effect to explain.')]
        elif wander:
            return _wander_none_statements(allan, ratios)
        elif beyond_own:
            # The white floor finds nothing for an effect; the Allan test finds slow structure. Both said.
            found = [Statement(f'No effect to add: the held-out residual is at the white noise floor ({ratios}) and '
                               f'no library effect lowers it.'),
                     Statement(f'Slow structure remains, though: {allan.describe()}, beyond the bound '
                               f'{allan.worst_bound():.3g}x of this run\'s own short-term noise model (white noise '
                               f'and bias instability fitted up to half a minute).'),
                     *_walk_statements(allan, unit, scale)]
        else:
            found = [Statement(f'The residual is at the noise floor ({ratios}): no structure left for an effect to '
                               f'explain.')]
        refit = [] if judged else [name for name, a in zip(AXES, axes) if a.rms > 1.1 * a.heldout_rms]
        if refit:
            found.append(Statement(f'The calibration as given fits this run worse than a refit of the same model '
                                   f'(axes {", ".join(refit)}): refit it on this run.'))
        return found
    if verdict == VERDICT_UNEXPLAINED:
        first = ladder[1].effects[-1] if len(ladder) > 1 else ''
        best: list[Statement]
        if first in unresolved:
            best = [Statement(f'{ladder[-1].label} removes {_percent(explained_total)} of the held-out excess, but '
                              f'the fit of {first} runs to the edge of what this run resolves ({unresolved[first]}): '
                              f'the run does not identify it, so it is not named (a longer run, or longer plateaus, '
                              f'would tell).')]
            follows = [Statement(f'The residual follows {_driver_sentence(base_drivers)}.')]
        elif len(ladder) > 1:
            best = [Statement(f'{ladder[-1].label} removes {_percent(explained_total)} of the held-out excess, '
                              f'too little to name it the cause.')]
            follows = _unexplained_statements(drivers)
        else:
            if candidates and candidates[0].explained > 0.0:
                best = [Statement(f'The best library effect, {candidates[0].effect}, removes only '
                                  f'{_percent(candidates[0].explained)} of the held-out excess.')]
            else:
                best = [Statement('No library effect lowers the held-out error.')]
            follows = _unexplained_statements(base_drivers)
        if judged:
            follows = _unexplained_statements(drivers if len(ladder) > 1 else base_drivers, judged=True)
            return [Statement(f'Significant structure remains beyond the noise model ({allan.source}): '
                              f'{allan.describe()} ({ratios}), which no library effect explains with parameters '
                              f'this run resolves.'), *best, *follows]
        beyond = f' and beyond this run\'s short-term noise model ({allan.describe()})' if beyond_own else ''
        found = [Statement(f'Significant structure remains above the noise floor ({ratios}){beyond} that no library '
                           f'effect explains with parameters this run resolves.'), *best, *follows]
        if allan is not None:
            found += _wander_statements(allan, unit, scale, excess_said=bool(beyond))
        return found
    best_candidate = next((c for c in candidates if c.effect == verdict), candidates[0])
    over = 'over the noise model' if judged else 'over the noise floor'
    found = [Statement(f'The model misses {verdict}: it removes {_percent(best_candidate.explained)} of the held-out '
                       f'excess {over} ({ratios} before).'),
             Statement(best_candidate.summary, detail=True)]
    if verdict.endswith('_per_axis'):
        shared = next((c for c in candidates if c.effect == verdict[:-len('_per_axis')]), None)
        if shared is not None:
            found.append(Statement(f'The per-axis form beats the shared {shared.effect} on held-out blocks (held-out '
                                   f'RMS {rms(shared.rms_after)} shared, {rms(best_candidate.rms_after)} per axis).'))
    if len(ladder) > 2:
        found.append(Statement('Then: ' + ', '.join(step.effects[-1] for step in ladder[2:])
                               + f' ({_percent(explained_total)} of the excess in all).'))
    for name, edges in unresolved.items():
        found.append(Statement(f'The fit of {name} runs to the edge of what this run resolves ({edges}).'))
    if still_significant.any():
        found += _unexplained_statements(
            drivers, judged=judged,
            lead_in=f'Structure remains on {", ".join(n for n, s in zip(AXES, still_significant) if s)}: the residual '
                    f'still follows')
    own = allan is not None and allan.source == 'residual'
    if own and still_significant.any():
        found += _wander_statements(allan, unit, scale)
    elif allan is not None and not allan.consistent:
        # Held-out blocks find nothing more (or the structure is said above), the Allan test finds this: said too.
        model = 'this run\'s own short-term noise model' if own else f'the noise model ({allan.source})'
        found.append(Statement(f'Slow structure remains after it, though: {allan.describe()}, beyond the bound '
                               f'{allan.worst_bound():.3g}x of {model}.'))
        if own:
            found += _walk_statements(allan, unit, scale)
    return found


DRIFT_OPENINGS = ('It is a slow drift in time', 'It is a drift in time')
"""How the statement that calls what remains a drift in time begins (:mod:`.verdict`)."""


def step_statements(statements: Sequence[Statement], steps: Sequence[Any], views: Any, residual: np.ndarray, *,
                    unit: str, scale: float, temperature_unit: str, named: bool,
                    offset_s: float = 0.0) -> list[Statement]:
    """The verdict's statements with each step named before any word on a slow drift.

    A drift statement stays only when the residual, its steps' levels taken out, still follows
    time first (then it speaks of what is left besides the steps). ``offset_s``: the first sample's
    time after the record's start (the moments are said from the record's start).
    """
    from tak_thermo_ros.core.diagnose.views import residual_drivers
    texts = []
    levelled = np.array(residual, dtype=float, copy=True)
    for step in steps:
        if not named:
            levelled[step.index:] -= step.amplitude
        moment = step_time_s(views, step, offset_s)
        code = float(views.temp_code[step.index])
        where = f'{code:.1f} C' if temperature_unit == 'C' else (
            f'{code:.4g} {temperature_unit}' if temperature_unit else f'temperature code {code:.0f}')
        changes = ', '.join(f'{AXES[c]} {float(step.amplitude[c]) * scale:+.3g} {unit} ({abs(float(step.z[c])):.0f} '
                            f'sigmas)' for c in step.named)
        texts.append(f'a step at {moment / 60.0:.2f} min ({where}): {changes}')
    fix = '' if named else ' (fit --effects step fits the largest)'
    said = [Statement(f'The residual steps: {"; ".join(texts)}. A sudden change of level that holds, against the '
                      f'record\'s own level changes at that time scale: not a slow drift{fix}.')]
    still_drifts = residual_drivers(levelled, views)[0].name in ('time', 'time at fixed temperature')
    out: list[Statement] = []
    placed = False
    for statement in statements:
        if statement.text.startswith(DRIFT_OPENINGS) and not placed:
            out += said
            placed = True
            if still_drifts:
                out.append(Statement('Besides the steps: ' + statement.text[0].lower() + statement.text[1:],
                                     statement.detail))
            continue
        out.append(statement)
    if not placed:
        out[1:1] = said
    return out
