"""The three streams of the bag contract as arrays, and their alignment on the counts stream.

Temperature codes may come at a lower rate than counts, and the reference is published at
least whenever it changes: both are *held* (the last value at or before the counts stamp).
Alignment uses header stamps, not bag receive times. What a sample may hold and why it is
dropped is :mod:`.drops`; the stamp rule, and nanoseconds against seconds, :mod:`.stamps`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.records.drops import counts_problems, reference_problems, temp_code_problems
from tak_thermo_ros.core.records.stamps import NANOSECONDS, StampHistory, seconds_from_ns, stamp_problems
from tak_thermo_ros.errors import CalibrationError


def no_orientation(count: int) -> tuple[np.ndarray, np.ndarray]:
    """The orientation of ``count`` Imu messages that give none (REP 145).

    ``(count, 4)`` identity quaternions ``(x, y, z, w)`` and ``(count, 9)`` covariances whose first
    element is -1.
    """
    orientation = np.zeros((count, 4))
    orientation[:, 3] = 1.0
    covariance = np.zeros((count, 9))
    covariance[:, 0] = -1.0
    return orientation, covariance


@dataclass(frozen=True)
class ChannelRecord:
    """One recorded run.

    :param counts_stamp_ns: ``(k,)`` int64 header stamps of the counts messages.
    :param counts: ``(k, 3)`` channel codes N.
    :param temp_stamp_ns: ``(m,)`` int64 stamps of the temperature-code messages.
    :param temp_code: ``(m,)`` raw temperature-sensor codes N_t.
    :param reference_stamp_ns: ``(r,)`` int64 stamps of the reference messages (may be empty).
    :param reference: ``(r, 3)`` true specific force along the sensor axes, m/s^2.
    :param frame_id: frame of the counts messages (the first one's).
    :param nominal_scale: nominal ``K0`` per axis (counts per m/s^2) that the recorder knows
        from the code resolution, or ``None``.
    :param input_kind: ``'counts'`` (the paper's whole-number codes, checked for rails) or
        ``'imu'`` (a driver's values in SI units and the temperature in degrees Celsius).
    :param aux: recorded auxiliary scalar signals: name ``aux:TOPIC`` or
        ``aux:TOPIC:FIELD`` -> ``(stamp_ns (a,), values (a,))``.
    """

    counts_stamp_ns: np.ndarray
    counts: np.ndarray
    temp_stamp_ns: np.ndarray
    temp_code: np.ndarray
    reference_stamp_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    reference: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    frame_id: str = ''
    nominal_scale: tuple[float, float, float] | None = None
    input_kind: str = 'counts'
    aux: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)

    @property
    def has_reference(self) -> bool:
        """Whether the run carries a reference (a calibration run)."""
        return len(self.reference_stamp_ns) > 0


def _usable_hold_index(source_stamp_ns: np.ndarray, problems: dict[str, np.ndarray], target_stamp_ns: np.ndarray,
                       ignored: dict[str, int]) -> np.ndarray:
    """:func:`hold_last_index` over the source rows without a problem; counts the others in ``ignored``."""
    usable = np.ones(len(source_stamp_ns), dtype=bool)
    for reason, mask in problems.items():
        if mask.any():
            ignored[reason] = int(np.count_nonzero(mask))
            usable &= ~mask
    rows = np.flatnonzero(usable)
    if not len(rows):
        return np.full(len(target_stamp_ns), -1)
    held = hold_last_index(source_stamp_ns[rows], target_stamp_ns)
    return np.where(held >= 0, rows[np.maximum(held, 0)], -1)


def hold_last_index(source_stamp_ns: np.ndarray, target_stamp_ns: np.ndarray) -> np.ndarray:
    """Index of the last source sample at or before each target stamp, ``-1`` where none.

    The source stamps need not be sorted; ties keep the later-recorded sample.
    """
    order = np.argsort(source_stamp_ns, kind='stable')
    position = np.searchsorted(source_stamp_ns[order], target_stamp_ns, side='right') - 1
    return np.where(position >= 0, order[np.maximum(position, 0)], -1)


def rows_at(source_stamp_ns: np.ndarray, target_stamp_ns: np.ndarray) -> np.ndarray:
    """Per target stamp, the last source row with exactly that stamp, ``-1`` where none."""
    source = np.asarray(source_stamp_ns, dtype=np.int64)
    held = hold_last_index(source, np.asarray(target_stamp_ns, dtype=np.int64))
    equal = (held >= 0) & (source[np.maximum(held, 0)] == target_stamp_ns) if len(source) else held >= 0
    return np.where(equal, held, -1)


@dataclass(frozen=True)
class AlignedSamples:
    """Counts samples with the held temperature code and reference, usable ones only.

    :param stamp_ns: ``(k,)`` stamps of the kept counts samples.
    :param counts: ``(k, 3)`` codes.
    :param temp_code: ``(k,)`` held temperature codes.
    :param reference: ``(k, 3)`` held reference, or ``None`` without a reference stream.
    :param dropped: reason -> number of counts samples left out.
    :param rows: ``(k,)`` index of each kept sample in the record's stream, or ``None``.
    :param ignored_temp_codes: reason of :data:`~.drops.TEMP_CODE_PROBLEMS` -> number of temperature
        codes that were ignored (not held), reasons with none left out.
    :param ignored_references: the same for reference messages (:func:`reference_problems`).
    :param aux: recorded signal name -> ``(k,)`` its value held at each kept sample's stamp
        (NaN before its first finite value; :func:`require_signals` leaves those samples out).
    :param stamp_history: what the stamp rule knows after the last sample (kept or not), for
        the next block of a run, or ``None``.
    """

    stamp_ns: np.ndarray
    counts: np.ndarray
    temp_code: np.ndarray
    reference: np.ndarray | None
    dropped: dict[str, int]
    rows: np.ndarray | None = None
    ignored_temp_codes: dict[str, int] = field(default_factory=dict)
    ignored_references: dict[str, int] = field(default_factory=dict)
    aux: dict[str, np.ndarray] = field(default_factory=dict)
    stamp_history: StampHistory | None = None

    def __len__(self) -> int:
        return len(self.stamp_ns)

    @property
    def stamp_s(self) -> np.ndarray:
        """Stamps as float seconds (:func:`seconds_from_ns`), what the correction takes."""
        return seconds_from_ns(self.stamp_ns)

    @property
    def time_s(self) -> np.ndarray:
        """Seconds since the first kept sample."""
        if len(self.stamp_ns) == 0:
            return np.zeros(0)
        return (self.stamp_ns - self.stamp_ns[0]) * 1e-9


def align(record: ChannelRecord, *, use_reference: bool = True, settle_time_s: float = 0.0,
          drop_saturated: bool = True, stamp_history: StampHistory | None = None,
          require_temperature: bool = True) -> AlignedSamples:
    """Hold temperature code and reference on the counts stamps and keep usable samples.

    Counts samples are left out, and counted by reason, in this order: the header stamp does
    not go on from the previous message's or the last kept one's (:func:`~.stamps.stamp_kept`:
    ``duplicate_stamp``, ``time_backwards``, ``stamp_jump``); for the reasons of
    :func:`counts_problems`: a code is NaN or infinite (``non_finite``), not a whole number
    (``non_integer``), or at a 16-bit rail (``saturated``, unless ``drop_saturated`` is false),
    a driver's value of magnitude :data:`~.drops.VALUE_LIMIT` or more (``non_physical``); no
    temperature code has arrived yet
    (``before_first_temp_code``); no reference yet (``before_first_reference``); within
    ``settle_time_s`` after a reference change (``settling``).

    A temperature code that is NaN, infinite or implausibly large (:func:`temp_code_problem`)
    is never held: the previous good code stays, as in the node; the ignored codes are counted
    in :attr:`AlignedSamples.ignored_temp_codes`. A reference message likewise
    (:func:`reference_problems`, :attr:`AlignedSamples.ignored_references`).

    :param stamp_history: what the stamp rule knows of the counts messages before the record's
        first one (a run aligned in blocks, :mod:`tak_thermo_ros.core.records.blocks`), or ``None``.
    :param require_temperature: ``False`` for a pass that reads no temperature (a record without
        one, or a correction without temperature terms): no sample is left out for want of a
        temperature, and a sample before the first one holds NaN.
    """
    stamps = record.counts_stamp_ns
    counts = record.counts
    keep = np.ones(len(stamps), dtype=bool)
    dropped: dict[str, int] = {}

    def leave_out(reason: str, mask: np.ndarray) -> None:
        newly = mask & keep
        if newly.any():
            dropped[reason] = dropped.get(reason, 0) + int(np.count_nonzero(newly))
            keep[newly] = False

    stamp_masks, stamp_history = stamp_problems(stamps, history=stamp_history)
    for reason, mask in stamp_masks.items():
        leave_out(reason, mask)
    for reason, mask in counts_problems(counts, whole_codes=record.input_kind == 'counts').items():
        if reason != 'saturated' or drop_saturated:
            leave_out(reason, mask)
    ignored_temp_codes: dict[str, int] = {}
    temp_problems = temp_code_problems(record.temp_code, record.input_kind)
    temp_index = _usable_hold_index(record.temp_stamp_ns, temp_problems, stamps,
                                    ignored_temp_codes)
    if require_temperature:
        leave_out('before_first_temp_code', temp_index < 0)
    reference = None
    ignored_references: dict[str, int] = {}
    if use_reference and record.has_reference:
        problems = reference_problems(record.reference)
        reference_index = _usable_hold_index(record.reference_stamp_ns, problems, stamps, ignored_references)
        usable_references = ~(problems['non_finite'] | problems['implausible'])
        leave_out('before_first_reference', reference_index < 0)
        if settle_time_s > 0.0:
            leave_out('settling', _within_settle_time(record, stamps, settle_time_s, usable_references))
        reference = record.reference[reference_index[keep]]
    held_temp = temp_index[keep]
    temp_code = np.where(held_temp >= 0, np.asarray(record.temp_code, dtype=float)[np.maximum(held_temp, 0)]
                         if len(record.temp_code) else np.nan, np.nan)
    return AlignedSamples(stamp_ns=stamps[keep], counts=counts[keep], temp_code=temp_code,
                          reference=reference, dropped=dropped, rows=np.flatnonzero(keep),
                          ignored_temp_codes=ignored_temp_codes, ignored_references=ignored_references,
                          aux={name: hold_signal(signal_stamps, values, stamps[keep])
                               for name, (signal_stamps, values) in record.aux.items()},
                          stamp_history=stamp_history)


def hold_signal(source_stamp_ns: np.ndarray, values: np.ndarray, target_stamp_ns: np.ndarray) -> np.ndarray:
    """A recorded signal held at its last finite value on each target stamp; NaN before the first.

    A non-finite value is never held (the previous one stays), as for the temperature.
    """
    values = np.asarray(values, dtype=float)
    rows = np.flatnonzero(np.isfinite(values))
    out = np.full(len(target_stamp_ns), np.nan)
    if not len(rows):
        return out
    held = hold_last_index(np.asarray(source_stamp_ns, dtype=np.int64)[rows], target_stamp_ns)
    out[held >= 0] = values[rows[held[held >= 0]]]
    return out


def require_signals(samples: AlignedSamples, signals: Sequence[str]) -> AlignedSamples:
    """Keep only the samples at which every named recorded signal has a held value.

    The others are counted as dropped ``before_first_<name>`` (the node waits likewise).

    :raises CalibrationError: a signal is not in the record at all.
    """
    keep = np.ones(len(samples), dtype=bool)
    dropped = dict(samples.dropped)
    for name in signals:
        if name not in samples.aux:
            recorded = ', '.join(sorted(samples.aux)) or 'none'
            msg = (f'the calibration needs the recorded signal {name} (topic {name[4:].split(":")[0]}), '
                   f'which the bag does not hold (recorded signals: {recorded})')
            raise CalibrationError(msg)
        missing = np.isnan(samples.aux[name]) & keep
        if missing.any():
            dropped[f'before_first_{name}'] = int(np.count_nonzero(missing))
            keep &= ~missing
    if keep.all():
        return samples
    return replace(samples, stamp_ns=samples.stamp_ns[keep], counts=samples.counts[keep],
                   temp_code=samples.temp_code[keep],
                   reference=None if samples.reference is None else samples.reference[keep], dropped=dropped,
                   rows=None if samples.rows is None else samples.rows[keep],
                   aux={name: values[keep] for name, values in samples.aux.items()})


def _within_settle_time(record: ChannelRecord, stamps: np.ndarray, settle_time_s: float,
                        usable: np.ndarray) -> np.ndarray:
    rows = np.flatnonzero(usable)
    order = rows[np.argsort(record.reference_stamp_ns[rows], kind='stable')]
    ref_stamps = record.reference_stamp_ns[order]
    values = record.reference[order]
    changed = np.ones(len(values), dtype=bool)
    changed[1:] = np.any(values[1:] != values[:-1], axis=1)
    change_stamps = ref_stamps[changed]
    last_change = np.searchsorted(change_stamps, stamps, side='right') - 1
    since = np.where(last_change >= 0, stamps - change_stamps[np.maximum(last_change, 0)], -1)
    return (since >= 0) & (since < int(settle_time_s * NANOSECONDS))


@dataclass(frozen=True)
class DriverRecord:
    """A run recorded from a ROS 2 IMU driver (``sensor_msgs/msg/Imu`` plus a temperature).

    Each sensor keeps its own samples. Most drivers publish both in one message: then
    ``accel_stamp_ns`` and ``gyro_stamp_ns`` are ``None`` and both sensors are stamped by
    ``stamp_ns``. A record whose sensors come at their own rates (a flight log's
    ``sensor_accel`` and ``sensor_gyro``, a CSV with empty cells, Imu messages that carry one
    sensor, the other's covariance[0] = -1) gives each sensor its own stamps; ``stamp_ns``
    then stamps the messages (what ``orientation`` belongs to), and each sensor's row is
    aligned, fitted and corrected on its own stamps.

    :param stamp_ns: ``(k,)`` header stamps of the Imu messages.
    :param accel: ``(k, 3)`` linear acceleration (specific force) as the driver gave it, m/s^2
        (``(a, 3)`` with ``accel_stamp_ns``).
    :param gyro: ``(k, 3)`` angular velocity as the driver gave it, rad/s (``(g, 3)`` with
        ``gyro_stamp_ns``).
    :param orientation: ``(k, 4)`` orientation quaternion ``(x, y, z, w)``, passed through.
    :param orientation_covariance: ``(k, 9)``, passed through.
    :param temp_stamp_ns: ``(m,)`` stamps of the temperature messages.
    :param temperature: ``(m,)`` temperature in degrees Celsius.
    :param reference_stamp_ns: ``(r,)`` stamps of the specific-force reference (may be empty).
    :param reference: ``(r, 3)`` true specific force along the sensor axes, m/s^2.
    :param rate_reference_stamp_ns: ``(s,)`` stamps of the angular-rate reference (may be empty).
    :param rate_reference: ``(s, 3)`` true angular rate along the sensor axes, rad/s.
    :param frame_id: frame of the Imu messages.
    :param aux: recorded auxiliary scalar signals, as :attr:`ChannelRecord.aux`.
    :param mag_stamp_ns: ``(g,)`` header stamps of the magnetometer's messages (may be empty).
    :param mag: ``(g, 3)`` the magnetic field as the driver gave it, tesla.
    :param mag_reference_stamp_ns: ``(f,)`` stamps of the reference field (a coil; may be empty).
    :param mag_reference: ``(f, 3)`` the true field along the sensor axes, tesla.
    :param mag_frame_id: frame of the magnetometer's messages.
    :param accel_stamp_ns: ``(a,)`` the accelerometer's own stamps, or ``None`` (``stamp_ns``).
    :param gyro_stamp_ns: ``(g,)`` the gyroscope's own stamps, or ``None`` (``stamp_ns``).
    """

    stamp_ns: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray
    orientation: np.ndarray
    orientation_covariance: np.ndarray
    temp_stamp_ns: np.ndarray
    temperature: np.ndarray
    reference_stamp_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    reference: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    rate_reference_stamp_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    rate_reference: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    frame_id: str = ''
    aux: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    mag_stamp_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    mag: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    mag_reference_stamp_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    mag_reference: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    mag_frame_id: str = ''
    accel_stamp_ns: np.ndarray | None = None
    gyro_stamp_ns: np.ndarray | None = None

    @property
    def shared_stamps(self) -> bool:
        """Whether both sensors come in every message (one stamp each for accelerometer and gyroscope)."""
        return self.accel_stamp_ns is None and self.gyro_stamp_ns is None

    def sensor_stamps(self, sensor: str) -> np.ndarray:
        """The stamps of ``'accel'``, ``'gyro'`` or ``'mag'``: its own, or the messages'."""
        own = {'accel': self.accel_stamp_ns, 'gyro': self.gyro_stamp_ns, 'mag': self.mag_stamp_ns}[sensor]
        return self.stamp_ns if own is None else own

    @property
    def first_stamp_ns(self) -> int | None:
        """The earliest stamp of either sensor (``None`` in an empty block)."""
        firsts = [int(np.min(stamps)) for stamps in (self.sensor_stamps('accel'), self.sensor_stamps('gyro'))
                  if len(stamps)]
        return min(firsts) if firsts else None

    def channel(self, sensor: str) -> ChannelRecord:
        """One sensor's three channels as a :class:`ChannelRecord` (nominal scale 1).

        The magnetometer (``'mag'``) is its own stream: its stamps, the field in tesla, the
        reference field.
        """
        if sensor == 'mag':
            return ChannelRecord(counts_stamp_ns=self.mag_stamp_ns, counts=self.mag, temp_stamp_ns=self.temp_stamp_ns,
                                 temp_code=self.temperature, reference_stamp_ns=self.mag_reference_stamp_ns,
                                 reference=self.mag_reference, frame_id=self.mag_frame_id,
                                 nominal_scale=(1.0, 1.0, 1.0), input_kind='imu', aux=self.aux)
        if sensor == 'accel':
            values, ref_stamps, reference = self.accel, self.reference_stamp_ns, self.reference
        elif sensor == 'gyro':
            values, ref_stamps, reference = self.gyro, self.rate_reference_stamp_ns, self.rate_reference
        else:
            msg = f'unknown sensor {sensor!r} (accel, gyro or mag)'
            raise ValueError(msg)
        return ChannelRecord(counts_stamp_ns=self.sensor_stamps(sensor), counts=values,
                             temp_stamp_ns=self.temp_stamp_ns, temp_code=self.temperature,
                             reference_stamp_ns=ref_stamps, reference=reference, frame_id=self.frame_id,
                             nominal_scale=(1.0, 1.0, 1.0), input_kind='imu', aux=self.aux)

    def six_channels(self) -> ChannelRecord:
        """Both sensors side by side, ``(k, 6)`` (accel x y z, gyro x y z), without reference.

        What ``apply`` aligns: a message is corrected or dropped whole, as in the node. A
        record whose sensors have their own stamps has no such rows (``apply`` corrects each
        sensor on its own stamps).

        :raises ValueError: the sensors have their own stamps.
        """
        if not self.shared_stamps:
            msg = 'six_channels: the accelerometer and the gyroscope have their own stamps'
            raise ValueError(msg)
        return ChannelRecord(counts_stamp_ns=self.stamp_ns, counts=np.hstack([self.accel, self.gyro]),
                             temp_stamp_ns=self.temp_stamp_ns, temp_code=self.temperature,
                             frame_id=self.frame_id, input_kind='imu', aux=self.aux)


@dataclass(frozen=True)
class SensorMessages:
    """Imu messages of two sensors that come at their own stamps (:func:`sensor_messages`).

    :param stamp_ns: ``(m,)`` each message's stamp, in stamp order.
    :param accel_row: ``(m,)`` the accelerometer sample each message carries, ``-1`` for none.
    :param gyro_row: ``(m,)`` the gyroscope sample each message carries, ``-1`` for none.
    """

    stamp_ns: np.ndarray
    accel_row: np.ndarray
    gyro_row: np.ndarray


def _occurrence(stamps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The stream in stamp order (stable) and, per sample, how many earlier samples share its stamp."""
    order = np.argsort(stamps, kind='stable')
    ordered = stamps[order]
    run_start = np.flatnonzero(np.r_[True, ordered[1:] != ordered[:-1]]) if len(ordered) else np.zeros(0, int)
    starts = np.repeat(run_start, np.diff(np.r_[run_start, len(ordered)]))
    return order, np.arange(len(ordered)) - starts


def sensor_messages(accel_stamp_ns: np.ndarray, gyro_stamp_ns: np.ndarray) -> SensorMessages:
    """The Imu messages that carry two sensors sampled at their own stamps, without resampling.

    An accelerometer and a gyroscope sample with the same stamp share a message (the k-th of
    each at that stamp pair up); every other sample has a message of its own, in which the
    other sensor is absent (``sensor_msgs`` marks it by its covariance[0] = -1). The one rule
    ``apply`` and the bag writer use, so that reading such a bag back gives each sensor its
    own samples again.
    """
    accel = np.asarray(accel_stamp_ns, dtype=np.int64)
    gyro = np.asarray(gyro_stamp_ns, dtype=np.int64)
    accel_order, accel_occurrence = _occurrence(accel)
    gyro_order, gyro_occurrence = _occurrence(gyro)
    stamps = np.concatenate([accel[accel_order], gyro[gyro_order]])
    occurrence = np.concatenate([accel_occurrence, gyro_occurrence])
    keys = np.unique(np.column_stack([stamps, occurrence]), axis=0) if len(stamps) else np.zeros((0, 2), np.int64)
    message_stamps = keys[:, 0]

    def rows(order: np.ndarray, own: np.ndarray, own_occurrence: np.ndarray) -> np.ndarray:
        out = np.full(len(keys), -1, dtype=np.int64)
        if len(order):
            ordered = own[order]
            at = np.searchsorted(message_stamps, ordered, side='left')
            # messages of one stamp are consecutive, in occurrence order
            out[at + own_occurrence] = order
        return out

    return SensorMessages(stamp_ns=message_stamps.copy(), accel_row=rows(accel_order, accel, accel_occurrence),
                          gyro_row=rows(gyro_order, gyro, gyro_occurrence))
