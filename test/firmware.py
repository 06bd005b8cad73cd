"""PX4's and ArduPilot's temperature compensation as their firmware applies it, written from their sources.

For the tests that hold ``tak_calib export`` against ``apply``, and for ``bench/bench_flight_logs.py``.
Re-implemented here on purpose (not imported from the package), float32 as the firmware computes:

- PX4 ``src/modules/temperature_compensation/TemperatureCompensation.cpp``,
  ``calc_thermal_offsets_3D``: ``dT = clamp(T, TMIN, TMAX) - TREF``,
  ``offset = X0 + X1 dT + X2 dT^2 + X3 dT^3``; ``update_offsets_*`` recomputes it only when the
  temperature has moved by more than 1 C since ``last_temperature`` (initially -100), and the
  sensor's calibration (``Accelerometer::Correct``) subtracts the last published offset from the
  raw sample; the parameters apply to the sensor whose ``device_id`` is ``TC_xn_ID``, when
  ``TC_x_ENABLE`` is 1.
- ArduPilot ``libraries/AP_InertialSensor/AP_InertialSensor_tempcal.cpp``, ``correct_sensor``:
  ``T`` and ``CALTEMP`` clamped to ``TMIN..TMAX``, ``v -= P(T - 35); v += P(CALTEMP - 35)``,
  ``P(t) = (c1 + (c2 + c3 t) t) t`` with ``ck = INS_TCALn_ACCk / 1e6``; then
  ``AP_InertialSensor_Backend`` subtracts the ordinary offsets ``INS_ACCOFFS`` / ``INS_GYROFFS``.
"""

from __future__ import annotations

import numpy as np

F32 = np.float32


def px4_offsets(params: dict[str, float], letter: str, instance: int, temperature: np.ndarray) -> np.ndarray:
    """``calc_thermal_offsets_3D`` at each temperature: ``(k, 3)`` float32."""
    prefix = f'TC_{letter}{instance}_'
    tmin, tmax, tref = (F32(params[prefix + key]) for key in ('TMIN', 'TMAX', 'TREF'))
    measured = np.asarray(temperature, dtype=F32)
    delta = np.where(measured > tmax, tmax - tref, np.where(measured < tmin, tmin - tref, measured - tref)).astype(F32)
    delta2 = (delta * delta).astype(F32)
    delta3 = (delta2 * delta).astype(F32)
    out = np.empty((len(measured), 3), dtype=F32)
    for axis in range(3):
        x0, x1, x2, x3 = (F32(params[f'{prefix}X{order}_{axis}']) for order in range(4))
        out[:, axis] = x0 + x1 * delta + x2 * delta2 + x3 * delta3
    return out


def px4_applied_offsets(params: dict[str, float], letter: str, instance: int, temperature: np.ndarray,
                        device_id: int, *, hold: bool = True) -> np.ndarray:
    """The thermal offset the firmware subtracts from each sample (zero unless enabled and the ID matches).

    ``hold``: the module's 1 C rule (the offset is the one computed at the last temperature
    that moved more than 1 C from the previous update); ``False``: recomputed every sample.
    """
    temperature = np.asarray(temperature, dtype=float)
    if int(params.get(f'TC_{letter}_ENABLE', 0)) != 1 or int(params.get(f'TC_{letter}{instance}_ID', -1)) != device_id:
        return np.zeros((len(temperature), 3), dtype=F32)
    every = px4_offsets(params, letter, instance, temperature)
    if not hold:
        return every
    held = np.empty_like(every)
    last_temperature = F32(-100.0)
    current = np.zeros(3, dtype=F32)
    for row, value in enumerate(temperature.astype(F32)):
        if abs(value - last_temperature) > F32(1.0):
            last_temperature = value
            current = every[row]
        held[row] = current
    return held


def ardupilot_correction(params: dict[str, float], instance: int, code: str, temperature: np.ndarray,
                         caltemp: float) -> np.ndarray:
    """What ``correct_sensor`` adds to each raw sample: ``-P(T - 35) + P(CALTEMP - 35)``, ``(k, 3)`` float32."""
    prefix = f'INS_TCAL{instance + 1}_'
    if int(params.get(prefix + 'ENABLE', 0)) != 1:
        return np.zeros((len(temperature), 3), dtype=F32)
    tmin, tmax = F32(params[prefix + 'TMIN']), F32(params[prefix + 'TMAX'])
    coefficients = np.array([[params[f'{prefix}{code}{order}_{axis}'] for axis in 'XYZ'] for order in (1, 2, 3)],
                            dtype=F32)

    def polynomial(value: np.ndarray) -> np.ndarray:
        t = (np.clip(np.asarray(value, dtype=F32), tmin, tmax) - F32(35.0)).astype(F32)[:, None]
        c1, c2, c3 = coefficients
        return ((c1 + (c2 + c3 * t) * t) * t * F32(1e-6)).astype(F32)

    return (-polynomial(temperature) + polynomial(np.array([caltemp]))).astype(F32)
