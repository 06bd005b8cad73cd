"""``temperature_shape``: a temperature dependence that the power series cannot follow."""

from __future__ import annotations

import re
from typing import Any, Mapping, Sequence

import numpy as np

from tak_thermo_ros.core.effects.base import Effect, ParameterSpec
from tak_thermo_ros.errors import CalibrationError

MAX_KNOTS = 8
_KNOT = re.compile(r'knot_(\d+)$')


class TemperatureShape(Effect):
    """A linear spline in the temperature code added to the offset polynomial.

    Model, per axis ``i``, with knots ``k_1 < ... < k_m`` in temperature codes::

        N_i += sum_j slope_i_j * max(N_t - k_j, 0)

    Each knot adds a change of slope, so together with the offset polynomial the offset can
    bend sharply (a kink: a regulator changing mode) or flatten (a saturation), which a
    low-order power series cannot. The fit places ``m`` knots evenly inside the calibrated
    range and chooses ``m`` (1 to 8) by blocked cross-validation, so extra knots that only
    follow the noise lose.

    Parameters: ``knot_1`` .. ``knot_m`` (temperature codes, fixed, not searched),
    ``slope_x_1`` .. ``slope_z_m`` (counts per code: change of slope at each knot).

    No state (the signal depends on the current temperature code only).
    """

    name = 'temperature_shape'
    summary = ('The offset bends with temperature in a way the chosen power series cannot follow (a kink '
               'or a saturation), so the residual against N_t shows a smooth systematic shape, the same on '
               'heating and on cooling.')
    confirm = ('More plateaus, closer together, across the range: the residual against temperature '
               'keeps its shape, and a spline with a knot near the bend removes it.')
    amplitude = ParameterSpec('slope', 0.0, -1e3, 1e3, 'counts/code', 'change of slope at the knot')

    @classmethod
    def structure_from_values(cls, values: Mapping[str, Any]) -> dict[str, Any]:
        """The number of knots: the ``knot_<j>`` keys present."""
        numbers = sorted(int(match.group(1)) for match in map(_KNOT.match, values) if match)
        return {'knots': len(numbers), 'numbers': tuple(numbers)}

    @classmethod
    def basis_suffixes_for(cls, structure: Mapping[str, Any]) -> tuple[str, ...]:
        """``_1`` .. ``_m``, one basis signal per knot."""
        return tuple(f'_{j}' for j in range(1, structure['knots'] + 1))

    @classmethod
    def shape_specs_for(cls, structure: Mapping[str, Any]) -> tuple[ParameterSpec, ...]:
        """``knot_1`` .. ``knot_m`` in temperature codes."""
        return tuple(ParameterSpec(f'knot_{j}', 0.0, -1e9, 1e9, 'codes', 'knot position')
                     for j in range(1, structure['knots'] + 1))

    @classmethod
    def check_structure(cls, values: Mapping[str, float], *, key: str) -> None:
        """Knots numbered 1..m (1 <= m <= 8), strictly increasing."""
        knots = [name for name in values if _KNOT.match(name)]
        if not knots:
            msg = f'{key}.knot_1: missing (temperature_shape needs at least one knot)'
            raise CalibrationError(msg)
        if len(knots) > MAX_KNOTS:
            msg = f'{key}.knot_{MAX_KNOTS + 1}: at most {MAX_KNOTS} knots'
            raise CalibrationError(msg)
        positions = [values[f'knot_{j}'] for j in range(1, len(knots) + 1) if f'knot_{j}' in values]
        if len(positions) != len(knots):
            missing = next(j for j in range(1, len(knots) + 1) if f'knot_{j}' not in values)
            msg = f'{key}.knot_{missing}: missing (knots are numbered 1..{len(knots)})'
            raise CalibrationError(msg)
        for j in range(1, len(positions)):
            if not positions[j] > positions[j - 1]:
                msg = f'{key}.knot_{j + 1}: knots must increase, got {positions[j]:g} after {positions[j - 1]:g}'
                raise CalibrationError(msg)

    def shape_varies(self) -> dict[str, bool]:
        """Knot positions are fixed; the number of knots is chosen by cross-validation."""
        return {name: False for name in self.shape_names()}

    def _prepare(self) -> None:
        self._knots = tuple(self._values[f'knot_{j}'] for j in range(1, self.structure['knots'] + 1))

    def knots(self) -> tuple[float, ...]:
        """Knot positions in temperature codes, in order."""
        return self._knots

    def step(self, state: Any, stamp_s: float, temp_code: float) -> tuple[Any, tuple[float, ...]]:
        """``max(N_t - k_j, 0)`` for every knot."""
        return state, tuple([temp_code - knot if temp_code > knot else 0.0 for knot in self._knots])

    def basis(self, stamp_s: np.ndarray, temp_code: np.ndarray) -> np.ndarray:
        """:meth:`step` over a series (elementwise, same operations)."""
        codes = np.asarray(temp_code, dtype=float)
        return np.column_stack([np.where(codes > knot, codes - knot, 0.0) for knot in self.knots()]
                               ) if len(codes) else np.zeros((0, len(self.knots())))

    @classmethod
    def structures(cls, time_s: np.ndarray, temp_code: np.ndarray) -> Sequence[Effect] | None:
        """1 to 8 knots, evenly spaced inside the range of the temperature codes."""
        low, high = float(np.min(temp_code)), float(np.max(temp_code))
        if not high > low:
            return []
        candidates = []
        for count in range(1, MAX_KNOTS + 1):
            knots = {f'knot_{j}': round(low + j * (high - low) / (count + 1), 2) for j in range(1, count + 1)}
            candidates.append(cls.from_values(knots, complete=False))
        return candidates
