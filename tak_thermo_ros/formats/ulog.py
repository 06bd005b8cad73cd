"""PX4 ULog files (``.ulg``) through pyulog (BSD), an optional library: read and, for tests and benchmarks, written.

Read (:func:`read_ulog`): instance ``N`` of ``sensor_accel``, ``sensor_gyro`` and
``sensor_mag`` (the topics PX4 logs raw, before any calibration, with the thermal-calibration
logging profile, ``SDLOG_PROFILE`` bit 2), each on its own ``timestamp_sample`` (else
``timestamp``), with its ``device_id``. The magnetometer's gauss become tesla. The
temperature is the IMU's thermometer, ``sensor_accel.temperature`` (``sensor_gyro``'s where the
accelerometer reports none). Refused in one line: a file pyulog cannot parse or finds
corrupt (a truncated file), an instance the log does not hold, no temperature, a
``device_id`` that changes mid-log.

Written (:func:`write_ulog`): a driver record as those topics plus ``sensor_baro`` (PX4's own
``Tools/process_sensor_caldata.py`` requires one), with pyulog's ``ULog.write_ulog``.
"""

from __future__ import annotations

import contextlib
import io
import os
import struct
from pathlib import Path

import numpy as np

from tak_thermo_ros.errors import FlightLogError
from tak_thermo_ros.core.records.plausible import stamp_ns_from_micros
from tak_thermo_ros.formats.flight_log import FlightLog, cached, checked_sensor, checked_temperature

GAUSS = 1e-4
"""Tesla per gauss (``sensor_mag`` is in gauss)."""
MAGIC = b'ULog\x01\x12\x35'
"""The first bytes of every ULog file."""
TOPICS = {'accel': 'sensor_accel', 'gyro': 'sensor_gyro', 'mag': 'sensor_mag'}


