"""A sensor's noise model per axis: the IEEE 952 terms, a driver's filter, Gauss-Markov bumps.

For a rate signal (gyroscope rad/s, accelerometer m/s^2) sampled every ``tau0 = 1 / rate``
seconds the Allan variances of independent noise processes add up. The five IEEE 952 (Annex C)
terms::

    avar(tau) = 3 Q^2 / tau^2       quantisation          Q  units*s
              + N^2 / tau           white noise density    N  units/sqrt(Hz) (angle / velocity random walk)
              + (2 ln 2 / pi) B^2   bias instability       B  units (flicker; the flat floor of the ADEV is 0.664 B)
              + K^2 tau / 3         random walk            K  units*sqrt(Hz) (rate / velocity random walk)
              + R^2 tau^2 / 2       rate ramp              R  units/s

and what real parts show besides:

- **a driver's low-pass filter** (and decimation): a share ``filter_share`` of the white noise
  density squared passes a first-order low-pass of time constant ``filter_time_constant``
  before the samples are taken, so neighbouring samples are correlated (an AR(1) process at
  the output rate, exactly so for a one-pole filter at any internal rate followed by
  decimation). Its Allan variance falls below ``N^2 / tau`` at the shortest averaging times
  and joins it beyond a few time constants; the density ``N`` stays the long-term one;
- **Gauss-Markov processes** (exponentially correlated, IEEE 952 lists them; a bump in the
  Allan deviation at about 1.89 times the correlation time): ``gauss_markov`` (their standard
  deviations) and ``gauss_markov_time`` (their correlation times), per process three numbers.

The Allan variance of an AR(1) process of variance ``s^2`` and lag-one correlation
``rho = exp(-tau0 / T)`` at ``m`` samples is exact (:func:`ar1_allan_variance`):
``(4 D(m) - D(2m)) / (2 m^2)`` with ``D(n) = s^2 (n + 2 rho (n (1 - rho) - 1 + rho^n) / (1 - rho)^2)``,
the variance of a sum of ``n`` samples. The fit of all this to a measured Allan variance is in
:mod:`tak_thermo_ros.core.noise.fit`. This module imports numpy only (the node loads
:class:`NoiseModel`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Mapping, Sequence

import numpy as np

from tak_thermo_ros.errors import NoiseError

FLICKER_FLOOR = math.sqrt(2.0 * math.log(2.0) / math.pi)
"""The flat Allan deviation of a flicker (bias instability) term ``B``: ``0.6643 B``."""
SOURCES = ('file', 'static_run', 'residual', 'fit')
"""Where a model comes from: a user's Kalibr-style file, a static constant-temperature run,
the calibration run's own residual after the fitted thermal model, the fit's own rests (white
noise within them, the wander between them: :mod:`tak_thermo_ros.core.noise.rests`)."""
OPTIONAL_TERMS = ('filter_time_constant', 'filter_share', 'random_walk_bound', 'bias_instability_bound',
                  'white_noise_density_error', 'bias_instability_error', 'random_walk_error')
"""The triples a model writes only when one of their values is not 0."""
UPPER_SIGMAS = 1.6448536
"""A wander term's one-sided 95 % upper limit is its value plus this many standard errors (its bound
where the record did not show it): what the calibration watch counts (never understating the wander)."""
TERMS = ('quantization', 'white_noise_density', 'bias_instability', 'random_walk', 'rate_ramp')
"""The five IEEE 952 terms, in the order of the Allan variance's slope (-2 to +2)."""
FLOOR_GRID = 4000
"""Points per search of the Allan deviation's minimum (log-spaced)."""
GAUSS_MARKOV_PEAK = 1.8926
"""A Gauss-Markov process's Allan deviation peaks at ``tau = 1.89 T`` (its correlation time ``T``)."""
_SERIES_BELOW = 1e-2
"""Below this ``n tau0 / T`` the AR(1) sums use their Taylor series (the closed form cancels)."""

Triple = tuple[float, float, float]
ZERO: Triple = (0.0, 0.0, 0.0)


