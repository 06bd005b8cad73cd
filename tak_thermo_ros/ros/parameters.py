"""The ``compensator`` node's own parameters: their defaults and descriptions, and the checks of their values.

:class:`~tak_thermo_ros.ros.node.CompensatorNode` declares :func:`_tunables` and reads each value
through these checks at start-up and at every run-time update; each refuses a bad value with one
line naming the parameter (``ValueError``). No rclpy here: plain values in, plain values out.
"""

from __future__ import annotations

import array
import math
from typing import Any, Sequence

QOS_CHOICES = ('sensor_data', 'reliable')
EXECUTOR_CHOICES = ('events', 'single_threaded')
MESSAGE_PATHS = ('raw', 'decoded')
"""``message_path``: the serialised bytes read and written by the package's CDR codec, or rclpy's messages."""


def _tunables() -> dict[str, tuple[Any, str, bool]]:
    """Name -> (default, description, read only) of the node's own parameters."""
    return {
        'calibration_file': ('', 'calibration parameters YAML to load instead of calibration.* '
                                 '(the file tak_calib fit writes); empty: use calibration.*', True),
        'qos': ('sensor_data', "input QoS: 'sensor_data' (best effort, REP 2003 consumer; matches "
                               "every publisher) or 'reliable' (retransmits, needs a reliable publisher; "
                               "a driver faster than the node still loses messages at the history depth)",
                True),
        'qos_depth': (1000, 'history depth of the subscriptions and the Imu publisher (1000: 250 ms of a 4 kHz '
                            'stream)', True),
        'executor': ('events', "'events' (rclpy.experimental.EventsExecutor, about half the CPU per "
                               "message) or 'single_threaded' (rclpy's default executor)", True),
        'message_path': ('raw', "'raw': the messages' serialised bytes, read and written at fixed offsets by the "
                                "package's CDR codec (no rclpy message objects: the least CPU per message); "
                                "'decoded': rclpy's message objects (for comparison)", True),
        'temp_timeout': (1.0, 'seconds after which the last temperature is stale '
                              '(diagnostics ERROR)', False),
        'stale_temperature': ('hold', "input while the temperature is stale: 'hold' the last "
                                      "temperature or 'drop' the messages", False),
        'out_of_range': ('clamp', "temperatures outside the calibrated range: 'clamp' to the "
                                  "edge or 'extrapolate' (always counted and logged)", False),
        'hardware_id': ('', "the unit's identifier (e.g. its serial number) in /diagnostics; empty: "
                            "the input's frame_id", True),
        'watch': (True, 'the calibration watch: rests found online, the calibration judged at each against the '
                        "file's noise model (/diagnostics '...: calibration watch'); needs the file's noise "
                        'sections', True),
        'latitude': ('', "degrees: the Earth rate's vertical part and gravity the watch expects at rest; "
                         "empty: unknown (counted as noise)", True),
        'turn_on': ('none', "'first_rest': take each run's turn-on offset at its first rest (judged against "
                            "the file's turn_on repeatability) and subtract it from then on, as tak_calib apply "
                            "--turn-on first-rest does; 'none': not", True),
        'learn': (False, 'learn the gyroscope curve at the rests (offset and slope per axis, bounded) and apply '
                         'it, writing learned_file; false returns to the calibration file at once', False),
        'learned_file': ('', 'where learning writes what it learned (a calibration file tak_calib reads), '
                             'read at the next start; never the calibration file itself', True),
        'gyro_turn_on_repeatability': ('', "deg/h (one value or x y z): the gyroscope's turn-on repeatability "
                                           "(a data sheet's bias repeatability) when the file holds none; empty: "
                                           "the first rest is unjudged, until learning has seen 5 runs", True),
        'accel_turn_on_repeatability': ('', "mg (one value or x y z): the accelerometer's, likewise", True),
    }


def _plain(value: Any) -> Any:
    """A parameter value as the calibration validator expects it (lists, not arrays)."""
    if isinstance(value, (array.array, tuple)) or hasattr(value, 'tolist'):
        return list(value)
    return value


def _choice(value: Any, name: str, choices: Sequence[str]) -> str:
    if value not in choices:
        msg = f'{name}: expected one of {", ".join(repr(c) for c in choices)}, got {value!r}'
        raise ValueError(msg)
    return value


def _timeout(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 < value < float('inf'):
        msg = f'temp_timeout: expected a number of seconds > 0, got {value!r}'
        raise ValueError(msg)
    return float(value)


def _depth(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        msg = f'qos_depth: expected an integer >= 1, got {value!r}'
        raise ValueError(msg)
    return value


def _flag(value: Any, name: str) -> bool:
    if not isinstance(value, bool):
        msg = f'{name}: expected true or false, got {value!r}'
        raise ValueError(msg)
    return value


def _path_value(value: Any, name: str, error: type[Exception] = ValueError) -> str:
    if not isinstance(value, str):
        msg = f'{name}: expected a path, got {value!r}'
        raise error(msg)
    return value


def _repeatability(value: Any, name: str, factor: float) -> tuple[float, float, float] | None:
    """A ``*_turn_on_repeatability`` parameter (one value or x y z, in ``1 / factor`` of SI) in SI, or ``None``."""
    if value == '' or value is None:
        return None
    items = list(value) if isinstance(value, (list, tuple)) or hasattr(value, 'tolist') else [value]
    if len(items) == 1:
        items = items * 3
    if len(items) != 3 or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
                              or v <= 0.0 for v in items):
        msg = f'{name}: expected one positive number or three (x y z), or empty; got {value!r}'
        raise ValueError(msg)
    return (items[0] / factor, items[1] / factor, items[2] / factor)


TURN_ON_CHOICES = ('none', 'first_rest')
