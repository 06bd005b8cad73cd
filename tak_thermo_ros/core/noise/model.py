"""A sensor's noise model per axis: the five IEEE 952 terms, and their fit to an Allan variance.

For a rate signal (gyroscope rad/s, accelerometer m/s^2) the Allan variance of the five
IEEE 952 (Annex C) noise terms adds up::

    avar(tau) = 3 Q^2 / tau^2       quantisation          Q  units*s
              + N^2 / tau           white noise density    N  units/sqrt(Hz) (angle / velocity random walk)
              + (2 ln 2 / pi) B^2   bias instability       B  units (flicker; the flat floor of the ADEV is 0.664 B)
              + K^2 tau / 3         random walk            K  units*sqrt(Hz) (rate / velocity random walk)
              + R^2 tau^2 / 2       rate ramp              R  units/s

:func:`fit_noise_model` fits the five squares, per axis, by non-negative least squares on the
Allan variance, each averaging time weighted by its equivalent degrees of freedom (the
variance of an Allan variance estimate with ``edf`` degrees of freedom is ``2 avar^2 / edf``),
re-weighted with the model's own prediction and the degrees of freedom of the noise type that
dominates there. This module imports numpy only (the node loads :class:`NoiseModel`);
scipy is imported by the fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Mapping, Sequence

import numpy as np

from tak_thermo_ros.errors import NoiseError

FLICKER_FLOOR = math.sqrt(2.0 * math.log(2.0) / math.pi)
"""The flat Allan deviation of a flicker (bias instability) term ``B``: ``0.6643 B``."""
SOURCES = ('file', 'static_run', 'residual')
"""Where a model comes from: a user's Kalibr-style file, a static constant-temperature run,
the calibration run's own residual after the fitted thermal model."""
TERMS = ('quantization', 'white_noise_density', 'bias_instability', 'random_walk', 'rate_ramp')
"""The five IEEE 952 terms, in the order of the Allan variance's slope (-2 to +2)."""
_SLOPES = np.array([-2, -1, 0, 1, 2])
_ALPHAS = np.array([2, 0, -1, -2, -2])  # the power-law exponent of each term (ramp: as random walk)
FIT_ITERATIONS = 4
"""Re-weightings of the fit (the first uses the measured Allan variance and white-rate weights)."""
FLOOR_GRID = 4000
"""Points per search of the Allan deviation's minimum (log-spaced)."""

Triple = tuple[float, float, float]


def allan_terms(taus: np.ndarray) -> np.ndarray:
    """``(t, 5)``: the Allan variance of each unit term at ``taus`` (coefficients: the squared terms)."""
    taus = np.asarray(taus, dtype=float)
    return np.column_stack([3.0 / taus ** 2, 1.0 / taus, np.full(taus.shape, FLICKER_FLOOR ** 2),
                            taus / 3.0, taus ** 2 / 2.0])


def _triple(value: Any, key: str, *, allow_inf: bool = False, positive: bool = False) -> Triple:
    items = value.tolist() if isinstance(value, np.ndarray) else value
    if isinstance(items, (int, float)) and not isinstance(items, bool):
        items = (items,) * 3
    if not isinstance(items, (list, tuple)) or len(items) != 3:
        msg = f'{key}: expected three numbers (x, y, z), got {value!r}'
        raise NoiseError(msg)
    out = []
    for axis, item in zip('xyz', items):
        if isinstance(item, bool) or not isinstance(item, (int, float, np.floating, np.integer)):
            msg = f'{key}[{axis}]: expected a number, got {type(item).__name__} {item!r}'
            raise NoiseError(msg)
        number = float(item)
        if math.isnan(number) or (math.isinf(number) and not (allow_inf and number > 0)) or number < 0.0 \
                or (positive and number <= 0.0):
            kind = 'positive' if positive else 'non-negative'
            msg = f'{key}[{axis}]: expected a {kind} finite number, got {number}'
            raise NoiseError(msg)
        out.append(number)
    return (out[0], out[1], out[2])


