"""The effect interface: a physical term that the paper's base model lacks.

An effect adds to the channel code ``N`` of each axis. Two kinds exist:

*offset* effects (thermal lag, hysteresis, warm-up, temperature shape, and every user-defined
effect) add to the offset::

    N_i += sum_b amplitude_i_b * phi_b(t, N_t; shape)

where ``phi_b`` are a few *basis signals* shared by the three axes, driven by the sample stamp
``t`` (seconds) and the temperature code ``N_t`` (after the corrector's out-of-range policy),
and shaped by a few *shape parameters* (a time constant, a width, knot positions). The
amplitudes enter linearly, so the fit solves them by least squares and searches only the shape
parameters (variable projection).

*input* effects (cross-axis coupling, scale nonlinearity; library only) add terms in the
specific force ``f``; the correction inverts them.

An effect with memory keeps a state from sample to sample. :meth:`Effect.start` gives the state
before the first sample, :meth:`Effect.step` advances it by one sample on plain floats (the
node's path), and :meth:`Effect.basis` runs the same recurrence over a whole series (the
offline path). Both paths perform the same float operations in the same order, so they agree
bit for bit.

A user-defined effect subclasses :class:`Effect`, sets the class variables, and implements
:meth:`Effect.start` and :meth:`Effect.step` (see ``docs/effects.md``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Mapping, Sequence, TypeVar

import numpy as np

from tak_thermo_ros.core.values import finite_number
from tak_thermo_ros.errors import CalibrationError, EffectError

AXIS_NAMES: tuple[str, str, str] = ('x', 'y', 'z')
OFFSET = 'offset'
INPUT = 'input'


@dataclass(frozen=True)
class ParameterSpec:
    """Declaration of one parameter.

    :param name: parameter name (for an amplitude: its prefix, the axis is appended).
    :param default: value taken when a scenario or a constructor leaves it out.
    :param min: lowest valid value.
    :param max: highest valid value.
    :param unit: unit, for messages and documentation.
    :param doc: one line of meaning.
    """

    name: str
    default: float
    min: float = -math.inf
    max: float = math.inf
    unit: str = ''
    doc: str = ''


@dataclass(frozen=True)
class Parameter:
    """A named parameter value with its bounds (as in lmfit).

    :param vary: ``True`` for a parameter the fit adjusts, ``False`` for a fixed one
        (e.g. knot positions).
    :param linear: ``True`` for an amplitude (solved by least squares), ``False`` for a shape
        parameter (searched).
    """

    name: str
    value: float
    min: float
    max: float
    vary: bool = True
    unit: str = ''
    linear: bool = True


class Effect:
    """Base class of every effect. An instance holds parameter values and is immutable.

    Class variables a subclass sets:

    ``name``: the effect's name in ``--effects`` and in the calibration file.
    ``summary``: one sentence of physics (what it is, how it shows in the residual).
    ``confirm``: which test run would confirm it.
    ``kind``: ``'offset'`` (default; the only kind a user-defined effect may have) or ``'input'``.
    ``needs_stamps``: whether :meth:`step` uses the stamp.
    ``needs_signal``: ``None`` (default), or the name of a recorded signal (``aux:TOPIC``,
    :mod:`tak_thermo_ros.core.effects.aux_signal`) that drives the effect *in place of the
    temperature code*: :meth:`start`, :meth:`step`, :meth:`basis` then receive that signal held
    at its last value where they would receive ``temp_code`` (see :func:`effect_input`).
    ``shape``: the shape parameters (:class:`ParameterSpec`), shared by the three axes.
    ``amplitude``: the amplitude template; its name gets ``_x``, ``_y``, ``_z`` (and a basis
    suffix from :meth:`basis_suffixes` when there is more than one basis signal).

    :param values: parameter values by name; a parameter left out takes its default.
    :raises CalibrationError: for an unknown name, a non-finite value or one out of bounds.
    """

    name: ClassVar[str] = ''
    summary: ClassVar[str] = ''
    confirm: ClassVar[str] = ''
    kind: ClassVar[str] = OFFSET
    needs_stamps: ClassVar[bool] = False
    needs_signal: ClassVar[str | None] = None
    shape: ClassVar[tuple[ParameterSpec, ...]] = ()
    amplitude: ClassVar[ParameterSpec] = ParameterSpec('amplitude', 0.0, unit='counts')
    fitted_axes: ClassVar[tuple[int, ...]] = (0, 1, 2)
    """The axes whose amplitudes the fit adjusts; on the others they are held at zero
    (:mod:`~tak_thermo_ros.core.effects.held`: ``thermal_lag[xz]``)."""
    held_base: ClassVar[type[Effect] | None] = None
    """For a held form, the effect it holds axes of."""

    def __init__(self, **values: float) -> None:
        self._values = self._checked(values, key=f'effects.{self.name}', complete=False)
        self._prepare()

    def _prepare(self) -> None:
        """Derive private constants from the values once (a subclass hook; default none)."""

    # ----- parameters ---------------------------------------------------------------------

    @classmethod
    def from_values(cls, values: Mapping[str, Any], *, key: str | None = None,
                    complete: bool = True) -> Effect:
        """Build an effect from a mapping, naming ``key`` in any error.

        :param complete: require every parameter (the calibration file); ``False`` lets a left-out
            parameter take its default (scenarios).
        """
        effect = cls.__new__(cls)
        effect._values = cls._checked(dict(values), key=key or f'effects.{cls.name}', complete=complete)
        effect._prepare()
        return effect

    @classmethod
    def structure_from_values(cls, values: Mapping[str, Any]) -> dict[str, Any]:
        """Structural settings read from the values before checking them (default: none)."""
        return {}

    @classmethod
    def basis_suffixes_for(cls, structure: Mapping[str, Any]) -> tuple[str, ...]:
        """Suffixes of the basis signals (default one signal, no suffix)."""
        return ('',)

    @classmethod
    def shape_specs_for(cls, structure: Mapping[str, Any]) -> tuple[ParameterSpec, ...]:
        """Shape parameters for a structure (default: the class's ``shape``)."""
        return cls.shape

    @classmethod
    def specs_for(cls, structure: Mapping[str, Any]) -> tuple[tuple[ParameterSpec, ...], tuple[ParameterSpec, ...]]:
        """``(shape specs, amplitude specs)`` with full names, amplitudes axis-major."""
        template = cls.amplitude
        amplitudes = tuple(
            ParameterSpec(f'{template.name}_{axis}{suffix}', template.default, template.min, template.max,
                          template.unit, template.doc)
            for axis in AXIS_NAMES for suffix in cls.basis_suffixes_for(structure))
        return cls.shape_specs_for(structure), amplitudes

    @classmethod
    def _checked(cls, values: Mapping[str, Any], *, key: str, complete: bool) -> dict[str, float]:
        shape_specs, amplitude_specs = cls.specs_for(cls.structure_from_values(values))
        specs = {spec.name: spec for spec in (*shape_specs, *amplitude_specs)}
        unknown = sorted(str(name) for name in set(values) - set(specs))
        if unknown:
            msg = (f'{key}.{unknown[0]}: unknown parameter of effect {cls.name} '
                   f'(known: {", ".join(specs)})')
            raise CalibrationError(msg)
        checked: dict[str, float] = {}
        for name, spec in specs.items():
            if name not in values:
                if complete:
                    msg = f'{key}.{name}: missing'
                    raise CalibrationError(msg)
                checked[name] = float(spec.default)
                continue
            number = finite_number(values[name], f'{key}.{name}')
            if not spec.min <= number <= spec.max:
                msg = f'{key}.{name}: {number:g} is outside [{spec.min:g}, {spec.max:g}] {spec.unit}'.rstrip()
                raise CalibrationError(msg)
            checked[name] = number
        cls.check_structure(checked, key=key)
        for name in cls.held_names_for(cls.structure_from_values(checked)):
            if checked[name] != 0.0:
                msg = (f'{key}.{name}: {checked[name]:g}, but the effect is fitted on {cls.fitted_axes_text()} only: '
                       f'an amplitude on a held axis is 0')
                raise CalibrationError(msg)
        return checked

    @classmethod
    def fitted_axes_text(cls) -> str:
        """``'x, z'``: the axes whose amplitudes the fit adjusts."""
        return ', '.join(AXIS_NAMES[axis] for axis in cls.fitted_axes)

    @classmethod
    def held_names_for(cls, structure: Mapping[str, Any]) -> tuple[str, ...]:
        """The amplitudes held at zero: those of the axes outside :attr:`fitted_axes`."""
        return tuple(f'{cls.amplitude.name}_{axis}{suffix}' for index, axis in enumerate(AXIS_NAMES)
                     if index not in cls.fitted_axes for suffix in cls.basis_suffixes_for(structure))

    @classmethod
    def check_structure(cls, values: Mapping[str, float], *, key: str) -> None:
        """Checks across parameters (default: none); raise :class:`CalibrationError`."""

    @property
    def values(self) -> dict[str, float]:
        """Parameter values by name (a copy)."""
        return dict(self._values)

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    @property
    def structure(self) -> dict[str, Any]:
        """Structural settings of this instance (e.g. the number of knots)."""
        return self.structure_from_values(self._values)

    def basis_suffixes(self) -> tuple[str, ...]:
        """Suffixes of this instance's basis signals."""
        return self.basis_suffixes_for(self.structure)

    @property
    def parameters(self) -> tuple[Parameter, ...]:
        """Every parameter with value and bounds: shape parameters first, then amplitudes."""
        shape_specs, amplitude_specs = self.specs_for(self.structure)
        vary = self.shape_varies()
        return (tuple(Parameter(s.name, self._values[s.name], s.min, s.max, vary.get(s.name, True), s.unit, False)
                      for s in shape_specs)
                + tuple(Parameter(s.name, self._values[s.name], s.min, s.max, True, s.unit, True)
                        for s in amplitude_specs))

    def shape_varies(self) -> dict[str, bool]:
        """Which shape parameters the fit searches (default: all)."""
        return {}

    def shape_names(self) -> tuple[str, ...]:
        """Names of the shape parameters."""
        return tuple(spec.name for spec in self.specs_for(self.structure)[0])

    def all_amplitude_names(self) -> tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]:
        """Amplitude names per axis x, y, z, one per basis signal in basis order (held ones too)."""
        suffixes = self.basis_suffixes()
        prefix = self.amplitude.name
        return tuple(tuple(f'{prefix}_{axis}{suffix}' for suffix in suffixes)
                     for axis in AXIS_NAMES)  # type: ignore[return-value]

    def amplitude_names(self) -> tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]:
        """The amplitudes the fit adjusts, per axis (none on an axis held at zero)."""
        return tuple(names if axis in self.fitted_axes else ()
                     for axis, names in enumerate(self.all_amplitude_names()))  # type: ignore[return-value]

    def held_names(self) -> tuple[str, ...]:
        """The amplitudes held at zero (:attr:`fitted_axes`)."""
        return self.held_names_for(self.structure)

    def axis_signals(self) -> tuple[tuple[int, ...], tuple[int, ...], tuple[int, ...]]:
        """Per axis, the basis signals its amplitudes (:meth:`all_amplitude_names`) multiply.

        Default: every signal on every axis. A per-axis form (``core.effects.per_axis``) uses
        signal ``i`` on axis ``i`` only.
        """
        every = tuple(range(len(self.basis_suffixes())))
        return (every, every, every)

    def axis_columns(self) -> tuple[tuple[int, ...], tuple[int, ...], tuple[int, ...]]:
        """Per axis, the basis signals the fit gives an amplitude (:meth:`amplitude_names`): none on a held axis."""
        return tuple(signals if axis in self.fitted_axes else ()
                     for axis, signals in enumerate(self.axis_signals()))  # type: ignore[return-value]

    def amplitudes(self) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
        """Amplitude values per axis, in basis order (zeros on a held axis)."""
        return tuple(tuple(self._values[name] for name in names)
                     for names in self.all_amplitude_names())  # type: ignore[return-value]

    def replace(self, **values: float) -> Effect:
        """A copy with some values changed (checked like the constructor)."""
        merged = {**self._values, **values}
        return type(self).from_values(merged, complete=False)

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and other._values == self._values  # type: ignore[attr-defined]

    def __hash__(self) -> int:
        return hash((type(self), tuple(sorted(self._values.items()))))

    def __repr__(self) -> str:
        inside = ', '.join(f'{name}={value:g}' for name, value in self._values.items())
        return f'{type(self).__name__}({inside})'

    def __setattr__(self, name: str, value: Any) -> None:
        if not name.startswith('_') or name == '_values' and '_values' in self.__dict__:
            msg = f'{type(self).__name__} is immutable: use .replace({name}=...)'
            raise AttributeError(msg)
        object.__setattr__(self, name, value)

    # ----- forward contribution (offset kind) -------------------------------------------------

    def start(self, stamp_s: float, temp_code: float) -> Any:
        """State before the first sample (the default, a stateless effect, has ``None``)."""
        return None

    def step(self, state: Any, stamp_s: float, temp_code: float) -> tuple[Any, tuple[float, ...]]:
        """Advance by one sample (plain floats): ``(new state, basis signal values)``."""
        raise NotImplementedError(f'{type(self).__name__}.step')

    def basis(self, stamp_s: np.ndarray, temp_code: np.ndarray) -> np.ndarray:
        """Basis signals ``(k, b)`` over a series, from the initial state.

        The default runs :meth:`step` sample by sample (bit-identical by construction); a
        subclass may override it with a faster path that performs the same float operations.
        """
        return self.stepped_basis(stamp_s, temp_code)[0]

    def stepped_basis(self, stamp_s: np.ndarray, temp_code: np.ndarray, *, state: Any = None,
                      started: bool = False) -> tuple[np.ndarray, Any]:
        """:meth:`step` over a series: basis signals ``(k, b)`` and the state after the last sample.

        :param state: the state to continue from (a block of a longer run), with ``started``.
        :param started: ``False``: the effect starts at the first sample (:meth:`start`).
        """
        stamps = np.asarray(stamp_s, dtype=float).tolist()
        codes = np.asarray(temp_code, dtype=float).tolist()
        width = len(self.basis_suffixes())
        out = np.empty((len(codes), width))
        if not codes:
            return out, state
        if not started:
            state = call_effect(self, 'start', self.start, stamps[0], codes[0])
        rows = []
        step = self.step
        try:
            for stamp, code in zip(stamps, codes):
                state, values = step(state, stamp, code)
                rows.append(values)
        except Exception as err:
            raise effect_failure(self, 'step', err) from err
        try:
            out[:] = rows
        except (TypeError, ValueError) as err:
            msg = (f'effect {self.name}: step() returned basis values of the wrong length '
                   f'(the effect has {width} basis signal{"s" if width != 1 else ""})')
            raise EffectError(msg) from err
        return out, state

    def search_basis(self, stamp_s: np.ndarray, temp_code: np.ndarray) -> np.ndarray:
        """Basis signals for the fit's shape search: may differ from :meth:`basis` by rounding.

        The search evaluates the basis many times; an effect may give a faster vectorised
        approximation here. The final fit and every correction use :meth:`basis`. Default:
        :meth:`basis`.
        """
        return self.basis(stamp_s, temp_code)

    def offsets(self, stamp_s: np.ndarray, temp_code: np.ndarray) -> np.ndarray:
        """Contribution ``(k, 3)`` in counts over a series (from the initial state)."""
        basis = checked_basis(self, stamp_s, temp_code)
        out = np.zeros((basis.shape[0], 3))
        for i, amplitudes in enumerate(self.amplitudes()):
            total = out[:, i]
            for b, amplitude in enumerate(amplitudes):
                total = total + amplitude * basis[:, b]
            out[:, i] = total
        return out

    # ----- fitting ------------------------------------------------------------------------

    @classmethod
    def search_space(cls, time_s: np.ndarray, temp_code: np.ndarray) -> dict[str, tuple[float, float, bool]]:
        """Search range of each shape parameter for this data: name -> ``(low, high, log)``.

        Default: each shape parameter's bounds, searched on a log scale when both are > 0.
        """
        space = {}
        for spec in cls.shape:
            space[spec.name] = (spec.min, spec.max, spec.min > 0.0)
        return space

    def search_values(self, time_s: np.ndarray, temp_code: np.ndarray,
                      residual: np.ndarray) -> dict[str, np.ndarray]:
        """Shape parameters the fit scans over given values instead of searching a range: name -> values.

        For a parameter whose objective is not smooth (the moment of a step: only the samples on
        each side count), the fit scans every ``n / 200``-th value, then each one around the
        best. ``residual`` ``(k, 3)``: the training samples' residual of the model without this
        effect (what the effect is to explain). Default: none.
        """
        return {}

    @classmethod
    def structures(cls, time_s: np.ndarray, temp_code: np.ndarray) -> Sequence[Effect] | None:
        """Candidate structures chosen among by blocked cross-validation, or ``None``.

        An effect whose complexity is discrete (the number of knots) returns one template per
        complexity (amplitudes zero); the fit keeps the one that predicts held-out blocks best.
        """
        return None

    # ----- input kind (library only) ----------------------------------------------------------

    def input_columns(self, axis: int, force: np.ndarray) -> list[tuple[str, np.ndarray]]:
        """Least-squares columns of an input effect on one axis: ``(amplitude name, column)``."""
        return []

    def input_counts(self, force: np.ndarray) -> np.ndarray:
        """Contribution ``(k, 3)`` in counts of an input effect for specific force ``(k, 3)``."""
        return np.zeros_like(np.asarray(force, dtype=float))


