"""ArduPilot DataFlash logs (``.bin``): read by our own reader, and written (tests and benchmarks).

pymavlink's ``DFReader`` (LGPL) builds one Python object per message; this reader walks the
file once to find each message (its type's length from the log's ``FMT`` messages), then
decodes the messages it needs (``IMU``, ``TCLR``, ``PARM``) with numpy, a whole type at once
(``bench/bench_flight_logs.py`` measures the two on the same file). No optional library is
needed.

Read (:func:`read_dataflash`): instance ``N`` of the ``IMU`` messages (``I`` = N; a log without
``I`` has ``IMU``, ``IMU2``, ``IMU3``): ``AccX..Z`` (m/s^2), ``GyrX..Z`` (rad/s) and ``T`` (C),
accelerometer and gyroscope on their shared ``TimeUS``. As ArduPilot's own
``Tools/scripts/tempcal_IMU.py`` does, what the firmware applied before logging is undone
from the log's parameters, exactly as ``AP_InertialSensor_Backend`` applies it: the board
rotation ``AHRS_ORIENTATION``, then the offsets and scale (``INS_ACCOFFS``, ``INS_ACCSCAL``,
``INS_GYROFFS``; ``INS_ACC2OFFS`` ... for instances 1 and 2), then a temperature calibration
in use (``INS_TCALn_ENABLE`` 1: the firmware subtracted ``P(clamp(T) - 35) - P(clamp(CALTEMP) - 35)``).
A log without ``IMU`` messages but with ``TCLR`` (the firmware's own learning records, already
raw) is read from those, accelerometer and gyroscope on their own stamps.

Refused in one line: a file that ends inside a message (truncated), ``IMU`` messages without
``T`` (an old firmware), an instance the log does not hold, no temperature, a device ID or a
parameter the reader undoes that changes while the instance is logged.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tak_thermo_ros.errors import FlightLogError
from tak_thermo_ros.core.records.plausible import stamp_ns_from_micros
from tak_thermo_ros.formats.flight_log import FlightLog, checked_sensor, checked_temperature, readable

HEAD = b'\xa3\x95'
"""The two bytes every DataFlash message starts with (then its type)."""
FMT_TYPE = 128
FMT_LENGTH = 89
FMT_FORMAT = 'BBnNZ'
FMT_COLUMNS = 'Type,Length,Name,Format,Columns'
TEMP_REFERENCE = 35.0
"""ArduPilot's fixed reference temperature of ``INS_TCALn``, degrees C (``AP_InertialSensor_tempcal.cpp``)."""
SCALE_FACTOR = 1.0e6
"""``INS_TCALn_ACCk`` and ``GYRk`` hold the coefficients times this."""

FORMAT_CHARACTERS: dict[str, tuple[str, float | None]] = {
    'a': ('(32,)<i2', None), 'b': ('<i1', None), 'B': ('<u1', None), 'g': ('<f2', None), 'h': ('<i2', None),
    'H': ('<u2', None), 'i': ('<i4', None), 'I': ('<u4', None), 'f': ('<f4', None), 'd': ('<f8', None),
    'n': ('S4', None), 'N': ('S16', None), 'Z': ('S64', None), 'c': ('<i2', 0.01), 'C': ('<u2', 0.01),
    'e': ('<i4', 0.01), 'E': ('<u4', 0.01), 'L': ('<i4', 1e-7), 'M': ('<i1', None), 'q': ('<i8', None),
    'Q': ('<u8', None),
}
"""DataFlash format characters: numpy type and multiplier (ArduPilot's ``LogStructure.h``)."""

