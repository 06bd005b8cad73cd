"""The paper's channel model and its calibration values.

Per axis, with ``n = N_t - N_t,ref`` (temperature-sensor code counted from normal
conditions) and ``f`` the specific force along the axis in m/s^2::

    N = K0 * F_c(n) * f + dNs0 + D * F_s(n)
    F_c(n) = 1 + a1 n + ... + ap n^p
    F_s(n) = b1 n + ... + bq n^q

``K0`` (``scale``) is counts per m/s^2 per conversion cycle at normal conditions, ``dNs0``
(``offset``) the output-referred zero offset at normal conditions, ``D`` (``offset_span``) the
largest change of the offset over the calibrated range, ``F_s`` normalised so that
``max |F_s| = 1`` over that range.

Polynomials are stored lowest order first, without their constant term, and are always
evaluated with Horner's scheme in the same operation order (see :func:`horner_no_constant`),
so that the vectorised and the per-sample correction paths give the same float64 results.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.effects.base import Effect
from tak_thermo_ros.core.link.uncertainty import LinkUncertainty
from tak_thermo_ros.core.noise.model import NoiseModel
from tak_thermo_ros.core.records.provenance import RecordPrint
from tak_thermo_ros.errors import CalibrationError

AXES: tuple[str, str, str] = ('x', 'y', 'z')
CALIBRATION_VERSION = 1
UNIT_CALIBRATION_VERSION = 2
SENSORS: tuple[str, str] = ('accel', 'gyro')
"""The two three-axis sensors of an IMU: accelerometer and gyroscope."""
MAG_SENSOR = 'mag'
"""The optional third sensor of a driver unit: the magnetometer (its own topic, tesla)."""
IDENTITY_3X3: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
THERMAL_FITTED = 'fitted'
"""A link with its temperature terms (today's files: the correction reads the temperature)."""
THERMAL_HELD = 'held'
"""A link taken at one temperature (or too narrow a span): no temperature terms, the record's
temperatures kept as ``temp_code_ref/min/max`` for the reader; corrected alike at every temperature."""
THERMAL_NONE = 'none'
"""A link from a record without any temperature: no temperature terms, no temperatures (0 in the
model, absent from the file); corrected alike at every temperature."""
THERMAL_STATES = (THERMAL_FITTED, THERMAL_HELD, THERMAL_NONE)


class InputKind(str, enum.Enum):
    """What the correction link takes in place of the paper's codes."""

    COUNTS = 'counts'
    """The paper: channel codes N (whole numbers) and a temperature-sensor code N_t."""
    IMU = 'imu'
    """A ROS 2 driver: ``sensor_msgs/msg/Imu`` values (m/s^2, rad/s, already scaled by the
    factory) in place of N, and the temperature in degrees Celsius in place of N_t."""


def horner_no_constant(coeffs: Sequence[float], n):
    """Evaluate ``c1 n + c2 n^2 + ... + ck n^k`` by Horner's scheme.

    Works on a Python float or a numpy array with the same operation order, hence with
    bit-identical results.

    :param coeffs: ``(c1, ..., ck)``, lowest order first.
    :param n: scalar or array.
    """
    value = 0.0 * n
    for coefficient in reversed(coeffs):
        value = (value + coefficient) * n
    return value


AxisTerms = tuple[float, float, float, tuple[float, ...], tuple[float, ...]]
"""One axis as the correction evaluates it: ``(K0, dNs0, D, F_s coefficients, F_c coefficients)``,
the coefficients highest order first (Horner), all plain floats."""


def correction_terms(calibration: Calibration) -> tuple[AxisTerms, AxisTerms, AxisTerms]:
    """The three axes' :data:`AxisTerms`: what every correction path precomputes."""
    return tuple(  # type: ignore[return-value]
        (float(a.scale), float(a.offset), float(a.offset_span),
         tuple(float(c) for c in reversed(a.offset_shape)),
         tuple(float(c) for c in reversed(a.scale_shape)))
        for a in calibration.axes)


def offset_and_gain(n, scale: float, offset: float, span: float, shape_s: tuple[float, ...],
                    shape_c: tuple[float, ...]):
    """``(dNs0 + D F_s(n), K0 F_c(n))`` of one axis (float or array, same operations in the same order).

    The one evaluation of the paper's polynomials that the correction paths share.
    """
    drift = 0.0 * n
    for coefficient in shape_s:
        drift = (drift + coefficient) * n
    factor = 0.0 * n
    for coefficient in shape_c:
        factor = (factor + coefficient) * n
    return offset + span * drift, scale * (factor + 1.0)


@dataclass(frozen=True)
class AxisModel:
    """Calibrated correction link of one axis.

    :param scale: ``K0``, counts per (m/s^2) per conversion cycle at normal conditions, > 0.
    :param offset: ``dNs0``, output-referred offset at normal conditions, counts.
    :param offset_span: ``D``, largest change of the offset over the calibrated range, counts.
    :param offset_shape: ``(b1, ..., bq)`` of ``F_s``, per code power.
    :param scale_shape: ``(a1, ..., ap)`` of ``F_c``, per code power. ``(0.0,)`` means
        no temperature dependence of the scale (ROS 2 parameters cannot hold empty lists).
    :param residual_rms: RMS of the fit residual in counts, or ``None`` when unknown.
    :param scale_observable: ``False`` when the calibration data could not separate scale
        from offset on this axis and the scale was held at its nominal value.
    """

    scale: float
    offset: float
    offset_span: float
    offset_shape: tuple[float, ...]
    scale_shape: tuple[float, ...] = (0.0,)
    residual_rms: float | None = None
    scale_observable: bool = True

    @classmethod
    def from_polynomials(cls, *, scale: float, offset: float, offset_coeffs: Sequence[float],
                         scale_coeffs: Sequence[float], code_offset_range: tuple[float, float],
                         residual_rms: float | None = None,
                         scale_observable: bool = True) -> AxisModel:
        """Build an axis from raw polynomial coefficients, normalising ``F_s`` as the paper does.

        :param offset_coeffs: ``(c1, ..., cq)`` of ``dNs(n) - dNs0 = c1 n + ... + cq n^q``.
        :param scale_coeffs: ``(a1, ..., ap)`` of ``F_c``.
        :param code_offset_range: ``(n_min, n_max)`` over which ``max |F_s| = 1``.
        """
        grid = np.linspace(code_offset_range[0], code_offset_range[1], 2001)
        span = float(np.max(np.abs(horner_no_constant(tuple(offset_coeffs), grid))))
        shape = tuple(float(c) / span for c in offset_coeffs) if span > 0.0 else tuple(
            0.0 for _ in offset_coeffs)
        return cls(scale=float(scale), offset=float(offset), offset_span=span,
                   offset_shape=shape or (0.0,),
                   scale_shape=tuple(float(a) for a in scale_coeffs) or (0.0,),
                   residual_rms=residual_rms, scale_observable=scale_observable)

    def offset_drift(self, n):
        """``dNs(n) - dNs0 = D * F_s(n)`` in counts (scalar or array)."""
        return self.offset_span * horner_no_constant(self.offset_shape, n)

    def scale_factor(self, n):
        """``F_c(n)`` (scalar or array)."""
        return horner_no_constant(self.scale_shape, n) + 1.0

    def forward(self, specific_force, n):
        """Channel code ``N`` (unrounded) for specific force ``f`` at code offset ``n``."""
        return (self.scale * self.scale_factor(n) * specific_force
                + (self.offset + self.offset_drift(n)))


MIN_TURN_ON_RECORDS = 5
"""A turn-on repeatability is determined from this many records (power-ups) or more. From ``n`` records a
spread's 95 % chi-square interval runs from ``sqrt((n-1) / chi2(0.975, n-1))`` to
``sqrt((n-1) / chi2(0.025, n-1))`` times the estimate: 0.45..32x from two, 0.52..6.3x from three,
0.60..2.9x from five. Below, the file says ``not determined`` and nothing judges against it."""
NOT_DETERMINED = 'not determined'
"""What a ``turn_on`` section holds in place of a repeatability the records do not determine."""


def _chi2_cdf(x: float, dof: int) -> float:
    """The chi-square distribution function of a whole number of degrees of freedom (closed forms)."""
    if x <= 0.0:
        return 0.0
    half = x / 2.0
    if dof % 2 == 0:
        term, total = 1.0, 1.0
        for k in range(1, dof // 2):
            term *= half / k
            total += term
        return 1.0 - math.exp(-half) * total
    root = math.sqrt(x)
    term, total = root, 0.0
    for k in range(1, (dof - 1) // 2 + 1):
        total += term
        term *= x / (2 * k + 1)
    return math.erf(root / math.sqrt(2.0)) - 2.0 * math.exp(-half) / math.sqrt(2.0 * math.pi) * total


def _chi2_quantile(probability: float, dof: int) -> float:
    """``chi2.ppf(probability, dof)`` by bisection of :func:`_chi2_cdf`."""
    low, high = 0.0, max(10.0, 10.0 * dof)
    while _chi2_cdf(high, dof) < probability:
        high *= 2.0
    for _ in range(200):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if _chi2_cdf(middle, dof) < probability else (low, middle)
    return 0.5 * (low + high)


def spread_interval(records: int) -> tuple[float, float]:
    """The 95 % chi-square interval of a spread estimated from ``records`` values, as factors of the estimate."""
    dof = max(int(records) - 1, 1)
    return (math.sqrt(dof / _chi2_quantile(0.975, dof)), math.sqrt(dof / _chi2_quantile(0.025, dof)))


@dataclass(frozen=True)
class TurnOn:
    """A sensor's turn-on offset repeatability: how far its offset moves from one power-up to the next.

    A MEMS unit's offset at power-up differs from the curve by a constant for the whole run (bias
    repeatability, run to run). Fitted from many records of one unit as a random effect (one
    constant per record, apart from the curve); the node and ``apply`` may take a run's own
    constant at its first rest, judged against this spread.

    :param repeatability: per axis x, y, z the standard deviation of the turn-on offset over
        power-ups, in the sensor's unit (m/s^2, rad/s), >= 0; ``None``: not determined (fewer than
        :data:`MIN_TURN_ON_RECORDS` records).
    :param repeatability_error: per axis the standard error of ``repeatability``, >= 0 (``None`` with it).
    :param records: how many records (power-ups) it was estimated from, >= 2.
    """

    repeatability: tuple[float, float, float] | None
    repeatability_error: tuple[float, float, float] | None
    records: int

    def __post_init__(self) -> None:
        if (self.repeatability is None) != (self.repeatability_error is None):
            msg = 'turn_on: repeatability and repeatability_error are given together (or neither: not determined)'
            raise CalibrationError(msg)
        for name in ('repeatability', 'repeatability_error'):
            values = getattr(self, name)
            if values is None:
                continue
            if len(values) != 3 or not all(math.isfinite(v) and v >= 0.0 for v in values):
                msg = f'turn_on.{name}: expected three finite numbers >= 0, got {list(values)}'
                raise CalibrationError(msg)
        if isinstance(self.records, bool) or not isinstance(self.records, int) or self.records < 2:
            msg = f'turn_on.records: expected a whole number >= 2, got {self.records!r}'
            raise CalibrationError(msg)

    @property
    def determined(self) -> bool:
        """Whether a reader may judge against it: a repeatability from :data:`MIN_TURN_ON_RECORDS` records or more.

        A file written before the rule may hold numbers from two records: they are not determined either.
        """
        return self.repeatability is not None and self.records >= MIN_TURN_ON_RECORDS

    def why_not(self) -> str:
        """Why it is not determined, in a few words (``''`` when it is)."""
        if self.determined:
            return ''
        low, high = spread_interval(self.records)
        return (f'{NOT_DETERMINED}: {self.records} records, at least {MIN_TURN_ON_RECORDS} needed; from '
                f'{self.records} the 95 % interval of a spread is {low:.2g}..{high:.2g}x its estimate')


@dataclass(frozen=True)
class Calibration:
    """The whole correction link: three axes and the calibrated temperature-code range.

    :param temp_code_ref: ``N_t,ref``, the temperature code at normal conditions.
    :param temp_code_min: lower end of the calibrated range of ``N_t``.
    :param temp_code_max: upper end of the calibrated range of ``N_t``.
    :param axes: the models of axes x, y, z.
    :param version: calibration file format version.
    :param notes: free-text remarks recorded with the calibration (e.g. what was held).
    :param effects: fitted effects beyond the paper's model (``tak_thermo_ros.core.effects``),
        each name at most once; the correction applies them in this order.
    :param noise: the noise model of the corrected output (SI: m/s^2 or rad/s), or ``None``;
        when given, the Imu covariance is its per-sample variance (``NoiseModel.sample_variance``).
    :param thermal: :data:`THERMAL_FITTED` (the temperature terms of the paper's link),
        :data:`THERMAL_HELD` or :data:`THERMAL_NONE` (no temperature terms: every axis has
        ``offset_span`` 0 and flat shapes, and the correction never reads a temperature).
    :param turn_on: the turn-on offset's repeatability over power-ups (:class:`TurnOn`), or ``None``
        when the calibration was fitted from one power-up (what to judge against: :attr:`known_turn_on`).
    :param uncertainty: the covariance of the link's own errors, held terms included
        (:class:`~tak_thermo_ros.core.link.uncertainty.LinkUncertainty`), or ``None`` (not stated).
    """

    temp_code_ref: float
    temp_code_min: float
    temp_code_max: float
    axes: tuple[AxisModel, AxisModel, AxisModel]
    version: int = CALIBRATION_VERSION
    notes: tuple[str, ...] = field(default=())
    effects: tuple[Effect, ...] = field(default=())
    noise: NoiseModel | None = None
    thermal: str = THERMAL_FITTED
    turn_on: TurnOn | None = None
    uncertainty: LinkUncertainty | None = None

    @property
    def known_turn_on(self) -> TurnOn | None:
        """The turn-on repeatability to judge a run against: ``turn_on`` when determined, else ``None``."""
        return self.turn_on if self.turn_on is not None and self.turn_on.determined else None

    def __post_init__(self) -> None:
        if len(self.axes) != 3:
            msg = f'calibration needs 3 axes, got {len(self.axes)}'
            raise CalibrationError(msg)
        if self.thermal not in THERMAL_STATES:
            msg = f'calibration.thermal: expected one of {", ".join(THERMAL_STATES)}, got {self.thermal!r}'
            raise CalibrationError(msg)
        if self.thermal != THERMAL_FITTED:
            for name, axis in zip(AXES, self.axes):
                if axis.offset_span != 0.0 or any(axis.offset_shape) or any(axis.scale_shape):
                    msg = (f'calibration.{name}: thermal is {self.thermal!r} (no temperature terms) but the axis '
                           f'holds offset_span {axis.offset_span:g} or a non-zero shape')
                    raise CalibrationError(msg)
        names = set()
        for effect in self.effects:
            if not isinstance(effect, Effect):
                msg = f'calibration.effects: expected Effect instances, got {type(effect).__name__}'
                raise CalibrationError(msg)
            if effect.name in names:
                msg = f'calibration.effects.{effect.name}: given twice'
                raise CalibrationError(msg)
            names.add(effect.name)
        object.__setattr__(self, 'effects', tuple(self.effects))

    @property
    def needs_temperature(self) -> bool:
        """Whether the correction reads the temperature (a link with temperature terms)."""
        return self.thermal == THERMAL_FITTED

    def axis(self, name: str) -> AxisModel:
        """Return the model of axis ``'x'``, ``'y'`` or ``'z'``."""
        return self.axes[AXES.index(name)]

    def code_offset_range(self) -> tuple[float, float]:
        """The calibrated range as ``(n_min, n_max)`` with ``n = N_t - N_t,ref``."""
        return (self.temp_code_min - self.temp_code_ref, self.temp_code_max - self.temp_code_ref)

    def nominal(self) -> Calibration:
        """The same unit with every temperature term and effect off (nominal scale and offset only)."""
        flat = tuple(replace(axis, offset_span=0.0, offset_shape=(0.0,), scale_shape=(0.0,))
                     for axis in self.axes)
        return replace(self, axes=flat, effects=())  # type: ignore[arg-type]

    def as_recorded(self) -> Calibration:
        """The same unit with scale 1, no offset, no temperature term, no effect: a driver's values as recorded.

        ``validate``'s *before* on a driver's bag (what the driver gives without this package), the
        same whatever calibration is given; codes have no unit without a scale, so a counts bag's
        *before* is :meth:`nominal`.
        """
        flat = tuple(replace(axis, scale=1.0, offset=0.0, offset_span=0.0, offset_shape=(0.0,), scale_shape=(0.0,))
                     for axis in self.axes)
        return replace(self, axes=flat, effects=())  # type: ignore[arg-type]

    def uncorrected(self, *, as_recorded: bool) -> Calibration:
        """``validate``'s *before*: :meth:`as_recorded` (a driver's values), else :meth:`nominal` (codes)."""
        return self.as_recorded() if as_recorded else self.nominal()

    def forward(self, specific_force: np.ndarray, temp_code: np.ndarray) -> np.ndarray:
        """The paper's forward model: unrounded codes ``(k, 3)`` for specific force ``(k, 3)`` in m/s^2.

        Polynomials are evaluated beyond the calibrated range as well (no clamping). Effects
        are not applied here: :func:`tak_thermo_ros.core.link.correction.forward_counts` includes them.
        """
        n = np.asarray(temp_code, dtype=float) - self.temp_code_ref
        force = np.asarray(specific_force, dtype=float)
        return np.column_stack([axis.forward(force[:, i], n) for i, axis in enumerate(self.axes)])


@dataclass(frozen=True)
class MagnetometerCalibration:
    """The magnetometer's correction: the thermal link, then the hard and soft iron.

    ``B_corrected = W (B_thermal - h)``, with ``B_thermal`` the output of the paper's link
    (``thermal``, per axis, tesla) and ``W`` symmetric positive definite.

    :param thermal: offset and scale against temperature per axis (tesla; degrees C).
    :param hard_iron: ``h``, tesla, in the sensor frame.
    :param soft_iron: ``W``, row-major 3x3 (nine floats: ROS 2 parameters hold no nested lists).
    """

    thermal: Calibration
    hard_iron: tuple[float, float, float] = (0.0, 0.0, 0.0)
    soft_iron: tuple[float, ...] = IDENTITY_3X3

    def __post_init__(self) -> None:
        object.__setattr__(self, 'hard_iron', tuple(float(v) for v in self.hard_iron))
        object.__setattr__(self, 'soft_iron', tuple(float(v) for v in self.soft_iron))
        if len(self.hard_iron) != 3:
            msg = f'calibration.mag.hard_iron: expected 3 numbers, got {len(self.hard_iron)}'
            raise CalibrationError(msg)
        if len(self.soft_iron) != 9:
            msg = f'calibration.mag.soft_iron: expected 9 numbers (row-major 3x3), got {len(self.soft_iron)}'
            raise CalibrationError(msg)

    @property
    def soft_iron_matrix(self) -> np.ndarray:
        """``W`` as a 3x3 array."""
        return np.array(self.soft_iron, dtype=float).reshape(3, 3)


@dataclass(frozen=True)
class UnitCalibration:
    """The correction of a whole IMU: one :class:`Calibration` per three-axis sensor.

    Every sensor follows the paper's link ``y = K F_c(T) u + b0 + D F_s(T)``: with
    :attr:`InputKind.COUNTS`, ``y`` is the channel code and ``T`` the temperature-sensor code
    (the accelerometer only, file version 1); with :attr:`InputKind.IMU`, ``y`` is the driver's
    value (m/s^2 or rad/s, nominal ``K = 1``) and ``T`` the temperature in degrees Celsius, for
    the accelerometer and the gyroscope (file version 2).

    :param input_kind: what the link takes in.
    :param accel: the accelerometer's link.
    :param gyro: the gyroscope's link (required with :attr:`InputKind.IMU`, absent with counts).
    :param mag: the magnetometer's correction (optional, driver input only). It is not one of
        :attr:`sensors`: its messages come on their own topic, with their own stamps.
    :param source: what the record it was fitted from was (driver input only; the file's
        ``source`` section, :data:`SOURCE_KEYS`): the correction does not use it, an export does.
    :param fitted_from: one print per record the link was fitted from (the file's ``fitted_from``,
        :class:`~tak_thermo_ros.core.records.provenance.RecordPrint`): ``validate`` and ``diagnose``
        of such a record say that it is in-sample; empty in a file written before it existed.
    """

    input_kind: InputKind
    accel: Calibration
    gyro: Calibration | None = None
    mag: MagnetometerCalibration | None = None
    source: dict[str, str | int | float] | None = None
    fitted_from: tuple[RecordPrint, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, 'input_kind', InputKind(self.input_kind))
        if self.input_kind is InputKind.IMU and self.gyro is None:
            msg = 'calibration.gyro: missing (a driver-input calibration corrects both sensors)'
            raise CalibrationError(msg)
        if self.input_kind is InputKind.COUNTS and self.gyro is not None:
            msg = 'calibration.gyro: the counts input (file version 1) has an accelerometer only'
            raise CalibrationError(msg)
        if self.input_kind is InputKind.COUNTS and self.mag is not None:
            msg = 'calibration.mag: the counts input (file version 1) has an accelerometer only'
            raise CalibrationError(msg)

    @property
    def sensors(self) -> tuple[tuple[str, Calibration], ...]:
        """``(name, calibration)`` of every sensor present, accelerometer first."""
        present = (('accel', self.accel), ('gyro', self.gyro))
        return tuple((name, calibration) for name, calibration in present if calibration is not None)

    @property
    def needs_temperature(self) -> bool:
        """Whether correcting the Imu (accelerometer and gyroscope) reads the temperature."""
        return any(calibration.needs_temperature for _, calibration in self.sensors)

    def sensor(self, name: str) -> Calibration:
        """The calibration of sensor ``'accel'`` or ``'gyro'`` (``'mag'``: the magnetometer's thermal link)."""
        mag = self.mag.thermal if self.mag is not None else None
        calibration = {'accel': self.accel, 'gyro': self.gyro, MAG_SENSOR: mag}.get(name)
        if calibration is None:
            msg = f'calibration.{name}: not in this calibration'
            raise CalibrationError(msg)
        return calibration


SOURCE_KEYS: dict[str, type] = {
    'format': str, 'instance': int, 'accel_device_id': int, 'gyro_device_id': int, 'mag_device_id': int,
    'temperature_rate_max': float, 'rate_max': float,
}
"""A calibration's ``source``: the record's format (``bag``, ``ulog``, ``dataflash``), the flight
log's sensor instance and the sensors' device IDs (0: none), the record's fastest temperature
change (C/s, over 60 s) and largest angular rate (rad/s, the reference or the measured)."""


def held_link(*, offsets: Sequence[float] = (0.0, 0.0, 0.0), scales: Sequence[float] = (1.0, 1.0, 1.0),
              residual_rms: Sequence[float | None] = (None, None, None), scale_observable: bool = False,
              temperatures: tuple[float, float, float] | None = None, notes: Sequence[str] = ()) -> Calibration:
    """A link without temperature terms: per axis a scale and an offset, the same at every temperature.

    :param temperatures: ``(ref, min, max)`` of the record it was taken from (:data:`THERMAL_HELD`),
        or ``None``: the record held no temperature (:data:`THERMAL_NONE`).
    """
    axes = tuple(AxisModel(scale=float(scale), offset=float(offset), offset_span=0.0, offset_shape=(0.0,),
                           scale_shape=(0.0,), residual_rms=rms, scale_observable=scale_observable)
                 for scale, offset, rms in zip(scales, offsets, residual_rms))
    ref, low, high = temperatures if temperatures is not None else (0.0, 0.0, 0.0)
    return Calibration(temp_code_ref=float(ref), temp_code_min=float(low), temp_code_max=float(high),
                       axes=axes, notes=tuple(notes),  # type: ignore[arg-type]
                       thermal=THERMAL_HELD if temperatures is not None else THERMAL_NONE)


def check_scale_positive(calibration: Calibration, *, key: str = 'calibration') -> None:
    """Raise unless ``F_c(n) > 0`` over the whole calibrated range on every axis."""
    n_low, n_high = calibration.code_offset_range()
    grid = np.linspace(n_low, n_high, 1001)
    for name, axis in zip(AXES, calibration.axes):
        factor = axis.scale_factor(grid)
        if not np.all(factor > 0.0):
            worst = float(grid[int(np.argmin(factor))]) + calibration.temp_code_ref
            msg = (f'{key}.{name}.scale_shape: F_c <= 0 inside the calibrated range '
                   f'(at temperature code {worst:.1f})')
            raise CalibrationError(msg)


SENSOR_RANGE = {'counts': (32768.0, 'codes', 'the 16-bit code range'),
                'accel': (2000.0, 'm/s^2', "any accelerometer's range"),
                'gyro': (100.0, 'rad/s', "any gyroscope's range"),
                'mag': (0.01, 'T', "any magnetometer's range")}
"""Per sensor, a bound beyond any unit's full scale, its unit and its name: the paper's 16-bit
codes; 2000 m/s^2 (about 200 g); 100 rad/s (5700 deg/s); 0.01 T (100 gauss). No offset a
sensor can output lies beyond it."""
DRIFT_SLACK = 10.0
"""How far the offset drift over the calibrated range may exceed ``offset_span``, the largest
change of the offset over that range by the file's own definition (``max |F_s| = 1``)."""
SCALE_FACTOR_RANGE = (0.5, 2.0)
"""Open interval of ``F_c`` over the calibrated range: the scale changes with temperature by
percent, not by a factor of two."""


def check_plausible(calibration: Calibration, sensor: str, *, key: str = 'calibration') -> None:
    """Refuse a correction that is implausible over its own calibrated range.

    On every axis, at 1001 temperatures across the range: the offset it removes,
    ``|dNs0 + D F_s(n)|``, stays within the sensor's :data:`SENSOR_RANGE`; the offset drift
    ``|D F_s(n)|`` within :data:`DRIFT_SLACK` times ``offset_span`` (what was fitted: the fit
    normalises ``F_s`` to a largest magnitude of 1 over the range; a shape or a range that
    makes it more extrapolates the fit far beyond its data); ``F_c(n)`` within
    :data:`SCALE_FACTOR_RANGE`. The one rule for a file and for a node's parameter update.

    :param sensor: a key of :data:`SENSOR_RANGE`.
    :raises CalibrationError: one line naming the key, the value, where and the bound.
    """
    full_scale, unit, what = SENSOR_RANGE[sensor]
    n_low, n_high = calibration.code_offset_range()
    grid = np.linspace(n_low, n_high, 1001)
    low, high = SCALE_FACTOR_RANGE
    for name, axis in zip(AXES, calibration.axes):
        with np.errstate(all='ignore'):
            drift = axis.offset_drift(grid)
            factor = axis.scale_factor(grid)
        at = int(np.argmax(np.abs(drift)))
        where = f'at temperature {float(grid[at]) + calibration.temp_code_ref:g}'
        if abs(drift[at]) > DRIFT_SLACK * axis.offset_span:
            msg = (f'{key}.{name}.offset_shape: the offset drifts by {drift[at]:.3g} {unit} {where}, '
                   f'{abs(drift[at]) / axis.offset_span:.3g} x offset_span ({axis.offset_span:.3g} {unit}; '
                   f'at most {DRIFT_SLACK:g} x): beyond what was fitted')
            raise CalibrationError(msg)
        removed = axis.offset + drift
        at = int(np.argmax(np.abs(removed)))
        if abs(removed[at]) > full_scale:
            msg = (f'{key}.{name}: the correction removes an offset of {removed[at]:.3g} {unit} at temperature '
                   f'{float(grid[at]) + calibration.temp_code_ref:g}, beyond {what} ({full_scale:g} {unit})')
            raise CalibrationError(msg)
        if not np.all((factor > low) & (factor < high)):
            at = int(np.argmax(np.abs(factor - 1.0)))
            msg = (f'{key}.{name}.scale_shape: F_c = {factor[at]:.3g} at temperature '
                   f'{float(grid[at]) + calibration.temp_code_ref:g}, outside {low:g}..{high:g}: the scale '
                   f'changes with temperature by percent')
            raise CalibrationError(msg)
