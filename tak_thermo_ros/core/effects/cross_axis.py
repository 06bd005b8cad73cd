"""``cross_axis``: each channel responds to the specific force along the other axes."""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from tak_thermo_ros.core.effects.base import AXIS_NAMES, INPUT, Effect, ParameterSpec

PAIRS: tuple[tuple[int, int], ...] = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))
"""``(channel, axis of the force)`` of the six coupling terms, in parameter order."""


class CrossAxis(Effect):
    """Misalignment: the sensitive axes are not quite the axes of the sensor frame.

    Model, per channel ``i`` and the other axes ``j``::

        N_i += sum_{j != i} c_ij * f_j

    The off-diagonal of a 3x3 sensitivity matrix whose diagonal is ``K0 F_c(n)``; a
    misalignment angle is about ``c_ij / K0`` rad.

    Parameters: ``c_xy``, ``c_xz``, ``c_yx``, ``c_yz``, ``c_zx``, ``c_zy`` (counts per m/s^2:
    channel first, force axis second).

    No state. The correction solves the 3x3 linear system per sample (Cramer's rule, the same
    operations in both paths).
    """

    name = 'cross_axis'
    summary = ('Each channel also responds to the specific force along the other two axes (axis '
               'misalignment), so the residual of one channel follows the inputs of the others.')
    confirm = ('Turntable positions that put 1 g on one axis at a time, then on two at once: a channel '
               'whose input is 0 g still moves with the others by c_ij g.')
    kind = INPUT
    amplitude = ParameterSpec('c', 0.0, -1e6, 1e6, 'counts/(m/s^2)', 'coupling of channel i to force j')

    @classmethod
    def specs_for(cls, structure: Mapping[str, Any]) -> tuple[tuple[ParameterSpec, ...], tuple[ParameterSpec, ...]]:
        """No shape parameters; the six couplings."""
        template = cls.amplitude
        return (), tuple(ParameterSpec(f'c_{AXIS_NAMES[i]}{AXIS_NAMES[j]}', 0.0, template.min, template.max,
                                       template.unit, template.doc) for i, j in PAIRS)

    def all_amplitude_names(self) -> tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]:
        """Per channel, the names of its two couplings."""
        return tuple(tuple(f'c_{AXIS_NAMES[i]}{AXIS_NAMES[j]}' for j in range(3) if j != i)
                     for i in range(3))  # type: ignore[return-value]

    def matrix(self) -> tuple[tuple[float, float, float], ...]:
        """The 3x3 coupling matrix, zero diagonal, counts per m/s^2."""
        rows = [[0.0, 0.0, 0.0] for _ in range(3)]
        for i, j in PAIRS:
            rows[i][j] = self._values[f'c_{AXIS_NAMES[i]}{AXIS_NAMES[j]}']
        return tuple(tuple(row) for row in rows)

    def input_columns(self, axis: int, force: np.ndarray) -> list[tuple[str, np.ndarray]]:
        """The columns ``f_j`` (j != i) with amplitudes ``c_ij``."""
        return [(f'c_{AXIS_NAMES[axis]}{AXIS_NAMES[j]}', force[:, j]) for j in range(3) if j != axis]

    def input_counts(self, force: np.ndarray) -> np.ndarray:
        """``sum_j c_ij f_j`` per channel, counts."""
        return np.asarray(force, dtype=float) @ np.array(self.matrix()).T
