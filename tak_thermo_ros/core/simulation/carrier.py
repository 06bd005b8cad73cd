"""The seed's three stages on a ferromagnetic carrier, simulated; and the record's CSV format.

The stages (the seed gives the steps and ranges; the order and the turn axes are this
package's reading of it, docs/magnetometer.md):

1. the carrier at its start attitude, the sensor turned about its mount's z axis from 0 to
   360 degrees in ``turn_step_deg`` (60) steps: separates the sensor's x and y offsets;
2. the sensor turned about its mount's x axis from 0 to 360 degrees in ``flip_step_deg``
   (180) steps: separates its z offset;
3. the carrier tilted about ``tilt_axis`` (pitch) from ``-tilt_range_deg`` to
   ``+tilt_range_deg`` (10) in ``tilt_step_deg`` (0.2) steps, one reading per step, while the
   sensor keeps turning about z as in stage 1, ``speed_ratio`` (100) times faster than the
   carrier on average: it dwells at each ``turn_step_deg`` position for as many carrier steps
   as that takes (60 / (100 x 0.2) = 3 readings).

Every reading carries the instrument errors of :class:`InstrumentErrors` (field, turn angle,
attitude), drawn per reading. One reading per second.

**The CSV record** (what ``carrier-simulate`` writes and ``carrier-fit`` reads): a header line,
then one row per reading, comma-separated::

    time_s,stage,turn_axis,turn_angle_deg,roll_deg,pitch_deg,heading_deg,field_x_uT,field_y_uT,field_z_uT

``turn_axis`` is ``x``, ``y`` or ``z`` (the mount axis the sensor is turned about); angles in
degrees; the field along the sensor's own axes in microtesla, or in tesla when the columns are
named ``field_x_T``, ``field_y_T``, ``field_z_T``. Extra columns are ignored; lines starting
with ``#`` are comments. The parser refuses, in one line naming the line, a missing column, a
value that is not a finite number, and (through :func:`check_record`) gauss- or
nanotesla-sized fields and a record with no turn of the sensor.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from tak_thermo_ros.core.magnetometer.carrier import (
    AXIS_NAMES,
    CarrierRecord,
    CarrierTruth,
    InstrumentErrors,
    check_record,
    predict,
)
from tak_thermo_ros.errors import CarrierError

TILT_AXES = {'roll': 0, 'pitch': 1}
CSV_COLUMNS = ('time_s', 'stage', 'turn_axis', 'turn_angle_deg', 'roll_deg', 'pitch_deg', 'heading_deg',
               'field_x_uT', 'field_y_uT', 'field_z_uT')
TESLA_COLUMNS = ('field_x_T', 'field_y_T', 'field_z_T')


def earth_field(magnitude_uT: float, inclination_deg: float, declination_deg: float) -> np.ndarray:
    """The Earth field's (north, east, down) components, microtesla."""
    inc, dec = math.radians(inclination_deg), math.radians(declination_deg)
    return magnitude_uT * np.array([math.cos(inc) * math.cos(dec), math.cos(inc) * math.sin(dec), math.sin(inc)])