def allan_terms(taus: np.ndarray) -> np.ndarray:
    """``(t, 5)``: the Allan variance of each unit IEEE 952 term at ``taus`` (coefficients: the squared terms)."""
    taus = np.asarray(taus, dtype=float)
    return np.column_stack([3.0 / taus ** 2, 1.0 / taus, np.full(taus.shape, FLICKER_FLOOR ** 2),
                            taus / 3.0, taus ** 2 / 2.0])


def _sum_variance(n: np.ndarray, decay: float) -> np.ndarray:
    """``D(n) / s^2``: the variance of a sum of ``n`` samples of an AR(1) process of unit variance.

    ``decay = tau0 / T`` (the lag-one correlation is ``exp(-decay)``).
    """
    n = np.asarray(n, dtype=float)
    rho = math.exp(-decay)
    gap = -math.expm1(-decay)  # 1 - rho, without cancellation
    x = n * decay
    with np.errstate(over='ignore', invalid='ignore'):
        closed = n * gap + np.expm1(-x)  # n (1 - rho) - (1 - rho^n)
    # Taylor series of the same in decay (with x = n decay small): no cancellation.
    series = decay ** 2 * (n * n - n) / 2.0 - decay ** 3 * (n ** 3 - n) / 6.0 + decay ** 4 * (n ** 4 - n) / 24.0
    inner = np.where(x < _SERIES_BELOW, series, closed)
    return n + 2.0 * rho * inner / gap ** 2


def ar1_allan_variance(clusters: np.ndarray, decay: float, variance: float = 1.0) -> np.ndarray:
    """The exact Allan variance at ``clusters`` samples of an AR(1) process sampled every ``tau0``.

    ``decay = tau0 / T`` with ``T`` the correlation time (lag-one correlation ``exp(-decay)``);
    ``variance``: the process's. A Gauss-Markov process sampled at ``tau0`` is such a process;
    for ``T >> tau0`` this is the continuous-time formula ``(2 s^2 T / tau) [1 - T / (2 tau)
    (3 - 4 e^(-tau/T) + e^(-2 tau/T))]``; ``decay`` infinite is white noise (``variance / m``).
    """
    m = np.asarray(clusters, dtype=float)
    if not math.isfinite(decay):
        return variance / m
    return variance * (4.0 * _sum_variance(m, decay) - _sum_variance(2.0 * m, decay)) / (2.0 * m * m)


def filtered_white_allan_variance(taus: np.ndarray, rate: float, time_constant: float) -> np.ndarray:
    """The Allan variance of unit-density white noise after a first-order low-pass, sampled at ``rate``.

    Beyond a few time constants it is ``1 / tau``; below, less (neighbouring samples are alike).
    A time constant of 0 is plain white noise.
    """
    taus = np.asarray(taus, dtype=float)
    if time_constant <= 0.0:
        return 1.0 / taus
    decay = 1.0 / (rate * time_constant)
    # An AR(1) of per-sample variance s^2 has the long-term density tau0 s^2 (1 + rho) / (1 - rho).
    variance = math.tanh(decay / 2.0) * rate
    return ar1_allan_variance(taus * rate, decay, variance)


def _triple(value: Any, key: str, *, allow_inf: bool = False, positive: bool = False,
            at_most: float | None = None) -> Triple:
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
        if at_most is not None and number > at_most:
            msg = f'{key}[{axis}]: expected at most {at_most:g}, got {number}'
            raise NoiseError(msg)
        out.append(number)
    return (out[0], out[1], out[2])


def _triples(value: Any, key: str, *, positive: bool = False) -> tuple[Triple, ...]:
    """Per process three numbers: a list of triples, or a flat list of ``3 k`` numbers (x y z, x y z, ...)."""
    items = value.tolist() if isinstance(value, np.ndarray) else value
    if not isinstance(items, (list, tuple)):
        msg = f'{key}: expected a list of three numbers (x, y, z) per process, got {value!r}'
        raise NoiseError(msg)
    if items and not isinstance(items[0], (list, tuple, np.ndarray)):
        if len(items) % 3:
            msg = f'{key}: expected three numbers (x, y, z) per process, got {len(items)} numbers'
            raise NoiseError(msg)
        items = [items[i:i + 3] for i in range(0, len(items), 3)]
    return tuple(_triple(item, f'{key}[{i}]', positive=positive) for i, item in enumerate(items))


