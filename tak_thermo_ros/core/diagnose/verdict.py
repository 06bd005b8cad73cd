"""The verdict: the rule that names an effect, ``'none'`` or ``'unexplained'``, and its messages."""

from __future__ import annotations

import functools
import math
from typing import Any, Sequence

import numpy as np

from tak_thermo_ros.core.diagnose.values import AxisSummary, Candidate, Driver, LadderStep, ModelScore
from tak_thermo_ros.core.diagnose.yardstick import tau_text
from tak_thermo_ros.core.noise.residual import RESIDUAL_LONGEST_TAU_S
from tak_thermo_ros.core.link.model import AXES

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

    The copy has white noise at the floor (:func:`~tak_thermo_ros.core.diagnose.discover.null_heldout`):
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


def _wander_sentence(allan: Any, *, excess_said: bool = False) -> str:
    """What a noise model fitted to the run's own residual can and cannot say.

    ``excess_said``: the message already names the excess over it (not repeated).
    """
    tau, axis, ratio = allan.worst()
    fitted = ('No noise model was given (--noise, --noise-run): the one here is white noise and bias instability '
              'fitted to this run\'s own residual at averaging times up to half a minute, where no thermal effect '
              'acts')
    if allan.consistent:
        return (f'{fitted}; what remains is consistent with it at every averaging time (Allan deviation at most '
                f'{ratio:.2f}x it, at tau {tau_text(tau)} on {AXES[axis]}). This run alone cannot tell the sensor\'s '
                f'own bias wander from a cause that is not in the bag: give the sensor\'s noise model (--noise '
                f'imu.yaml) or a static run at constant temperature (--noise-run BAG) to judge it.')
    walk = ' '.join(f'{value:.2g}' for value in allan.walk_to_explain(RESIDUAL_LONGEST_TAU_S))
    against = '' if excess_said else f'; against it, {allan.describe()}'
    return (f'{fitted}{against}. The sensor\'s own rate random walk, which half a minute '
            f'does not show, would explain the excess only if it were at least {walk} (x y z, in the residual\'s unit '
            f'times sqrt(Hz)): if the part\'s data sheet or a static run at constant temperature (--noise-run BAG) '
            f'gives less, the cause is not in the bag; if as much, it is the sensor\'s own noise (give that model '
            f'with --noise imu.yaml to judge it).')


def _wander_none_text(allan: Any, ratios: str) -> str:
    """``none`` because the excess over the white floor is this run's own bias wander."""
    tau, axis, ratio = allan.worst()
    return (f'The residual is consistent with this sensor\'s own noise at every averaging time: it stands above '
            f'the white floor ({ratios}), no library effect explains that on held-out blocks, and its Allan '
            f'deviation stays within the bound of a noise model fitted to this run\'s residual at averaging '
            f'times up to half a minute (white noise and bias instability, where no thermal effect acts), '
            f'up to tau {tau_text(float(allan.taus.max()))} (at most {ratio:.2f}x the model, at tau {tau_text(tau)} '
            f'on {AXES[axis]}): bias wander, which no temperature model can or should follow; no structure left '
            f'for an effect to explain. The noise model comes from this run itself: give the sensor\'s noise '
            f'model (--noise imu.yaml) or a static run at constant temperature (--noise-run BAG) to judge the '
            f'residual against an independent one.')


def _unexplained_sentence(drivers: Sequence[Driver], *, judged: bool = False) -> str:
    """What a residual that no library effect explains still follows, and what that suggests.

    Called only when no library effect explains the structure: the temperature effects (a
    spline in ``N_t``, a lag, hysteresis, warm-up) have then failed on held-out blocks, which is
    the evidence that a residual sorted by time is not a function of temperature or its history.
    """
    by_name = {d.name: d for d in drivers}
    lead = drivers[0]
    text = f'the residual still follows {_driver_sentence(drivers)}'
    if lead.name in ('time', 'time at fixed temperature') and judged:
        text += ('; it is a drift in time beyond the bias wander the noise model predicts, that no function of '
                 'the temperature code or of its history in the library predicts on held-out time blocks: look for '
                 'a quantity that is not in the bag (supply voltage, humidity, mechanical stress, a reference that '
                 'moves)')
    elif lead.name in ('time', 'time at fixed temperature'):
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


