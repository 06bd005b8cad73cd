"""The carrier method: the Earth's field from a magnetometer on a ferromagnetic carrier (Poisson's model).

In the carrier frame the field at the sensor is Poisson's model of a carrier's magnetism::

    B_carrier = (I + D) C^T b + p

``b`` is the Earth's field in the navigation frame (north, east, down), ``C`` the carrier's
attitude (carrier to navigation: heading about down, then pitch, then roll), ``D`` the 3x3
Poisson coefficients (the field the Earth's field induces in the soft iron; row = component
of the carrier's field, column = component of the Earth's field in the carrier frame) and
``p`` the permanent (hard-iron) field. The fluxgate sensor can be turned on its mount by a
measured angle ``A`` about a mount axis ``k``; it reads the field along its own axes plus its
own offset ``o`` (fixed in the sensor) and noise::

    m = R_k(A)^T B_carrier + o + n

Turning the sensor separates ``o`` from ``B_carrier`` (about z: the x and y offsets; about x:
the y and z offsets); tilting the carrier changes ``C^T b`` and separates ``D`` from ``p``.

**What cannot be identified** (see docs/magnetometer.md):

- An isotropic ``D = d I`` is the same as an Earth field ``(1 + d)`` times stronger, for any
  attitudes: the scale of ``b`` against the trace of ``D`` needs an outside datum.
- Tilting about one carrier axis (the seed's stage 3, heading fixed) leaves the Earth field's
  component along that axis in the carrier frame inseparable from the hard iron along it, and
  the column of ``D`` along that axis inseparable from ``p``; a rotation of ``b`` about the tilt
  axis trades against a skew part of the other two columns; the rest of those two columns shows
  only through the curvature ``1 - cos(tilt)`` (1.5 % of the field at 10 degrees).

So the parametrisation is explicit: :class:`CarrierModel` names the free Poisson coefficients
(the others held at zero) and a gauge on ``b`` (a known declination and/or total intensity,
each with its standard uncertainty, propagated). The fit refuses, in one line naming the
parameters that move together, a record and model that cannot determine them.

The estimate (weighted least squares with errors-in-variables weights) is
:mod:`tak_thermo_ros.core.magnetometer.carrier_fit`'s. Pure numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from tak_thermo_ros.errors import CarrierError

AXIS_NAMES = ('x', 'y', 'z')
POISSON_NAMES = tuple(row + col for row in AXIS_NAMES for col in AXIS_NAMES)
"""The nine Poisson coefficients ``D[row, col]`` by name: ``'xz'`` is D[x, z]."""
NAV_NAMES = ('north', 'east', 'down')

FIELD_RANGE_UT = (1.0, 2000.0)
"""Plausible median field magnitude of a record, microtesla (Earth 22-67 uT plus a carrier's)."""


def axis_rotation(axis: int, angle: np.ndarray | float) -> np.ndarray:
    """Rotation matrices (active) by ``angle`` (rad) about coordinate axis ``axis`` (0, 1, 2): shape (..., 3, 3)."""
    angle = np.asarray(angle, dtype=float)
    c, s = np.cos(angle), np.sin(angle)
    one, zero = np.ones_like(angle), np.zeros_like(angle)
    if axis == 0:
        rows = ((one, zero, zero), (zero, c, -s), (zero, s, c))
    elif axis == 1:
        rows = ((c, zero, s), (zero, one, zero), (-s, zero, c))
    else:
        rows = ((c, -s, zero), (s, c, zero), (zero, zero, one))
    return np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def attitude_matrix(roll: np.ndarray, pitch: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """Carrier-to-navigation (NED) matrices ``C = Rz(heading) Ry(pitch) Rx(roll)``, angles in rad."""
    return axis_rotation(2, heading) @ axis_rotation(1, pitch) @ axis_rotation(0, roll)


@dataclass(frozen=True)
class InstrumentErrors:
    """The instruments' errors: the seed's +/- values and what +/- means.

    ``distribution='uniform'`` reads +/-x as bounds (standard deviation x / sqrt 3),
    ``'normal'`` as one standard deviation. The attitude error applies to roll, pitch and heading,
    independently per reading; the turn-angle and field errors likewise per reading.
    """

    field_uT: float = 0.001
    turn_rad: float = 3e-3
    attitude_rad: float = math.radians(0.1)
    distribution: str = 'uniform'

    def __post_init__(self) -> None:
        if self.distribution not in ('uniform', 'normal'):
            msg = f"instrument errors: distribution must be 'uniform' or 'normal', got {self.distribution!r}"
            raise CarrierError(msg)
        for name in ('field_uT', 'turn_rad', 'attitude_rad'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                msg = f'instrument errors: {name} must be finite and >= 0, got {value}'
                raise CarrierError(msg)

    def sigma(self, bound: float) -> float:
        """The standard deviation of an error given as +/- ``bound``."""
        return bound / math.sqrt(3.0) if self.distribution == 'uniform' else bound

    def draw(self, rng: np.random.Generator, bound: float, shape: tuple[int, ...]) -> np.ndarray:
        """Random errors of +/- ``bound``."""
        if self.distribution == 'uniform':
            return rng.uniform(-bound, bound, shape)
        return rng.normal(0.0, bound, shape)


@dataclass(frozen=True)
class CarrierRecord:
    """A record of the three stages: one row per reading.

    ``turn_axis`` is the mount axis (0 x, 1 y, 2 z) the sensor is turned about, ``turn_angle_rad``
    the measured turn; ``roll_rad``, ``pitch_rad``, ``heading_rad`` the measured attitude;
    ``field_uT`` (n, 3) the sensor's readings along its own axes, microtesla.
    """

    time_s: np.ndarray
    stage: np.ndarray
    turn_axis: np.ndarray
    turn_angle_rad: np.ndarray
    roll_rad: np.ndarray
    pitch_rad: np.ndarray
    heading_rad: np.ndarray
    field_uT: np.ndarray

    def __len__(self) -> int:
        return len(self.time_s)

    def subset(self, keep: np.ndarray) -> CarrierRecord:
        """The readings selected by ``keep`` (a boolean mask or indices)."""
        return CarrierRecord(*(np.asarray(getattr(self, name))[keep] for name in self.__dataclass_fields__))


def check_record(record: CarrierRecord) -> None:
    """Refuse, in one line, a record the carrier method cannot use.

    :raises CarrierError: unequal lengths, a non-finite value, a turn axis other than 0, 1, 2,
        field readings of an implausible size (gauss, tesla or nanotesla in a microtesla column),
        no turn of the sensor on its mount, too few readings.
    """
    n = len(record.time_s)
    columns = {name: np.asarray(getattr(record, name)) for name in record.__dataclass_fields__}
    for name, values in columns.items():
        expected = (n, 3) if name == 'field_uT' else (n,)
        if values.shape != expected:
            msg = f'carrier record: {name} has shape {values.shape}, expected {expected}'
            raise CarrierError(msg)
        if not np.all(np.isfinite(values.astype(float))):
            row = int(np.nonzero(~np.isfinite(values.astype(float)).reshape(n, -1).all(axis=1))[0][0])
            msg = f'carrier record: {name} is not finite in reading {row} (counted from 0)'
            raise CarrierError(msg)
    if n < 8:
        msg = f'carrier record: {n} readings; the method needs at least 8 (turns and tilts)'
        raise CarrierError(msg)
    if not np.all(np.isin(columns['turn_axis'], (0, 1, 2))):
        msg = 'carrier record: turn_axis must be x, y or z (0, 1, 2)'
        raise CarrierError(msg)
    magnitude = float(np.median(np.linalg.norm(columns['field_uT'], axis=1)))
    low, high = FIELD_RANGE_UT
    if not low <= magnitude <= high:
        guess = ('gauss' if 1e-3 <= magnitude < low else 'tesla' if magnitude < 1e-3 else 'nanotesla')
        msg = (f'carrier record: the median field magnitude is {magnitude:.4g} uT, outside {low:g}..{high:g} uT '
               f'(numbers of that size look like {guess}; the field columns must be microtesla, or tesla '
               f'with the _T column names)')
        raise CarrierError(msg)
    angles = np.unwrap(columns['turn_angle_rad'])
    if float(np.ptp(angles)) < math.radians(1.0):
        msg = ("carrier record: the sensor is never turned on its mount (turn angle constant): its own offset "
               "cannot be told from the carrier's field")
        raise CarrierError(msg)


@dataclass(frozen=True)
class Gauge:
    """Outside knowledge of the Earth's field that fixes what the record cannot: each value optional.

    ``declination_deg``: the horizontal field's direction east of north (a chart or model);
    ``magnitude_uT``: the total intensity (a geomagnetic model, or a scalar magnetometer away
    from the carrier). Their standard uncertainties are propagated into every estimate.
    """

    declination_deg: float | None = None
    declination_sigma_deg: float = 0.0
    magnitude_uT: float | None = None
    magnitude_sigma_uT: float = 0.0

    def given(self) -> dict[str, tuple[float, float]]:
        """The given values in the fit's units (rad, uT) with their standard uncertainties."""
        values = {}
        if self.declination_deg is not None:
            values['declination'] = (math.radians(self.declination_deg), math.radians(self.declination_sigma_deg))
        if self.magnitude_uT is not None:
            values['magnitude'] = (float(self.magnitude_uT), float(self.magnitude_sigma_uT))
        return values

    def describe(self) -> str:
        """The gauge in words."""
        parts = []
        if self.declination_deg is not None:
            parts.append(f'declination {self.declination_deg:g} +- {self.declination_sigma_deg:g} deg')
        if self.magnitude_uT is not None:
            parts.append(f'|B_earth| {self.magnitude_uT:g} +- {self.magnitude_sigma_uT:g} uT')
        return ', '.join(parts) if parts else 'none (all three Earth-field components free)'


@dataclass(frozen=True)
class CarrierModel:
    """The parametrisation: which Poisson coefficients are free (the others held at zero) and the gauge.

    The default is the seed's: one Poisson coefficient, ``D[z, z]`` (the vertical soft iron,
    Krylov's ``k``, which tilting about a horizontal axis reveals), and a known declination.
    """

    poisson: tuple[str, ...] = ('zz',)
    gauge: Gauge = field(default_factory=lambda: Gauge(declination_deg=7.0))

    def __post_init__(self) -> None:
        unknown = [name for name in self.poisson if name not in POISSON_NAMES]
        if unknown or len(set(self.poisson)) != len(self.poisson):
            msg = (f'carrier model: Poisson coefficients must be distinct names of {", ".join(POISSON_NAMES)}, '
                   f'got {self.poisson}')
            raise CarrierError(msg)

    def earth_names(self) -> tuple[str, ...]:
        """The names of the Earth-field parameters this gauge leaves free."""
        given = self.gauge.given()
        if 'declination' in given and 'magnitude' in given:
            return ('inclination',)
        if 'declination' in given:
            return ('horizontal', 'down')
        if 'magnitude' in given:
            return ('inclination', 'declination')
        return NAV_NAMES

    def parameter_names(self) -> tuple[str, ...]:
        """Every fitted parameter's name, in the order of the parameter vector."""
        return (tuple(f'b_{name}' for name in self.earth_names()) + tuple(f'D_{name}' for name in self.poisson)
                + tuple(f'p_{axis}' for axis in AXIS_NAMES) + tuple(f'o_{axis}' for axis in AXIS_NAMES))


def earth_from_parameters(model: CarrierModel, values: np.ndarray, given: dict[str, float]) -> np.ndarray:
    """The Earth field's (north, east, down) components from the Earth parameters and the gauge's values."""
    names = model.earth_names()
    if names == NAV_NAMES:
        return np.asarray(values, dtype=float)
    if names == ('horizontal', 'down'):
        declination = given['declination']
        return np.array([values[0] * math.cos(declination), values[0] * math.sin(declination), values[1]])
    if names == ('inclination',):
        inclination, declination = values[0], given['declination']
    else:
        inclination, declination = values[0], values[1]
    magnitude = given['magnitude']
    return magnitude * np.array([math.cos(inclination) * math.cos(declination),
                                 math.cos(inclination) * math.sin(declination), math.sin(inclination)])


def earth_parameters(model: CarrierModel, north_east_down: np.ndarray) -> np.ndarray:
    """The Earth parameters of a field (north, east, down) under ``model``'s gauge.

    The inverse, in the gauge's plane.
    """
    n, e, d = (float(v) for v in north_east_down)
    names = model.earth_names()
    if names == NAV_NAMES:
        return np.array([n, e, d])
    given = {key: value for key, (value, _) in model.gauge.given().items()}
    if names == ('horizontal', 'down'):
        declination = given['declination']
        return np.array([n * math.cos(declination) + e * math.sin(declination), d])
    inclination = math.atan2(d, math.hypot(n, e))
    if names == ('inclination',):
        return np.array([inclination])
    return np.array([inclination, math.atan2(e, n)])


@dataclass(frozen=True)
class CarrierTruth:
    """The quantities the method estimates (a simulator's truth, or an estimate's values)."""

    earth_uT: np.ndarray
    poisson: np.ndarray
    hard_iron_uT: np.ndarray
    sensor_offset_uT: np.ndarray


def predict(truth: CarrierTruth, record: CarrierRecord) -> np.ndarray:
    """The sensor's readings (n, 3) of Poisson's model for the record's turns and attitudes (no noise)."""
    return _predict(truth.earth_uT, np.eye(3) + truth.poisson, truth.hard_iron_uT, truth.sensor_offset_uT,
                    record.turn_axis, record.turn_angle_rad, record.roll_rad, record.pitch_rad, record.heading_rad)


def _turn_matrices(turn_axis: np.ndarray, turn_angle: np.ndarray) -> np.ndarray:
    turn = np.empty((len(turn_axis), 3, 3))
    for axis in (0, 1, 2):
        rows = turn_axis == axis
        if np.any(rows):
            turn[rows] = axis_rotation(axis, turn_angle[rows])
    return turn


def _predict_with(earth: np.ndarray, induced: np.ndarray, hard_iron: np.ndarray, offset: np.ndarray,
                  attitude: np.ndarray, turn: np.ndarray) -> np.ndarray:
    """``R^T ((I + D) C^T b + p) + o`` for precomputed attitude (C) and turn (R) matrices."""
    earth_carrier = np.einsum('nji,j->ni', attitude, earth)
    carrier_field = earth_carrier @ induced.T + hard_iron
    return np.einsum('nji,nj->ni', turn, carrier_field) + offset


def _predict(earth: np.ndarray, induced: np.ndarray, hard_iron: np.ndarray, offset: np.ndarray,
             turn_axis: np.ndarray, turn_angle: np.ndarray, roll: np.ndarray, pitch: np.ndarray,
             heading: np.ndarray) -> np.ndarray:
    return _predict_with(earth, induced, hard_iron, offset, attitude_matrix(roll, pitch, heading),
                         _turn_matrices(turn_axis, turn_angle))
