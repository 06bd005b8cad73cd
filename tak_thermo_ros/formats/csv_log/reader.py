"""A delimited log into the bag contract: :func:`read_csv_log` (a file), :func:`parse_csv_log` (its lines).

The table's columns become a static run's counts record (codes, the reference) or a driver's
record (values as logged, in SI units), each checked on the way (units, ranges, a board that
moved); the rules are in the package's docstring (:mod:`tak_thermo_ros.formats.csv_log`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from tak_thermo_ros.core.records.record import ChannelRecord, DriverRecord, no_orientation
from tak_thermo_ros.core.records.drops import COUNTS_MAX, COUNTS_MIN, TEMPERATURE_RANGE, TEMP_CODE_LIMIT
from tak_thermo_ros.core.records.plausible import temperature_unit_problem
from tak_thermo_ros.core.records.static_run import STATIC_TOLERANCE_DEG, StaticReference, static_reference
from tak_thermo_ros.errors import LogError
from tak_thermo_ros.formats.csv_log.options import ACC_UNITS, GYRO_UNITS, MAG_UNITS, CsvImportOptions, ImportedLog
from tak_thermo_ros.formats.csv_log.table import _present, _read_table

FIELD_RANGE_T = (2e-6, 1e-3)
"""Median ``|B|`` magnetometer columns may give, tesla: the Earth's field is 22-67 uT; below 2 uT
or above 1 mT (beyond a magnetometer's range) the unit is wrong (gauss read as microtesla,
microtesla as gauss)."""


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
