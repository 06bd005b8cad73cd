"""``warmup``: an offset that decays exponentially after power-on."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tak_thermo_ros.core.effects.base import Effect, ParameterSpec, typical_interval


class Warmup(Effect):
    """Self-heating and charge settling after power-on shift the offset for a while.

    Model, per axis ``i``::

        N_i += amplitude_i * exp(-(t - t0) / tau_s)

    Power-on ``t0`` is the stamp of the first sample the corrector (or the fit) sees: the first
    sample of the series for ``Corrector.correct`` and the fit, the first message after start
    or ``Corrector.reset()`` in the node. Record from power-on for this effect to mean
    anything.

    Parameters: ``tau_s`` (s, decay time constant, searched), ``amplitude_x``,
    ``amplitude_y``, ``amplitude_z`` (counts at power-on).

    Online state ``t0``; initial state: the first sample's stamp (signal 1 at that sample).
    A stamp before ``t0`` gives the signal 1.
    """

    name = 'warmup'
    summary = ('An offset that decays exponentially after power-on (self-heating, reference settling), '
               'so the residual is large at the start of a run and fades with time, whatever the '
               'temperature does.')
    confirm = ('Power-cycle the unit at a constant chamber temperature and record the first hours: the '
               'offset decays again from the same amplitude after every power-on.')
    needs_stamps = True
    shape = (ParameterSpec('tau_s', 600.0, 1e-3, 1e8, 's', 'decay time constant'),)
    amplitude = ParameterSpec('amplitude', 0.0, -1e5, 1e5, 'counts', 'offset at power-on')

    def _prepare(self) -> None:
        self._tau = self._values['tau_s']

    def start(self, stamp_s: float, temp_code: float) -> Any:
        """Initial state: power-on at the first sample's stamp."""
        return stamp_s

    def step(self, state: Any, stamp_s: float, temp_code: float) -> tuple[Any, tuple[float, ...]]:
        """The basis signal ``exp(-(t - t0) / tau_s)``; the state does not change."""
        since = stamp_s - state
        return state, (math.exp(-since / self._tau) if since > 0.0 else 1.0,)

    def basis(self, stamp_s: np.ndarray, temp_code: np.ndarray) -> np.ndarray:
        """:meth:`step` over a series (the same ``math.exp`` on the same floats)."""
        stamps = np.asarray(stamp_s, dtype=float).tolist()
        if not stamps:
            return np.zeros((0, 1))
        tau = self._tau
        exp = math.exp
        power_on = stamps[0]
        since = [stamp - power_on for stamp in stamps]
        return np.array([exp(-s / tau) if s > 0.0 else 1.0 for s in since]).reshape(-1, 1)

    def search_basis(self, stamp_s: np.ndarray, temp_code: np.ndarray) -> np.ndarray:
        """Vectorised ``numpy.exp`` (may differ from ``math.exp`` in the last bit): for the search only."""
        stamps = np.asarray(stamp_s, dtype=float)
        if not len(stamps):
            return np.zeros((0, 1))
        since = stamps - stamps[0]
        return np.where(since > 0.0, np.exp(-np.maximum(since, 0.0) / self._tau), 1.0).reshape(-1, 1)

    @classmethod
    def search_space(cls, time_s: np.ndarray, temp_code: np.ndarray) -> dict[str, tuple[float, float, bool]]:
        """``tau_s`` from a few sample intervals to the run's length, log scale."""
        duration = float(time_s[-1] - time_s[0]) if len(time_s) > 1 else 1.0
        low = max(3.0 * typical_interval(time_s), 1.0)
        return {'tau_s': (low, max(duration, 10.0 * low), True)}
