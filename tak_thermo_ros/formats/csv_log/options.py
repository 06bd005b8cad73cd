"""How to read a delimited log and what the import gives.

:class:`CsvImportOptions`, with the units it knows, and :class:`ImportedLog`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tak_thermo_ros.core.records.record import ChannelRecord, DriverRecord
from tak_thermo_ros.core.values import STANDARD_GRAVITY
from tak_thermo_ros.errors import LogError

TIME_UNITS: dict[str, int] = {'s': 1_000_000_000, 'ms': 1_000_000, 'us': 1_000, 'ns': 1}
"""Nanoseconds per unit of the time column."""
ACC_UNITS: dict[str, float] = {'m/s^2': 1.0, 'g': STANDARD_GRAVITY}
"""m/s^2 per unit of the acceleration columns."""
GYRO_UNITS = {'rad/s': 1.0, 'deg/s': math.pi / 180.0}
"""Angular-rate units of a log and their factor to rad/s."""
MAG_UNITS = {'T': 1.0, 'uT': 1e-6, 'mT': 1e-3, 'gauss': 1e-4, 'mG': 1e-7}
"""Magnetic-field units of a log and their factor to tesla."""
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
