"""Import a delimited (CSV/TSV) log into the bag contract: a static thermal run, or a driver's log.

Most users calibrate the way PX4 and ArduPilot do: the board lies still in one orientation and
the temperature is swept; the log comes as a delimited text file with a time column, three
acceleration columns and a temperature column. This module turns such a log into a
:class:`~tak_thermo_ros.core.records.record.ChannelRecord` (pure: no rosbags; ``bagio.write_record``
writes it).

Units and rounding
------------------
- Time: the ``time_unit`` column (``s``, ``ms``, ``us``, ``ns``) becomes int64 nanoseconds.
  Integer text is converted exactly; decimal text through :class:`decimal.Decimal`, rounded
  to the nearest nanosecond. Stamps must strictly increase and fit the bag's time type
  (``builtin_interfaces/Time``: whole seconds 0 .. 2**31 - 1, i.e. 1970-01-01 .. 2038-01-19);
  a stamp outside it is an error naming the line and the column, as is a step of a year or more
  between rows (a clock step, :func:`~tak_thermo_ros.core.records.plausible.clock_step`).
- Numbers: ASCII decimal text only (:data:`ASCII_NUMBER`); a wanted column named twice in the
  header is refused.
- Acceleration: the columns in ``m/s^2`` or ``g`` (``1 g = 9.80665 m/s^2``, the standard
  value, whatever the local gravity) become channel codes
  ``N = round(a / acc_resolution)`` with ``acc_resolution`` in m/s^2 per count (round half to
  even). The nominal scale written to the bag is ``1 / acc_resolution`` counts per m/s^2 on each
  axis; ``fit`` holds an axis's scale at that value when the axis sees one input only.
  Every code must stay strictly inside the 16-bit range (``-32768 < N < 32767``; the rails
  count as saturated): a value beyond it is an error naming the column and the row.
- Temperature: the column in degrees Celsius (mostly kelvin-like or implausible values are refused,
  :func:`~tak_thermo_ros.core.records.plausible.temperature_unit_problem`) becomes the sensor code
  ``N_t = round(T / temp_resolution)``, ``temp_resolution`` in degrees per code.
- A driver's log (gyroscope columns): the values as logged, in SI units; the temperature column
  is optional (a driver that logs none: no temperature topic) and may be constant (a noise run);
  magnetometer columns (``mag_columns``, in ``mag_unit``) become ``/imu/mag`` in tesla (at
  their own stamps where their cells are empty in other rows). No reference is written unless
  given, and the board may move (a unit turned by hand): ``fit`` decides what the record
  determines.
- Reference (the true specific force, m/s^2, sensor frame): the run is static, so it is one
  constant vector, written once at the first stamp. Unless given explicitly, it is estimated
  as the mean measured direction scaled to local gravity,
  ``g_local * mean(a) / |mean(a)|``: this takes the tilt from the data and attributes the
  error of the mean magnitude to the channel. A component of the mean offset perpendicular to
  gravity is indistinguishable from tilt on a single orientation and ends in the reference.
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Iterable

import numpy as np

from tak_thermo_ros.core.records.record import (
    COUNTS_MAX,
    COUNTS_MIN,
    TEMP_CODE_LIMIT,
    TEMPERATURE_RANGE,
    ChannelRecord,
    DriverRecord,
    no_orientation,
)
from tak_thermo_ros.core.records.plausible import (
    MAX_STAMP_NS,
    clock_step_words,
    refuse_clock_step,
    temperature_unit_problem,
)
from tak_thermo_ros.core.values import STANDARD_GRAVITY
from tak_thermo_ros.core.records.static_run import STATIC_TOLERANCE_DEG, StaticReference, static_reference
from tak_thermo_ros.errors import LogError

TIME_UNITS: dict[str, int] = {'s': 1_000_000_000, 'ms': 1_000_000, 'us': 1_000, 'ns': 1}
"""Nanoseconds per unit of the time column."""
ACC_UNITS: dict[str, float] = {'m/s^2': 1.0, 'g': STANDARD_GRAVITY}
"""m/s^2 per unit of the acceleration columns."""
DELIMITERS = ('\t', ',', ';')
"""Delimiters that are sniffed from the header line when none is given."""
ASCII_NUMBER = re.compile(r'[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?')
"""A number as a log writes it: ASCII decimal digits, an optional point and exponent (no ``1_000``,
no other scripts' digits, which Python's ``float`` would take)."""
CHUNK_ROWS = 65_536
"""Rows converted to arrays at a time: the text of a large log is never held as Python objects."""
GYRO_UNITS = {'rad/s': 1.0, 'deg/s': math.pi / 180.0}
"""Angular-rate units of a log and their factor to rad/s."""
MAG_UNITS = {'T': 1.0, 'uT': 1e-6, 'mT': 1e-3, 'gauss': 1e-4, 'mG': 1e-7}
"""Magnetic-field units of a log and their factor to tesla."""
FIELD_RANGE_T = (2e-6, 1e-3)
"""Median ``|B|`` magnetometer columns may give, tesla: the Earth's field is 22-67 uT; below 2 uT
or above 1 mT (beyond a magnetometer's range) the unit is wrong (gauss read as microtesla,
microtesla as gauss)."""

_DELIMITER_NAMES = {'\t': 'tab', ',': 'comma', ';': 'semicolon', ' ': 'space', '|': 'pipe'}


@dataclass(frozen=True)
class CsvImportOptions:
    """How to read a delimited log.

    :param acc_columns: names of the x, y, z acceleration columns (sensor frame).
    :param temp_column: name of the temperature column (degrees Celsius).
    :param time_column: name of the time column.
    :param time_unit: unit of the time column, one of :data:`TIME_UNITS`.
    :param acc_unit: unit of the acceleration columns, one of :data:`ACC_UNITS`.
    :param acc_resolution: m/s^2 per count of the channel code.
    :param temp_resolution: degrees Celsius per temperature-sensor code.
    :param gravity: local gravity, m/s^2 (magnitude of the estimated reference).
    :param reference: the specific force in the sensor frame, m/s^2, when known; ``None``
        estimates it from the mean measured direction.
    :param delimiter: field delimiter; ``None`` sniffs tab, comma or semicolon from the header.
    :param frame_id: frame written on the counts messages.
    :param gyro_columns: names of the x, y, z angular-rate columns; given, the log becomes a
        driver bag (``sensor_msgs/msg/Imu`` in SI units and the temperature in degrees C, no
        rounding to codes) instead of the paper's counts.
    :param gyro_unit: unit of the angular-rate columns, one of :data:`GYRO_UNITS`.
    :param gyro_file: a second file that holds the angular-rate columns with its own time
        column (the gyroscope logged apart at its own rate), or ``None``: they are in the log.
    :param gyro_time_column: that file's time column (default: ``time_column``), in ``time_unit``.
    :param mag_columns: names of the x, y, z magnetic-field columns (a driver bag only).
    :param mag_unit: unit of the magnetic-field columns, one of :data:`MAG_UNITS`.

    ``temp_column`` is optional for a driver's log (``gyro_columns`` given); the paper's counts
    need it.
    """

    acc_columns: tuple[str, str, str]
    temp_column: str | None = None
    time_column: str = 'timestamp'
    time_unit: str = 's'
    acc_unit: str = 'm/s^2'
    acc_resolution: float = 1e-3
    temp_resolution: float = 0.01
    gravity: float = STANDARD_GRAVITY
    reference: tuple[float, float, float] | None = None
    delimiter: str | None = None
    frame_id: str = 'imu'
    gyro_columns: tuple[str, str, str] | None = None
    gyro_unit: str = 'rad/s'
    gyro_file: str | None = None
    gyro_time_column: str | None = None
    mag_columns: tuple[str, str, str] | None = None
    mag_unit: str = 'T'

    def __post_init__(self) -> None:
        checks = (
            (self.mag_columns is None or len(self.mag_columns) == 3, 'mag_columns',
             f'needs three names (x y z), got {len(self.mag_columns or ())}'),
            (self.mag_columns is None or self.gyro_columns is not None, 'mag_columns',
             'a magnetometer goes into a driver bag: give the gyroscope columns too'),
            (self.mag_unit in MAG_UNITS, 'mag_unit', f'{self.mag_unit!r} is not one of {", ".join(MAG_UNITS)}'),
            (self.temp_column is not None or self.gyro_columns is not None, 'temp_column',
             "the paper's counts bag (no gyroscope columns) needs the temperature column"),
            (self.gyro_file is None or self.gyro_columns is not None, 'gyro_file',
             'needs the gyro columns (--gyro-columns X Y Z) it holds'),
            (self.gyro_columns is None or len(self.gyro_columns) == 3, 'gyro_columns',
             f'needs three names (x y z), got {len(self.gyro_columns or ())}'),
            (self.gyro_unit in GYRO_UNITS, 'gyro_unit', f'{self.gyro_unit!r} is not one of {", ".join(GYRO_UNITS)}'),
            (len(self.acc_columns) == 3, 'acc_columns', f'needs three names (x y z), got {len(self.acc_columns)}'),
            (self.time_unit in TIME_UNITS, 'time_unit',
             f'{self.time_unit!r} is not one of {", ".join(TIME_UNITS)}'),
            (self.acc_unit in ACC_UNITS, 'acc_unit', f'{self.acc_unit!r} is not one of {", ".join(ACC_UNITS)}'),
            (math.isfinite(self.acc_resolution) and self.acc_resolution > 0, 'acc_resolution',
             f'must be a positive number of m/s^2 per count, got {self.acc_resolution:g}'),
            (math.isfinite(self.temp_resolution) and self.temp_resolution > 0, 'temp_resolution',
             f'must be a positive number of degrees per code, got {self.temp_resolution:g}'),
            (math.isfinite(self.gravity) and self.gravity > 0, 'gravity',
             f'must be a positive number of m/s^2, got {self.gravity:g}'),
            (self.reference is None or (len(self.reference) == 3 and all(math.isfinite(v) for v in self.reference)
                                        and any(v != 0.0 for v in self.reference)),
             'reference', 'needs three finite numbers, not all zero (m/s^2)'),
            (self.delimiter is None or len(self.delimiter) == 1, 'delimiter',
             f'must be one character, got {self.delimiter!r}'),
        )
        for ok, key, problem in checks:
            if not ok:
                msg = f'{key}: {problem}'
                raise LogError(msg)

    @property
    def nominal_scale(self) -> float:
        """Counts per m/s^2 implied by the resolution."""
        return 1.0 / self.acc_resolution


@dataclass(frozen=True)
class ImportedLog:
    """A delimited log turned into the bag contract, with what the import found.

    :param record: the run as the bag contract holds it.
    :param rows: number of data rows.
    :param delimiter: the delimiter used.
    :param header: the column names.
    :param acceleration: ``(k, 3)`` measured acceleration, m/s^2 (before rounding to codes).
    :param temperature: ``(k,)`` temperature, degrees Celsius (before rounding to codes).
    :param reference: ``(3,)`` the constant reference, m/s^2, sensor frame.
    :param mean_direction: ``(3,)`` unit vector of the mean measured acceleration.
    :param reference_estimated: ``True`` when the reference is the mean direction scaled to
        gravity, ``False`` when it was given.
    :param max_tilt_deg: largest angle between a sample and the mean direction, degrees.
    :param driver: with gyroscope columns, the driver bag's contents (then ``record`` is its
        accelerometer channel).

    A driver's log without a temperature column has ``temperature`` empty.
    """

    record: ChannelRecord
    rows: int
    delimiter: str
    header: tuple[str, ...]
    acceleration: np.ndarray
    temperature: np.ndarray
    reference: np.ndarray
    mean_direction: np.ndarray
    reference_estimated: bool
    max_tilt_deg: float
    driver: DriverRecord | None = None

    @property
    def duration_s(self) -> float:
        """Time from the first to the last row, seconds."""
        stamps = self.record.counts_stamp_ns
        return float(stamps[-1] - stamps[0]) * 1e-9

    @property
    def delimiter_name(self) -> str:
        """The delimiter in words (``tab``, ``comma``, ...)."""
        return _DELIMITER_NAMES.get(self.delimiter, repr(self.delimiter))


def delimiter_from_option(text: str) -> str:
    r"""The delimiter character of a command-line value: ``tab``, ``\t``, ``comma``, ``,`` ..."""
    names = {'tab': '\t', '\\t': '\t', 'comma': ',', 'semicolon': ';', 'space': ' ', 'pipe': '|'}
    character = names.get(text.lower(), text)
    if len(character) != 1:
        msg = f'--delimiter: expected one character or tab/comma/semicolon, got {text!r}'
        raise LogError(msg)
    return character


def read_csv_log(path: str | Path, options: CsvImportOptions) -> ImportedLog:
    """Read and convert a delimited log file (UTF-8, a byte-order mark is skipped).

    :raises LogError: one line naming the file and the row or column that is wrong.
    """
    path = Path(path)
    gyro_path = Path(options.gyro_file) if options.gyro_file is not None else None
    current = path
    try:
        with path.open(encoding='utf-8-sig', newline='') as stream:
            if gyro_path is None:
                return parse_csv_log(stream, options, source=str(path))
            current = gyro_path
            with gyro_path.open(encoding='utf-8-sig', newline='') as gyro_stream:
                return parse_csv_log(stream, options, source=str(path), gyro_lines=gyro_stream,
                                     gyro_source=str(gyro_path))
    except FileNotFoundError:
        msg = f'{current}: no such log file'
        raise LogError(msg) from None
    except UnicodeDecodeError as err:
        msg = f'{current}: not a UTF-8 text file (byte {err.start})'
        raise LogError(msg) from None


@dataclass(frozen=True)
class _Table:
    """A delimited file's time column (ns), its wanted columns (NaN where a cell is empty) and line numbers."""

    stamp_ns: np.ndarray
    values: np.ndarray
    line_numbers: np.ndarray
    delimiter: str
    header: tuple[str, ...]


