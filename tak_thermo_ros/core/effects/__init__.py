"""The effect library: physical terms that the paper's base model lacks, one class each.

``LIBRARY`` maps the fixed vocabulary to the classes; :func:`resolve_effect` also accepts a
user-defined effect as ``'module:Class'`` (see ``docs/effects.md``). ``PER_AXIS`` maps the
per-axis forms of the effects whose shape parameters can differ between axes
(``thermal_lag_per_axis``, ``hysteresis_per_axis``, ``warmup_per_axis``; see
:mod:`~tak_thermo_ros.core.effects.per_axis`); they resolve by name like the library. A name
with axes in brackets, ``thermal_lag[xz]``, is the effect fitted on those axes only
(:mod:`~tak_thermo_ros.core.effects.held`).
"""

from __future__ import annotations

import importlib
import os
import sys

from tak_thermo_ros.core.effects.base import (
    INPUT,
    OFFSET,
    Effect,
    Parameter,
    ParameterSpec,
)
from tak_thermo_ros.core.effects.aux_signal import AUX_PREFIX, AuxSignal, aux_effect_class, is_aux_effect
from tak_thermo_ros.core.effects.cross_axis import CrossAxis
from tak_thermo_ros.core.effects.held import held_form, held_of, split_held
from tak_thermo_ros.core.effects.hysteresis import Hysteresis
from tak_thermo_ros.core.effects.per_axis import PER_AXIS_SUFFIX, PerAxisEffect, per_axis_form
from tak_thermo_ros.core.effects.scale_nonlinearity import ScaleNonlinearity
from tak_thermo_ros.core.effects.step import Step
from tak_thermo_ros.core.effects.temperature_shape import TemperatureShape
from tak_thermo_ros.core.effects.thermal_lag import ThermalLag
from tak_thermo_ros.core.effects.warmup import Warmup
from tak_thermo_ros.core.records.stamps import seconds, seconds_from_ns
from tak_thermo_ros.errors import FitError

LIBRARY: dict[str, type[Effect]] = {
    cls.name: cls for cls in (ThermalLag, Hysteresis, ScaleNonlinearity, CrossAxis, Warmup, TemperatureShape, Step)
}
"""The library effects by name."""

PER_AXIS: dict[str, type[Effect]] = {
    form.name: form for form in (per_axis_form(ThermalLag), per_axis_form(Hysteresis), per_axis_form(Warmup))
}
"""The per-axis forms by name (``<shared name>_per_axis``)."""

__all__ = [
    'AUX_PREFIX',
    'INPUT',
    'LIBRARY',
    'OFFSET',
    'PER_AXIS',
    'PER_AXIS_SUFFIX',
    'PerAxisEffect',
    'AuxSignal',
    'CrossAxis',
    'Effect',
    'Hysteresis',
    'Parameter',
    'ParameterSpec',
    'ScaleNonlinearity',
    'Step',
    'TemperatureShape',
    'ThermalLag',
    'Warmup',
    'aux_effect_class',
    'effect_spec',
    'held_form',
    'held_of',
    'is_aux_effect',
    'resolve_effect',
    'seconds',
    'seconds_from_ns',
]


def _import_module(module: str, spec: str):
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as err:
        if err.name != module.split('.')[0] and err.name != module:
            msg = f"effect '{spec}': importing module {module} failed: {err}"
            raise FitError(msg) from None
    # Not on the path: look in the current directory too (console scripts do not put it there).
    here = os.getcwd()
    if here not in sys.path:
        sys.path.append(here)
        try:
            return importlib.import_module(module)
        except ModuleNotFoundError:
            pass
        finally:
            sys.path.remove(here)
    msg = (f"effect '{spec}': no module named {module} (put it on PYTHONPATH or in the current directory; "
           f"library effects: {', '.join(LIBRARY)})")
    raise FitError(msg)


def resolve_effect(spec: str | type[Effect]) -> type[Effect]:
    """The effect class of a library name, of a recorded signal ``'aux:TOPIC[:FIELD]'``, or of ``'module:Class'``.

    (user-defined).

    :raises FitError: naming ``spec`` when it is unknown, cannot be imported, or is not an
        offset-kind subclass of :class:`Effect` with a name of its own.
    """
    if isinstance(spec, type):
        if getattr(spec, 'held_base', None) is not None:
            return held_form(resolve_effect(spec.held_base), spec.fitted_axes)
        cls = spec
        spec = f'{cls.__module__}:{cls.__qualname__}'
    else:
        spec = str(spec).strip()
        name, axes = split_held(spec)
        if axes is not None:
            return held_form(resolve_effect(name), axes)
        if spec in LIBRARY:
            return LIBRARY[spec]
        if spec in PER_AXIS:
            return PER_AXIS[spec]
        if spec.startswith(AUX_PREFIX):
            return aux_effect_class(spec)
        if ':' not in spec:
            msg = f"effect '{spec}': unknown (library effects: {', '.join(LIBRARY)}; or give module:Class)"
            raise FitError(msg)
        module_name, _, class_name = spec.partition(':')
        if not module_name or not class_name:
            msg = f"effect '{spec}': expected module:Class"
            raise FitError(msg)
        module = _import_module(module_name, spec)
        cls = module
        for part in class_name.split('.'):
            cls = getattr(cls, part, None)
            if cls is None:
                msg = f"effect '{spec}': module {module_name} has no {class_name}"
                raise FitError(msg)
    if not isinstance(cls, type) or not issubclass(cls, Effect):
        msg = f"effect '{spec}': {cls!r} is not a subclass of tak_thermo_ros.core.effects.Effect"
        raise FitError(msg)
    if LIBRARY.get(cls.name) is cls or PER_AXIS.get(cls.name) is cls or is_aux_effect(cls):
        return cls
    if not cls.name or cls.name in LIBRARY or cls.name in PER_AXIS:
        msg = (f"effect '{spec}': set the class variable name to a name of its own "
               f"(not empty, not a library name), got {cls.name!r}")
        raise FitError(msg)
    if cls.kind != OFFSET:
        msg = f"effect '{spec}': user-defined effects must be of kind 'offset', got {cls.kind!r}"
        raise FitError(msg)
    if cls.step is Effect.step:
        msg = f"effect '{spec}': {cls.__name__} does not implement step()"
        raise FitError(msg)
    return cls


def effect_spec(cls: type[Effect]) -> str:
    """What the calibration file stores to find the class again.

    The library name, the signal name ``aux:...``, or 'module:Class'; for a held form, its
    effect's (the file adds ``axes``).
    """
    cls = held_of(cls)
    if LIBRARY.get(cls.name) is cls or PER_AXIS.get(cls.name) is cls or is_aux_effect(cls):
        return cls.name
    return f'{cls.__module__}:{cls.__qualname__}'