def is_ulog(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is a file that starts as a ULog does."""
    path = Path(path)
    if not path.is_file():
        return False
    with path.open('rb') as stream:
        return stream.read(len(MAGIC)) == MAGIC


def _pyulog():
    from tak_thermo_ros.optional import require
    return require('pyulog', 'reading a PX4 ULog')


HEADER_BYTES = 16
"""A ULog's file header: magic, version, start timestamp; then messages of ``uint16 size, uint8 type, payload``."""


def _cut_at(path: Path) -> int | None:
    """The byte at which the file's last message starts if the file ends inside it (a truncated log), else ``None``."""
    data = path.read_bytes()
    end = len(data)
    position = HEADER_BYTES
    while position + 3 <= end:
        size = data[position] | (data[position + 1] << 8)
        if position + 3 + size > end:
            return position
        position += 3 + size
    return position if position < end else None


def _joined(path: Path, topic: str, instance: int, datasets: list) -> dict[str, np.ndarray]:
    """The fields of a topic instance logged in one or more subscriptions, joined in the order of their first stamps.

    (A logger that subscribes to a topic instance again logs it under a new message ID: each
    part keeps its own order; where the parts overlap, the stamp rule leaves the repeats out.)

    :raises FlightLogError: the parts log different fields.
    """
    if len(datasets) == 1:
        return datasets[0].data
    fields = set(datasets[0].data)
    if any(set(d.data) != fields for d in datasets[1:]):
        msg = f'{path}: {topic} instance {instance} is logged in {len(datasets)} subscriptions with different fields'
        raise FlightLogError(msg)

    def first_stamp(dataset) -> int:
        stamps = dataset.data[_stamp_field(path, topic, instance, dataset.data)]
        return int(stamps[0]) if len(stamps) else 0

    ordered = sorted(datasets, key=first_stamp)
    return {name: np.concatenate([d.data[name] for d in ordered]) for name in fields}


def _stamp_field(path: Path, topic: str, instance: int, data: dict[str, np.ndarray]) -> str:
    """The field a topic's samples are stamped by: ``timestamp_sample``, else ``timestamp``; refuses one without."""
    for name in ('timestamp_sample', 'timestamp'):
        if name in data:
            if np.asarray(data[name]).dtype.kind not in 'iu':
                msg = f'{path}: {topic} instance {instance}: its field {name} is not a whole number'
                raise FlightLogError(msg)
            return name
    msg = f'{path}: {topic} instance {instance} has no timestamp field'
    raise FlightLogError(msg)


def _numbers(path: Path, topic: str, instance: int, data: dict[str, np.ndarray], names: tuple[str, ...]) -> np.ndarray:
    """The fields ``names`` of a topic as float columns; refuses a missing one or one that holds no numbers."""
    for name in names:
        if name not in data or np.asarray(data[name]).dtype.kind not in 'iuf':
            what = 'no field' if name not in data else 'a field that is not a number,'
            msg = f'{path}: {topic} instance {instance} has {what} {name}'
            raise FlightLogError(msg)
    return np.column_stack([np.asarray(data[name], dtype=float) for name in names])


def read_ulog(path: str | os.PathLike[str], instance: int = 0) -> FlightLog:
    """Instance ``instance`` of a ULog's IMU topics, read once per process (:func:`~.flight_log.cached`).

    :raises FlightLogError: as the module says.
    :raises DependencyError: pyulog is not installed.
    """
    return cached(_read, path, instance)


class _Endless(Exception):
    """pyulog read the file over and over (:class:`_BoundedReader`)."""


class _BoundedReader:
    """The file as pyulog reads it, stopped when it has read the file :data:`READS_PER_BYTE` times over.

    pyulog 1.2 resyncs on damaged data by seeking back to one byte past a message's start; a
    message whose size runs past the end then sends it back before its start, forever. Every
    byte it reads is counted here, so that such a file ends in one line, not a hang.
    """

    def __init__(self, stream, size: int) -> None:
        self._stream = stream
        self._budget = READS_PER_BYTE * (size + 1024)

    def read(self, count: int = -1) -> bytes:
        """Read, as the file does, and count it."""
        data = self._stream.read(count)
        self._budget -= len(data) + 1
        if self._budget < 0:
            raise _Endless
        return data

    def seek(self, offset: int, whence: int = 0) -> int:
        """Seek, as the file does."""
        return self._stream.seek(offset, whence)

    def tell(self) -> int:
        """Where the file is."""
        return self._stream.tell()

    def close(self) -> None:
        """Nothing: the file is closed by its owner."""


READS_PER_BYTE = 8
"""How many times over pyulog may read a file (once, plus its resyncs over damaged bytes)."""


def _read(path: Path, instance: int) -> FlightLog:
    pyulog = _pyulog()
    cut = _cut_at(path)
    if cut is not None:
        msg = f'{path}: the ULog is truncated or corrupt (its last message, at byte {cut}, is cut short); nothing read'
        raise FlightLogError(msg)
    printed = io.StringIO()  # pyulog prints its warnings: said below in our words, not on the user's terminal
    try:
        with path.open('rb') as stream, contextlib.redirect_stdout(printed):  # ours to close, whatever pyulog does
            ulog = pyulog.ULog(_BoundedReader(stream, path.stat().st_size), list(TOPICS.values()))
    except _Endless:
        msg = f'{path}: not a readable ULog (pyulog went round in circles over damaged data)'
        raise FlightLogError(msg) from None
    except Exception as err:  # pyulog raises many kinds on a damaged file
        detail = str(err).splitlines()[0] if str(err) else type(err).__name__
        msg = f'{path}: not a readable ULog ({detail})'
        raise FlightLogError(msg) from None
    if ulog.file_corruption:
        msg = f'{path}: the ULog is truncated or corrupt (pyulog found damaged data); nothing read from it'
        raise FlightLogError(msg)
    said = [line.strip() for line in printed.getvalue().splitlines() if line.strip()]
    found: dict[tuple[str, int], list] = {}
    for dataset in ulog.data_list:
        found.setdefault((dataset.name, dataset.multi_id), []).append(dataset)
    for sensor in ('accel', 'gyro'):
        if (TOPICS[sensor], instance) not in found:
            held = sorted(multi for name, multi in found if name == TOPICS[sensor])
            if not held:
                msg = (f'{path}: no {TOPICS[sensor]} topic (log with the thermal-calibration profile, SDLOG_PROFILE '
                       f'bit 2, to record the raw sensors with their temperature)')
            else:
                msg = (f'{path}: no instance {instance} of {TOPICS[sensor]} (instances in the log: '
                       f'{", ".join(str(m) for m in held)}; --instance N)')
            raise FlightLogError(msg)
    stamps, values, device_ids = {}, {}, {}
    temperatures = []
    subscriptions = {}
    for sensor, topic in TOPICS.items():
        datasets = found.get((topic, instance))
        if not datasets:
            stamps[sensor], values[sensor], device_ids[sensor] = np.zeros(0, dtype=np.int64), np.zeros((0, 3)), 0
            continue
        data = _joined(path, topic, instance, datasets)
        subscriptions[sensor] = len(datasets)
        micros = data[_stamp_field(path, topic, instance, data)]
        sample = _numbers(path, topic, instance, data, ('x', 'y', 'z'))
        if sensor == 'mag':
            sample = sample * GAUSS
        stamp_ns = stamp_ns_from_micros(micros)
        stamps[sensor], values[sensor], device_ids[sensor] = checked_sensor(
            path, sensor, stamp_ns, sample, data.get('device_id'), f'{topic} instance {instance}')
        if sensor != 'mag' and 'temperature' in data:
            temperatures.append((f'{topic}.temperature', stamp_ns,
                                 _numbers(path, topic, instance, data, ('temperature',))[:, 0]))
    chosen = next((t for t in temperatures if np.isfinite(t[2]).any()), None)
    if chosen is None:
        where = f'{TOPICS["accel"]} and {TOPICS["gyro"]} instance {instance}'
        chosen = (where, np.zeros(0, dtype=np.int64), np.zeros(0))
    temp_stamps, temperature = checked_temperature(path, chosen[1], chosen[2], chosen[0])
    lines = [f'{path.name}: PX4 ULog, instance {instance}: {len(stamps["accel"])} sensor_accel, '
             f'{len(stamps["gyro"])} sensor_gyro, {len(stamps["mag"])} sensor_mag samples',
             f'{path.name}: each sensor on its own stamps; the temperature is {chosen[0]}']
    lines += [f'{path.name}: {TOPICS[sensor]} in {count} subscriptions, joined in the order of their first stamps'
              for sensor, count in subscriptions.items() if count > 1]
    lines += [f'{path.name}: pyulog: {line}' for line in said[:1]]
    return FlightLog(path=path, format='ulog', instance=instance, stamps=stamps, values=values,
                     temp_stamp_ns=temp_stamps, temperature=temperature, device_ids=device_ids, lines=tuple(lines),
                     temperature_source=chosen[0])


# ----- writing (tests and benchmarks: a simulated unit's log, as PX4 writes it) ---------------------

_FIELDS = {
    'sensor_accel': [('uint64_t', 'timestamp'), ('uint64_t', 'timestamp_sample'), ('uint32_t', 'device_id'),
                     ('float', 'x'), ('float', 'y'), ('float', 'z'), ('float', 'temperature'),
                     ('uint32_t', 'error_count')],
    'sensor_gyro': [('uint64_t', 'timestamp'), ('uint64_t', 'timestamp_sample'), ('uint32_t', 'device_id'),
                    ('float', 'x'), ('float', 'y'), ('float', 'z'), ('float', 'temperature'),
                    ('uint32_t', 'error_count')],
    'sensor_mag': [('uint64_t', 'timestamp'), ('uint64_t', 'timestamp_sample'), ('uint32_t', 'device_id'),
                   ('float', 'x'), ('float', 'y'), ('float', 'z'), ('float', 'temperature'),
                   ('uint32_t', 'error_count')],
    'sensor_baro': [('uint64_t', 'timestamp'), ('uint64_t', 'timestamp_sample'), ('uint32_t', 'device_id'),
                    ('uint32_t', 'error_count'), ('float', 'pressure'), ('float', 'temperature')],
}
"""The fields PX4's ``msg/Sensor*.msg`` log (padding left out), in their order."""
_NUMPY = {'uint64_t': '<u8', 'uint32_t': '<u4', 'float': '<f4'}


def write_ulog(path: str | os.PathLike[str],
               topics: dict[tuple[str, int], dict[str, np.ndarray] | list[dict[str, np.ndarray]]], *,
               parameters: dict[str, float | int] | None = None, info: dict[str, str] | None = None) -> None:
    """Write topics as a ULog with pyulog's ``ULog.write_ulog`` (atomically).

    :param topics: ``(topic, instance)`` -> field -> ``(k,)`` values (a list of those: the instance
        logged in several subscriptions, as a logger that subscribes again writes it), fields as PX4 logs them
        (:data:`_FIELDS`: ``timestamp`` and ``timestamp_sample`` in microseconds; ``x``, ``y``,
        ``z`` in m/s^2, rad/s or gauss; ``temperature`` C; ``pressure`` hPa).
    :param parameters: initial parameters (an int is an ``int32_t``, a float a ``float``).
    :param info: information messages (``sys_name``, ``ver_hw`` ...).
    """
    import io
    from tak_thermo_ros.formats.files import write_bytes_atomic
    pyulog = _pyulog()
    ulog = pyulog.ULog(None)
    formats = {}
    for name in sorted({topic for topic, _ in topics}):  # in one order: the same log writes the same bytes
        text = f'{name}:' + ''.join(f'{kind} {field};' for kind, field in _FIELDS[name])
        formats[name] = pyulog.ULog.MessageFormat(text.encode(), None)
    ulog._message_formats = formats
    data_list = []
    subscriptions = [(key, part) for key, values in sorted(topics.items(), key=lambda item: item[0])
                     for part in (values if isinstance(values, list) else [values])]
    for msg_id, ((name, instance), values) in enumerate(subscriptions):
        added = pyulog.ULog._MessageAddLogged(struct.pack('<BH', instance, msg_id) + name.encode(), None, formats)
        dtype = np.dtype([(field, _NUMPY[kind]) for kind, field in _FIELDS[name]])
        count = len(values['timestamp'])
        rows = np.zeros(count, dtype=dtype)
        for _, field in _FIELDS[name]:
            if field in values:
                rows[field] = values[field]
        added.buffer = bytearray(rows.tobytes())
        data_list.append(pyulog.ULog.Data(added))
    ulog._data_list = data_list
    ulog._file_version = 1
    ulog._start_timestamp = int(min((int(v['timestamp'][0]) for _, v in subscriptions if len(v['timestamp'])),
                                    default=0))
    for key, value in (info or {}).items():
        ulog._msg_info_dict[key] = value
        ulog._msg_info_dict_types[key] = f'char[{len(value)}]'
    ulog._initial_parameters = dict(parameters or {})
    stream = io.BytesIO()
    ulog.write_ulog(stream)
    write_bytes_atomic(path, stream.getvalue())


def driver_topics(record, *, instance: int = 0, device_ids: dict[str, int] | None = None,
                  baro: bool = True) -> dict[tuple[str, int], dict[str, np.ndarray]]:
    """A driver record (each sensor on its own stamps) as the ULog topics PX4 logs (:func:`write_ulog`).

    The temperature is held on each sensor's stamps; ``baro`` adds a ``sensor_baro`` at the
    accelerometer's stamps (constant pressure, the same temperature).
    """
    from tak_thermo_ros.core.records.record import hold_signal
    ids = {'accel': 2490378, 'gyro': 2490634, 'mag': 396809, 'baro': 6620449, **(device_ids or {})}
    topics: dict[tuple[str, int], dict[str, np.ndarray]] = {}
    sensors = [('accel', record.accel), ('gyro', record.gyro)]
    if len(record.mag_stamp_ns):
        sensors.append(('mag', record.mag / GAUSS))
    for sensor, values in sensors:
        stamps = record.sensor_stamps(sensor)
        micros = stamps // 1000
        temperature = hold_signal(record.temp_stamp_ns, record.temperature, stamps)
        topics[(TOPICS[sensor], instance)] = {
            'timestamp': micros + 50, 'timestamp_sample': micros, 'device_id': np.full(len(stamps), ids[sensor]),
            'x': values[:, 0], 'y': values[:, 1], 'z': values[:, 2], 'temperature': temperature}
    if baro:
        stamps = record.sensor_stamps('accel')
        micros = stamps // 1000
        topics[('sensor_baro', instance)] = {
            'timestamp': micros + 60, 'timestamp_sample': micros, 'device_id': np.full(len(stamps), ids['baro']),
            'pressure': np.full(len(stamps), 1013.25),
            'temperature': hold_signal(record.temp_stamp_ns, record.temperature, stamps)}
    return topics
