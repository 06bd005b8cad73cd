"""``scale_nonlinearity``: a second-order response to the input."""

from __future__ import annotations

import numpy as np

from tak_thermo_ros.core.effects.base import AXIS_NAMES, INPUT, Effect, ParameterSpec


class ScaleNonlinearity(Effect):
    """The channel's response to specific force is slightly quadratic.

    Model, per axis ``i``::

        N_i += k2_i * f_i^2

    with ``f_i`` the specific force along the axis in m/s^2. It is told apart from the offset
    only where an axis sees 0 g as well as +-g (the simulator's tilted positions give that),
    and from the scale only where it sees both signs.

    Parameters: ``k2_x``, ``k2_y``, ``k2_z`` (counts per (m/s^2)^2).

    No state. The correction inverts it together with ``cross_axis`` by a fixed number of
    fixed-point iterations (see ``Corrector``).
    """

    name = 'scale_nonlinearity'
    summary = ('The response to specific force has a second-order term k2 f^2, so the residual is the '
               'same at +g and -g and differs from the one at 0 g: it follows f^2, not f and not temperature.')
    confirm = ('Turntable positions at +1 g, -1 g and 0 g (tilted) on each axis at one temperature: '
               'the mean of the +g and -g codes differs from the 0 g code by k2 g^2.')
    kind = INPUT
    amplitude = ParameterSpec('k2', 0.0, -1.0, 1.0, 'counts/(m/s^2)^2', 'second-order response')

    def quadratic(self) -> tuple[float, float, float]:
        """``(k2_x, k2_y, k2_z)``."""
        return tuple(self._values[f'k2_{axis}'] for axis in AXIS_NAMES)  # type: ignore[return-value]

    def input_columns(self, axis: int, force: np.ndarray) -> list[tuple[str, np.ndarray]]:
        """The column ``f_i^2`` with amplitude ``k2_i``."""
        column = force[:, axis]
        return [(f'k2_{AXIS_NAMES[axis]}', column * column)]

    def input_counts(self, force: np.ndarray) -> np.ndarray:
        """``k2_i f_i^2`` per axis, counts."""
        force = np.asarray(force, dtype=float)
        return force * force * np.array(self.quadratic())