def amplitude_names(effect_type: type[Effect], suffixes: Sequence[str] = ('',)) -> tuple[str, ...]:
    """All amplitude names of an effect class for the given basis suffixes."""
    return tuple(f'{effect_type.amplitude.name}_{axis}{suffix}' for axis in AXIS_NAMES for suffix in suffixes)


def typical_interval(time_s: np.ndarray) -> float:
    """Median positive interval between successive stamps, seconds (1.0 when unknown)."""
    steps = np.diff(np.asarray(time_s, dtype=float))
    steps = steps[steps > 0.0]
    return float(np.median(steps)) if steps.size else 1.0


_Result = TypeVar('_Result')


def effect_failure(effect: Effect | type[Effect], method: str, err: BaseException) -> EffectError:
    """The one-line error for an exception raised inside an effect's method (kept as the cause)."""
    if isinstance(err, EffectError):
        return err
    detail = str(err).splitlines()[0] if str(err) else ''
    return EffectError(f'effect {effect.name}: {method}() raised {type(err).__name__}'
                       f'{": " + detail if detail else ""}')


def call_effect(effect: Effect | type[Effect], method: str, function: Callable[..., _Result],
                *args: Any) -> _Result:
    """Call an effect's method.

    An exception inside it becomes an :class:`EffectError` naming the effect and the method (the original is its
    cause, shown by ``--debug``).
    """
    try:
        return function(*args)
    except Exception as err:
        raise effect_failure(effect, method, err) from err