@dataclass(frozen=True)
class NoiseModel:
    """One sensor's noise, per axis x, y, z, in SI units of its samples.

    :param white_noise_density: units/sqrt(Hz): angle random walk of a gyroscope (rad/s/sqrt(Hz)),
        velocity random walk of an accelerometer (m/s^2/sqrt(Hz)); Kalibr's ``*_noise_density``.
    :param bias_instability: units; the flicker term, whose flat Allan deviation is 0.664 times it.
    :param bias_instability_tau: s, the averaging time where the model's Allan deviation is
        lowest (the floor); ``inf`` when nothing rises at long times (a fitted model: not within
        the measured averaging times).
    :param random_walk: units*sqrt(Hz): rate (velocity) random walk; Kalibr's ``*_random_walk``.
    :param update_rate: Hz, the sample rate the model was estimated at (the per-sample
        variance of the white noise is ``white_noise_density^2 * update_rate``).
    :param source: ``file``, ``static_run`` or ``residual`` (:data:`SOURCES`).
    :param quantization: units*s (Allan variance ``3 Q^2 / tau^2``).
    :param rate_ramp: units/s (Allan variance ``R^2 tau^2 / 2``).
    """

    white_noise_density: Triple
    bias_instability: Triple
    bias_instability_tau: Triple
    random_walk: Triple
    update_rate: float
    source: str
    quantization: Triple = (0.0, 0.0, 0.0)
    rate_ramp: Triple = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for name in ('white_noise_density', 'bias_instability', 'random_walk', 'quantization', 'rate_ramp'):
            object.__setattr__(self, name, _triple(getattr(self, name), name))
        object.__setattr__(self, 'bias_instability_tau',
                           _triple(self.bias_instability_tau, 'bias_instability_tau', allow_inf=True, positive=True))
        rate = self.update_rate
        if isinstance(rate, bool) or not isinstance(rate, (int, float, np.floating, np.integer)) \
                or not math.isfinite(float(rate)) or float(rate) <= 0.0:
            msg = f'update_rate: expected a positive finite number of Hz, got {rate!r}'
            raise NoiseError(msg)
        object.__setattr__(self, 'update_rate', float(rate))
        if self.source not in SOURCES:
            msg = f'source: expected one of {", ".join(SOURCES)}, got {self.source!r}'
            raise NoiseError(msg)

    def coefficients(self) -> np.ndarray:
        """``(3, 5)``: per axis the squares of the five terms, in the order of :data:`TERMS`."""
        return np.array([getattr(self, name) for name in TERMS], dtype=float).T ** 2

    def allan_variance(self, taus: Sequence[float] | np.ndarray) -> np.ndarray:
        """The Allan variance ``(t, 3)`` this model predicts at ``taus`` (s)."""
        return allan_terms(np.asarray(taus, dtype=float)) @ self.coefficients().T

    def allan_deviation(self, taus: Sequence[float] | np.ndarray) -> np.ndarray:
        """The Allan deviation ``(t, 3)`` this model predicts at ``taus`` (s)."""
        return np.sqrt(self.allan_variance(taus))

    def sample_variance(self) -> Triple:
        """Per axis, the variance of one sample's noise: the model's Allan variance at one sample period.

        For white noise alone that is exactly ``white_noise_density^2 * update_rate``; the other
        terms add what they predict at ``tau = 1 / update_rate`` (quantisation, where a short run
        cannot tell it from white noise, most of it; bias instability and random walk next to
        nothing), so that an axis whose fit put its short-time noise into quantisation still
        gets the variance its samples show, never 0 (which REP 145 reads as "unknown").
        """
        return _triple(self.allan_variance([1.0 / self.update_rate])[0].tolist(), 'sample_variance')

    def to_mapping(self) -> dict[str, Any]:
        """Plain numbers and lists (YAML); :func:`noise_model_from_mapping` reads it back."""
        return {f.name: (list(getattr(self, f.name)) if isinstance(getattr(self, f.name), tuple)
                         else getattr(self, f.name)) for f in fields(self)}

    def to_json(self) -> dict[str, Any]:
        """As :meth:`to_mapping`, with a floor time at infinity as ``None`` (strict JSON has no infinity)."""
        return {key: [v if math.isfinite(v) else None for v in value] if isinstance(value, list) else value
                for key, value in self.to_mapping().items()}


