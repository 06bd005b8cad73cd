"""The joint parameter vector of one sensor: its three axes' columns side by side.

:class:`Layout` names each parameter and its kind (scale, offset, their temperature terms, a
coupling, an effect term, a record's turn-on offset); :class:`Terms` builds a sensor's design
(the temperature powers, the misalignment, the effects, a pool's turn-on columns) and its layout;
:func:`sensor_matrix` is the sensor's matrix ``M(T)`` a parameter vector gives.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.effects import CrossAxis, Effect
from tak_thermo_ros.core.fit.design import OFFSET_POLYNOMIAL, SCALE_POLYNOMIAL, AxisDesign, Column, Frame, axis_design
from tak_thermo_ros.core.fit.random_effects import TURN_ON, record_indicators, turn_on_columns
from tak_thermo_ros.core.link.model import AXES


@dataclass(frozen=True)
class Layout:
    """The three axes' columns side by side: one parameter vector per sensor.

    :param columns: per axis its design's labels.
    :param starts: where each axis's columns begin.
    :param kinds: per parameter: ``scale``, ``scale_T``, ``offset``, ``offset_T``, ``coupling``, ``effect``.
    :param names: per parameter its name (``x.scale``, ``x.offset_T2``, ``cross_axis.c_yx``, ``warmup.amplitude_x``).
    """

    columns: tuple[tuple[Column, ...], ...]
    starts: tuple[int, ...]
    kinds: tuple[str, ...]
    names: tuple[str, ...]

    @classmethod
    def of(cls, columns: Sequence[tuple[Column, ...]]) -> Layout:
        starts, kinds, names = [], [], []
        for axis, labels in enumerate(columns):
            starts.append(len(kinds))
            scale = offset = 0
            for label in labels:
                if label.term == SCALE_POLYNOMIAL:
                    kinds.append('scale' if scale == 0 else 'scale_T')
                    names.append(f'{AXES[axis]}.scale' + (f'_T{scale}' if scale else ''))
                    scale += 1
                elif label.term == OFFSET_POLYNOMIAL:
                    kinds.append('offset' if offset == 0 else 'offset_T')
                    names.append(f'{AXES[axis]}.offset' + (f'_T{offset}' if offset else ''))
                    offset += 1
                elif label.term == TURN_ON:
                    kinds.append('turn_on')
                    names.append(f'{AXES[axis]}.turn_on.{label.parameter}')
                else:
                    kinds.append('coupling' if label.effect == CrossAxis.name else 'effect')
                    names.append(f'{label.effect}.{label.parameter}')
        return cls(tuple(columns), tuple(starts), tuple(kinds), tuple(names))

    @property
    def width(self) -> int:
        return len(self.kinds)

    def axis_part(self, theta: np.ndarray, axis: int) -> np.ndarray:
        start = self.starts[axis]
        return theta[start:start + len(self.columns[axis])]

    def index(self, name: str) -> int:
        return self.names.index(name)

    def turn_on(self, axis: int) -> list[int]:
        """The columns of one axis's turn-on offsets (a pool's records), in record order."""
        start = self.starts[axis]
        return [start + j for j, label in enumerate(self.columns[axis]) if label.term == TURN_ON]

    def initial(self) -> np.ndarray:
        """Scale 1, everything else 0."""
        theta = np.zeros(self.width)
        theta[[i for i, kind in enumerate(self.kinds) if kind == 'scale']] = 1.0
        return theta


def joint(designs: Sequence[AxisDesign], layout: Layout) -> np.ndarray:
    """``(n, 3, W)``: each axis's design in its own columns of the sensor's parameter vector."""
    rows = len(designs[0].target)
    out = np.zeros((rows, 3, layout.width))
    for axis, design in enumerate(designs):
        start = layout.starts[axis]
        out[:, axis, start:start + design.matrix.shape[1]] = design.matrix
    return out


@dataclass
class Terms:
    """What a sensor's design needs besides the force: the temperature powers, the effects and their bases."""

    frame: Frame
    bias_order: int
    scale_order: int
    effects: tuple[Effect, ...] = ()
    records: int = 1
    """A pool's records: each adds its turn-on offset's column per axis (a random effect)."""

    def designs(self, powers: Sequence[np.ndarray], force: np.ndarray, counts: np.ndarray,
                bases: Sequence[np.ndarray], record: np.ndarray | None = None) -> list[AxisDesign]:
        offset_bases = [(effect, basis) for effect, basis in zip(self.effects, bases)]
        designs = [axis_design(axis, powers, force, counts, bias_order=self.bias_order, scale_order=self.scale_order,
                               input_effects=(CrossAxis(),), offset_bases=offset_bases) for axis in range(3)]
        if self.records < 2:
            return designs
        indicators = record_indicators(np.zeros(len(force), dtype=np.int64) if record is None else record,
                                       self.records)
        labels = turn_on_columns(self.records)
        return [AxisDesign(np.hstack([design.matrix, indicators]), design.target, design.columns + labels)
                for design in designs]

    def layout(self) -> Layout:
        dummy = np.zeros((1, 3))
        powers = [np.zeros(1)] * (max(self.bias_order, self.scale_order) + 1)
        bases = [np.zeros((1, len(effect.basis_suffixes()))) for effect in self.effects]
        return Layout.of([design.columns for design in self.designs(powers, dummy, dummy, bases)])


def sensor_matrix(theta: np.ndarray, layout: Layout, powers: Sequence[np.ndarray], scale_order: int) -> np.ndarray:
    """``M(T)`` ``(n, 3, 3)``: ``K0 F_c(T)`` on the diagonal, the couplings off it."""
    count = len(powers[0])
    out = np.zeros((count, 3, 3))
    for axis in range(3):
        part = layout.axis_part(theta, axis)
        out[:, axis, axis] = sum(part[j] * powers[j] for j in range(scale_order + 1))
    for index, name in enumerate(layout.names):
        if layout.kinds[index] == 'coupling':
            channel, force = AXES.index(name[-2]), AXES.index(name[-1])
            out[:, channel, force] = theta[index]
    return out
