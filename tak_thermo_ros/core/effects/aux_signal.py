"""``aux:TOPIC``: part of the offset follows a recorded auxiliary signal (e.g. the supply voltage).

A bag may carry scalar signals besides the temperature: a supply voltage
(``sensor_msgs/BatteryState``), a pressure, a humidity, a plain ``std_msgs`` number. Each one is
named ``aux:TOPIC`` (the message's one obvious number) or ``aux:TOPIC:FIELD`` (another numeric
field) and can drive an effect of its own: :func:`aux_effect_class` makes the effect class of
one signal, whose name is the signal's name.

The effect sees the signal *held at its last value* on each sample's stamp, exactly as the
temperature is held, in place of the temperature code (``Effect.needs_signal``).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, Mapping

import numpy as np

from tak_thermo_ros.core.effects.base import Effect, ParameterSpec, typical_interval
from tak_thermo_ros.errors import FitError

AUX_PREFIX = 'aux:'
_INTEGERS = ('Int8', 'Int16', 'Int32', 'Int64', 'UInt8', 'UInt16', 'UInt32', 'UInt64')
AUX_FIELDS: dict[str, tuple[str, ...]] = {
    'std_msgs/msg/Float32': ('data',),
    'std_msgs/msg/Float64': ('data',),
    **{f'std_msgs/msg/{name}': ('data',) for name in _INTEGERS},
    'sensor_msgs/msg/Temperature': ('temperature',),
    'sensor_msgs/msg/FluidPressure': ('fluid_pressure',),
    'sensor_msgs/msg/RelativeHumidity': ('relative_humidity',),
    'sensor_msgs/msg/BatteryState': ('voltage', 'temperature', 'current', 'charge', 'capacity',
                                     'design_capacity', 'percentage'),
}
"""Auxiliary scalar signal types: their numeric fields, the obvious one (named ``aux:TOPIC``) first."""


def split_signal_name(signal: str) -> tuple[str, str]:
    """``(topic, field)`` of a signal name ``aux:TOPIC`` or ``aux:TOPIC:FIELD`` (field ``''`` when left out).

    :raises FitError: the name does not start with ``aux:/`` or names an empty field.
    """
    rest = signal[len(AUX_PREFIX):] if signal.startswith(AUX_PREFIX) else ''
    if not rest.startswith('/') or len(rest) < 2:
        msg = (f"effect '{signal}': an auxiliary signal is named aux:TOPIC or aux:TOPIC:FIELD "
               f"(e.g. aux:/power/battery_state)")
        raise FitError(msg)
    topic, colon, field = rest.partition(':')
    if colon and (not field or ':' in field):
        msg = f"effect '{signal}': expected aux:TOPIC:FIELD with one field name"
        raise FitError(msg)
    return topic, field


def signal_field(msgtype: str, signal: str) -> str:
    """The message field that carries ``signal`` on a topic of type ``msgtype``.

    :raises FitError: the type is not an auxiliary signal type, or has no such numeric field.
    """
    fields = AUX_FIELDS.get(msgtype)
    if fields is None:
        msg = f'{signal}: topic type {msgtype} is not a scalar signal type ({", ".join(AUX_FIELDS)})'
        raise FitError(msg)
    field = split_signal_name(signal)[1] or fields[0]
    if field not in fields:
        msg = f'{signal}: {msgtype} has no numeric field {field} ({", ".join(fields)})'
        raise FitError(msg)
    return field


def signal_name(topic: str, field: str = '') -> str:
    """The signal name of a topic (and a field other than the message's obvious number)."""
    return f'{AUX_PREFIX}{topic}' + (f':{field}' if field else '')


class AuxSignal(Effect):
    """Part of the offset follows a recorded scalar signal, held, optionally lagged.

    Model, per axis ``i``::

        N_i += slope_i * (V_lag - reference),     tau_s dV_lag/dt = V - V_lag

    ``V`` is the signal held at its last value on the sample's stamp. ``tau_s = 0`` is no lag
    (``V_lag = V``); a lag is discretised like ``thermal_lag``'s:
    ``V_lag <- V + (V_lag - V) exp(-dt / tau_s)``. ``reference`` is the signal value at which
    the term vanishes (fixed, the training samples' median), so the base model's offset keeps
    its meaning at a typical supply.

    Parameters: ``tau_s`` (s, searched; the search's lowest value is far below one sample
    interval, where ``exp(-dt / tau_s)`` is exactly 0: no lag), ``reference`` (signal units,
    fixed), ``slope_x``, ``slope_y``, ``slope_z`` (channel units per signal unit).

    Online state ``(V_lag, last stamp)``; initial state: ``V_lag`` equal to the first value.
    """

    name = 'aux_signal'
    signal: ClassVar[str] = ''
    summary = ('Part of the offset follows a recorded auxiliary signal (such as the supply voltage), '
               'held at its last value, linear, optionally lagged: the residual correlates with that signal.')
    confirm = ('A run at constant temperature with the signal stepped (e.g. the supply voltage changed): '
               'the offset steps with it.')
    needs_stamps = True
    shape = (ParameterSpec('tau_s', 0.0, 0.0, 1e8, 's', 'time constant of the lag (0: none)'),
             ParameterSpec('reference', 0.0, -1e12, 1e12, '', 'signal value at which the term is zero'))
    amplitude = ParameterSpec('slope', 0.0, -1e6, 1e6, 'per signal unit', 'offset per unit of the signal')

    def _prepare(self) -> None:
        self._tau = self._values['tau_s']
        self._reference = self._values['reference']

    def shape_varies(self) -> dict[str, bool]:
        """``reference`` is fixed; ``tau_s`` is searched."""
        return {'reference': False}

    def start(self, stamp_s: float, temp_code: float) -> Any:
        """Initial state: the lagged value equals the first held value."""
        return (temp_code, stamp_s)

    def step(self, state: Any, stamp_s: float, temp_code: float) -> tuple[Any, tuple[float, ...]]:
        """Advance the lagged value by one sample (``temp_code`` is the held signal value here)."""
        lagged, last = state
        dt = stamp_s - last
        if self._tau == 0.0:
            decay = 0.0
        else:
            decay = math.exp(-dt / self._tau) if dt > 0.0 else 1.0
        lagged = temp_code + (lagged - temp_code) * decay
        return (lagged, stamp_s), (lagged - self._reference,)

    def basis(self, stamp_s: np.ndarray, temp_code: np.ndarray) -> np.ndarray:
        """The recurrence of :meth:`step` over a series (same float operations)."""
        stamps = np.asarray(stamp_s, dtype=float).tolist()
        values = np.asarray(temp_code, dtype=float).tolist()
        if not values:
            return np.zeros((0, 1))
        out = [0.0] * len(values)
        tau, reference, exp = self._tau, self._reference, math.exp
        lagged, last = values[0], stamps[0]
        previous_dt = None
        decay = 0.0
        for k, (stamp, value) in enumerate(zip(stamps, values)):
            dt = stamp - last
            if tau != 0.0 and dt != previous_dt:
                decay = exp(-dt / tau) if dt > 0.0 else 1.0
                previous_dt = dt
            lagged = value + (lagged - value) * decay
            out[k] = lagged - reference
            last = stamp
        return np.array(out).reshape(-1, 1)

    @classmethod
    def structures(cls, time_s: np.ndarray, temp_code: np.ndarray) -> list[Effect]:
        """One template: ``reference`` at the median of the signal (``temp_code``) on the training samples."""
        values = np.asarray(temp_code, dtype=float)
        reference = float(np.median(values)) if len(values) else 0.0
        return [cls.from_values({'reference': reference}, complete=False)]

    @classmethod
    def search_space(cls, time_s: np.ndarray, temp_code: np.ndarray) -> dict[str, tuple[float, float, bool]]:
        """``tau_s`` from 1/1000 of a sample interval (no lag: ``exp(-1000) == 0``) to twice the run, log scale."""
        duration = float(time_s[-1] - time_s[0]) if len(time_s) > 1 else 1.0
        interval = typical_interval(time_s)
        return {'tau_s': (1e-3 * interval, max(2.0 * duration, 10.0 * interval), True)}


def recorded_candidates(aux: Mapping[str, np.ndarray]) -> list[str]:
    """The recorded signals worth trying as effects.

    Each topic's obvious number (``aux:TOPIC``) that has a value at every sample and is not constant (a constant is
    the offset itself).
    """
    names = []
    for name, values in sorted(aux.items()):
        values = np.asarray(values, dtype=float)
        if split_signal_name(name)[1] or not len(values) or not np.all(np.isfinite(values)):
            continue
        if float(np.ptp(values)) > 0.0:
            names.append(name)
    return names


def signals_with_values(aux: Mapping[str, np.ndarray]) -> list[str]:
    """The obvious-number signals (``aux:TOPIC``) with at least one held value in a run."""
    return [name for name, values in sorted(aux.items())
            if not split_signal_name(name)[1] and np.any(np.isfinite(np.asarray(values, dtype=float)))]


_CLASSES: dict[str, type[AuxSignal]] = {}


def aux_effect_class(signal: str) -> type[AuxSignal]:
    """The effect class of one signal (``aux:TOPIC`` or ``aux:TOPIC:FIELD``), made once per name.

    :raises FitError: the name is not a signal name.
    """
    split_signal_name(signal)
    cls = _CLASSES.get(signal)
    if cls is None:
        cls = type('AuxSignal', (AuxSignal,), {'name': signal, 'signal': signal, 'needs_signal': signal,
                                               '__module__': __name__, '__qualname__': 'AuxSignal'})
        _CLASSES[signal] = cls
    return cls


def is_aux_effect(effect: Effect | type[Effect]) -> bool:
    """Whether an effect (or class) is an auxiliary-signal effect of one signal."""
    cls = effect if isinstance(effect, type) else type(effect)
    return issubclass(cls, AuxSignal) and bool(cls.signal)