def noise_model_from_mapping(raw: Any, where: str) -> NoiseModel:
    """A :class:`NoiseModel` from the keys of :meth:`NoiseModel.to_mapping`.

    ``quantization`` and ``rate_ramp`` are optional (0), ``bias_instability_tau`` too (the floor of
    the other terms, :func:`floor_tau`); a single number stands for all three axes.

    :raises NoiseError: naming ``where`` and the key, on a missing, unknown or bad value.
    """
    if not isinstance(raw, Mapping):
        msg = f'{where}: expected a mapping of noise terms'
        raise NoiseError(msg)
    known = {f.name for f in fields(NoiseModel)}
    unknown = sorted(str(k) for k in raw if k not in known)
    if unknown:
        msg = f'{where}.{unknown[0]}: unknown key (known: {", ".join(sorted(known))})'
        raise NoiseError(msg)
    required = ('white_noise_density', 'bias_instability', 'random_walk', 'update_rate', 'source')
    missing = [k for k in required if k not in raw]
    if missing:
        msg = f'{where}: missing key {missing[0]}'
        raise NoiseError(msg)
    values = dict(raw)
    try:
        if 'bias_instability_tau' not in values:
            values['bias_instability_tau'] = floor_tau(
                _triple(values['white_noise_density'], 'white_noise_density'),
                _triple(values['bias_instability'], 'bias_instability'),
                _triple(values['random_walk'], 'random_walk'),
                _triple(values.get('quantization', 0.0), 'quantization'),
                _triple(values.get('rate_ramp', 0.0), 'rate_ramp'))
        return NoiseModel(**values)
    except NoiseError as err:
        msg = f'{where}.{err}'
        raise NoiseError(msg) from None


def floor_tau(white: Triple, bias: Triple, random_walk: Triple, quantization: Triple = (0.0, 0.0, 0.0),
              rate_ramp: Triple = (0.0, 0.0, 0.0), *, taus: tuple[float, float] | None = None) -> Triple:
    """Per axis, the averaging time (s) where the model's Allan deviation is lowest.

    Without quantisation and ramp it is ``sqrt(3) N / K`` (where white noise and random walk
    cross; a flat flicker term does not move it), ``inf`` when ``K`` is 0. Otherwise it is searched
    on a log grid over ``taus`` (default 1 us to 1e9 s); a minimum at the grid's upper end (the
    Allan deviation still falling at the longest averaging time) is ``inf``.
    """
    out = []
    for axis in range(3):
        q, n, k, r = quantization[axis], white[axis], random_walk[axis], rate_ramp[axis]
        if taus is None and q == 0.0 and r == 0.0:
            out.append(math.sqrt(3.0) * n / k if k > 0.0 else (math.inf if n > 0.0 else 1.0))
            continue
        low, high = taus or (1e-6, 1e9)
        grid = np.geomspace(low, high, FLOOR_GRID)
        coefficients = np.array([q, n, bias[axis], k, r]) ** 2
        avar = allan_terms(grid) @ coefficients
        best = int(np.argmin(avar))
        out.append(math.inf if best == len(grid) - 1 else float(grid[best]))
    return (out[0], out[1], out[2])


