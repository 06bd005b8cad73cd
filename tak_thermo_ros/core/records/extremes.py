"""A run's temperature course and largest rate: what an export and ``diagnose`` state their limits by."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tak_thermo_ros.core.records.record import AlignedSamples

RATE_WINDOW_S = 60.0
"""The temperature's rate of change is taken over this long (a thermometer's quantum and noise average out)."""
KEEP_EVERY_S = 5.0
"""One held temperature is kept per this many seconds (memory stays small over any run)."""
GAP_S = 2.0 * RATE_WINDOW_S
"""Samples further apart than this start a new stretch of the grid (:func:`temperature_course`): the grid
holds at most ``GAP_S / KEEP_EVERY_S`` points per sample, whatever time the run spans."""
ONE_WAY_FRACTION = 0.1
"""A run whose temperature came back by less than this fraction of its swing moved one way only."""


@dataclass(frozen=True)
class TemperatureCourse:
    """How the temperature went over a run (smoothed over 60 s).

    :param low: the lowest temperature; ``high`` the highest.
    :param rate_max: the fastest change, per second.
    :param rise: the sum of every rise; ``fall`` of every fall (both >= 0).
    """

    low: float
    high: float
    rate_max: float
    rise: float
    fall: float

    @property
    def one_way(self) -> bool:
        """The temperature only rose (or only fell): a lag cannot be told from the curve."""
        swing = max(self.rise, self.fall)
        return swing > 0.0 and min(self.rise, self.fall) < ONE_WAY_FRACTION * swing


def temperature_course(stamp_s: np.ndarray, temperature: np.ndarray) -> TemperatureCourse:
    """The course of a run's temperature from its (time-ordered) samples.

    The temperature is held on a grid of one point per :data:`KEEP_EVERY_S` (linear between
    samples) within each stretch of the run whose samples are at most :data:`GAP_S` apart, so
    that the grid is bounded by the samples, not by the time they span (a stamp that jumps by
    years costs nothing). Across a longer gap the temperature is taken as linear: its slope is
    a candidate for the fastest change, and its change counts as one move up or down.
    """
    stamps = np.asarray(stamp_s, dtype=float)
    values = np.asarray(temperature, dtype=float)
    if len(stamps) < 2 or stamps[-1] - stamps[0] < RATE_WINDOW_S:
        low = float(values.min()) if len(values) else 0.0
        high = float(values.max()) if len(values) else 0.0
        return TemperatureCourse(low, high, 0.0, 0.0, 0.0)
    step = int(round(RATE_WINDOW_S / KEEP_EVERY_S))
    cuts = np.flatnonzero(np.diff(stamps) > GAP_S) + 1
    rate_max = 0.0
    chain: list[np.ndarray] = []  # the held temperature once a minute, stretch after stretch
    for start, end in zip(np.r_[0, cuts], np.r_[cuts, len(stamps)]):
        times, held_at = stamps[start:end], values[start:end]
        grid = np.arange(times[0], times[-1] + 1e-9, KEEP_EVERY_S)
        held = np.interp(grid, times, held_at)
        if len(held) > step:
            rate_max = max(rate_max, float(np.abs(held[step:] - held[:-step]).max()) / RATE_WINDOW_S)
        chain.append(held[::step])
    for before, after in zip(cuts - 1, cuts):
        rate_max = max(rate_max, abs(values[after] - values[before]) / (stamps[after] - stamps[before]))
    moves = np.diff(np.concatenate(chain))
    return TemperatureCourse(low=float(values.min()), high=float(values.max()), rate_max=rate_max,
                             rise=float(moves[moves > 0].sum()), fall=float(-moves[moves < 0].sum()))


class RunExtremes:
    """A consumer of aligned blocks (in time order): the temperature's course and the largest reference.

    ``reference_max`` is the largest norm of the held reference (a rate table's rate, rad/s, on a
    gyroscope's pass).
    """

    def __init__(self) -> None:
        self._stamps: list[float] = []
        self._temperatures: list[float] = []
        self.reference_max = 0.0

    def __call__(self, aligned: AlignedSamples) -> None:
        if not len(aligned):
            return
        seconds = aligned.stamp_ns.astype(np.float64) * 1e-9
        last = self._stamps[-1] if self._stamps else -np.inf
        for stamp, temperature in zip(seconds.tolist(), aligned.temp_code.tolist()):
            if stamp - last >= KEEP_EVERY_S:
                self._stamps.append(stamp)
                self._temperatures.append(temperature)
                last = stamp
        if aligned.reference is not None and len(aligned.reference):
            self.reference_max = max(self.reference_max, float(np.linalg.norm(aligned.reference, axis=1).max()))

    @property
    def course(self) -> TemperatureCourse:
        """The run's temperature course."""
        return temperature_course(np.asarray(self._stamps), np.asarray(self._temperatures))

    @property
    def temperature_rate_max(self) -> float:
        """The largest ``|T(t + 60 s) - T(t)| / 60 s`` of the run (0 for a run shorter than 60 s)."""
        return self.course.rate_max