ROTATIONS: dict[int, tuple[float, float, float]] = {
    0: (0, 0, 0), 1: (0, 0, 45), 2: (0, 0, 90), 3: (0, 0, 135), 4: (0, 0, 180), 5: (0, 0, 225), 6: (0, 0, 270),
    7: (0, 0, 315), 8: (180, 0, 0), 9: (180, 0, 45), 10: (180, 0, 90), 11: (180, 0, 135), 12: (0, 180, 0),
    13: (180, 0, 225), 14: (180, 0, 270), 15: (180, 0, 315), 16: (90, 0, 0), 17: (90, 0, 45), 18: (90, 0, 90),
    19: (90, 0, 135), 20: (270, 0, 0), 21: (270, 0, 45), 22: (270, 0, 90), 23: (270, 0, 135), 24: (0, 90, 0),
    25: (0, 270, 0), 26: (0, 180, 90), 27: (0, 180, 270), 28: (90, 90, 0), 29: (180, 90, 0), 30: (270, 90, 0),
    31: (90, 180, 0), 32: (270, 180, 0), 33: (90, 270, 0), 34: (180, 270, 0), 35: (270, 270, 0),
    36: (90, 180, 90), 37: (90, 0, 270), 39: (0, 315, 0), 40: (90, 315, 0), 41: (0, 7, 0),
}
"""``AHRS_ORIENTATION`` -> (roll, pitch, yaw) degrees of ArduPilot's ``enum Rotation`` (38 and the
custom rotations are not supported)."""


@dataclass(frozen=True)
class MessageType:
    """One type of a DataFlash log, from its ``FMT`` message."""

    type: int
    length: int
    name: str
    format: str
    columns: tuple[str, ...]

    def dtype(self) -> np.dtype:
        """The packed little-endian numpy type of the message body (after the 3-byte header)."""
        return np.dtype([(column, FORMAT_CHARACTERS[char][0]) for column, char in zip(self.columns, self.format)])