def _read_table(lines: Iterable[str], time_column: str, columns: tuple[str, ...], options: CsvImportOptions,
                source: str) -> _Table:
    """A delimited file's rows, :data:`CHUNK_ROWS` at a time: an empty cell is NaN, another non-number refused."""
    iterator = iter(lines)
    header_line, skipped = _first_non_blank(iterator)
    if header_line is None:
        msg = f'{source}: empty file (no header line)'
        raise LogError(msg)
    delimiter = options.delimiter or _sniff_delimiter(header_line, source)
    header = tuple(name.strip() for name in next(csv.reader([header_line], delimiter=delimiter)))
    wanted = (time_column, *columns)
    index = []
    for name in wanted:
        if name not in header:
            msg = (f'{source}: no column {name!r} (columns: {", ".join(header)}; '
                   f'{_DELIMITER_NAMES.get(delimiter, repr(delimiter))}-delimited)')
            raise LogError(msg)
        if header.count(name) > 1:
            positions = ', '.join(str(i + 1) for i, given in enumerate(header) if given == name)
            msg = f'{source}: column {name!r} appears {header.count(name)} times in the header (columns {positions})'
            raise LogError(msg)
        index.append(header.index(name))

    time_factor = TIME_UNITS[options.time_unit]
    stamp_parts: list[np.ndarray] = []
    value_parts: list[np.ndarray] = []
    line_parts: list[np.ndarray] = []
    stamps: list[int] = []
    values: list[float] = []
    lines_read: list[int] = []
    rows = 0

    def flush() -> None:
        stamp_parts.append(np.array(stamps, dtype=np.int64))
        value_parts.append(np.array(values, dtype=float).reshape(-1, len(wanted) - 1))
        line_parts.append(np.array(lines_read, dtype=np.int64))
        stamps.clear()
        values.clear()
        lines_read.clear()

    reader = csv.reader(iterator, delimiter=delimiter)
    value_columns = tuple(zip(index[1:], wanted[1:]))
    for fields in _rows(reader, source, skipped):
        if not fields or all(not field.strip() for field in fields):
            continue
        rows += 1
        line = reader.line_num + skipped
        if len(fields) != len(header):
            msg = f'{source}: row {rows} (line {line}): {len(fields)} fields, the header has {len(header)}'
            raise LogError(msg)
        stamps.append(_stamp_ns(fields[index[0]].strip(), time_factor, (source, rows, line), time_column))
        for i, name in value_columns:
            values.append(_number(fields[i].strip(), (source, rows, line), name))
        lines_read.append(line)
        if len(stamps) == CHUNK_ROWS:
            flush()
    if stamps:
        flush()
    if not rows:
        msg = f'{source}: no data rows after the header'
        raise LogError(msg)
    stamp_ns = np.concatenate(stamp_parts)
    stamp_parts.clear()  # the pieces freed (not del: flush() refers to the list)
    line_numbers = np.concatenate(line_parts)
    line_parts.clear()
    table = np.concatenate(value_parts)
    value_parts.clear()
    _check_increasing(stamp_ns, source, line_numbers, time_column)
    refuse_clock_step(stamp_ns, LogError, lambda row, step_ns: (
        f'{source}: row {row + 1} (line {line_numbers[row]}): time in column {time_column!r} '
        f'{clock_step_words(step_ns, "from the row before")}'))
    return _Table(stamp_ns, table, line_numbers, delimiter, header)


