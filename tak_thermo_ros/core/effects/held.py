"""An effect fitted on some axes only: its amplitudes on the other axes held at zero.

A unit's lag may sit in two channels and not the third. Fitted on all three, the third axis's
amplitude then takes whatever slow wander of that channel looks most like the effect's signal:
within its noise of zero on the fitted record, and worse than nothing on an excursion the fit
never saw. The held form ``thermal_lag[xz]`` is the same effect with ``slope_y`` held at zero:
the fit gives no column to a held axis, and the correction applies the zero like any other
amplitude (an added ``0 * signal`` changes no float).

The form is a subclass of the effect made once per set of axes (:func:`held_form`), named
``<name>[<axes>]``; in the calibration file it is the effect's own entry with a string
``axes`` (``thermal_lag: {axes: xz, tau_s: ..., slope_x: ..., slope_y: 0.0, slope_z: ...}``), a
ROS 2 parameter like ``class`` (:mod:`~tak_thermo_ros.formats.calibration_file`).

Only offset effects of the library or of a user's module have a held form: a per-axis form's
held axis would leave its own shape parameters with nothing to fit, an input effect's
amplitudes couple the axes, and a recorded signal's effect is named by its topic.
"""

from __future__ import annotations

import re
from typing import Sequence

from tak_thermo_ros.core.effects.base import AXIS_NAMES, OFFSET, Effect
from tak_thermo_ros.errors import FitError

_HELD = re.compile(r'^(?P<name>.+)\[(?P<axes>[^\[\]]*)\]$')
_FORMS: dict[tuple[type[Effect], tuple[int, ...]], type[Effect]] = {}


def axes_text(axes: Sequence[int]) -> str:
    """``(0, 2)`` -> ``'xz'``."""
    return ''.join(AXIS_NAMES[axis] for axis in sorted(set(axes)))


def parse_axes(text: str, where: str) -> tuple[int, ...]:
    """``'xz'`` -> ``(0, 2)``; one to three distinct letters of x, y, z.

    :raises FitError: naming ``where`` for any other text.
    """
    letters = str(text).strip().lower()
    if not letters or any(letter not in AXIS_NAMES for letter in letters) or len(set(letters)) != len(letters):
        msg = f'{where}: axes {text!r}: expected one to three of x, y, z, each once (e.g. xz)'
        raise FitError(msg)
    return tuple(sorted(AXIS_NAMES.index(letter) for letter in letters))


def split_held(spec: str) -> tuple[str, tuple[int, ...] | None]:
    """``'thermal_lag[xz]'`` -> ``('thermal_lag', (0, 2))``; a spec without brackets -> ``(spec, None)``."""
    found = _HELD.match(spec.strip())
    if found is None:
        return spec, None
    return found['name'].strip(), parse_axes(found['axes'], f"effect '{spec}'")


def held_of(cls: type[Effect]) -> type[Effect]:
    """The effect a held form holds axes of (the class itself when it is no held form)."""
    return cls.held_base or cls


def held_form(cls: type[Effect], axes: Sequence[int]) -> type[Effect]:
    """The form of ``cls`` fitted on ``axes`` only (``cls`` itself for all three), made once per set.

    :raises FitError: for an input effect or a per-axis form, or no axis.
    """
    base = held_of(cls)
    fitted = tuple(sorted(set(int(axis) for axis in axes)))
    if fitted == (0, 1, 2):
        return base
    letters = axes_text(fitted)
    if not fitted or any(axis not in (0, 1, 2) for axis in fitted):
        msg = f'effect {base.name}: fitted on no axis'
        raise FitError(msg)
    if base.kind != OFFSET or getattr(base, 'shared', None) is not None or base.needs_signal:
        kind = ('an input effect' if base.kind != OFFSET else 'an effect of a recorded signal' if base.needs_signal
                else 'a per-axis form')
        msg = f'effect {base.name}[{letters}]: {kind} is fitted on every axis (hold axes of an offset effect)'
        raise FitError(msg)
    key = (base, fitted)
    if key not in _FORMS:
        namespace = {
            'name': f'{base.name}[{letters}]',
            'fitted_axes': fitted,
            'held_base': base,
            '__doc__': f'{base.__name__} fitted on {", ".join(letters)} only (see :mod:`{__name__}`).',
            '__module__': base.__module__,
        }
        _FORMS[key] = type(f'{base.__name__}On{letters.upper()}', (base,), namespace)
    return _FORMS[key]