def fit_noise_model(allan: Any, *, source: str, update_rate: float | None = None,
                    min_terms: int = 2, terms: Sequence[str] = TERMS) -> NoiseModel:
    """The five IEEE 952 terms of each axis of an Allan variance, by weighted non-negative least squares.

    :param allan: an :class:`~tak_thermo_ros.core.noise.allan.AllanVariance` of a rate signal.
    :param source: ``file``, ``static_run`` or ``residual``.
    :param update_rate: Hz (default: the Allan variance's sample rate).
    :param min_terms: averaging times with fewer terms than this are left out.
    :param terms: the terms fitted (:data:`TERMS` by default); the others are zero.
    :raises NoiseError: fewer than five usable averaging times, or not three axes, or an unknown term.

    Weights: the relative error of an Allan variance with ``edf`` equivalent degrees of freedom
    is ``sqrt(2 / edf)``; the first fit divides by the measured value and uses white-rate degrees
    of freedom, each re-weighting (:data:`FIT_ITERATIONS`) divides by the model's prediction and
    uses the degrees of freedom of the term that dominates the prediction at that averaging
    time (so that the fit is not pulled towards low measured values). Columns are normalised
    before ``scipy.optimize.nnls`` (the terms span many decades). The bias instability's floor
    time is the minimum of the fitted Allan deviation over the measured averaging times.
    """
    from scipy.optimize import nnls

    from tak_thermo_ros.core.noise.allan import equivalent_degrees_of_freedom
    if allan.axes != 3:
        msg = f'noise model: expected three axes, got {allan.axes}'
        raise NoiseError(msg)
    usable = (allan.counts >= min_terms) & np.all(np.isfinite(allan.avar), axis=1)
    if int(np.count_nonzero(usable)) < len(TERMS):
        msg = (f'noise model: only {int(np.count_nonzero(usable))} averaging times with enough data '
               f'({allan.samples} samples at {allan.rate:g} Hz); at least {len(TERMS)} are needed')
        raise NoiseError(msg)
    unknown = sorted(set(terms) - set(TERMS))
    if unknown or not terms:
        msg = f'noise model: unknown terms {", ".join(unknown)} (known: {", ".join(TERMS)})' if unknown else \
            'noise model: no term to fit'
        raise NoiseError(msg)
    fitted = np.array([name in terms for name in TERMS])
    taus = allan.taus[usable]
    basis = allan_terms(taus) * fitted
    edf_by_alpha = {alpha: equivalent_degrees_of_freedom(allan, alpha)[usable] for alpha in (2, 0, -1, -2)}
    coefficients = np.zeros((3, len(TERMS)))
    for axis in range(3):
        measured = allan.avar[usable, axis]
        if not np.any(measured > 0.0):
            continue  # a constant channel: every term is zero
        tiny = measured[measured > 0.0].min() * 1e-6
        reference = np.maximum(measured, tiny)
        edf = edf_by_alpha[0]
        solution = np.zeros(len(TERMS))
        for _ in range(FIT_ITERATIONS):
            weights = np.sqrt(edf / 2.0) / reference
            design = basis * weights[:, None]
            scale = np.linalg.norm(design, axis=0)
            scale[scale == 0.0] = 1.0
            scaled, _residual = nnls(design / scale, measured * weights)
            solution = np.where(fitted, scaled / scale, 0.0)
            parts = basis * solution
            predicted = parts.sum(axis=1)
            reference = np.maximum(np.where(predicted > 0.0, predicted, measured), tiny)
            dominant = _ALPHAS[np.argmax(parts, axis=1)]
            edf = np.select([dominant == a for a in (2, 0, -1)], [edf_by_alpha[2], edf_by_alpha[0], edf_by_alpha[-1]],
                            edf_by_alpha[-2])
        coefficients[axis] = solution
    terms = np.sqrt(coefficients)
    per_term = {name: tuple(float(v) for v in terms[:, i]) for i, name in enumerate(TERMS)}
    tau_range = (float(taus.min()), float(taus.max()))
    floor = floor_tau(per_term['white_noise_density'], per_term['bias_instability'], per_term['random_walk'],
                      per_term['quantization'], per_term['rate_ramp'], taus=tau_range)
    return NoiseModel(bias_instability_tau=floor, update_rate=update_rate or allan.rate, source=source,
                      **per_term)  # type: ignore[arg-type]
