"""The sensor's noise model as the verdict's yardstick.

A real MEMS sensor's bias wanders (bias instability) and walks (random walk): its residual after
a perfect thermal model is not white. With a noise model of the sensor (a data sheet or Kalibr
file, or a static run at constant temperature), :func:`~tak_thermo_ros.core.diagnose.diagnose`
judges the residual against it:

1. **Averaging time** (:func:`averaging_time`): the cross-validation works on means of the
   residual over bins of ``tau_b`` seconds, the averaging time at which the noise model's Allan
   deviation is lowest (its bias-instability time), at most a tenth of a held-out block. White
   noise falls as ``1/sqrt(tau_b)`` there, while a thermal effect, slow by nature, stays: a lag
   far below the per-sample noise stands out at 30 s.
2. **The null under the noise model** (:func:`null_under_noise`): the model is fitted to the run,
   and :data:`NULL_REPLICATES` copies of its prediction with simulated noise (white at the
   measured floor, the noise model's bias instability and random walk) are cross-validated like
   the run. Their mean held-out mean square is the yardstick (what a complete model leaves on
   this run, bias wander and the error of parameters fitted without the held-out block included);
   their spread is the noise of that yardstick. The ladder's rules (excess, share explained,
   significance) then apply unchanged with this yardstick in place of the white floor.
3. **Allan deviation against the model** (:func:`allan_check`): the overlapping Allan deviation
   of the residual at octave averaging times, against the noise model's prediction, with
   chi-square bounds on its equivalent degrees of freedom (a family-wise :data:`ALLAN_ALPHA`
   over averaging times and axes) and the noise model's own uncertainty
   (:data:`MODEL_TOLERANCE`). ``none`` needs the residual inside the bounds at every averaging
   time; an ``unexplained`` verdict names the averaging time and the excess.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from tak_thermo_ros.core.link.model import AXES
from tak_thermo_ros.core.noise.residual import RESIDUAL_LONGEST_TAU_S
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.errors import TakError

NULL_REPLICATES = 8
"""Simulated copies of the run under the noise model whose held-out score is the yardstick."""
ALLAN_ALPHA = 0.01
"""Family-wise false-alarm probability of the Allan test over its averaging times and axes."""
MODEL_TOLERANCE = 1.25
"""A noise model from a data sheet or a static run is known to about 25 % in Allan deviation
(a static run of an hour pins the bias instability to 10-20 %, a data sheet gives typical
values): the residual's Allan deviation must exceed the model's by this factor besides the
chi-square bound of its own estimate."""
BINS_PER_BLOCK = 10
"""The averaging bins are at most a tenth of a held-out time block long."""
MIN_BIN_FILL = 0.5
"""A bin cut short by a turntable move or a gap is kept when it holds at least this share of
the samples a full bin holds."""


# ------------------------------------------------------------------------------- the model

def _triple(values: Any) -> np.ndarray:
    array = np.asarray(values, dtype=float).reshape(-1)
    return np.broadcast_to(array, (3,)).astype(float) if array.size in (1, 3) else array[:3]


def wander_avar(noise: Any, taus: np.ndarray) -> np.ndarray:
    """``(t, 3)`` the Allan variance of the noise model without its white and quantisation terms.

    The white part of the residual is measured on the run itself (successive differences);
    the noise model supplies what white noise does not: bias instability, random walk, ramp,
    Gauss-Markov processes.
    """
    taus = np.asarray(taus, dtype=float)
    if hasattr(noise, 'wander_allan_variance'):
        return np.asarray(noise.wander_allan_variance(taus), dtype=float).reshape(len(taus), -1)
    full = np.asarray(noise.allan_deviation(taus), dtype=float) ** 2
    full = full.reshape(len(taus), -1)
    white = _triple(noise.white_noise_density) ** 2 / taus[:, None]
    quantization = _triple(getattr(noise, 'quantization', 0.0)) ** 2 * 3.0 / taus[:, None] ** 2
    return np.maximum(full - white - quantization, 0.0)


def predicted_avar(noise: Any, taus: np.ndarray, white_floor: np.ndarray, sample_period_s: float) -> np.ndarray:
    """``(t, 3)`` Allan variance of the residual the noise model predicts.

    The measured white floor (per sample) averaged over ``tau``, plus the model's bias instability
    and random walk.
    """
    taus = np.asarray(taus, dtype=float)
    white = (np.asarray(white_floor, dtype=float) ** 2)[None, :] * sample_period_s / taus[:, None]
    return white + wander_avar(noise, taus)


def averaging_time(noise: Any, white_floor: np.ndarray, sample_period_s: float, block_s: float) -> float:
    """The verdict's averaging time ``tau_b``.

    Where the predicted Allan deviation is lowest (summed over the axes in units of each axis'
    minimum), between one sample and a tenth of a held-out block (:data:`BINS_PER_BLOCK`).
    """
    longest = block_s / BINS_PER_BLOCK
    if longest <= sample_period_s:
        return sample_period_s
    taus = np.geomspace(sample_period_s, longest, 40)
    adev = np.sqrt(predicted_avar(noise, taus, white_floor, sample_period_s))
    scaled = np.sum(adev / np.maximum(adev.min(axis=0), 1e-300), axis=1)
    return float(taus[int(np.argmin(scaled))])


# ------------------------------------------------------------------------------------ bins

def bin_labels(time_s: np.ndarray, breaks: np.ndarray, tau_s: float, sample_period_s: float) -> np.ndarray:
    """``(k,)`` averaging bin of each sample (0, 1, ...), ``-1`` for samples left out.

    Bins are ``tau_s`` long, start again at every segment break (a turntable move, a gap), and
    a bin with fewer than :data:`MIN_BIN_FILL` of a full bin's samples is left out.
    """
    count = len(time_s)
    segment = np.cumsum(np.asarray(breaks, dtype=bool)) - 1 if count else np.zeros(0, dtype=np.int64)
    starts = np.flatnonzero(breaks) if count else np.zeros(0, dtype=np.int64)
    offset = time_s - time_s[starts][segment] if count else time_s
    within = np.floor(offset / tau_s + 1e-9).astype(np.int64)
    key = segment * (int(within.max(initial=0)) + 1) + within
    _, raw = np.unique(key, return_inverse=True)
    raw = raw.reshape(-1)
    sizes = np.bincount(raw)
    full = max(tau_s / sample_period_s, 1.0)
    kept = sizes >= MIN_BIN_FILL * full
    renumber = np.full(len(sizes), -1, dtype=np.int64)
    renumber[kept] = np.arange(int(np.count_nonzero(kept)))
    return renumber[raw]


def bin_means(values: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Means of ``values`` (``(k,)`` or ``(k, n)``) per bin of ``labels`` (``-1`` left out)."""
    values = np.asarray(values, dtype=float)
    keep = labels >= 0
    bins = int(labels.max(initial=-1)) + 1
    counts = np.maximum(np.bincount(labels[keep], minlength=bins), 1)
    if values.ndim == 1:
        return np.bincount(labels[keep], weights=values[keep], minlength=bins) / counts
    return np.column_stack([np.bincount(labels[keep], weights=values[keep, i], minlength=bins) / counts
                            for i in range(values.shape[1])])


