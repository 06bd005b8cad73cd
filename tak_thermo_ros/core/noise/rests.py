"""A noise model from what a fit saw: the white noise within its rests, the wander between them.

Every fit has stretches where the unit's input is known and held: the rests of everyday and
hand-held records, a table run's plateaus, a static run's quiet length. What the fit leaves there
(the corrected output less what the unit should read) is the sensor's own noise, and it is the
yardstick the calibration watch judges a run's rests against (``docs/noise.md``, ``docs/watch.md``).
So every fit writes it (``source: fit``):

1. **Within the stretches, the white noise** (:func:`.white.white_noise`): the Allan variance at one
   sample and at one window (:data:`~tak_thermo_ros.core.records.still.WINDOW_S`, half a second:
   between the means of successive windows of a stretch), pooled over every stretch, each
   ``N^2 / tau`` for white noise (the window's with the wander's share besides), each with its
   relative standard error ``sqrt(2 / edf)``. Where they agree the density is one sample's; more
   at one sample is quantisation (``3 Q^2 / tau^2``), less the driver's low-pass filter (its time
   constant solved from the ratio, :func:`~tak_thermo_ros.core.noise.model.filtered_white_allan_variance`),
   and the density the window's (the long-term one a rest's mean averages).
2. **Between the stretches, the wander** (:func:`.wander.fit_wander`): the stretches' mean residuals have the
   covariance the watch itself uses (:class:`~tak_thermo_ros.core.link.rest_noise.ChannelNoise`: each
   mean's white noise, and between two means the flicker term's ``(4 B^2 / pi)(ln 2 + ln(S / T) / 2)``
   and the random walk's ``K^2 (gap + T1 / 3 + T2 / 3)``), and ``B`` and ``K`` are their restricted
   maximum likelihood (REML): the likelihood of the contrasts that no fixed effect reaches. The
   fixed effects are what the fit took off (the offset and scale polynomials in temperature) and
   each record's own level (its turn-on offset: the spread of turn-on offsets is not wander), so
   what the fit absorbed of the wander (a temperature polynomial follows a walk over a monotone
   warm-up) is not lost from the estimate.
3. **Seen, or bounded** (:class:`.wander.Term`): a term is *seen* when the data reject it being 0 by
   :data:`.wander.SEEN_DELTA` in ``-2 log L`` (two standard deviations); then its value and its standard
   error (half the profile likelihood's 68 % interval). Otherwise the value is 0 and its *bound*
   is the profile likelihood's one-sided 97.5 % upper limit (and never above what the window's
   Allan variance allows), written as ``bias_instability_bound`` / ``random_walk_bound``: never a 0
   that reads as known. The watch counts a bounded term at its bound
   (:attr:`~tak_thermo_ros.core.noise.model.NoiseModel.bias_instability_upper`), erring on the side
   of a wander it does not understate.

Gauss-Markov processes and a rate ramp are not estimated from rests (a few minutes between rests
do not tell a correlation time); a flicker term stands for them over the separations seen.

Step 1 is :mod:`.white`, steps 2 and 3 :mod:`.wander`; this module puts them together
(:func:`rest_noise`) and gathers a run's windows within its stretches (:class:`StretchWindows`).
Numpy at import; scipy inside the functions that need it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from tak_thermo_ros.core.noise.model import FLICKER_FLOOR, UPPER_SIGMAS, NoiseModel, floor_tau
from tak_thermo_ros.core.noise.wander import RestMeans, Wander, fit_wander
from tak_thermo_ros.core.noise.white import ShortSums, White, wander_ceiling, white_noise
from tak_thermo_ros.core.records.still import MIN_WINDOW_SAMPLES, WINDOW_S

MAX_WINDOWS = 1 << 17
"""A run's windows (:class:`StretchWindows`) are made longer than half a second beyond this many."""


@dataclass(frozen=True)
class RestNoise:
    """A sensor's noise model from a fit's stretches, and what it was found from.

    :param model: the noise model (``source: fit``; errors and bounds in it).
    :param white: per axis the white noise within the stretches.
    :param wander: per axis the wander between them (one for every axis when ``shared``).
    :param shared: the wander is one projection's (``|f|`` along the vertical at the rests), written on every axis.
    :param kind: what the stretches were: ``rests`` (still intervals found in the record) or ``stretches``
        (a table run's plateaus, a static run's length).
    """

    model: NoiseModel
    white: tuple[White, ...]
    wander: tuple[Wander, ...]
    shared: bool = False
    kind: str = 'stretches'

    @property
    def means(self) -> int:
        """Stretch means the wander was judged on."""
        return max(w.means for w in self.wander)

    @property
    def records(self) -> int:
        """Records (power-ups) they come from."""
        return max(w.records for w in self.wander)


