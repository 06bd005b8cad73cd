"""``thermal_lag``: part of the offset drift follows a lagged copy of the temperature code."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tak_thermo_ros.core.effects.base import Effect, ParameterSpec, typical_interval


class ThermalLag(Effect):
    """The drifting part sits at a thermal distance from the temperature sensor.

    Model, per axis ``i``::

        N_i += slope_i * (N_lag - N_t),     tau_s dN_lag/dt = N_t - N_lag

    ``N_lag`` is a first-order-lagged copy of the temperature code, discretised exactly for a
    code held between samples: ``N_lag <- N_t + (N_lag - N_t) exp(-dt / tau_s)``.

    Parameters: ``tau_s`` (s, time constant, searched), ``slope_x``, ``slope_y``, ``slope_z``
    (counts per temperature code: how much offset follows the lagged copy instead of the
    sensor).

    Online state ``(N_lag, last stamp)``; initial state: ``N_lag`` equal to the first sample's
    temperature code (the unit is taken to be in thermal equilibrium at start) and the first
    sample's stamp. A stamp that goes backwards holds ``N_lag`` for that step.
    """

    name = 'thermal_lag'
    summary = ('Part of the offset drift follows a lagged copy of the temperature code (time constant '
               'tau_s), so during ramps the residual is proportional to dN_t/dt and heating and cooling '
               'ramps leave loops that close again on the plateaus.')
    confirm = ('A heating and a cooling ramp at two different rates: the loop opening grows with the ramp '
               'rate and vanishes after a few tau_s on each plateau.')
    needs_stamps = True
    shape = (ParameterSpec('tau_s', 1800.0, 1e-3, 1e8, 's', 'time constant of the lag'),)
    amplitude = ParameterSpec('slope', 0.0, -1e3, 1e3, 'counts/code',
                              'offset per code of lag (N_lag - N_t)')

    def _prepare(self) -> None:
        self._tau = self._values['tau_s']

    def start(self, stamp_s: float, temp_code: float) -> Any:
        """Initial state: in equilibrium with the first temperature code."""
        return (temp_code, stamp_s)

    def step(self, state: Any, stamp_s: float, temp_code: float) -> tuple[Any, tuple[float, ...]]:
        """Advance the lagged code by one sample; the basis signal is ``N_lag - N_t``."""
        lagged, last = state
        dt = stamp_s - last
        decay = math.exp(-dt / self._tau) if dt > 0.0 else 1.0
        lagged = temp_code + (lagged - temp_code) * decay
        return (lagged, stamp_s), (lagged - temp_code,)

    def basis(self, stamp_s: np.ndarray, temp_code: np.ndarray) -> np.ndarray:
        """The recurrence of :meth:`step` over a series (same float operations)."""
        stamps = np.asarray(stamp_s, dtype=float).tolist()
        codes = np.asarray(temp_code, dtype=float).tolist()
        out = [0.0] * len(codes)
        if not codes:
            return np.zeros((0, 1))
        tau = self._tau
        exp = math.exp
        lagged, last = codes[0], stamps[0]
        previous_dt = None
        decay = 1.0
        for k, (stamp, code) in enumerate(zip(stamps, codes)):
            dt = stamp - last
            if dt != previous_dt:
                decay = exp(-dt / tau) if dt > 0.0 else 1.0
                previous_dt = dt
            lagged = code + (lagged - code) * decay
            out[k] = lagged - code
            last = stamp
        return np.array(out).reshape(-1, 1)

    def search_basis(self, stamp_s: np.ndarray, temp_code: np.ndarray) -> np.ndarray:
        """The same recurrence solved in closed form by segments (vectorised): for the search only.

        With ``a_k = sum_{i<=k} dt_i / tau``, ``N_lag,k = exp(-a_k) (N_lag,0 + sum_j (1 - d_j) N_t,j
        exp(a_j))``; segments restart where ``a`` has grown by 500, before ``exp(a)`` overflows.
        """
        stamps = np.asarray(stamp_s, dtype=float)
        codes = np.asarray(temp_code, dtype=float)
        if not len(codes):
            return np.zeros((0, 1))
        steps = np.maximum(np.diff(stamps, prepend=stamps[0]), 0.0) / self._tau
        decay = np.exp(-steps)
        growth = np.cumsum(steps)
        lagged = np.empty(len(codes))
        start, previous = 0, codes[0]
        while start < len(codes):
            end = int(np.searchsorted(growth, growth[start] + 500.0, side='left'))
            end = max(end, start + 1)
            relative = growth[start:end] - growth[start]
            weights = np.exp(relative)
            inputs = (1.0 - decay[start:end]) * codes[start:end]
            inputs[0] += decay[start] * previous
            lagged[start:end] = np.cumsum(inputs * weights) / weights
            previous = lagged[end - 1]
            start = end
        return (lagged - codes).reshape(-1, 1)

    @classmethod
    def search_space(cls, time_s: np.ndarray, temp_code: np.ndarray) -> dict[str, tuple[float, float, bool]]:
        """``tau_s`` from a few sample intervals to twice the run's length, log scale."""
        duration = float(time_s[-1] - time_s[0]) if len(time_s) > 1 else 1.0
        low = max(3.0 * typical_interval(time_s), 1.0)
        return {'tau_s': (low, max(2.0 * duration, 10.0 * low), True)}