def _verdict_message(verdict: str, axes: Sequence[AxisSummary], ladder: Sequence[LadderStep],
                     candidates: Sequence[Candidate], drivers: Sequence[Driver],
                     base_drivers: Sequence[Driver], still_significant: np.ndarray,
                     explained_total: float, unresolved: dict[str, str], *, allan: Any = None,
                     judged: bool = False, averaging_s: float = 0.0, wander: bool = False) -> str:
    ratios = ', '.join(f'{name} {a.heldout_rms / a.noise_floor:.2f}x' for name, a in zip(AXES, axes))
    if judged:
        ratios = f'held-out RMS of {tau_text(averaging_s)} means / the noise model\'s: {ratios}'
    else:
        ratios = f'held-out RMS / floor: {ratios}'
    if verdict == VERDICT_NONE:
        if judged:
            tau, axis, ratio = allan.worst()
            text = (f'The residual is consistent with the noise model ({allan.source}) at every averaging time '
                    f'({ratios}; Allan deviation at most {ratio:.2f}x the model, at tau {tau_text(tau)} on '
                    f'{AXES[axis]}, within the bound): no structure left for an effect to explain.')
        elif wander:
            return _wander_none_text(allan, ratios)
        else:
            text = f'The residual is at the noise floor ({ratios}): no structure left for an effect to explain.'

        refit = [] if judged else [name for name, a in zip(AXES, axes) if a.rms > 1.1 * a.heldout_rms]
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
        if judged:
            follows = _unexplained_sentence(drivers if len(ladder) > 1 else base_drivers, judged=True)
            return (f'Significant structure remains beyond the noise model ({allan.source}): '
                    f'{allan.describe()} ({ratios}), which no library effect explains with parameters this run '
                    f'resolves.{best} {follows[0].upper()}{follows[1:]}.')
        beyond = ''
        if allan is not None and allan.source == 'residual' and not allan.consistent:
            beyond = f' and beyond this run\'s short-term noise model ({allan.describe()})'
        text = (f'Significant structure remains above the noise floor ({ratios}){beyond} '
                f'that no library effect explains with parameters this run resolves.{best} '
                f'{follows[0].upper()}{follows[1:]}.')
        if allan is not None:
            text += f' {_wander_sentence(allan, excess_said=bool(beyond))}'
        return text
    best = next((c for c in candidates if c.effect == verdict), candidates[0])
    over = 'over the noise model' if judged else 'over the noise floor'
    text = (f'The model misses {verdict}: it removes {_percent(best.explained)} of the held-out excess '
            f'{over} ({ratios} before). {best.summary}')
    if verdict.endswith('_per_axis'):
        shared = next((c for c in candidates if c.effect == verdict[:-len('_per_axis')]), None)
        if shared is not None:
            text += (f' The per-axis form beats the shared {shared.effect} on held-out blocks '
                     f'(held-out RMS {", ".join(rms_text(v) for v in shared.rms_after)} shared, '
                     f'{", ".join(rms_text(v) for v in best.rms_after)} per axis).')
    if len(ladder) > 2:
        text += (' Then: ' + ', '.join(step.effects[-1] for step in ladder[2:])
                 + f' ({_percent(explained_total)} of the excess in all).')
    for name, edges in unresolved.items():
        text += f' The fit of {name} runs to the edge of what this run resolves ({edges}).'
    if still_significant.any():
        text += (f' Structure remains on {", ".join(n for n, s in zip(AXES, still_significant) if s)}: '
                 f'{_unexplained_sentence(drivers, judged=judged)}.')
        if allan is not None and allan.source == 'residual':
            text += f' {_wander_sentence(allan)}'
    return text
