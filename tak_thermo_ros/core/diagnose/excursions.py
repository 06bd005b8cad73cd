"""Judged on what the fit never saw: whole thermal excursions as the held-out unit.

Interleaved time blocks (:mod:`.crossval`) share their excursion with their neighbours: a block
held out in the middle of a cooling ramp is predicted from the same ramp on either side, so a
model that only follows that ramp's own history scores well there. A calibration is used on
another day's heating and cooling; here it is judged so:

1. **Excursions** (:func:`excursions`): the temperature course cut into heatings, coolings and
   plateaus by the sign of its rate (a :data:`RATE_WINDOW_FRACTION` of the record smoothed), a
   turn counted only once the temperature has moved back by at least :data:`MIN_SPAN_FRACTION` of
   the record's range, a plateau only where it holds within that span for at least
   :data:`MIN_PLATEAU_FRACTION` of the record (with a driver's temperature in degrees C, a tenth of
   a range of 92 C is 9.2 C).
   (a plateau: the temperature within an eighth of that span for that long).
2. **Held out whole** (:func:`~.heldout.judge_ladder`): each model of the ladder is fitted
   without one excursion (at most :data:`MAX_FOLDS` folds, excursions dealt round-robin) and its
   residual taken on it, when the fitted excursions hold one of its kind (a heating is judged by
   a model that saw a heating), and where the model interpolates: the held-out samples whose
   temperature lies within :data:`GAP_FRACTION` of the range of one the fitted excursions saw (not
   merely between their extremes), and every effect's signal within what they saw.
3. **Beyond their noise**: sample by sample the held-out gain of the squared residual, in units of
   the floor squared, summed over the axes; its mean over the judged samples has its standard
   error from the gain's own correlation (the noise model of
   :func:`~tak_thermo_ros.core.fit.uncertainty.mean_error`: a gain that wanders with the
   residual's bias is known to far less than white noise would say). An effect is recommended
   when that mean exceeds :data:`GAIN_SIGMAS` standard errors and no axis gets worse by more
   than :func:`~.heldout.worse_sigmas` of its standard errors (Bonferroni over the axes,
   :data:`WORSE_ALPHA`) and :data:`WORSE_MIN`; the verdict says on how many of how many
   excursions it was better. A record of one excursion, or whose excursions hold no two of a
   kind, cannot judge this, and says so; a rung whose fits see too few of the held-out
   excursions (its signal outside what they saw) stands on the interleaved blocks alone.
4. **A second record** (``diagnose --held-out REC2``): each model fitted on the whole diagnosed
   record, judged on the second record's excursions the same way.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.diagnose.views import RATE_WINDOW_S, _runs

MIN_SPAN_FRACTION = 0.1
"""An excursion moves the temperature by at least this share of the record's range (a turn counts once
the temperature has come back by as much)."""
MIN_PLATEAU_FRACTION = 0.05
"""A plateau holds the temperature within that span for at least this share of the record."""
RATE_WINDOW_FRACTION = 0.02
"""The temperature's rate is taken over this share of the record (at most :data:`RATE_WINDOW_S`)."""
GAP_FRACTION = 0.02
"""A held-out sample is judged where its temperature lies within this share of the range of one the fit saw."""
MAX_FOLDS = 8
"""At most this many fits per model: with more excursions, they are dealt round-robin into this many folds."""
MIN_JUDGED = 16
"""An excursion is judged on at least this many samples."""
GAIN_SIGMAS = 2.33
"""The held-out gain summed over the excursions must exceed this many standard errors (1 % one-sided)."""
WORSE_ALPHA = 0.01
"""The chance, over the three axes, that a model which changes nothing is called worse."""
WORSE_MIN = 1.0
"""... and by more than the floor's own variance in its held-out mean square (at the floor: RMS 41 %
up): an axis an effect does not act on pays a little for the amplitude its fit gives it there (a
slope fitted to bias wander: 10-20 % in RMS on simulated wandering runs), which is said ("slightly
worse") but is no reason to refuse an effect that the other axes need; a model that makes an axis
worse than that (the real cycle's gyroscope hysteresis: z from 9.7 to 17 times the floor) is refused."""
HEATING, COOLING, PLATEAU = 'heating', 'cooling', 'plateau'


@dataclass(frozen=True)
class Excursion:
    """One heating, cooling or plateau: samples ``start`` to ``stop`` (one past the last), its temperatures."""

    start: int
    stop: int
    kind: str
    first: float
    last: float
    low: float
    high: float

    def describe(self, unit: str = '') -> str:
        """``'cooling 52.1..-17.6 C'``, ``'plateau at 20 C'``."""
        if self.kind == PLATEAU:
            return f'plateau at {(self.low + self.high) / 2.0:.3g}{unit}'
        return f'{self.kind} {self.first:.3g}..{self.last:.3g}{unit}'


