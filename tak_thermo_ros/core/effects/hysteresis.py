"""``hysteresis``: the offset depends on the direction of the last temperature change."""

from __future__ import annotations

from typing import Any

import numpy as np

from tak_thermo_ros.core.effects.base import Effect, ParameterSpec


class Hysteresis(Effect):
    """A play (backlash) operator on the temperature code drives part of the offset.

    Model, per axis ``i``, with ``r = width_codes / 2``::

        p <- min(max(p, N_t - r), N_t + r)        (the play operator)
        N_i += amplitude_i * (N_t - p) / r

    ``(N_t - p) / r`` is +1 after heating, -1 after cooling, and moves linearly in between
    while the code reverses through the play's width; it stays put on a plateau (unlike a lag).

    Parameters: ``width_codes`` (temperature codes, full width of the play, searched),
    ``amplitude_x``, ``amplitude_y``, ``amplitude_z`` (counts: the offset after heating is
    ``+amplitude``, after cooling ``-amplitude``).

    Online state ``p``; initial state: ``p`` equal to the first sample's temperature code
    (the signal starts at 0, halfway between the heating and the cooling branch).
    Stamps are not used: only the order of the samples.
    """

    name = 'hysteresis'
    summary = ('The offset depends on whether the temperature last rose or fell (a play operator of '
               'width width_codes), so heating and cooling branches differ by a constant step that '
               'persists on plateaus, which a thermal lag does not.')
    confirm = ('Reach one plateau once from below and once from above and hold it: a hysteresis step '
               'stays for the whole plateau, a lag decays within a few time constants.')
    shape = (ParameterSpec('width_codes', 40.0, 1e-6, 1e7, 'codes',
                           'full width of the play in temperature codes'),)
    amplitude = ParameterSpec('amplitude', 0.0, -1e5, 1e5, 'counts',
                              'offset on the heating branch (minus on cooling)')

    def _prepare(self) -> None:
        self._half = self._values['width_codes'] * 0.5

    def start(self, stamp_s: float, temp_code: float) -> Any:
        """Initial state: the play centred on the first temperature code."""
        return temp_code

    def step(self, state: Any, stamp_s: float, temp_code: float) -> tuple[Any, tuple[float, ...]]:
        """Advance the play operator by one sample; the basis signal is ``(N_t - p) / r``."""
        half = self._half
        low = temp_code - half
        high = temp_code + half
        play = state if state > low else low
        play = play if play < high else high
        return play, ((temp_code - play) / half,)

    def basis(self, stamp_s: np.ndarray, temp_code: np.ndarray) -> np.ndarray:
        """The recurrence of :meth:`step` over a series (same float operations)."""
        codes = np.asarray(temp_code, dtype=float).tolist()
        if not codes:
            return np.zeros((0, 1))
        half = self._half
        out = [0.0] * len(codes)
        play = codes[0]
        for k, code in enumerate(codes):
            low = code - half
            high = code + half
            play = play if play > low else low
            play = play if play < high else high
            out[k] = (code - play) / half
        return np.array(out).reshape(-1, 1)

    def search_basis(self, stamp_s: np.ndarray, temp_code: np.ndarray) -> np.ndarray:
        """:meth:`basis` over the runs of equal codes only (for the search; the same values).

        The play operator is idempotent for a repeated code (clipping twice into the same band
        changes nothing), so a held code repeats the previous output exactly: the recurrence
        runs once per run of equal codes, which on plateaus is a small fraction of the samples.
        """
        codes = np.asarray(temp_code, dtype=float)
        if not len(codes):
            return np.zeros((0, 1))
        starts = np.flatnonzero(np.concatenate(([True], codes[1:] != codes[:-1])))
        compressed = self.basis(np.zeros(len(starts)), codes[starts])[:, 0]
        run_index = np.cumsum(np.concatenate(([True], codes[1:] != codes[:-1]))) - 1
        return compressed[run_index].reshape(-1, 1)

    @classmethod
    def search_space(cls, time_s: np.ndarray, temp_code: np.ndarray) -> dict[str, tuple[float, float, bool]]:
        """``width_codes`` from the temperature's quantum to half its range, log scale.

        The quantum is the smallest step between the distinct temperatures of the run: one code
        for the paper's codes, e.g. 1/256 degrees C for a driver's temperature (a play narrower
        than one degree is common there), and at least a ten-thousandth of the range.
        """
        levels = np.unique(np.asarray(temp_code, dtype=float))
        span = float(levels[-1] - levels[0]) if len(levels) else 2.0
        steps = np.diff(levels)
        low = max(float(steps.min()), 1e-4 * span) if steps.size else 1.0
        return {'width_codes': (low, max(span / 2.0, 2.0 * low), True)}