def _rows(reader, source: str, skipped: int):
    """The reader's rows; what the csv module refuses (a field over 131,072 characters, a NUL byte) in one line."""
    while True:
        try:
            fields = next(reader)
        except StopIteration:
            return
        except csv.Error as err:
            msg = f'{source}: line {reader.line_num + skipped}: not a delimited row ({err})'
            raise LogError(msg) from None
        yield fields


def _present(values: np.ndarray, names: tuple[str, ...], source: str, line_numbers: np.ndarray) -> np.ndarray:
    """Rows where a sensor has a sample: all its cells given; all empty is no sample, some empty is refused."""
    empty = np.isnan(values)
    none = empty.all(axis=1)
    partly = np.flatnonzero(empty.any(axis=1) & ~none)
    if partly.size:
        row = int(partly[0])
        column = names[int(np.flatnonzero(empty[row])[0])]
        msg = (f'{source}: row {row + 1} (line {line_numbers[row]}), column {column!r}: \'\' is not a finite number '
               f'(a sensor\'s cells are all given, or all empty where it has no sample)')
        raise LogError(msg)
    return ~none


def parse_csv_log(lines: Iterable[str], options: CsvImportOptions, *, source: str = '<log>',
                  gyro_lines: Iterable[str] | None = None, gyro_source: str = '<gyro log>') -> ImportedLog:
    """Convert the lines of a delimited log (header line first) into the bag contract.

    :param lines: the text, one line per item (a file object serves).
    :param options: columns, units and resolutions.
    :param source: the name used in messages.
    :param gyro_lines: the gyroscope's own file (``options.gyro_file``), its own time column.
    The rows are converted to arrays :data:`CHUNK_ROWS` at a time, so that memory stays near
    the size of the arrays (48 bytes per row), whatever the length of the log.

    Sensors that come at their own rates are imported without resampling: a row whose cells of
    a sensor (its three axes; the temperature) are all empty holds no sample of it, and the
    gyroscope may come in a file of its own. Each sensor then keeps its own stamps (a driver
    bag's Imu messages carry one sensor each where they differ, the other marked absent).

    :raises LogError: missing column, non-numeric field, a sensor's cells partly empty, a stamp
        outside the bag's time type, time not increasing, a constant column (no temperature
        sweep, a stuck axis), a value beyond the 16-bit code range, a board that moved, or an
        empty file; one line naming the row or column.
    """
    in_log = options.gyro_columns if options.gyro_columns and gyro_lines is None else ()
    temp_columns = (options.temp_column,) if options.temp_column is not None else ()
    mag_columns = options.mag_columns or ()
    columns = (*options.acc_columns, *temp_columns, *in_log, *mag_columns)
    main = _read_table(lines, options.time_column, columns, options, source)
    stamp_ns, table, line_numbers = main.stamp_ns, main.values, main.line_numbers
    accel_rows = _present(table[:, :3], options.acc_columns, source, line_numbers)
    temp_rows = (_present(table[:, 3:4], temp_columns, source, line_numbers) if temp_columns
                 else np.zeros(len(stamp_ns), dtype=bool))
    # A gyroscope at rest may read one value; so may a driver's temperature (a noise run).
    driver = options.gyro_columns is not None
    checked = 3 if driver else 3 + len(temp_columns)
    _check_not_constant(table[:, :checked], columns[:checked], source)
    acceleration = table[accel_rows, :3] * ACC_UNITS[options.acc_unit]
    temperature = table[temp_rows, 3].copy() if temp_columns else np.zeros(0)
    problem = temperature_unit_problem(temperature)
    if problem is not None:
        msg = f'{source}: column {options.temp_column!r}: {problem}'
        raise LogError(msg)
    first = 3 + len(temp_columns)
    gyro = None
    if in_log:
        gyro_rows = _present(table[:, first:first + 3], in_log, source, line_numbers)
        gyro = (stamp_ns[gyro_rows], table[gyro_rows, first:first + 3] * GYRO_UNITS[options.gyro_unit])
    field = None
    if mag_columns:
        at = first + len(in_log)
        mag_rows = _present(table[:, at:at + 3], mag_columns, source, line_numbers)
        field = (stamp_ns[mag_rows], table[mag_rows, at:at + 3] * MAG_UNITS[options.mag_unit])
    if gyro is None and gyro_lines is not None and options.gyro_columns is not None:
        own = _read_table(gyro_lines, options.gyro_time_column or options.time_column, options.gyro_columns,
                          options, gyro_source)
        rows = _present(own.values, options.gyro_columns, gyro_source, own.line_numbers)
        gyro = (own.stamp_ns[rows], own.values[rows] * GYRO_UNITS[options.gyro_unit])
    del table
    streams = _Streams(stamp_ns[accel_rows], stamp_ns[temp_rows], line_numbers[accel_rows], line_numbers[temp_rows])
    if gyro is not None:
        return _driver_log(streams, acceleration, gyro, temperature, options, source, main.delimiter, main.header,
                           rows=len(stamp_ns), field=field)
    delimiter, header = main.delimiter, main.header
    if not len(streams.accel_stamp_ns):
        msg = f'{source}: no row holds the acceleration columns'
        raise LogError(msg)
    line_numbers = streams.accel_lines
    counts = np.round(acceleration / options.acc_resolution)
    _check_code_range(counts, acceleration, options, source, line_numbers)
    temp_code = np.round(temperature / options.temp_resolution)
    _check_temp_code_range(temp_code, temperature, options, source, streams.temp_lines)
    if np.all(temp_code == temp_code[0]):
        msg = (f'{source}: column {options.temp_column!r} varies by only {np.ptp(temperature):g} C, less than '
               f'one code of {options.temp_resolution:g} C: no temperature sweep at this --temp-resolution')
        raise LogError(msg)

    static, reference = _reference(acceleration, options, source, line_numbers)
    record = ChannelRecord(
        counts_stamp_ns=streams.accel_stamp_ns, counts=counts, temp_stamp_ns=streams.temp_stamp_ns,
        temp_code=temp_code, reference_stamp_ns=stamp_ns[:1].copy(), reference=reference.reshape(1, 3),
        frame_id=options.frame_id, nominal_scale=(options.nominal_scale,) * 3)
    return ImportedLog(record=record, rows=len(stamp_ns), delimiter=delimiter, header=header,
                       acceleration=acceleration, temperature=temperature, reference=reference,
                       mean_direction=static.direction, reference_estimated=options.reference is None,
                       max_tilt_deg=static.max_tilt_deg)