@dataclass(frozen=True)
class NoiseModel:
    """One sensor's noise, per axis x, y, z, in SI units of its samples.

    :param white_noise_density: units/sqrt(Hz): angle random walk of a gyroscope (rad/s/sqrt(Hz)),
        velocity random walk of an accelerometer (m/s^2/sqrt(Hz)); Kalibr's ``*_noise_density``.
        The long-term density (a driver's filter shapes only the shortest averaging times).
    :param bias_instability: units; the flicker term, whose flat Allan deviation is 0.664 times it
        (IEEE 952's ``B``).
    :param bias_instability_tau: s, the averaging time where the model's Allan deviation is
        lowest (the floor); ``inf`` when nothing rises at long times (a fitted model: not within
        the measured averaging times).
    :param random_walk: units*sqrt(Hz): rate (velocity) random walk; Kalibr's ``*_random_walk``.
    :param update_rate: Hz, the sample rate the model was estimated at (the per-sample
        variance of the white noise is ``white_noise_density^2 * update_rate``).
    :param source: ``file``, ``static_run`` or ``residual`` (:data:`SOURCES`).
    :param quantization: units*s (Allan variance ``3 Q^2 / tau^2``).
    :param rate_ramp: units/s (Allan variance ``R^2 tau^2 / 2``).
    :param filter_time_constant: s, a first-order low-pass (the driver's) on a share of the white
        noise; 0: none.
    :param filter_share: the share (0..1) of ``white_noise_density^2`` that passes that filter.
    :param gauss_markov: per Gauss-Markov process, its standard deviation per axis (units); 0
        where an axis has no such process.
    :param gauss_markov_time: per process, its correlation time per axis (s, positive).
    :param random_walk_bound: units*sqrt(Hz): where the record shows no random walk
        (``random_walk`` 0), the largest one it allows (from its longest averaging times); 0
        where the walk is measured or nothing is known.
    :param bias_instability_bound: units: likewise for the bias instability (``bias_instability``
        0 where the record does not show one: the largest it allows).
    :param white_noise_density_error: the standard error of ``white_noise_density`` (0: not stated);
        ``bias_instability_error`` and ``random_walk_error`` likewise (a model estimated from a
        fit's rests states them, :mod:`tak_thermo_ros.core.noise.rests`).
    """

    white_noise_density: Triple
    bias_instability: Triple
    bias_instability_tau: Triple
    random_walk: Triple
    update_rate: float
    source: str
    quantization: Triple = ZERO
    rate_ramp: Triple = ZERO
    filter_time_constant: Triple = ZERO
    filter_share: Triple = ZERO
    gauss_markov: tuple[Triple, ...] = ()
    gauss_markov_time: tuple[Triple, ...] = ()
    random_walk_bound: Triple = ZERO
    bias_instability_bound: Triple = ZERO
    white_noise_density_error: Triple = ZERO
    bias_instability_error: Triple = ZERO
    random_walk_error: Triple = ZERO

    def __post_init__(self) -> None:
        for name in ('white_noise_density', 'bias_instability', 'random_walk', 'quantization', 'rate_ramp',
                     'filter_time_constant', 'random_walk_bound', 'bias_instability_bound',
                     'white_noise_density_error', 'bias_instability_error', 'random_walk_error'):
            object.__setattr__(self, name, _triple(getattr(self, name), name))
        object.__setattr__(self, 'filter_share', _triple(self.filter_share, 'filter_share', at_most=1.0))
        object.__setattr__(self, 'bias_instability_tau',
                           _triple(self.bias_instability_tau, 'bias_instability_tau', allow_inf=True, positive=True))
        object.__setattr__(self, 'gauss_markov', _triples(self.gauss_markov, 'gauss_markov'))
        object.__setattr__(self, 'gauss_markov_time', _triples(self.gauss_markov_time, 'gauss_markov_time',
                                                               positive=True))
        if len(self.gauss_markov) != len(self.gauss_markov_time):
            msg = (f'gauss_markov: {len(self.gauss_markov)} processes but gauss_markov_time has '
                   f'{len(self.gauss_markov_time)}')
            raise NoiseError(msg)
        rate = self.update_rate
        if isinstance(rate, bool) or not isinstance(rate, (int, float, np.floating, np.integer)) \
                or not math.isfinite(float(rate)) or float(rate) <= 0.0:
            msg = f'update_rate: expected a positive finite number of Hz, got {rate!r}'
            raise NoiseError(msg)
        object.__setattr__(self, 'update_rate', float(rate))
        if self.source not in SOURCES:
            msg = f'source: expected one of {", ".join(SOURCES)}, got {self.source!r}'
            raise NoiseError(msg)

    @property
    def bias_instability_upper(self) -> Triple:
        """Per axis the bias instability at its one-sided 95 % upper limit: what a test must not understate.

        The value plus :data:`UPPER_SIGMAS` of its standard error, or where the record showed none its
        bound; the value itself where neither is stated (a data sheet's, a static run's fit).
        """
        return _upper(self.bias_instability, self.bias_instability_error, self.bias_instability_bound)

    @property
    def random_walk_upper(self) -> Triple:
        """Per axis the random walk at its one-sided 95 % upper limit (as :attr:`bias_instability_upper`)."""
        return _upper(self.random_walk, self.random_walk_error, self.random_walk_bound)

    def coefficients(self) -> np.ndarray:
        """``(3, 5)``: per axis the squares of the five IEEE 952 terms, in the order of :data:`TERMS`."""
        return np.array([getattr(self, name) for name in TERMS], dtype=float).T ** 2

    def parts(self, taus: Sequence[float] | np.ndarray) -> dict[str, np.ndarray]:
        """Each process's Allan variance ``(t, 3)`` at ``taus`` (s); they add up to :meth:`allan_variance`.

        Keys: the five :data:`TERMS` (``white_noise_density`` with the driver's filter) and
        ``gauss_markov`` (all processes together).
        """
        taus = np.asarray(taus, dtype=float).reshape(-1)
        unit = allan_terms(taus)
        coefficients = self.coefficients()
        parts = {name: unit[:, [i]] * coefficients[:, i][None, :] for i, name in enumerate(TERMS)}
        white = np.empty((len(taus), 3))
        for axis in range(3):
            share, constant = self.filter_share[axis], self.filter_time_constant[axis]
            shape = unit[:, 1]
            if share > 0.0 and constant > 0.0:
                filtered = filtered_white_allan_variance(taus, self.update_rate, constant)
                shape = (1.0 - share) * shape + share * filtered
            white[:, axis] = self.white_noise_density[axis] ** 2 * shape
        parts['white_noise_density'] = white
        bumps = np.zeros((len(taus), 3))
        clusters = taus * self.update_rate
        for sigma, times in zip(self.gauss_markov, self.gauss_markov_time):
            for axis in range(3):
                if sigma[axis] > 0.0:
                    bumps[:, axis] += ar1_allan_variance(clusters, 1.0 / (self.update_rate * times[axis]),
                                                         sigma[axis] ** 2)
        parts['gauss_markov'] = bumps
        return parts

    def allan_variance(self, taus: Sequence[float] | np.ndarray) -> np.ndarray:
        """The Allan variance ``(t, 3)`` this model predicts at ``taus`` (s)."""
        return sum(self.parts(taus).values())  # type: ignore[return-value]

    def allan_deviation(self, taus: Sequence[float] | np.ndarray) -> np.ndarray:
        """The Allan deviation ``(t, 3)`` this model predicts at ``taus`` (s)."""
        return np.sqrt(self.allan_variance(taus))

    def wander_allan_variance(self, taus: Sequence[float] | np.ndarray) -> np.ndarray:
        """``(t, 3)`` the Allan variance of the slow processes: bias instability, random walk, ramp, Gauss-Markov.

        What the white noise (filtered or not) and the quantisation leave out: the bias's wander.
        """
        parts = self.parts(taus)
        return parts['bias_instability'] + parts['random_walk'] + parts['rate_ramp'] + parts['gauss_markov']

    def sample_variance(self) -> Triple:
        """Per axis, the variance of one sample's noise: the model's Allan variance at one sample period.

        For white noise alone that is exactly ``white_noise_density^2 * update_rate``; the other
        terms add what they predict at ``tau = 1 / update_rate`` (quantisation, where a short run
        cannot tell it from white noise, most of it; bias instability and random walk next to
        nothing), so that an axis whose fit put its short-time noise into quantisation still
        gets the variance its samples show, never 0 (which REP 145 reads as "unknown").
        """
        return _triple(self.allan_variance([1.0 / self.update_rate])[0].tolist(), 'sample_variance')

    def floor(self) -> Triple:
        """Per axis the model's lowest Allan deviation (at ``bias_instability_tau``); NaN where it has none.

        The convention of data sheets for in-run bias stability (ADI, Bosch, TDK state the
        Allan deviation's minimum), beside IEEE 952's ``B`` (:attr:`bias_instability`).
        """
        out = []
        for axis, tau in enumerate(self.bias_instability_tau):
            out.append(float(self.allan_deviation([tau])[0, axis]) if math.isfinite(tau) else math.nan)
        return (out[0], out[1], out[2])

    def has_extra_terms(self) -> bool:
        """Whether the model holds more than the five IEEE 952 terms (a filter, Gauss-Markov processes)."""
        return any(self.filter_share) or any(any(sigma) for sigma in self.gauss_markov)

    def to_mapping(self) -> dict[str, Any]:
        """Plain numbers and lists (YAML, ROS 2 parameters); :func:`noise_model_from_mapping` reads it back.

        The terms beyond the five are written only when present: the filter's two triples, the
        Gauss-Markov processes as flat lists of three numbers per process (x y z, x y z, ...),
        the bounds and the standard errors (:data:`OPTIONAL_TERMS`).
        """
        mapping: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in ('gauss_markov', 'gauss_markov_time'):
                if value:
                    mapping[f.name] = [v for triple in value for v in triple]
            elif f.name in OPTIONAL_TERMS:
                if any(value):
                    mapping[f.name] = list(value)
            else:
                mapping[f.name] = list(value) if isinstance(value, tuple) else value
        return mapping

    def to_json(self) -> dict[str, Any]:
        """As :meth:`to_mapping`, with a floor time at infinity as ``None`` (strict JSON has no infinity)."""
        return {key: [v if math.isfinite(v) else None for v in value] if isinstance(value, list) else value
                for key, value in self.to_mapping().items()}


