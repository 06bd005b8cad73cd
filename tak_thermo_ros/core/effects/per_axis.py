"""Per-axis forms of the library effects whose shape parameters can differ between the axes.

The shared form of ``thermal_lag`` drives the three axes with one lagged copy of the
temperature code; when the three channels' drift sits at different thermal distances from the
sensor (say, their ADC references), each axis lags with its own time constant. The per-axis
form ``thermal_lag_per_axis`` has the shape parameters ``tau_s_x``, ``tau_s_y``, ``tau_s_z``
and the same amplitudes ``slope_x``, ``slope_y``, ``slope_z`` as the shared form: axis ``i``
follows the basis signal of the shared effect evaluated with its own shape parameters.

Implementation: the per-axis effect has one basis signal per axis (suffixes ``_x``, ``_y``,
``_z``, each the shared class's signal with that axis's shape); :meth:`PerAxisEffect.axis_signals`
tells the fit that axis ``i`` uses signal ``i`` only, and :meth:`PerAxisEffect.amplitudes`
returns the amplitudes padded with zeros to the three signals, so the correction link, the
forward model and the simulator apply it unchanged (an added ``0 * signal`` changes no float).

Names are valid ROS parameter names (``calibration.effects.thermal_lag_per_axis.tau_s_x``), so
the node reads such a calibration like any other.
"""

from __future__ import annotations

from typing import Any, ClassVar, Mapping

import numpy as np

from tak_thermo_ros.core.effects.base import AXIS_NAMES, OFFSET, Effect, ParameterSpec

PER_AXIS_SUFFIX = '_per_axis'


class PerAxisEffect(Effect):
    """Base of the per-axis forms: each axis has its own copy of the shared class's shape.

    Subclasses set ``shared`` (the shared class); :func:`per_axis_form` builds them.
    """

    shared: ClassVar[type[Effect]] = Effect

    @classmethod
    def specs_for(cls, structure: Mapping[str, Any]) -> tuple[tuple[ParameterSpec, ...], tuple[ParameterSpec, ...]]:
        """Shape parameters ``<name>_x, _y, _z`` per shared shape parameter; amplitudes as the shared class."""
        template = cls.amplitude
        amplitudes = tuple(ParameterSpec(f'{template.name}_{axis}', template.default, template.min, template.max,
                                         template.unit, template.doc) for axis in AXIS_NAMES)
        return cls.shape_specs_for(structure), amplitudes

    @classmethod
    def basis_suffixes_for(cls, structure: Mapping[str, Any]) -> tuple[str, ...]:
        """One basis signal per axis."""
        return tuple(f'_{axis}' for axis in AXIS_NAMES)

    def _prepare(self) -> None:
        shared_names = [spec.name for spec in self.shared.shape]
        self._axis_effects = tuple(
            self.shared.from_values({name: self._values[f'{name}_{axis}'] for name in shared_names},
                                    key=f'effects.{self.name}', complete=False)
            for axis in AXIS_NAMES)

    def axis_effect(self, axis: int) -> Effect:
        """The shared class with axis ``axis``'s shape parameters (amplitudes zero)."""
        return self._axis_effects[axis]

    def axis_signals(self) -> tuple[tuple[int, ...], tuple[int, ...], tuple[int, ...]]:
        """Axis ``i`` uses basis signal ``i`` only."""
        return ((0,), (1,), (2,))

    def all_amplitude_names(self) -> tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]:
        """One amplitude per axis, for its own basis signal."""
        prefix = self.amplitude.name
        return tuple((f'{prefix}_{axis}',) for axis in AXIS_NAMES)  # type: ignore[return-value]

    def amplitudes(self) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
        """Amplitudes per axis over all three basis signals: zero on the other axes' signals."""
        prefix = self.amplitude.name
        return tuple(tuple(self._values[f'{prefix}_{axis}'] if b == i else 0.0 for b in range(3))
                     for i, axis in enumerate(AXIS_NAMES))  # type: ignore[return-value]

    def start(self, stamp_s: float, temp_code: float) -> Any:
        """The three axes' states of the shared class."""
        return tuple(effect.start(stamp_s, temp_code) for effect in self._axis_effects)

    def step(self, state: Any, stamp_s: float, temp_code: float) -> tuple[Any, tuple[float, ...]]:
        """Advance each axis's copy; the signals are their first basis signals."""
        states = []
        values = []
        for effect, own in zip(self._axis_effects, state):
            own, signal = effect.step(own, stamp_s, temp_code)
            states.append(own)
            values.append(signal[0])
        return tuple(states), tuple(values)

    def basis(self, stamp_s: np.ndarray, temp_code: np.ndarray) -> np.ndarray:
        """The shared class's series path per axis (bit-identical with :meth:`step` as it is)."""
        return np.column_stack([effect.basis(stamp_s, temp_code)[:, 0] for effect in self._axis_effects]) \
            if len(temp_code) else np.zeros((0, 3))

    def search_basis(self, stamp_s: np.ndarray, temp_code: np.ndarray) -> np.ndarray:
        """The shared class's search path per axis."""
        return np.column_stack([effect.search_basis(stamp_s, temp_code)[:, 0] for effect in self._axis_effects]) \
            if len(temp_code) else np.zeros((0, 3))

    @classmethod
    def search_space(cls, time_s: np.ndarray, temp_code: np.ndarray) -> dict[str, tuple[float, float, bool]]:
        """The shared class's range for each axis's copy of a shape parameter."""
        space = cls.shared.search_space(time_s, temp_code)
        return {f'{name}_{axis}': bounds for name, bounds in space.items() for axis in AXIS_NAMES}


def per_axis_form(shared: type[Effect]) -> type[PerAxisEffect]:
    """The per-axis form of an offset effect with one basis signal and shape parameters."""
    shape = tuple(ParameterSpec(f'{spec.name}_{axis}', spec.default, spec.min, spec.max, spec.unit,
                                f'{spec.doc} (axis {axis})'.strip())
                  for spec in shared.shape for axis in AXIS_NAMES)
    namespace = {
        'name': shared.name + PER_AXIS_SUFFIX,
        'summary': shared.summary + ' Per axis: each axis has its own ' + ', '.join(s.name for s in shared.shape) + '.',
        'confirm': shared.confirm,
        'kind': OFFSET,
        'needs_stamps': shared.needs_stamps,
        'shape': shape,
        'amplitude': shared.amplitude,
        'shared': shared,
        '__doc__': f'{shared.__name__} with its shape parameters per axis (see :mod:`{__name__}`).',
        '__module__': __name__,
    }
    return type(f'{shared.__name__}PerAxis', (PerAxisEffect,), namespace)  # type: ignore[return-value]