def _reference(acceleration: np.ndarray, options: CsvImportOptions, source: str,
               line_numbers: np.ndarray) -> tuple[StaticReference, np.ndarray]:
    """The static run's reference (:func:`~tak_thermo_ros.core.records.static_run.static_reference`) or the given."""
    static = static_reference(acceleration, gravity=options.gravity)
    if options.reference is not None:
        return static, np.asarray(options.reference, dtype=float)
    if static.magnitude < 0.1 * options.gravity:
        msg = (f'{source}: mean acceleration |{static.magnitude:.4g}| m/s^2 is far below gravity: not a static run '
               f'(or the acceleration unit is wrong); give the reference explicitly')
        raise LogError(msg)
    worst = static.worst_row
    if static.max_tilt_deg > STATIC_TOLERANCE_DEG:
        msg = (f'{source}: row {worst + 1} (line {line_numbers[worst]}): the measured direction is '
               f'{static.max_tilt_deg:.1f} deg from the mean direction: the board moved, the log is not one static '
               f'orientation (split it, or give the reference)')
        raise LogError(msg)
    return static, static.specific_force


@dataclass(frozen=True)
class _Streams:
    """The log's stamps of the accelerometer's and the temperature's samples, and their lines."""

    accel_stamp_ns: np.ndarray
    temp_stamp_ns: np.ndarray
    accel_lines: np.ndarray
    temp_lines: np.ndarray


