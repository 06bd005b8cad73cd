"""A run's extremes that an export states its limits by: the fastest temperature change and the largest rate."""

from __future__ import annotations

import numpy as np

from tak_thermo_ros.core.records.record import AlignedSamples

RATE_WINDOW_S = 60.0
"""The temperature's rate of change is taken over this long (a thermometer's quantum and noise average out)."""
KEEP_EVERY_S = 5.0
"""One held temperature is kept per this many seconds (memory stays small over any run)."""


class RunExtremes:
    """A consumer of aligned blocks (in time order): the fastest temperature change over 60 s and the largest reference.

    ``temperature_rate_max`` is in the temperature's unit per second; ``reference_max`` is the
    largest norm of the held reference (a rate table's rate, rad/s, on a gyroscope's pass).
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
    def temperature_rate_max(self) -> float:
        """The largest ``|T(t + 60 s) - T(t)| / 60 s`` of the run (0 for a run shorter than 60 s)."""
        stamps = np.asarray(self._stamps)
        if len(stamps) < 2 or stamps[-1] - stamps[0] < RATE_WINDOW_S:
            return 0.0
        grid = np.arange(stamps[0], stamps[-1] + 1e-9, KEEP_EVERY_S)
        held = np.interp(grid, stamps, np.asarray(self._temperatures))
        step = int(round(RATE_WINDOW_S / KEEP_EVERY_S))
        return float(np.max(np.abs(held[step:] - held[:-step])) / RATE_WINDOW_S)