def bin_samples(samples: AlignedSamples, labels: np.ndarray) -> AlignedSamples:
    """The run as means over the averaging bins.

    Stamps, codes, temperature, reference and recorded signals averaged (the reference is constant
    inside a bin: bins end at its moves).
    """
    first = samples.stamp_ns[0] if len(samples) else 0
    stamps = first + np.round(bin_means((samples.stamp_ns - first).astype(float), labels)).astype(np.int64)
    reference = None if samples.reference is None else bin_means(samples.reference, labels)
    return AlignedSamples(stamp_ns=stamps, counts=bin_means(samples.counts, labels),
                          temp_code=bin_means(samples.temp_code, labels), reference=reference,
                          dropped=dict(samples.dropped),
                          aux={name: bin_means(values, labels) for name, values in samples.aux.items()})


# ------------------------------------------------------------------------------ whitening

def whitener(noise: Any, time_s: np.ndarray, white_variance: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """The noise model's whitening filter for a residual sampled at ``time_s``.

    A Kalman filter per axis whose state is the sensor's bias (a random walk plus the
    Gauss-Markov process of its bias instability and the model's own Gauss-Markov processes,
    as :func:`simulate_noise` draws them) and
    whose measurement noise is white with ``white_variance`` (``(k, 3)`` or ``(3,)``). Its
    innovations, each divided by its predicted standard deviation and multiplied by the mean
    white standard deviation, are white at that level when the residual is the noise model's
    noise: slow wander the model predicts is followed, structure faster than the wander can
    move is not. The gains depend on the times only and are computed once.

    :returns: a function ``(k, 3) residual -> (k, 3) whitened residual``.
    """
    count = len(time_s)
    variance = np.broadcast_to(np.asarray(white_variance, dtype=float), (count, 3))
    walk = _triple(noise.random_walk) ** 2
    instability = (0.664 / 0.6182 * _triple(noise.bias_instability)) ** 2
    correlation = np.maximum(_triple(getattr(noise, 'bias_instability_tau', 100.0)) / 1.89, 1e-9)
    markov = [(_triple(sigma) ** 2, np.maximum(_triple(time), 1e-9))
              for sigma, time in zip(getattr(noise, 'gauss_markov', ()), getattr(noise, 'gauss_markov_time', ()))]
    if not np.any(walk > 0.0) and not np.any(instability > 0.0) and not any(np.any(v > 0.0) for v, _ in markov):
        return lambda residual: np.asarray(residual, dtype=float)
    duration = float(time_s[-1] - time_s[0]) if count else 0.0
    # State per axis: the walk (starting at zero: the fit takes the mean bias; with the spread it
    # reaches over the run), the bias instability's Gauss-Markov process, the model's own
    # Gauss-Markov processes. Covariances (3, n, n); the measurement is the sum of the states.
    levels = np.column_stack([walk, instability, *(v for v, _ in markov)])
    times = np.column_stack([np.full(3, np.inf), correlation, *(t for _, t in markov)])
    states = levels.shape[1]
    cov = np.zeros((3, states, states))
    cov[:, 0, 0] = walk * max(duration, 1.0)
    for j in range(1, states):
        cov[:, j, j] = levels[:, j]
    gains = np.zeros((count, 3, states))
    scale = np.zeros((count, 3))
    decays = np.ones((count, 3, states))
    for k in range(count):
        step = float(time_s[k] - time_s[k - 1]) if k else 0.0
        decay = np.exp(-step / times)
        decays[k] = decay
        if k:
            cov = cov * decay[:, :, None] * decay[:, None, :]
            cov[:, 0, 0] += walk * step
            for j in range(1, states):
                cov[:, j, j] += levels[:, j] * (1.0 - decay[:, j] ** 2)
        row = cov.sum(axis=1)  # H P with H = (1, ..., 1): each state's covariance with the sum
        predicted = row.sum(axis=1) + variance[k]
        gain = row / predicted[:, None]
        gains[k] = gain
        scale[k] = np.sqrt(predicted)
        # Joseph-free update: P = P - g (H P).
        cov = cov - gain[:, :, None] * row[:, None, :]
    level = np.sqrt(np.mean(variance, axis=0))

    def whiten(residual: np.ndarray) -> np.ndarray:
        residual = np.asarray(residual, dtype=float)
        state = np.zeros((3, states))
        out = np.empty_like(residual)
        for k in range(count):
            state *= decays[k]
            innovation = residual[k] - state.sum(axis=1)
            state += gains[k] * innovation[:, None]
            out[k] = innovation / scale[k] * level
        return out

    return whiten


# ------------------------------------------------------------------------------ simulation

def simulate_noise(noise: Any, count: int, sample_period_s: float, white_floor: np.ndarray,
                   seed: int | list[int], *, longest_s: float = math.inf) -> np.ndarray:
    """``(count, 3)`` a residual that the noise model predicts at a steady sample rate.

    White at the measured floor plus the model's bias instability, random walk and Gauss-Markov
    processes (:func:`~tak_thermo_ros.core.simulation.noise.bias_wander`, the flicker centred on
    the model's bias-instability time, at most ``longest_s``).
    """
    from tak_thermo_ros.core.simulation.noise import bias_wander
    rng = np.random.default_rng(seed)
    white = rng.standard_normal((count, 3)) * np.asarray(white_floor, dtype=float)
    centre = tuple(float(min(max(t, 2.0 * sample_period_s), longest_s)) if math.isfinite(t) else float(longest_s)
                   for t in _triple(noise.bias_instability_tau))
    processes = tuple(zip(getattr(noise, 'gauss_markov', ()), getattr(noise, 'gauss_markov_time', ())))
    markov = tuple(tuple((float(sigma[axis]), float(time[axis])) for sigma, time in processes if sigma[axis] > 0.0)
                   for axis in range(3))
    wander = bias_wander([*np.atleast_1d(seed).tolist(), 1], count, 1.0 / sample_period_s,
                         tuple(float(v) for v in _triple(noise.bias_instability)), centre,  # type: ignore[arg-type]
                         tuple(float(v) for v in _triple(noise.random_walk)), markov)  # type: ignore[arg-type]
    return white + wander


@dataclass(frozen=True)
class NullYardstick:
    """The held-out score of a complete model on copies of the run under the noise model.

    :param floor: ``(3,)`` RMS of the held-out bin means the copies show (the yardstick).
    :param sigma: ``(3,)`` their spread from copy to copy, in units of ``floor^2``.
    :param replicates: copies simulated.
    """

    floor: np.ndarray
    sigma: np.ndarray
    replicates: int


def null_under_noise(samples: AlignedSamples, labels: np.ndarray, cv_samples: AlignedSamples,
                     fold: np.ndarray, effects: Sequence[Any], settings: Any, noise: Any,
                     white_floor: np.ndarray, *, folds: int, replicates: int = NULL_REPLICATES,
                     seed: int = 0, whiten: Callable[[np.ndarray], np.ndarray] | None = None) -> NullYardstick:
    """Cross-validate the model on ``replicates`` copies of the binned run in which it is true.

    :param samples: the run, per sample (the noise is simulated at these stamps, then binned).
    :param labels: ``(k,)`` averaging bin of each sample (:func:`bin_labels`).
    :param cv_samples: the binned run the cross-validation sees.
    :param fold: ``(b,)`` fold of each bin.
    """
    from dataclasses import replace as copy_with

    from tak_thermo_ros.core.diagnose.crossval import _with_range, cross_validate, fit_with
    from tak_thermo_ros.core.link.correction import Corrector
    result = fit_with(cv_samples, effects, settings)
    low, high = float(cv_samples.temp_code.min()), float(cv_samples.temp_code.max())
    predicted = Corrector(_with_range(result.calibration, low, high)).predict_counts(
        cv_samples.reference, cv_samples.temp_code, stamp_s=cv_samples.stamp_s, aux=cv_samples.aux)
    period = float(np.median(np.diff(samples.time_s))) if len(samples) > 1 else 1.0
    duration = float(samples.time_s[-1]) if len(samples) else 1.0
    scores = []
    for replicate in range(replicates):
        simulated = simulate_noise(noise, len(samples), period, white_floor, [seed, replicate],
                                   longest_s=max(duration / 10.0, 2.0 * period))
        residual = bin_means(simulated, labels)
        copy = copy_with(cv_samples, counts=predicted + residual)
        score = cross_validate(copy, tuple(effects), fold, settings, folds=folds, whiten=whiten)
        if score.ok:
            scores.append(score.heldout_rms ** 2)
    if not scores:
        return NullYardstick(floor=np.asarray(white_floor, dtype=float), sigma=np.zeros(3), replicates=0)
    mean_square = np.mean(scores, axis=0)
    spread = np.std(scores, axis=0, ddof=1) if len(scores) > 1 else np.zeros(3)
    # The yardstick's own error (a mean of the copies) adds to the spread of one copy.
    sigma = spread / mean_square * math.sqrt(1.0 + 1.0 / len(scores))
    return NullYardstick(floor=np.sqrt(mean_square), sigma=sigma, replicates=len(scores))


# ------------------------------------------------------------------------------ Allan test

@dataclass(frozen=True)
class AllanCheck:
    """The residual's Allan deviation against the noise model, per averaging time and axis.

    :param taus: ``(t,)`` averaging times, s.
    :param residual_adev: ``(t, 3)`` overlapping Allan deviation of the residual.
    :param model_adev: ``(t, 3)`` what the noise model predicts (measured white floor included).
    :param bound: ``(t, 3)`` the largest ratio residual / model that noise explains.
    :param source: where the noise model comes from (``file``, ``static_run``, ``residual``).
    """

    taus: np.ndarray
    residual_adev: np.ndarray
    model_adev: np.ndarray
    bound: np.ndarray
    source: str

    @property
    def ratio(self) -> np.ndarray:
        """``(t, 3)`` residual Allan deviation over the model's."""
        return self.residual_adev / np.maximum(self.model_adev, 1e-300)

    @property
    def outside(self) -> np.ndarray:
        """``(t, 3)`` True where the residual exceeds the model by more than noise explains."""
        return self.ratio > self.bound

    @property
    def consistent(self) -> bool:
        """Whether the residual is inside the bounds at every averaging time on every axis."""
        return not bool(self.outside.any())

    def worst(self) -> tuple[float, int, float]:
        """``(tau, axis, ratio)`` where the ratio over the bound is largest."""
        if not len(self.taus):
            return 0.0, 0, 1.0
        index = np.unravel_index(int(np.argmax(self.ratio / self.bound)), self.ratio.shape)
        return float(self.taus[index[0]]), int(index[1]), float(self.ratio[index])

    def worst_bound(self) -> float:
        """The bound at :meth:`worst`."""
        if not len(self.taus):
            return 1.0
        index = np.unravel_index(int(np.argmax(self.ratio / self.bound)), self.ratio.shape)
        return float(self.bound[index])

    def summary_lines(self, which: str = '') -> list[str]:
        """The test in words: the worst ratio to the noise model, where, and whether the bound holds it.

        :param which: after which model (``' after the ladder'``), or ``''``.
        """
        if not len(self.taus):
            return ['  Allan deviation: the run is too short to estimate it']
        tau, axis, ratio = self.worst()
        return [f'  residual\'s Allan deviation{which}: at most {ratio:.3g}x the noise model, at tau '
                f'{tau_text(tau)} on {AXES[axis]}',
                f'  {"inside" if self.consistent else "BEYOND"} the bound of {self.worst_bound():.3g}x there '
                f'(what the noise model\'s own scatter allows)']

    def walk_to_explain(self, longer_than_s: float = 0.0) -> np.ndarray:
        """``(3,)`` the least rate random walk that would explain the excess, per axis.

        A random walk of ``K`` adds ``K^2 tau / 3`` to the Allan variance; this is the ``K`` that
        closes the largest gap between the residual and the model at averaging times longer than
        ``longer_than_s`` (zero where the residual stays below the model). In the residual's unit
        times sqrt(Hz).
        """
        longer = self.taus > longer_than_s
        if not longer.any():
            return np.zeros(self.residual_adev.shape[1])
        gap = (self.residual_adev[longer] ** 2 - self.model_adev[longer] ** 2) * 3.0 / self.taus[longer, None]
        return np.sqrt(np.maximum(gap.max(axis=0), 0.0))

    def describe(self) -> str:
        """``'residual Allan deviation 3.14x the noise model at tau 300 s on z'`` (three figures, as the bound)."""
        tau, axis, ratio = self.worst()
        return f'residual Allan deviation {ratio:.3g}x the noise model at tau {tau_text(tau)} on {AXES[axis]}'

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        tau, axis, ratio = self.worst()
        return {'taus': [float(t) for t in self.taus], 'source': self.source, 'consistent': self.consistent,
                'residual_adev': {name: [float(v) for v in self.residual_adev[:, i]] for i, name in enumerate(AXES)},
                'model_adev': {name: [float(v) for v in self.model_adev[:, i]] for i, name in enumerate(AXES)},
                'bound': {name: [float(v) for v in self.bound[:, i]] for i, name in enumerate(AXES)},
                'worst': {'tau_s': tau, 'axis': AXES[axis], 'ratio': ratio}}


def tau_text(tau: float) -> str:
    """An averaging time in a message: ``'0.5 s'``, ``'30 s'``, ``'300 s'``, ``'1.2 h'``."""
    if tau >= 3600.0:
        return f'{tau / 3600.0:.2g} h'
    return f'{tau:.2g} s' if tau < 10.0 else f'{tau:.0f} s'


def allan_check(residual: np.ndarray, sample_period_s: float, noise: Any, white_floor: np.ndarray, *,
                alpha: float = ALLAN_ALPHA, tolerance: float = MODEL_TOLERANCE) -> AllanCheck:
    """The overlapping Allan deviation of a residual at octave averaging times, against the noise model.

    The bound at each averaging time is the upper chi-square quantile of the estimate on its
    equivalent degrees of freedom (:func:`~tak_thermo_ros.core.noise.allan.equivalent_degrees_of_freedom`
    for the noise type that dominates the prediction there: white, flicker or random-walk rate),
    Bonferroni over averaging times and axes, times :data:`MODEL_TOLERANCE` for a model from a
    file or a static run (a model fitted to this very residual needs none). Averaging times up to
    a tenth of the run (at least eight independent averages).
    """
    from scipy.stats import chi2

    from tak_thermo_ros.core.noise.allan import allan_variance, cluster_sizes, equivalent_degrees_of_freedom
    residual = np.asarray(residual, dtype=float)
    clusters = cluster_sizes(len(residual) // 8) if len(residual) >= 16 else np.zeros(0, dtype=np.int64)
    if not len(clusters):
        empty = np.zeros((0, 3))
        return AllanCheck(taus=np.zeros(0), residual_adev=empty, model_adev=empty, bound=empty,
                          source=str(noise.source))
    allan = allan_variance(residual, 1.0 / sample_period_s, clusters=clusters)
    taus = allan.taus
    wander = wander_avar(noise, taus)
    # The white level is measured, not tested: what the residual shows at the shortest averaging
    # time beyond the model's wander there (at least the floor from successive differences, which
    # leaves out isolated jumps that the Allan variance keeps).
    level = np.maximum(allan.avar[0] - wander[0], np.asarray(white_floor, dtype=float) ** 2 * sample_period_s / taus[0])
    white = level[None, :] * taus[0] / taus[:, None]
    walk = (_triple(noise.random_walk) ** 2)[None, :] * taus[:, None] / 3.0
    model = white + wander
    # The power-law exponent of the noise that dominates the prediction: 0 white rate,
    # -2 random-walk rate, -1 flicker (bias instability) otherwise.
    alphas = np.where(white >= wander, 0, np.where(walk >= 0.5 * wander, -2, -1))
    quantile = 1.0 - alpha / (len(taus) * residual.shape[1])
    bound = np.empty_like(model)
    for i in range(residual.shape[1]):
        dof = equivalent_degrees_of_freedom(allan, alphas[:, i])
        bound[:, i] = np.sqrt(chi2.ppf(quantile, dof) / dof)
    slack = 1.0 if noise.source == 'residual' else tolerance
    return AllanCheck(taus=taus, residual_adev=np.sqrt(allan.avar), model_adev=np.sqrt(model), bound=bound * slack,
                      source=str(noise.source))


def wander_explains(check: AllanCheck) -> bool:
    """Whether a residual is consistent with a noise model fitted to its own short averaging times.

    The model (``source='residual'``, :func:`~tak_thermo_ros.core.noise.residual.model_from_residual`)
    comes from averaging times up to :data:`~tak_thermo_ros.core.noise.residual.RESIDUAL_LONGEST_TAU_S`,
    where it agrees with the residual by construction; the test is at the longer ones, where a
    thermal effect or a drift would rise above its flat bias-instability floor. So the residual
    must be inside the bounds at every averaging time, and those must reach at least twice that
    length.
    """
    if check.source != 'residual' or not len(check.taus):
        return False
    return check.consistent and float(check.taus.max()) >= 2.0 * RESIDUAL_LONGEST_TAU_S


def sample_period(samples: AlignedSamples) -> float:
    """The median step between samples, s (1 s for fewer than two samples)."""
    if len(samples) < 2:
        return 1.0
    return max(float(np.median(np.diff(samples.stamp_ns))) * 1e-9, 1e-9)


def _rung_allan(samples: AlignedSamples, cv_samples: AlignedSamples, ladder: Sequence[Any],
                model_specs: tuple[Any, ...], present: tuple[Any, ...], residual: np.ndarray,
                residual_after: np.ndarray | None, settings: Any, noise: Any, white_floor: np.ndarray,
                period: float) -> tuple[tuple[str, AllanCheck], ...]:
    """The Allan test of the residual on every rung of the ladder.

    The calibration as given, then the model refitted with each effect added (the last rung: the
    ladder's refit).
    """
    from tak_thermo_ros.core.diagnose.crossval import _effect_name, _with_range, fit_with
    from tak_thermo_ros.core.fit import residual_counts
    checks = [(ladder[0].label, allan_check(residual, period, noise, white_floor))]
    added = [spec for spec in model_specs if spec not in present]
    for index, step in enumerate(ladder[1:], start=1):
        if index == len(ladder) - 1 and residual_after is not None:
            rung_residual = residual_after
        else:
            names = set(step.effects)
            specs = tuple(spec for spec in (*present, *added) if _effect_name(spec) in names)
            try:
                fitted = fit_with(cv_samples, specs, settings)
            except TakError:
                continue
            low, high = float(samples.temp_code.min()), float(samples.temp_code.max())
            rung_residual = residual_counts(_with_range(fitted.calibration, low, high), samples)
        checks.append((step.label, allan_check(rung_residual, period, noise, white_floor)))
    return tuple(checks)