def _driver_log(streams: _Streams, acceleration: np.ndarray, gyro: tuple[np.ndarray, np.ndarray],
                temperature: np.ndarray, options: CsvImportOptions, source: str, delimiter: str,
                header: tuple[str, ...], *, rows: int,
                field: tuple[np.ndarray, np.ndarray] | None = None) -> ImportedLog:
    """A log with gyroscope columns as a driver bag: values as logged (SI units), temperature in C.

    Without ``--reference`` no reference topic is written and the board may move: ``fit`` takes
    a run in one orientation as static (the mean direction scaled to gravity, zero rate), as for
    any driver bag recorded without one, and decides what a moving one determines. Where the
    accelerometer's and the gyroscope's stamps differ, each keeps its own. The temperature may be
    constant or absent (``temperature`` empty: no temperature topic); the magnetic field
    (``field``: its stamps and values in tesla) is written on ``/imu/mag``.
    """
    gyro_stamp_ns, rate = gyro
    low, high = TEMPERATURE_RANGE['imu']
    outside = np.flatnonzero(~((temperature > low) & (temperature < high)))
    if outside.size:
        row = int(outside[0])
        msg = (f'{source}: line {streams.temp_lines[row]}: temperature {temperature[row]:g} C is outside '
               f'{low:g}..{high:g} C (is the column in degrees Celsius?)')
        raise LogError(msg)
    for name, stamps in (('acceleration', streams.accel_stamp_ns), ('angular-rate', gyro_stamp_ns)):
        if len(stamps) < 2:
            msg = f'{source}: {len(stamps)} rows hold the {name} columns: a run needs more'
            raise LogError(msg)
    if field is not None:
        _check_field(field[1], options, source)
    static = static_reference(acceleration, gravity=options.gravity)
    reference = np.asarray(options.reference, dtype=float) if options.reference is not None else static.specific_force
    accel_stamp_ns = streams.accel_stamp_ns
    shared = np.array_equal(accel_stamp_ns, gyro_stamp_ns)
    messages = accel_stamp_ns if shared else np.union1d(accel_stamp_ns, gyro_stamp_ns)
    count = len(messages)
    orientation, orientation_covariance = no_orientation(count)  # REP 145: a log gives no orientation
    given = options.reference is not None
    first = min(int(accel_stamp_ns[0]), int(gyro_stamp_ns[0]))
    mag = {} if field is None else dict(mag_stamp_ns=field[0], mag=field[1], mag_frame_id=options.frame_id)
    driver = DriverRecord(
        stamp_ns=messages, accel=acceleration, gyro=rate, orientation=orientation,
        orientation_covariance=orientation_covariance, temp_stamp_ns=streams.temp_stamp_ns, temperature=temperature,
        reference_stamp_ns=np.array([first], dtype=np.int64) if given else np.zeros(0, dtype=np.int64),
        reference=reference.reshape(1, 3) if given else np.zeros((0, 3)), frame_id=options.frame_id, **mag,
        **({} if shared else {'accel_stamp_ns': accel_stamp_ns, 'gyro_stamp_ns': gyro_stamp_ns}))
    return ImportedLog(record=driver.channel('accel'), rows=rows, delimiter=delimiter, header=header,
                       acceleration=acceleration, temperature=temperature, reference=reference,
                       mean_direction=static.direction, reference_estimated=not given,
                       max_tilt_deg=static.max_tilt_deg, driver=driver)


