"""A delimited file's text into columns: the header and its delimiter, the time column as int64 nanoseconds, numbers.

Rows are converted :data:`CHUNK_ROWS` at a time; every refusal is one line naming the file, the
row (and its line) and the column.
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation
from typing import Iterable

import numpy as np

from tak_thermo_ros.core.records.plausible import MAX_STAMP_NS, clock_step_words, refuse_clock_step
from tak_thermo_ros.errors import LogError
from tak_thermo_ros.formats.csv_log.options import _DELIMITER_NAMES, TIME_UNITS, CsvImportOptions

DELIMITERS = ('\t', ',', ';')
"""Delimiters that are sniffed from the header line when none is given."""
ASCII_NUMBER = re.compile(r'[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?')
"""A number as a log writes it: ASCII decimal digits, an optional point and exponent (no ``1_000``,
no other scripts' digits, which Python's ``float`` would take)."""
CHUNK_ROWS = 65_536
"""Rows converted to arrays at a time: the text of a large log is never held as Python objects."""


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