def is_dataflash(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is a file that starts with a DataFlash ``FMT`` message."""
    path = Path(path)
    if not path.is_file():
        return False
    with path.open('rb') as stream:
        return stream.read(3) == HEAD + bytes([FMT_TYPE])


def _text(raw: bytes) -> str:
    return raw.split(b'\0', 1)[0].decode('ascii', errors='replace')


def index_messages(path: Path, data: bytes) -> tuple[dict[int, MessageType], dict[int, np.ndarray], int]:
    """Every message's position, by type, and the log's types; the bytes skipped between messages.

    :raises FlightLogError: the file ends inside a message (truncated), or a ``FMT`` is invalid.
    """
    types: dict[int, MessageType] = {FMT_TYPE: MessageType(FMT_TYPE, FMT_LENGTH, 'FMT', FMT_FORMAT,
                                                           tuple(FMT_COLUMNS.split(',')))}
    positions: dict[int, list[int]] = {}
    lengths = {FMT_TYPE: FMT_LENGTH}
    end = len(data)
    position = 0
    skipped = 0
    find = data.find
    while position + 3 <= end:
        if data[position] != 0xA3 or data[position + 1] != 0x95 or data[position + 2] not in lengths:
            found = find(HEAD, position + 1)
            found = end if found < 0 else found
            skipped += found - position
            position = found
            continue
        kind = data[position + 2]
        length = lengths[kind]
        if position + length > end:
            msg = (f'{path}: the log ends inside a message (a {types[kind].name} at byte {position} needs {length} '
                   f'bytes, {end - position} remain): a truncated file')
            raise FlightLogError(msg)
        if kind == FMT_TYPE:
            body = data[position + 3:position + FMT_LENGTH]
            described = MessageType(body[0], body[1], _text(body[2:6]), _text(body[6:22]),
                                    tuple(c for c in _text(body[22:86]).split(',') if c))
            if described.length < 3 or any(char not in FORMAT_CHARACTERS for char in described.format) \
                    or len(described.format) != len(described.columns):
                msg = f'{path}: FMT of {described.name!r} at byte {position} is not a valid message format'
                raise FlightLogError(msg)
            if described.type != FMT_TYPE:
                types[described.type] = described
                lengths[described.type] = described.length
        positions.setdefault(kind, []).append(position)
        position += length
    if end - position > 0 and position < end:
        skipped += end - position
    return types, {kind: np.asarray(rows, dtype=np.int64) for kind, rows in positions.items()}, skipped


def decode(data: np.ndarray, kind: MessageType, positions: np.ndarray, path: Path) -> np.ndarray:
    """The messages of one type at ``positions`` as a structured array (multipliers not applied)."""
    dtype = kind.dtype()
    if dtype.itemsize != kind.length - 3:
        msg = (f'{path}: {kind.name}: its format {kind.format} takes {dtype.itemsize} bytes, its FMT says '
               f'{kind.length - 3}')
        raise FlightLogError(msg)
    body = data[positions[:, None] + np.arange(3, kind.length)]
    return np.ascontiguousarray(body).view(dtype).reshape(len(positions))


def column(records: np.ndarray, kind: MessageType, name: str) -> np.ndarray:
    """A column as floats with its format's multiplier applied."""
    multiplier = FORMAT_CHARACTERS[kind.format[kind.columns.index(name)]][1]
    values = records[name].astype(float)
    return values * multiplier if multiplier is not None else values


def read_dataflash(path: str | os.PathLike[str], instance: int = 0) -> FlightLog:
    """Instance ``instance`` of a DataFlash log's IMU, what the firmware applied undone.

    :raises FlightLogError: as the module says.
    """
    return _read(readable(path), instance)


@dataclass(frozen=True)
class _Parameters:
    """The log's parameters (``PARM``), each name's values in log order."""

    values: dict[str, list[tuple[int, float]]]
    path: Path

    def at(self, name: str, default: float) -> float:
        """The value in force at the start (its first), or ``default``.

        :raises FlightLogError: it is NaN or infinite (what the firmware applied cannot be undone).
        """
        entries = self.values.get(name)
        if not entries:
            return default
        value = entries[0][1]
        if not math.isfinite(value):
            msg = f'{self.path}: parameter {name} is {value}, not a finite number'
            raise FlightLogError(msg)
        return value

    def whole(self, name: str, default: int, low: int = 0, high: int = 2 ** 32 - 1) -> int:
        """:meth:`at` of a parameter that is a whole number within ``low..high`` (an enum, a flag, a device ID)."""
        value = self.at(name, default)
        if value != round(value) or not low <= value <= high:
            msg = f'{self.path}: parameter {name} is {value:g}, not a whole number within {low}..{high}'
            raise FlightLogError(msg)
        return int(value)

    def check_constant(self, names: list[str], start_us: int, end_us: int) -> None:
        """Refuse a parameter the reader undoes that changes while the instance is logged."""
        for name in names:
            entries = self.values.get(name, [])
            for (_, first), (stamp, value) in zip(entries, entries[1:]):
                if value != first and start_us < stamp <= end_us:
                    msg = (f'{self.path}: parameter {name} changes from {first:g} to {value:g} at '
                           f'{stamp * 1e-6:.1f} s, while the IMU is logged: what the firmware applied differs before '
                           f'and after (split the log there)')
                    raise FlightLogError(msg)


def _parameters(path: Path, data: np.ndarray, types: dict[int, MessageType],
                positions: dict[int, np.ndarray]) -> _Parameters:
    values: dict[str, list[tuple[int, float]]] = {}
    for kind in types.values():
        if kind.name != 'PARM' or kind.type not in positions:
            continue
        check_columns(path, kind, text=('Name',), numbers=('Value',),
                      whole=('TimeUS',) if 'TimeUS' in kind.columns else ())
        records = decode(data, kind, positions[kind.type], path)
        stamps = (records['TimeUS'].tolist() if 'TimeUS' in kind.columns else [0] * len(records))
        for stamp, name, value in zip(stamps, records['Name'].tolist(), column(records, kind, 'Value').tolist()):
            values.setdefault(_text(name), []).append((int(stamp), float(value)))
    return _Parameters(values, path)


TEXT_CHARACTERS = frozenset('nNZ')
"""Format characters of text."""
WHOLE_CHARACTERS = frozenset('bBhHiIqQM')
"""Format characters of whole numbers (no multiplier)."""


def check_columns(path: Path, kind: MessageType, *, text: tuple[str, ...] = (), numbers: tuple[str, ...] = (),
                  whole: tuple[str, ...] = ()) -> None:
    """Refuse a message type whose ``FMT`` lacks a column the reader takes, or gives it the wrong kind of value.

    :param text: columns of text; ``numbers``: of numbers (not text, not an array); ``whole``: of
        whole numbers (``TimeUS``, an instance).
    :raises FlightLogError: one line naming the type and the column.
    """
    for names, allowed, what in ((text, TEXT_CHARACTERS, 'text'),
                                 (numbers, frozenset(FORMAT_CHARACTERS) - TEXT_CHARACTERS - {'a'}, 'a number'),
                                 (whole, WHOLE_CHARACTERS, 'a whole number')):
        for name in names:
            if name not in kind.columns:
                msg = (f'{path}: {kind.name} messages have no column {name} (format {kind.format}, columns '
                       f'{",".join(kind.columns)})')
                raise FlightLogError(msg)
            char = kind.format[kind.columns.index(name)]
            if char not in allowed:
                msg = f'{path}: {kind.name} column {name} is not {what} (format character {char!r})'
                raise FlightLogError(msg)


def rotation_matrix(orientation: int, path: Path) -> np.ndarray:
    """``AHRS_ORIENTATION`` as the matrix the firmware rotates sensor vectors by (roll, pitch, yaw; Z-Y-X)."""
    if orientation not in ROTATIONS:
        msg = f'{path}: AHRS_ORIENTATION {orientation} is not a rotation this reader undoes (0..41 except 38)'
        raise FlightLogError(msg)
    roll, pitch, yaw = (math.radians(v) for v in ROTATIONS[orientation])
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), \
        math.sin(yaw)
    matrix = np.array([[cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
                       [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
                       [-sp, sr * cp, cr * cp]])
    return np.round(matrix, 12)


def tcal_offset(temperature: np.ndarray, coefficients: np.ndarray, tmin: float, tmax: float) -> np.ndarray:
    """``P(clamp(T) - 35)`` of ``INS_TCALn``: ``coefficients`` ``(3 orders, 3 axes)`` already divided by 1e6.

    The firmware's ``polynomial_eval``: ``(c1 + (c2 + c3 t) t) t``, no constant term.
    """
    t = (np.clip(np.asarray(temperature, dtype=float), tmin, tmax) - TEMP_REFERENCE)[:, None]
    c1, c2, c3 = coefficients
    return (c1 + (c2 + c3 * t) * t) * t


def _suffix(instance: int) -> str:
    return '' if instance == 0 else str(instance + 1)


def _device_id_names(instance: int) -> dict[str, str]:
    """Per sensor the parameter naming its device ID (``INS_ACC_ID``, ``INS_GYR2_ID`` ...)."""
    return {sensor: f'INS_{prefix}{_suffix(instance)}_ID' for sensor, prefix in (('accel', 'ACC'), ('gyro', 'GYR'))}


def _device_ids(parameters: _Parameters, instance: int) -> dict[str, int]:
    """Per sensor its device ID at the log's start (0 where the log names none)."""
    return {sensor: parameters.whole(name, 0) for sensor, name in _device_id_names(instance).items()}


def _read(path: Path, instance: int) -> FlightLog:
    raw = path.read_bytes()
    types, positions, skipped = index_messages(path, raw)
    data = np.frombuffer(raw, dtype=np.uint8)
    parameters = _parameters(path, data, types, positions)
    by_name = {kind.name: kind for kind in types.values()}
    lines = [f'{path.name}: ArduPilot DataFlash log, {sum(len(p) for p in positions.values())} messages'
             + (f' ({skipped} bytes between messages skipped)' if skipped else '')]
    imu = _imu_messages(path, data, by_name, positions, instance)
    if imu is None:
        return _tclr(path, data, by_name, positions, instance, parameters, lines)
    kind, records = imu
    stamps_us = records['TimeUS']
    accel = np.column_stack([column(records, kind, f'Acc{a}') for a in 'XYZ'])
    gyro = np.column_stack([column(records, kind, f'Gyr{a}') for a in 'XYZ'])
    temperature = column(records, kind, 'T')
    accel, gyro = _undo_firmware(path, parameters, instance, accel, gyro, temperature, stamps_us, lines)
    stamp_ns = stamp_ns_from_micros(stamps_us)
    device_ids = _device_ids(parameters, instance)
    parameters.check_constant(list(_device_id_names(instance).values()), int(stamps_us.min()), int(stamps_us.max()))
    where = f'{kind.name} instance {instance}'
    accel_stamps, accel, _ = checked_sensor(path, 'accel', stamp_ns, accel, None, where)
    gyro_stamps, gyro, _ = checked_sensor(path, 'gyro', stamp_ns, gyro, None, where)
    temp_stamps, temperature = checked_temperature(path, stamp_ns, temperature, f'{where} T')
    lines.append(f'{path.name}: instance {instance}: {len(accel_stamps)} {kind.name} samples, both sensors, T')
    return FlightLog(path=path, format='dataflash', instance=instance,
                     stamps={'accel': accel_stamps, 'gyro': gyro_stamps, 'mag': np.zeros(0, dtype=np.int64)},
                     values={'accel': accel, 'gyro': gyro, 'mag': np.zeros((0, 3))}, temp_stamp_ns=temp_stamps,
                     temperature=temperature, device_ids=device_ids, lines=tuple(lines),
                     temperature_source=f'{kind.name}.T')


def _imu_messages(path: Path, data: np.ndarray, by_name: dict[str, MessageType], positions: dict[int, np.ndarray],
                  instance: int) -> tuple[MessageType, np.ndarray] | None:
    """The instance's ``IMU`` messages (``I`` = instance, or ``IMU``/``IMU2``/``IMU3``), ``None`` without any."""
    kind = by_name.get('IMU')
    if kind is None or kind.type not in positions:
        return None
    if 'I' in kind.columns:
        _check_imu_columns(path, kind)
        records = decode(data, kind, positions[kind.type], path)
        held = sorted(set(records['I'].tolist()))
        if instance not in held:
            listed = ', '.join(map(str, held))
            msg = f'{path}: no IMU instance {instance} (instances in the log: {listed}; --instance N)'
            raise FlightLogError(msg)
        return kind, records[records['I'] == instance]
    name = 'IMU' if instance == 0 else f'IMU{instance + 1}'
    named = by_name.get(name)
    if named is None or named.type not in positions:
        held = [n for n in ('IMU', 'IMU2', 'IMU3') if n in by_name and by_name[n].type in positions]
        msg = f'{path}: no {name} messages (instance {instance}; the log holds {", ".join(held)}; --instance N)'
        raise FlightLogError(msg)
    _check_imu_columns(path, named)
    return named, decode(data, named, positions[named.type], path)


def _check_imu_columns(path: Path, kind: MessageType) -> None:
    """The columns the reader takes of ``IMU`` messages, each of the right kind (a ``T``: else an older firmware)."""
    if 'T' not in kind.columns:
        msg = (f'{path}: {kind.name} messages have no temperature T (format {kind.format}, columns '
               f'{",".join(kind.columns)}): an older firmware\'s log cannot give a thermal calibration')
        raise FlightLogError(msg)
    check_columns(path, kind, whole=('TimeUS', *(('I',) if 'I' in kind.columns else ())),
                  numbers=(*(f'{sensor}{axis}' for sensor in ('Acc', 'Gyr') for axis in 'XYZ'), 'T'))


def _undo_firmware(path: Path, parameters: _Parameters, instance: int, accel: np.ndarray, gyro: np.ndarray,
                   temperature: np.ndarray, stamps_us: np.ndarray, lines: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """The sensor-frame raw samples from what the firmware logged (see the module's description)."""
    suffix = _suffix(instance)
    accel_offsets = [f'INS_ACC{suffix}OFFS_{axis}' for axis in 'XYZ']
    accel_scales = [f'INS_ACC{suffix}SCAL_{axis}' for axis in 'XYZ']
    gyro_offsets = [f'INS_GYR{suffix}OFFS_{axis}' if suffix else f'INS_GYROFFS_{axis}' for axis in 'XYZ']
    tcal = f'INS_TCAL{instance + 1}_'
    coefficient_names = [f'{tcal}{sensor}{order}_{axis}' for sensor in ('ACC', 'GYR') for order in (1, 2, 3)
                         for axis in 'XYZ']
    watched = ['AHRS_ORIENTATION', *accel_offsets, *accel_scales, *gyro_offsets, f'{tcal}ENABLE', f'{tcal}TMIN',
               f'{tcal}TMAX', f'INS_ACC{instance + 1}_CALTEMP', f'INS_GYR{instance + 1}_CALTEMP', *coefficient_names]
    parameters.check_constant(watched, int(stamps_us.min()), int(stamps_us.max()))
    orientation = parameters.whole('AHRS_ORIENTATION', 0)
    rotation = rotation_matrix(orientation, path)
    # the firmware logs rotation @ v: undo it (rotation is orthonormal); a sample that is not
    # finite stays as it is (the passes leave it out and count it)
    accel, gyro = _rotated(accel, rotation), _rotated(gyro, rotation)
    offsets = np.array([parameters.at(name, 0.0) for name in accel_offsets])
    scales = np.array([parameters.at(name, 1.0) or 1.0 for name in accel_scales])
    accel = accel / scales + offsets
    gyro = gyro + np.array([parameters.at(name, 0.0) for name in gyro_offsets])
    undone = [f'board rotation {orientation}' if orientation else '', 'offsets and scale']
    if parameters.whole(f'{tcal}ENABLE', 0, high=2 ** 31) == 1:
        tmin, tmax = parameters.at(f'{tcal}TMIN', 0.0), parameters.at(f'{tcal}TMAX', 70.0)
        for sensor, name in (('ACC', 'accel'), ('GYR', 'gyro')):
            coefficients = np.array([[parameters.at(f'{tcal}{sensor}{order}_{axis}', 0.0) / SCALE_FACTOR
                                      for axis in 'XYZ'] for order in (1, 2, 3)])
            caltemp = parameters.at(f'INS_{sensor}{instance + 1}_CALTEMP', -300.0)
            applied = tcal_offset(temperature, coefficients, tmin, tmax) - tcal_offset(
                np.array([caltemp]), coefficients, tmin, tmax)
            if name == 'accel':
                accel = accel + applied
            else:
                gyro = gyro + applied
        undone.append(f'{tcal}* ({tmin:g}..{tmax:g} C)')
    lines.append(f'{path.name}: undone as the firmware applied it: {", ".join(u for u in undone if u)}')
    return accel, gyro


def _rotated(values: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """``values @ rotation`` on the finite rows; the others as they were."""
    finite = np.all(np.isfinite(values), axis=1)
    out = values.copy()
    out[finite] = values[finite] @ rotation
    return out


def _tclr(path: Path, data: np.ndarray, by_name: dict[str, MessageType], positions: dict[int, np.ndarray],
          instance: int, parameters: _Parameters, lines: list[str]) -> FlightLog:
    """A log without IMU messages: the firmware's temperature-learning records ``TCLR`` (raw, sensor frame)."""
    kind = by_name.get('TCLR')
    if kind is None or kind.type not in positions:
        msg = f'{path}: no IMU and no TCLR messages (the log holds {", ".join(sorted(by_name))})'
        raise FlightLogError(msg)
    check_columns(path, kind, whole=('TimeUS', 'I', 'SType'), numbers=('Temp', 'X', 'Y', 'Z'))
    records = decode(data, kind, positions[kind.type], path)
    held = sorted(set(records['I'].tolist()))
    if instance not in held:
        msg = f'{path}: no TCLR instance {instance} (instances in the log: {", ".join(map(str, held))}; --instance N)'
        raise FlightLogError(msg)
    records = records[records['I'] == instance]
    stamps, values, temperatures = {}, {}, []
    for sensor, code in (('accel', 0), ('gyro', 1)):
        rows = records[records['SType'] == code]
        stamp_ns = stamp_ns_from_micros(rows['TimeUS'])
        sample = np.column_stack([column(rows, kind, axis) for axis in 'XYZ'])
        stamps[sensor], values[sensor], _ = checked_sensor(path, sensor, stamp_ns, sample, None,
                                                           f'TCLR instance {instance}')
        temperatures.append((stamp_ns, column(rows, kind, 'Temp')))
    temp_stamps, temperature = checked_temperature(path, np.concatenate([t[0] for t in temperatures]),
                                                   np.concatenate([t[1] for t in temperatures]),
                                                   f'TCLR instance {instance} Temp')
    stamps['mag'], values['mag'] = np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    lines.append(f'{path.name}: instance {instance}: no IMU messages; the learning records TCLR, '
                 f'{len(stamps["accel"])} + {len(stamps["gyro"])} samples')
    device_ids = _device_ids(parameters, instance)
    return FlightLog(path=path, format='dataflash', instance=instance, stamps=stamps, values=values,
                     temp_stamp_ns=temp_stamps, temperature=temperature, device_ids=device_ids, lines=tuple(lines),
                     temperature_source='TCLR.Temp')


# ----- writing (tests and benchmarks; pymavlink has no writer) ---------------------------------------

IMU_FORMAT = ('QBffffffIIfBBHH', 'TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz')
"""The ``IMU`` message of ArduPilot 4.x (``AP_InertialSensor/LogStructure.h``)."""
PARM_FORMAT = ('QNf', 'TimeUS,Name,Value')


def message_bytes(kind: MessageType, values: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """``(TimeUS, (k, length) bytes)`` of ``k`` messages of one type (header included)."""
    dtype = kind.dtype()
    count = len(next(iter(values.values()))) if values else 0
    rows = np.zeros(count, dtype=dtype)
    for name in kind.columns:
        if name in values:
            multiplier = FORMAT_CHARACTERS[kind.format[kind.columns.index(name)]][1]
            value = np.asarray(values[name])
            rows[name] = np.round(value / multiplier) if multiplier is not None else value
    body = rows.view(np.uint8).reshape(count, dtype.itemsize)
    header = np.tile(np.frombuffer(HEAD + bytes([kind.type]), dtype=np.uint8), (count, 1))
    stamps = np.asarray(values.get('TimeUS', np.zeros(count)), dtype=np.int64)
    return stamps, np.hstack([header, body])


def write_dataflash(path: str | os.PathLike[str], messages: dict[str, tuple[str, str, dict[str, np.ndarray]]], *,
                    parameters: dict[str, float] | None = None) -> None:
    """Write a DataFlash log atomically: the ``FMT`` of each type, the parameters, then the messages by ``TimeUS``.

    :param messages: name -> ``(format, columns, column -> (k,) values)`` (values in the
        column's unit: a multiplier is applied as the format says).
    :param parameters: ``PARM`` messages at time 0.
    """
    from tak_thermo_ros.formats.files import write_bytes_atomic
    kinds = {'FMT': MessageType(FMT_TYPE, FMT_LENGTH, 'FMT', FMT_FORMAT, tuple(FMT_COLUMNS.split(',')))}
    every = {'PARM': PARM_FORMAT, **{name: (fmt, columns) for name, (fmt, columns, _) in messages.items()}}
    for number, (name, (fmt, columns)) in enumerate(every.items(), start=64):
        kinds[name] = MessageType(number, 3 + MessageType(0, 0, name, fmt, tuple(columns.split(','))).dtype().itemsize,
                                  name, fmt, tuple(columns.split(',')))
    fmt_rows = {'Type': np.array([k.type for k in kinds.values()]),
                'Length': np.array([k.length for k in kinds.values()]),
                'Name': np.array([k.name.encode() for k in kinds.values()]),
                'Format': np.array([k.format.encode() for k in kinds.values()]),
                'Columns': np.array([','.join(k.columns).encode() for k in kinds.values()])}
    parts = [message_bytes(kinds['FMT'], fmt_rows)[1]]
    names = sorted(parameters or {})
    if names:
        parts.append(message_bytes(kinds['PARM'], {'TimeUS': np.zeros(len(names), dtype=np.int64),
                                                   'Name': np.array([n.encode() for n in names]),
                                                   'Value': np.array([(parameters or {})[n] for n in names])})[1])
    timed = [message_bytes(kinds[name], values) for name, (_, _, values) in messages.items()]
    if timed:
        stamps = np.concatenate([stamp for stamp, _ in timed])
        each = [message for _, rows in timed for message in rows.view(f'V{rows.shape[1]}').ravel().tolist()]
        parts.append(b''.join(each[i] for i in np.argsort(stamps, kind='stable').tolist()))
    write_bytes_atomic(path, b''.join(p if isinstance(p, bytes) else p.tobytes() for p in parts))


def driver_messages(record, *, instance: int = 0) -> dict[str, tuple[str, str, dict[str, np.ndarray]]]:
    """A driver record whose sensors share their stamps as ArduPilot's ``IMU`` messages (:func:`write_dataflash`)."""
    from tak_thermo_ros.core.records.record import hold_signal
    if not (record.shared_stamps or np.array_equal(record.sensor_stamps('accel'), record.sensor_stamps('gyro'))):
        msg = 'an IMU message holds both sensors: the record\'s accelerometer and gyroscope need the same stamps'
        raise FlightLogError(msg)
    stamps = record.sensor_stamps('accel')
    count = len(stamps)
    values = {'TimeUS': stamps // 1000, 'I': np.full(count, instance),
              'T': hold_signal(record.temp_stamp_ns, record.temperature, stamps)}
    for prefix, data in (('Acc', record.accel), ('Gyr', record.gyro)):
        for axis, column_values in zip('XYZ', data.T):
            values[f'{prefix}{axis}'] = column_values
    return {'IMU': (*IMU_FORMAT, values)}