def _check_field(field: np.ndarray, options: CsvImportOptions, source: str) -> None:
    """The magnetometer columns, in tesla, give a plausible field (else the unit is wrong), in one line."""
    columns = ' '.join(options.mag_columns or ())
    if not len(field):
        msg = f'{source}: columns {columns} are empty in every row: no magnetometer sample (leave out --mag-columns)'
        raise LogError(msg)
    median = float(np.median(np.linalg.norm(field, axis=1)))
    low, high = FIELD_RANGE_T
    if not low <= median <= high:
        msg = (f'{source}: columns {columns} in {options.mag_unit} give a median |B| of {median * 1e6:.3g} uT, '
               f'outside {low * 1e6:g}..{high * 1e6:g} uT (the Earth\'s field is 22-67 uT): wrong --mag-unit?')
        raise LogError(msg)


def _first_non_blank(iterator) -> tuple[str | None, int]:
    """The first non-blank line and how many lines it took to reach it."""
    for number, line in enumerate(iterator, start=1):
        if line.strip():
            return line.rstrip('\r\n'), number
    return None, 0


def _sniff_delimiter(header_line: str, source: str) -> str:
    counts = {d: header_line.count(d) for d in DELIMITERS}
    best = max(DELIMITERS, key=lambda d: counts[d])
    if counts[best] == 0:
        msg = (f'{source}: cannot tell the delimiter from the header line (no tab, comma or semicolon); '
               f'give --delimiter')
        raise LogError(msg)
    return best


