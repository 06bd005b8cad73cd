"""The correction link with effects: one implementation, two paths (series and one sample).

Per axis ``i``, with ``G_i = K0_i F_c,i(n)`` and ``e_i`` the sum of the offset effects::

    N_i = G_i f_i + k2_i f_i^2 + sum_{j != i} c_ij f_j + dNs_i(n) + e_i

The correction forms ``y_i = N_i - (dNs_i(n) + e_i)`` and solves for ``f``: by division
without input effects; with ``cross_axis`` by Cramer's rule on the 3x3 matrix
``diag(G) + C``; with ``scale_nonlinearity`` by :data:`FIXED_POINT_ITERATIONS` fixed-point
iterations ``f <- solve(y - k2 f^2)`` from ``f = solve(y)`` (the quadratic term is a small
fraction of the linear one, so each iteration gains some three digits).

:meth:`EffectLink.correct` (numpy arrays) and :meth:`EffectLink.correct_sample` (plain
floats, with the online state of the effects with memory) run the same float operations in
the same order, so they agree bit for bit. :class:`~tak_thermo_ros.core.link.correction.Corrector`
delegates to this class when its calibration has effects, and only then.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from tak_thermo_ros.core.effects.base import INPUT, OFFSET, checked_basis, effect_failure, effect_input
from tak_thermo_ros.core.effects.cross_axis import CrossAxis
from tak_thermo_ros.core.effects.scale_nonlinearity import ScaleNonlinearity
from tak_thermo_ros.core.link.model import Calibration, correction_terms, offset_and_gain
from tak_thermo_ros.errors import CalibrationError

FIXED_POINT_ITERATIONS = 6


def _solver(gain: tuple, cross: tuple | None):
    """A function ``r -> f`` solving ``(diag(gain) + cross) f = r`` (floats or arrays alike)."""
    g0, g1, g2 = gain
    if cross is None:
        return lambda r0, r1, r2: (r0 / g0, r1 / g1, r2 / g2)
    (_, c01, c02), (c10, _, c12), (c20, c21, _) = cross
    # Adjugate of [[g0, c01, c02], [c10, g1, c12], [c20, c21, g2]], then the determinant.
    a00 = g1 * g2 - c12 * c21
    a01 = c02 * c21 - c01 * g2
    a02 = c01 * c12 - c02 * g1
    a10 = c12 * c20 - c10 * g2
    a11 = g0 * g2 - c02 * c20
    a12 = c02 * c10 - g0 * c12
    a20 = c10 * c21 - g1 * c20
    a21 = c01 * c20 - g0 * c21
    a22 = g0 * g1 - c01 * c10
    det = g0 * a00 + c01 * a10 + c02 * a20
    return lambda r0, r1, r2: ((a00 * r0 + a01 * r1 + a02 * r2) / det,
                               (a10 * r0 + a11 * r1 + a12 * r2) / det,
                               (a20 * r0 + a21 * r1 + a22 * r2) / det)


class EffectLink:
    """The correction of a calibration with effects, and the online state of its effects.

    :param calibration: the calibration (its effects may be empty: then this is the base link).
    :param clamp: clamp temperature codes to the calibrated range (else extrapolate).
    """

    def __init__(self, calibration: Calibration, *, clamp: bool) -> None:
        self.calibration = calibration
        self._clamp = clamp
        self._ref = float(calibration.temp_code_ref)
        self._low = float(calibration.temp_code_min)
        self._high = float(calibration.temp_code_max)
        self._axes = correction_terms(calibration)
        self._offset_effects = tuple(e for e in calibration.effects if e.kind == OFFSET)
        self._amplitudes = tuple(tuple(tuple(float(a) for a in axis) for axis in e.amplitudes())
                                 for e in self._offset_effects)
        self._cross = None
        self._quadratic = None
        for effect in calibration.effects:
            if effect.kind != INPUT:
                continue
            if isinstance(effect, CrossAxis):
                self._cross = tuple(tuple(float(c) for c in row) for row in effect.matrix())
            elif isinstance(effect, ScaleNonlinearity):
                quadratic = tuple(float(q) for q in effect.quadratic())
                self._quadratic = quadratic if any(quadratic) else None
            else:
                msg = f'calibration.effects.{effect.name}: unsupported input effect {type(effect).__name__}'
                raise CalibrationError(msg)
        self._needs_stamps = tuple(e.name for e in calibration.effects if e.needs_stamps)
        self.signals = tuple(dict.fromkeys(e.needs_signal for e in self._offset_effects if e.needs_signal))
        """Names of the recorded signals the effects need (``aux:TOPIC``), in order."""
        self._states: list[Any] | None = None

    def reset(self) -> None:
        """Forget the online state: the next sample starts the effects with memory afresh."""
        self._states = None

    def _temp_code(self, temp_code):
        if not self._clamp:
            return temp_code
        if isinstance(temp_code, np.ndarray):
            return np.clip(temp_code, self._low, self._high)
        return min(max(temp_code, self._low), self._high)

    def _check_stamps(self, stamp_s) -> None:
        if stamp_s is None and self._needs_stamps:
            msg = (f'calibration.effects.{self._needs_stamps[0]}: this effect has memory and needs '
                   f'the samples\' stamps (stamp_s)')
            raise CalibrationError(msg)

    def _base(self, n):
        """Per axis ``(dNs(n), G(n))`` (the shared evaluation, floats and arrays alike)."""
        return [offset_and_gain(n, *terms) for terms in self._axes]

    def _solve(self, y: tuple, gain: tuple):
        solve = _solver(gain, self._cross)
        f = solve(*y)
        quadratic = self._quadratic
        if quadratic is not None:
            q0, q1, q2 = quadratic
            y0, y1, y2 = y
            for _ in range(FIXED_POINT_ITERATIONS):
                f0, f1, f2 = f
                f = solve(y0 - q0 * (f0 * f0), y1 - q1 * (f1 * f1), y2 - q2 * (f2 * f2))
        return f

    def offset_series(self, temp_code: np.ndarray, stamp_s: np.ndarray | None,
                      aux: Mapping[str, np.ndarray] | None = None) -> list[np.ndarray]:
        """Sum of the offset effects per axis over a series (from the initial state), counts.

        :param aux: ``(k,)`` held values of the recorded signals the effects need, by name.
        """
        count = len(temp_code)
        stamps = np.zeros(count) if stamp_s is None else np.asarray(stamp_s, dtype=float)
        extra = [np.zeros(count), np.zeros(count), np.zeros(count)]
        for effect, amplitudes in zip(self._offset_effects, self._amplitudes):
            basis = checked_basis(effect, stamps, effect_input(effect, temp_code, aux))
            for i, axis_amplitudes in enumerate(amplitudes):
                total = extra[i]
                for b, amplitude in enumerate(axis_amplitudes):
                    total = total + amplitude * basis[:, b]
                extra[i] = total
        return extra

    def correct(self, counts: np.ndarray, temp_code: np.ndarray,
                stamp_s: np.ndarray | None = None, aux: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
        """Specific force ``(k, 3)`` over a series, from the effects' initial state."""
        self._check_stamps(stamp_s)
        counts = np.asarray(counts, dtype=float)
        code = self._temp_code(np.asarray(temp_code, dtype=float))
        n = code - self._ref
        extra = self.offset_series(code, stamp_s, aux)
        base = self._base(n)
        y = tuple(counts[:, i] - (base[i][0] + extra[i]) for i in range(3))
        f = self._solve(y, tuple(gain for _, gain in base))
        return np.column_stack(f)

    def correct_sample(self, counts_x: float, counts_y: float, counts_z: float, temp_code: float,
                       stamp_s: float, aux: Mapping[str, float] | None = None) -> tuple[float, float, float]:
        """Specific force of one sample (plain floats), advancing the online state.

        :param aux: held values of the recorded signals the effects need, by name.
        """
        code = self._temp_code(temp_code)
        n = code - self._ref
        states = self._states
        if states is None:
            states = []
            for effect in self._offset_effects:
                try:
                    states.append(effect.start(stamp_s, effect_input(effect, code, aux)))
                except Exception as err:
                    raise effect_failure(effect, 'start', err) from err
            self._states = states
        extra = [0.0, 0.0, 0.0]
        for index, (effect, amplitudes) in enumerate(zip(self._offset_effects, self._amplitudes)):
            try:
                state, basis = effect.step(states[index], stamp_s,
                                           code if effect.needs_signal is None else effect_input(effect, code, aux))
            except Exception as err:
                raise effect_failure(effect, 'step', err) from err
            states[index] = state
            for i, axis_amplitudes in enumerate(amplitudes):
                total = extra[i]
                for amplitude, value in zip(axis_amplitudes, basis):
                    total = total + amplitude * value
                extra[i] = total
        base = self._base(n)
        y = (counts_x - (base[0][0] + extra[0]), counts_y - (base[1][0] + extra[1]),
             counts_z - (base[2][0] + extra[2]))
        f = self._solve(y, (base[0][1], base[1][1], base[2][1]))
        return f[0], f[1], f[2]

    def predict_counts(self, specific_force: np.ndarray, temp_code: np.ndarray,
                       stamp_s: np.ndarray | None = None,
                       aux: Mapping[str, np.ndarray] | None = None) -> np.ndarray:
        """Forward model: unrounded codes ``(k, 3)`` for specific force ``(k, 3)``, effects included."""
        self._check_stamps(stamp_s)
        force = np.asarray(specific_force, dtype=float)
        code = self._temp_code(np.asarray(temp_code, dtype=float))
        base = self._base(code - self._ref)
        extra = self.offset_series(code, stamp_s, aux)
        out = np.column_stack([base[i][1] * force[:, i] + (base[i][0] + extra[i]) for i in range(3)])
        for effect in self.calibration.effects:
            if effect.kind == INPUT:
                out = out + effect.input_counts(force)
        return out