def excursions(time_s: np.ndarray, temperature: np.ndarray) -> tuple[Excursion, ...]:
    """The record's thermal excursions, in time order (see the module docstring)."""
    time_s = np.asarray(time_s, dtype=float)
    values = np.asarray(temperature, dtype=float)
    count = len(values)
    if count == 0:
        return ()
    span = MIN_SPAN_FRACTION * float(values.max() - values.min())
    duration = float(time_s[-1] - time_s[0])
    if count < 2 or span <= 0.0 or duration <= 0.0:
        return (_excursion(values, 0, count, PLATEAU),)
    window = min(RATE_WINDOW_S, RATE_WINDOW_FRACTION * duration)
    half = window / 2.0
    ahead = np.interp(np.minimum(time_s + half, time_s[-1]), time_s, values)
    behind = np.interp(np.maximum(time_s - half, time_s[0]), time_s, values)
    smooth = (ahead + behind) / 2.0
    cuts = {0, count, *_turns(smooth, span)}
    plateaus = _plateaus(smooth, MIN_PLATEAU_FRACTION * duration / max(float(np.median(np.diff(time_s))), 1e-12),
                         span / 8.0)
    for a, b in plateaus:
        cuts.update((a, b))
    inside = np.zeros(count, dtype=bool)
    for a, b in plateaus:
        inside[a:b] = True
    edges = sorted(cuts)
    pieces: list[list] = []
    for a, b in zip(edges[:-1], edges[1:]):
        if inside[a]:
            kind = PLATEAU
        else:
            kind = HEATING if smooth[b - 1] >= smooth[a] else COOLING
        small = kind != PLATEAU and abs(smooth[b - 1] - smooth[a]) < span / 2.0
        if pieces and (small or pieces[-1][2] == kind):
            pieces[-1][1] = b
        elif small and pieces == [] and b < count:
            pieces.append([a, b, None])  # joins what follows
        else:
            if pieces and pieces[-1][2] is None:
                pieces[-1][1:] = [b, kind]
            else:
                pieces.append([a, b, kind])
    return tuple(_excursion(values, a, b, kind or PLATEAU) for a, b, kind in pieces)


def _plateaus(smooth: np.ndarray, length: float, band: float) -> list[tuple[int, int]]:
    """Stretches of at least ``length`` samples whose temperature stays within ``band``."""
    from scipy.ndimage import maximum_filter1d, minimum_filter1d
    size = max(int(round(length)), 1)
    if size > len(smooth):
        return []
    # A sample is a plateau's when some window of ``size`` samples holding it stays within the band.
    spread = maximum_filter1d(smooth, size, origin=-(size // 2)) - minimum_filter1d(smooth, size, origin=-(size // 2))
    starts = np.flatnonzero(spread[:len(smooth) - size + 1] < band)
    inside = np.zeros(len(smooth) + 1, dtype=np.int64)
    np.add.at(inside, starts, 1)
    np.add.at(inside, starts + size, -1)
    return _runs(np.cumsum(inside)[:-1] > 0)


def _turns(smooth: np.ndarray, span: float) -> list[int]:
    """Where the temperature turns: a running extreme, once the temperature has come back from it by ``span``."""
    turns: list[int] = []
    direction = 0
    high = low = extreme = 0
    for index in range(1, len(smooth)):
        value = smooth[index]
        if direction == 0:
            high = index if value > smooth[high] else high
            low = index if value < smooth[low] else low
            if smooth[high] - smooth[low] >= span:
                direction, extreme = (1, high) if high > low else (-1, low)
        elif direction * (value - smooth[extreme]) >= 0.0:
            extreme = index
        elif direction * (smooth[extreme] - value) >= span:
            turns.append(extreme)
            direction, extreme = -direction, index
    return turns


def _excursion(values: np.ndarray, start: int, stop: int, kind: str) -> Excursion:
    part = values[start:stop]
    return Excursion(start=start, stop=stop, kind=kind, first=float(part[0]), last=float(part[-1]),
                     low=float(part.min()), high=float(part.max()))


def excursion_labels(count: int, found: Sequence[Excursion]) -> np.ndarray:
    """``(count,)`` the excursion of each sample."""
    labels = np.zeros(count, dtype=np.int64)
    for index, excursion in enumerate(found):
        labels[excursion.start:excursion.stop] = index
    return labels