@dataclass(frozen=True)
class CarrierScenario:
    """Every number of a simulated carrier run (the seed's stages and instrument errors by default).

    The true values are this package's choice (the seed gives none): a mid-latitude Earth field
    of 50 uT, inclination 65 deg, declination 7 deg; one Poisson coefficient D[z, z] = 0.1; a hard
    iron of (2.0, -1.5, 3.0) uT; a sensor offset of (0.3, -0.2, 0.5) uT; heading 30 deg.
    ``poisson`` is the full 3x3 truth (row-major), so a run can also hide coefficients a model
    leaves out.
    """

    magnitude_uT: float = 50.0
    inclination_deg: float = 65.0
    declination_deg: float = 7.0
    poisson: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.1)
    hard_iron_uT: tuple[float, float, float] = (2.0, -1.5, 3.0)
    sensor_offset_uT: tuple[float, float, float] = (0.3, -0.2, 0.5)
    heading_deg: float = 30.0
    tilt_axis: str = 'pitch'
    tilt_range_deg: float = 10.0
    tilt_step_deg: float = 0.2
    turn_step_deg: float = 60.0
    flip_step_deg: float = 180.0
    speed_ratio: float = 100.0
    second_tilt_axis: str | None = None
    errors: InstrumentErrors = field(default_factory=InstrumentErrors)
    seed: int = 0

    def __post_init__(self) -> None:
        if self.tilt_axis not in TILT_AXES or (self.second_tilt_axis not in (None, *TILT_AXES)):
            msg = (f'carrier scenario: tilt axes must be roll or pitch, '
                   f'got {self.tilt_axis!r}, {self.second_tilt_axis!r}')
            raise CarrierError(msg)
        for name in ('tilt_range_deg', 'tilt_step_deg', 'turn_step_deg', 'flip_step_deg', 'speed_ratio'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                msg = f'carrier scenario: {name} must be a positive number, got {value}'
                raise CarrierError(msg)
        if len(self.poisson) != 9:
            msg = f'carrier scenario: poisson needs 9 coefficients (row-major), got {len(self.poisson)}'
            raise CarrierError(msg)

    def truth(self) -> CarrierTruth:
        """The true Earth field, Poisson coefficients, hard iron and sensor offset."""
        return CarrierTruth(earth_field(self.magnitude_uT, self.inclination_deg, self.declination_deg),
                            np.asarray(self.poisson, dtype=float).reshape(3, 3), np.asarray(self.hard_iron_uT, float),
                            np.asarray(self.sensor_offset_uT, float))


def _turns(step_deg: float) -> np.ndarray:
    """0 to 360 degrees in steps of ``step_deg`` (both ends), radians."""
    count = int(math.floor(360.0 / step_deg + 1e-9))
    return np.radians(np.arange(count + 1) * step_deg)


def stage_design(scenario: CarrierScenario) -> CarrierRecord:
    """The stages' true turns and attitudes, with the field left zero (no errors)."""
    turn1 = _turns(scenario.turn_step_deg)
    turn2 = _turns(scenario.flip_step_deg)
    count = int(round(2.0 * scenario.tilt_range_deg / scenario.tilt_step_deg)) + 1
    tilts = np.radians(np.linspace(-scenario.tilt_range_deg, scenario.tilt_range_deg, count))
    # the sensor turns speed_ratio times faster than the carrier on average, in turn_step_deg steps
    sensor_travel = scenario.speed_ratio * (np.degrees(tilts) - np.degrees(tilts[0]))
    turn3 = np.radians(np.floor(sensor_travel / scenario.turn_step_deg + 1e-9) * scenario.turn_step_deg % 360.0)
    axes = [scenario.tilt_axis] + ([scenario.second_tilt_axis] if scenario.second_tilt_axis else [])
    stage = [np.full(turn1.size, 1), np.full(turn2.size, 2)]
    turn_axis = [np.full(turn1.size, 2), np.full(turn2.size, 0)]
    turn_angle = [turn1, turn2]
    roll = [np.zeros(turn1.size + turn2.size)]
    pitch = [np.zeros(turn1.size + turn2.size)]
    for axis in axes:
        stage.append(np.full(tilts.size, 3))
        turn_axis.append(np.full(tilts.size, 2))
        turn_angle.append(turn3)
        roll.append(tilts if axis == 'roll' else np.zeros(tilts.size))
        pitch.append(tilts if axis == 'pitch' else np.zeros(tilts.size))
    n = sum(part.size for part in stage)
    return CarrierRecord(np.arange(n, dtype=float), np.concatenate(stage), np.concatenate(turn_axis),
                         np.concatenate(turn_angle), np.concatenate(roll), np.concatenate(pitch),
                         np.full(n, math.radians(scenario.heading_deg)), np.zeros((n, 3)))


def simulate_carrier(scenario: CarrierScenario | None = None) -> tuple[CarrierRecord, CarrierTruth]:
    """A seeded run of the stages: the record (measured angles, noisy field) and the truth."""
    scenario = scenario or CarrierScenario()
    rng = np.random.default_rng(scenario.seed)
    design = stage_design(scenario)
    truth = scenario.truth()
    true_field = predict(truth, design)
    e = scenario.errors
    n = len(design)
    measured = replace(
        design,
        field_uT=true_field + e.draw(rng, e.field_uT, (n, 3)),
        turn_angle_rad=design.turn_angle_rad + e.draw(rng, e.turn_rad, (n,)),
        roll_rad=design.roll_rad + e.draw(rng, e.attitude_rad, (n,)),
        pitch_rad=design.pitch_rad + e.draw(rng, e.attitude_rad, (n,)),
        heading_rad=design.heading_rad + e.draw(rng, e.attitude_rad, (n,)))
    return measured, truth


def record_csv(record: CarrierRecord) -> str:
    """The record as CSV text (microtesla, degrees)."""
    out = io.StringIO()
    out.write(','.join(CSV_COLUMNS) + '\n')
    for i in range(len(record)):
        row = [f'{record.time_s[i]:.6f}', str(int(record.stage[i])), AXIS_NAMES[int(record.turn_axis[i])],
               *(f'{math.degrees(float(v)):.9f}' for v in (record.turn_angle_rad[i], record.roll_rad[i],
                                                           record.pitch_rad[i], record.heading_rad[i])),
               *(f'{float(v):.9f}' for v in record.field_uT[i])]
        out.write(','.join(row) + '\n')
    return out.getvalue()


def _number(text: str, column: str, line: int, where: str) -> float:
    try:
        value = float(text)
    except ValueError:
        msg = f'{where}: line {line}: {column} is not a number: {text!r}'
        raise CarrierError(msg) from None
    if not math.isfinite(value):
        msg = f'{where}: line {line}: {column} is not finite: {text!r}'
        raise CarrierError(msg)
    return value


def parse_record_csv(text: str, where: str = 'record') -> CarrierRecord:
    """A :class:`CarrierRecord` from CSV text (module docstring); every value finite, checked.

    :raises CarrierError: one line naming ``where`` and the line.
    """
    lines = [(number, line) for number, line in enumerate(text.splitlines(), start=1)
             if line.strip() and not line.lstrip().startswith('#')]
    if not lines:
        msg = f'{where}: empty (no header line)'
        raise CarrierError(msg)
    header_line, header_text = lines[0]
    header = [name.strip() for name in next(csv.reader([header_text]))]
    tesla = all(name in header for name in TESLA_COLUMNS)
    field_columns = TESLA_COLUMNS if tesla else CSV_COLUMNS[7:]
    needed = CSV_COLUMNS[:7] + field_columns
    missing = [name for name in needed if name not in header]
    if missing:
        msg = (f'{where}: line {header_line}: missing column(s) {", ".join(missing)} '
               f'(expected {",".join(CSV_COLUMNS)}; or field_x_T,field_y_T,field_z_T in tesla)')
        raise CarrierError(msg)
    index = {name: header.index(name) for name in needed}
    rows: dict[str, list[float]] = {name: [] for name in needed}
    for number, line in lines[1:]:
        cells = [cell.strip() for cell in next(csv.reader([line]))]
        if len(cells) < len(header):
            msg = f'{where}: line {number}: {len(cells)} fields, the header has {len(header)}'
            raise CarrierError(msg)
        for name in needed:
            cell = cells[index[name]]
            if name == 'turn_axis':
                if cell.lower() not in AXIS_NAMES:
                    msg = f'{where}: line {number}: turn_axis must be x, y or z, got {cell!r}'
                    raise CarrierError(msg)
                rows[name].append(float(AXIS_NAMES.index(cell.lower())))
            else:
                rows[name].append(_number(cell, name, number, where))
    if not rows['time_s']:
        msg = f'{where}: no readings after the header'
        raise CarrierError(msg)
    scale = 1e6 if tesla else 1.0
    field_uT = np.column_stack([np.asarray(rows[name]) * scale for name in field_columns])
    record = CarrierRecord(np.asarray(rows['time_s']), np.asarray(rows['stage']).astype(int),
                           np.asarray(rows['turn_axis']).astype(int), np.radians(rows['turn_angle_deg']),
                           np.radians(rows['roll_deg']), np.radians(rows['pitch_deg']),
                           np.radians(rows['heading_deg']), field_uT)
    try:
        check_record(record)
    except CarrierError as err:
        msg = f'{where}: {str(err).removeprefix("carrier record: ")}'
        raise CarrierError(msg) from None
    return record


def read_record_csv(path: str | Path) -> CarrierRecord:
    """Read a CSV record file (:func:`parse_record_csv`)."""
    try:
        text = Path(path).read_text(encoding='utf-8')
    except UnicodeDecodeError:
        msg = f'{path}: not a UTF-8 text file'
        raise CarrierError(msg) from None
    return parse_record_csv(text, str(path))