def _where(place: tuple[str, int, int]) -> str:
    source, row, line = place
    return f'{source}: row {row} (line {line})'


def _stamp_ns(text: str, factor: int, place: tuple[str, int, int], column: str) -> int:
    """Nanoseconds of one time field; ``place`` is ``(source, row, line)`` for the message."""
    if not ASCII_NUMBER.fullmatch(text):
        msg = f'{_where(place)}, column {column!r}: {text!r} is not a number (ASCII decimal digits)'
        raise LogError(msg)
    try:
        stamp = int(text) * factor
    except ValueError:
        try:
            value = Decimal(text)
        except InvalidOperation:
            value = Decimal('NaN')
        if not value.is_finite():
            msg = f'{_where(place)}, column {column!r}: {text!r} is not a number'
            raise LogError(msg) from None
        if value.adjusted() > 30:  # far beyond any stamp; converting it would take ages
            stamp = MAX_STAMP_NS + 1
        else:
            stamp = int((value * factor).to_integral_value())
    if not 0 <= stamp <= MAX_STAMP_NS:
        msg = (f'{_where(place)}, column {column!r}: {text} {"is before 1970" if stamp < 0 else "is after 2038"} '
               f'(--time-unit?)')
        raise LogError(msg)
    return stamp


def _number(text: str, place: tuple[str, int, int], column: str) -> float:
    """A cell's number; an empty cell is NaN (no sample: :func:`_present` decides), anything else must be finite."""
    if not text:
        return math.nan
    try:
        value = float(text) if ASCII_NUMBER.fullmatch(text) else math.nan
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        msg = f'{_where(place)}, column {column!r}: {text!r} is not a finite number in ASCII decimal'
        raise LogError(msg)
    return value