def rest_noise(short: ShortSums, channels: list[RestMeans], *, up: np.ndarray | None = None,
               kind: str = 'stretches') -> RestNoise | None:
    """A sensor's noise model: the white noise within the stretches, the wander between them (the module's steps).

    :param short: the sensor's three axes' sums within the stretches.
    :param channels: per axis its means (three), or one projection's (``|f|``) with ``up``.
    :param up: ``(k, 3)`` with one channel: each mean's up direction (its white noise is
        ``sum_j u_j^2 N_j^2``); the wander found is written on every axis.
    :param kind: ``rests`` or ``stretches`` (:class:`RestNoise`).
    :returns: ``None`` when the stretches hold too few samples for a white noise density.
    """
    whites = white_noise(short)
    if not all(white.density > 0.0 for white in whites):
        return None
    ceilings = [wander_ceiling(short, axis) for axis in range(3)]
    if len(channels) == 1:
        means = channels[0]
        squares = np.asarray(up, dtype=float) ** 2
        projected = replace(means, white=means.white * (squares @ np.array([w.density ** 2 for w in whites])))
        ceiling = (max(c[0] for c in ceilings), max(c[1] for c in ceilings))
        wanders = (fit_wander(projected, White(1.0, 0.0), ceiling=ceiling),) * 3
    else:
        wanders = tuple(fit_wander(means, white, ceiling=ceiling)
                        for means, white, ceiling in zip(channels, whites, ceilings))
    # The most the wander can add at one window: its terms at their upper limits.
    uppers = [(max(w.flicker.value + UPPER_SIGMAS * w.flicker.error, w.flicker.bound),
               max(w.walk.value + UPPER_SIGMAS * w.walk.error, w.walk.bound)) for w in wanders]
    whites = white_noise(short, np.array([(FLICKER_FLOOR * b) ** 2 + k * k * short.window_s / 3.0 for b, k in uppers]))

    def triple(values) -> tuple[float, float, float]:
        items = [float(v) for v in values]
        return items[0], items[1], items[2]

    white = triple(w.density for w in whites)
    flicker = triple(w.flicker.value for w in wanders)
    walk = triple(w.walk.value for w in wanders)
    quantization = triple(w.quantization for w in whites)
    filtered = triple(w.filter_time_constant for w in whites)
    model = NoiseModel(
        white_noise_density=white, bias_instability=flicker,
        bias_instability_tau=floor_tau(white, flicker, walk, quantization), random_walk=walk,
        update_rate=1.0 / short.period_s, source='fit', quantization=quantization,
        filter_time_constant=filtered, filter_share=triple(1.0 if f > 0.0 else 0.0 for f in filtered),
        random_walk_bound=triple(w.walk.bound for w in wanders),
        bias_instability_bound=triple(w.flicker.bound for w in wanders),
        white_noise_density_error=triple(w.error for w in whites),
        bias_instability_error=triple(w.flicker.error for w in wanders),
        random_walk_error=triple(w.walk.error for w in wanders))
    return RestNoise(model, tuple(whites), wanders, shared=len(channels) == 1, kind=kind)