def _upper(value: Triple, error: Triple, bound: Triple) -> Triple:
    out = [max(v + UPPER_SIGMAS * e, b) for v, e, b in zip(value, error, bound)]
    return (out[0], out[1], out[2])


def noise_model_from_mapping(raw: Any, where: str) -> NoiseModel:
    """A :class:`NoiseModel` from the keys of :meth:`NoiseModel.to_mapping`.

    ``quantization``, ``rate_ramp`` and the terms beyond the five are optional (0, none),
    ``bias_instability_tau`` too (the floor of the other terms, :func:`floor_tau`); a single
    number stands for all three axes.

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
            values['bias_instability_tau'] = model_floor_tau(NoiseModel(**{**values, 'bias_instability_tau': 1.0}))
        return NoiseModel(**values)
    except NoiseError as err:
        msg = f'{where}.{err}'
        raise NoiseError(msg) from None


def floor_tau(white: Triple, bias: Triple, random_walk: Triple, quantization: Triple = ZERO,
              rate_ramp: Triple = ZERO, *, taus: tuple[float, float] | None = None) -> Triple:
    """Per axis, the averaging time (s) where the five IEEE 952 terms' Allan deviation is lowest.

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


def model_floor_tau(model: NoiseModel, taus: tuple[float, float] | None = None) -> Triple:
    """Per axis where ``model``'s Allan deviation is lowest, searched over ``taus`` (s).

    A model of the five terms alone without ``taus``: :func:`floor_tau` (analytic where it can
    be). Otherwise a log grid over ``taus`` (default: two samples to 1e9 s); a minimum at its
    upper end is ``inf`` (still falling).
    """
    if taus is None and not model.has_extra_terms():
        return floor_tau(model.white_noise_density, model.bias_instability, model.random_walk,
                         model.quantization, model.rate_ramp)
    low, high = taus or (2.0 / model.update_rate, 1e9)
    grid = np.geomspace(low, high, FLOOR_GRID)
    avar = model.allan_variance(grid)
    best = np.argmin(avar, axis=0)
    out = [math.inf if int(b) == len(grid) - 1 else float(grid[int(b)]) for b in best]
    return (out[0], out[1], out[2])