def effect_input(effect: Effect, temp_code: Any, aux: Mapping[str, Any] | None) -> Any:
    """What drives an effect: the temperature code, or the held signal it names (``needs_signal``).

    Works on series (arrays) and on one sample (floats) alike.

    :param aux: held signal values by name, aligned with ``temp_code`` (or ``None``).
    :raises CalibrationError: the effect needs a signal that ``aux`` does not hold.
    """
    signal = effect.needs_signal
    if not signal:
        return temp_code
    if aux is None or signal not in aux:
        msg = (f'calibration.effects.{effect.name}: this effect needs the recorded signal {signal} '
               f'(topic {signal[4:].split(":")[0]}), which the data does not hold')
        raise CalibrationError(msg)
    return aux[signal]


def checked_basis(effect: Effect, stamp_s: np.ndarray, temp_code: np.ndarray, *,
                  search: bool = False) -> np.ndarray:
    """:meth:`Effect.basis` (or :meth:`Effect.search_basis`) checked at the boundary.

    :raises EffectError: the method raised, or returned anything but a finite ``(k, b)``
        array with ``k`` the number of samples and ``b`` the effect's basis signals.
    """
    method = 'search_basis' if search else 'basis'
    values = call_effect(effect, method, effect.search_basis if search else effect.basis, stamp_s, temp_code)
    expected = (len(temp_code), len(effect.basis_suffixes()))
    try:
        basis = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        basis = None
    if basis is None or basis.shape != expected:
        got = 'values that are not an array' if basis is None else f'shape {basis.shape}'
        msg = f'effect {effect.name}: {method}() returned {got}, expected {expected}'
        raise EffectError(msg)
    if not np.all(np.isfinite(basis)):
        msg = f'effect {effect.name}: {method}() returned non-finite values (NaN or infinite)'
        raise EffectError(msg)
    return basis


def basis_from(effect: Effect, state: Any, stamp_s: np.ndarray, temp_code: np.ndarray,
               *, started: bool) -> tuple[np.ndarray, Any]:
    """Basis signals ``(k, b)`` of a block continuing from ``state``, and the state after it.

    The block path of the fit and of the correction alike (:meth:`Effect.stepped_basis`).

    :param started: ``False`` before the run's first sample (the effect starts at it).
    :raises EffectError: non-finite values.
    """
    out, state = effect.stepped_basis(stamp_s, temp_code, state=state, started=started)
    if not np.all(np.isfinite(out)):
        msg = f'effect {effect.name}: basis() returned non-finite values (NaN or infinite)'
        raise EffectError(msg)
    return out, state