class StretchWindows:
    """One sensor's samples in windows within stretches of a held reference: one row per window (bounded).

    A stretch is a run of samples whose reference does not change and whose stamps have no gap (more
    than 1.5 sampling intervals apart: a table settling, a turn, a lost message); it is cut into
    windows of :data:`~tak_thermo_ros.core.records.still.WINDOW_S` (at least
    :data:`~tak_thermo_ros.core.records.still.MIN_WINDOW_SAMPLES` samples; longer when the run would
    hold more than :data:`MAX_WINDOWS`), a stretch's last partial window left out. Per window: its
    stretch, first and last stamp, the means of the values, references and temperature, and the sum of
    half the squared steps between its successive samples. A consumer of a fit's aligned blocks
    (``tak_calib fit``'s pass over a table run or a static run).

    :param expected: about how many samples the run holds (sets the window so that the rows stay bounded).
    """

    COLUMNS = 13

    def __init__(self, expected: int = 0) -> None:
        self.expected = expected
        self.window = 0
        self.period_ns = 0.0
        self._tail: tuple[np.ndarray, ...] | None = None
        """The current stretch's samples not yet in a window (or the first samples, before the period is known)."""
        self._last: tuple[int, np.ndarray] | None = None
        self._stretch = 0
        self._rows: list[np.ndarray] = []

    def __call__(self, aligned) -> None:
        """One aligned block (stamps, values ``counts``, ``reference``, ``temp_code``), in time order."""
        if not len(aligned) or aligned.reference is None:
            return
        block = (np.asarray(aligned.stamp_ns, dtype=np.int64), np.asarray(aligned.counts, dtype=float),
                 np.asarray(aligned.reference, dtype=float), np.asarray(aligned.temp_code, dtype=float))
        if not self.window:
            if self._tail is not None:
                block = tuple(np.concatenate([old, new]) for old, new in zip(self._tail, block))
                self._tail = None
            steps = np.diff(block[0])
            steps = steps[steps > 0]
            if len(steps) < 2:
                self._tail = block
                return
            self.period_ns = float(np.median(steps))
            self.window = max(MIN_WINDOW_SAMPLES, int(round(WINDOW_S * 1e9 / self.period_ns)),
                              math.ceil(self.expected / MAX_WINDOWS))
        stamps, values, reference, temperature = block
        breaks = np.zeros(len(stamps), dtype=bool)
        if self._last is not None:
            breaks[0] = self._breaks(self._last[0], stamps[0], self._last[1], reference[0])
        breaks[1:] = self._breaks(stamps[:-1], stamps[1:], reference[:-1], reference[1:])
        self._last = (int(stamps[-1]), reference[-1])
        if self._tail is not None and not breaks[0]:  # the stretch goes on: its samples not yet in a window first
            tail = len(self._tail[0])
            stamps, values, reference, temperature = (np.concatenate([old, new]) for old, new in
                                                      zip(self._tail, block))
            breaks = np.concatenate([np.zeros(tail, dtype=bool), breaks])
        self._tail = None
        edges = np.concatenate([[0], np.flatnonzero(breaks[1:]) + 1, [len(stamps)]])
        w = self.window
        for start, end in zip(edges[:-1], edges[1:]):
            if breaks[start]:
                self._stretch += 1
            whole = start + (end - start) // w * w
            if whole > start:
                self._add(stamps[start:whole], values[start:whole], reference[start:whole],
                          temperature[start:whole])
            if end == len(stamps) and whole < end:
                self._tail = (stamps[whole:], values[whole:], reference[whole:], temperature[whole:])

    def _breaks(self, before, after, reference_before, reference_after):
        gap = (np.asarray(after) - np.asarray(before)) > 1.5 * self.period_ns
        change = np.any(np.abs(np.asarray(reference_after) - np.asarray(reference_before))
                        > 1e-9 * (1.0 + np.abs(np.asarray(reference_before))), axis=-1)
        return gap | change

    def _add(self, stamps: np.ndarray, values: np.ndarray, reference: np.ndarray, temperature: np.ndarray) -> None:
        w = self.window
        shaped = values.reshape(-1, w, 3)
        steps = 0.5 * np.sum(np.diff(shaped, axis=1) ** 2, axis=1)
        windows = len(shaped)
        self._rows.append(np.column_stack([
            np.full(windows, float(self._stretch)), stamps.reshape(-1, w)[:, 0].astype(float),
            stamps.reshape(-1, w)[:, -1].astype(float), shaped.mean(axis=1),
            reference.reshape(-1, w, 3).mean(axis=1), temperature.reshape(-1, w).mean(axis=1), steps]))

    def rows(self) -> np.ndarray:
        """``(windows, 13)`` per window: stretch, first and last stamp (ns), the means, the sums of half the steps.

        The columns: stretch, first stamp, last stamp, the values' means (3), the references' means (3),
        the temperature's mean, the sums of half the squared steps between successive samples (3).
        """
        return np.vstack(self._rows) if self._rows else np.zeros((0, self.COLUMNS))