def _check_increasing(stamp_ns: np.ndarray, source: str, line_numbers: np.ndarray, column: str) -> None:
    steps = np.diff(stamp_ns)
    bad = np.flatnonzero(steps <= 0)
    if bad.size:
        row = int(bad[0]) + 1  # 0-based index of the later sample
        how = 'goes backwards' if steps[bad[0]] < 0 else 'repeats'
        msg = (f'{source}: row {row + 1} (line {line_numbers[row]}): time {how} in column {column!r} '
               f'({stamp_ns[row]} ns after {stamp_ns[row - 1]} ns); stamps must increase')
        raise LogError(msg)


def _check_not_constant(table: np.ndarray, names: tuple[str, ...], source: str) -> None:
    if len(table) < 2:
        msg = f'{source}: one data row only; a thermal run needs a temperature sweep'
        raise LogError(msg)
    for column, name in enumerate(names):
        given = table[~np.isnan(table[:, column]), column]
        if len(given) < 2:
            msg = f'{source}: column {name!r} holds {len(given)} value(s): a run needs more'
            raise LogError(msg)
        if np.all(given == given[0]):
            what = ('no temperature sweep to calibrate from' if column == 3
                    else 'a stuck or disconnected axis')
            rows = f'all {len(given)} rows' if len(given) == len(table) else f'its {len(given)} rows'
            msg = f'{source}: column {name!r} is constant ({given[0]:g}) over {rows}: {what}'
            raise LogError(msg)


def _check_code_range(counts: np.ndarray, acceleration: np.ndarray, options: CsvImportOptions,
                      source: str, line_numbers: np.ndarray) -> None:
    outside = (counts <= COUNTS_MIN) | (counts >= COUNTS_MAX)
    if not outside.any():
        return
    row, axis = (int(v) for v in np.argwhere(outside)[0])
    needed = float(np.max(np.abs(acceleration))) / (COUNTS_MAX - 1.0)
    msg = (f'{source}: row {row + 1} (line {line_numbers[row]}), column {options.acc_columns[axis]!r}: '
           f'{acceleration[row, axis]:g} m/s^2 is {counts[row, axis]:.0f} counts at that resolution: it would '
           f'saturate; give --acc-resolution {needed:.3g} or more')
    raise LogError(msg)


def _check_temp_code_range(temp_code: np.ndarray, temperature: np.ndarray, options: CsvImportOptions,
                           source: str, line_numbers: np.ndarray) -> None:
    """Every temperature code must be a plausible sensor code (``|N_t| < TEMP_CODE_LIMIT``)."""
    outside = np.abs(temp_code) >= TEMP_CODE_LIMIT
    if not outside.any():
        return
    row = int(np.flatnonzero(outside)[0])
    msg = (f'{source}: row {row + 1} (line {line_numbers[row]}), column {options.temp_column!r}: '
           f'{temperature[row]:g} C is a temperature code of {temp_code[row]:.3g} at a resolution of '
           f'{options.temp_resolution:g} C per code, beyond any sensor code (|code| < {TEMP_CODE_LIMIT:g}); '
           f'use a larger --temp-resolution')
    raise LogError(msg)
