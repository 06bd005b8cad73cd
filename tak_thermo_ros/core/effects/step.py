"""``step``: a sudden level change of the offset at one moment of the record."""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from tak_thermo_ros.core.effects.base import Effect, ParameterSpec
from tak_thermo_ros.core.records.steps import find_steps

MIN_SIDE_SAMPLES = 10
"""The fit places the step with at least this many samples (and 1 % of them) on each side: a
change before the tenth sample is an outlier or a start-up, not a level the record holds."""
CANDIDATE_STEPS = 1
"""The fit places the step at the residual's most sudden level change (the largest against the
record's own spread), not where least squares alone would put it: a step placed anywhere splits the
slow structure of a residual instead (a temperature reversal under a lag)."""
NEAR_SAMPLES = 1
"""... trying each moment within this many samples of it (least squares alone, given more room, moves a
step towards the slow structure on either side)."""


class Step(Effect):
    """A level change at one moment: package stress released, a solder joint, icing below 0 C.

    Model, per axis ``i``::

        N_i += amplitude_i * (1 if t >= origin_s + at_s else 0)

    ``t`` is the sample stamp in seconds (the record's own clock, as the node sees it), so the
    fit, ``apply`` and the node change level at the same sample. ``origin_s`` is the first stamp of
    the record the step was fitted on (fixed); ``at_s`` the moment after it (searched over the
    midpoints between samples). On another run a step fitted at a moment of this one holds the
    level after the step from that moment on (a later run: throughout): the sensor's latest
    level. The offsets of the base model are the level before.

    Parameters: ``origin_s`` (s, fixed), ``at_s`` (s, searched), ``amplitude_x``,
    ``amplitude_y``, ``amplitude_z`` (counts: the change of the offset at the step).

    Stateless: the basis signal depends on the stamp alone.
    """

    name = 'step'
    summary = ('A sudden change of the offset at one moment (package stress released, a connection, icing), '
               'on one or several axes at once, after which the level holds: neither a function of the '
               'temperature nor a slow drift.')
    confirm = ('Look at the raw output around the moment: a step within a sample or two that stays; repeat the '
               'run: a step of the sensor recurs at random moments, one of the temperature at the same one.')
    needs_stamps = True
    shape = (ParameterSpec('origin_s', 0.0, -1e12, 1e12, 's', 'first stamp of the record fitted (fixed)'),
             ParameterSpec('at_s', 0.0, -1e12, 1e12, 's', 'the moment of the step after origin_s'))
    amplitude = ParameterSpec('amplitude', 0.0, -1e5, 1e5, 'counts', 'the change of the offset at the step')

    def _prepare(self) -> None:
        self._at = self._values['origin_s'] + self._values['at_s']

    @property
    def stamp_s(self) -> float:
        """The stamp of the step, seconds (``origin_s + at_s``)."""
        return self._at

    def shape_varies(self) -> dict[str, bool]:
        """``origin_s`` is fixed (the record's first stamp); ``at_s`` is searched."""
        return {'origin_s': False}

    def step(self, state: Any, stamp_s: float, temp_code: float) -> tuple[Any, tuple[float, ...]]:
        """The basis signal: 1 from the step on, 0 before."""
        return state, (1.0 if stamp_s >= self._at else 0.0,)

    def basis(self, stamp_s: np.ndarray, temp_code: np.ndarray) -> np.ndarray:
        """:meth:`step` over a series (the same comparison on the same floats)."""
        stamps = np.asarray(stamp_s, dtype=float)
        return (stamps >= self._at).astype(float).reshape(-1, 1)

    @classmethod
    def structures(cls, time_s: np.ndarray, temp_code: np.ndarray) -> Sequence[Effect] | None:
        """One structure: the origin at the first stamp the fit sees (too few samples: said by the search)."""
        if not len(time_s):
            return None
        return [cls.from_values({'origin_s': float(np.min(time_s))}, complete=False)]

    @classmethod
    def search_space(cls, time_s: np.ndarray, temp_code: np.ndarray) -> dict[str, tuple[float, float, bool]]:
        """``at_s`` between the run's first and last stamps (linear scale)."""
        stamps = np.asarray(time_s, dtype=float)
        if not len(stamps):
            return {}
        return {'at_s': (0.0, float(stamps.max() - stamps.min()), False)}

    def search_values(self, time_s: np.ndarray, temp_code: np.ndarray,
                      residual: np.ndarray) -> dict[str, np.ndarray]:
        """The moments the fit tries: around the sudden level changes of the residual, midway between samples.

        The most sudden change (:func:`~tak_thermo_ros.core.records.steps.find_steps`, the
        record's own spread as the yardstick, whether or not it stands out of it; see
        :data:`CANDIDATE_STEPS`), each moment within :data:`NEAR_SAMPLES` of it, enough samples on
        each side; every moment when the residual has no sudden change at all.
        """
        stamps = np.asarray(time_s, dtype=float)
        order = np.argsort(stamps, kind='stable')
        stamps, residual = stamps[order], np.asarray(residual, dtype=float)[order]
        side = max(MIN_SIDE_SAMPLES, len(stamps) // 100)
        if len(stamps) < 2 * side + 1:
            return {'at_s': np.zeros(0)}
        found = find_steps(residual, threshold=0.0, max_steps=CANDIDATE_STEPS)
        indices = sorted({step.index + shift for step in found for shift in range(-NEAR_SAMPLES, NEAR_SAMPLES + 1)
                          if side <= step.index + shift <= len(stamps) - side})
        if not indices:
            indices = list(range(side, len(stamps) - side + 1))
        indices = np.array(indices)
        middles = 0.5 * (stamps[indices - 1] + stamps[indices])
        return {'at_s': np.unique(middles[stamps[indices - 1] < stamps[indices]]) - self['origin_s']}
