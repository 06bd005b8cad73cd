"""What a record holds, and what a fit can therefore take from it.

Every command first says what the record holds: its streams and rates, how long it runs, the
temperature span, whether the unit rests or moves and which orientations it rests in. The
numbers come from one pass over the record's blocks (:class:`SurveyCollector`, fed by the
command's own pass where it has one) and the still-interval detector
(:mod:`~tak_thermo_ros.core.records.still`). :func:`fit_plan` is the one place that decides
which fit a record gets:

- reference topics recorded: a **table** run (the references are the truth);
- none, and the unit rests in two or more orientations: a **hand-held** record
  (:mod:`~tak_thermo_ros.core.fit.handheld`);
- none, rests in one orientation and the unit moving between them (still less than
  :data:`STATIC_STILL_FRACTION` of the time, or turned away from them by more than
  :data:`~tak_thermo_ros.core.records.static_run.STATIC_TOLERANCE_DEG`): an **everyday**
  record, a pool of one (:mod:`~tak_thermo_ros.passes.pool`: a vehicle at rest near level,
  moving in between);
- none, one orientation or none found: a **static** run (gravity along the mean measured
  direction; the static path refuses a unit that moved);
- none, and the unit never rests: **moving**, nothing to fit.

A reference in one direction only (an imported static log's) makes a **static** run as well: it
holds one input per axis, so every scale is held, as without one.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from tak_thermo_ros.core.records.plausible import temperature_counts, temperature_counts_problem
from tak_thermo_ros.core.records.record import REFERENCE_LIMIT, TEMPERATURE_RANGE, ChannelRecord, DriverRecord
from tak_thermo_ros.core.records.static_run import STATIC_TOLERANCE_DEG
from tak_thermo_ros.core.records.still import ORIENTATION_DEG, StillDetector, StillIntervals, distinct_directions

MOVING_FRACTION = 0.5
"""A record without a still interval whose windows are still less than this share of the time never rests."""
STATIC_STILL_FRACTION = 0.8
"""A static run is still at least this share of its windows (a chamber's: 95-100 %); rests in one
orientation that take less are an everyday record's (a vehicle's: a third to two thirds)."""
TURNING_RATE = 1e-3
"""rad/s: a rate reference beyond this turns the unit (the Earth's rate is 7.3e-5)."""


class Plan(str, enum.Enum):
    """Which fit a record gets (:func:`fit_plan`)."""

    TABLE = 'table'
    STATIC = 'static'
    HANDHELD = 'handheld'
    EVERYDAY = 'everyday'
    MOVING = 'moving'


@dataclass(frozen=True)
class Stream:
    """One stream of a record: its topic, message count and mean rate (Hz; 0 when unknown)."""

    role: str
    topic: str
    count: int
    rate_hz: float


@dataclass(frozen=True)
class RecordSurvey:
    """What a record holds.

    :param kind: ``counts`` (the paper's codes) or ``imu`` (a driver).
    :param streams: the record's streams, main first.
    :param duration_s: from the first main stamp to the last.
    :param temperature: lowest and highest plausible temperature (C, or codes), or ``None``.
    :param still: the still intervals of the main stream.
    :param reference_directions: distinct directions of the recorded specific-force reference
        (``None`` without one).
    :param mean: ``(3,)`` the mean of the accelerometer's finite samples (a static run's reference).
    :param samples: finite accelerometer samples in that mean.
    :param shared_stamps: both sensors in every message (``False``: a record whose sensors come at
        their own stamps, such as a flight log; the rests are then found on the accelerometer alone).
    """

    kind: str
    streams: tuple[Stream, ...]
    duration_s: float
    temperature: tuple[float, float] | None
    still: StillIntervals
    reference_directions: int | None
    mean: np.ndarray
    samples: int
    shared_stamps: bool = True
    temperature_problem: str | None = None
    """Why a driver's temperatures are not degrees Celsius (:mod:`~.plausible`), or ``None``."""
    rate_reference_moves: bool = False
    """A recorded rate reference that turns (a rate table), not zero or the Earth's rate alone."""

    @property
    def has_reference(self) -> bool:
        """Whether a specific-force reference was recorded (a table run)."""
        return self.reference_directions is not None

    @property
    def temperature_span(self) -> float:
        """Highest minus lowest temperature (0 without one)."""
        return 0.0 if self.temperature is None else self.temperature[1] - self.temperature[0]

    @property
    def plan(self) -> Plan:
        """:func:`fit_plan` of this record."""
        return fit_plan(self)


def fit_plan(survey: RecordSurvey) -> Plan:
    """The one decision of which fit a record gets (see the module's description)."""
    if survey.has_reference:
        return Plan.TABLE if survey.reference_directions != 1 or survey.rate_reference_moves else Plan.STATIC
    still = survey.still
    if still.orientations() >= 2:
        return Plan.HANDHELD
    if len(still) and (still.still_fraction < STATIC_STILL_FRACTION or still.moved_deg > STATIC_TOLERANCE_DEG):
        return Plan.EVERYDAY
    if not len(still) and still.windows and still.still_fraction < MOVING_FRACTION:
        return Plan.MOVING
    return Plan.STATIC


class SurveyCollector:
    """The numbers of a :class:`RecordSurvey`, gathered from a record's blocks in log order."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self.detector: StillDetector | None = None
        self.shared_stamps = True
        self.low = math.inf
        self.high = -math.inf
        self.temperatures = 0
        self.references: list[np.ndarray] = []
        self.reference_count = 0
        self.rate_references = 0
        self.rate_reference_max = 0.0
        self.mags = 0
        self.total = np.zeros(3)
        self.finite = 0
        self.unit_counts = [0, 0, 0, math.inf, -math.inf]  # plausible.temperature_counts, summed

    def add(self, block: ChannelRecord | DriverRecord) -> None:
        """One block as the record's reader gives it."""
        if isinstance(block, DriverRecord):
            if block.shared_stamps:
                stamps, values = block.stamp_ns, np.hstack([block.accel, block.gyro])
            else:  # the sensors at their own stamps: the rests from the accelerometer alone
                self.shared_stamps = False
                stamps, values = block.sensor_stamps('accel'), block.accel
            temperature, reference = block.temperature, block.reference
            self.rate_references += len(block.rate_reference_stamp_ns)
            rates = block.rate_reference[np.all(np.isfinite(block.rate_reference), axis=1)]
            if len(rates):
                self.rate_reference_max = max(self.rate_reference_max, float(np.linalg.norm(rates, axis=1).max()))
            self.mags += len(block.mag_stamp_ns)
        else:
            stamps, values = block.counts_stamp_ns, block.counts
            temperature, reference = block.temp_code, block.reference
        if self.detector is None:
            self.detector = StillDetector(channels=values.shape[1])
        if values.shape[1] == self.detector.channels:
            self.detector.push(stamps, values)
        finite = np.all(np.isfinite(values), axis=1)
        self.total += values[finite, :3].sum(axis=0)
        self.finite += int(np.count_nonzero(finite))
        low, high = TEMPERATURE_RANGE[self.kind]
        plausible = temperature[np.isfinite(temperature) & (temperature > low) & (temperature < high)]
        if len(plausible):
            self.low = min(self.low, float(plausible.min()))
            self.high = max(self.high, float(plausible.max()))
        self.temperatures += len(temperature)
        if self.kind == 'imu' and len(temperature):
            finite, implausible, kelvin, least, most = temperature_counts(temperature)
            counts = self.unit_counts
            self.unit_counts = [counts[0] + finite, counts[1] + implausible, counts[2] + kelvin,
                                min(counts[3], least), max(counts[4], most)]
        if len(reference):
            self.reference_count += len(reference)
            plausible_rows = np.all(np.isfinite(reference) & (np.abs(reference) < REFERENCE_LIMIT), axis=1)
            reference = reference[plausible_rows]
            norms = np.linalg.norm(reference, axis=1)
            ok = norms > 0.0
            directions = reference[ok] / norms[ok, None]
            if len(directions):
                kept = distinct_directions(np.vstack([*self.references, directions]), degrees=ORIENTATION_DEG)
                self.references = [np.vstack([*self.references, directions])[kept]]

    def finish(self, streams: tuple[tuple[str, str, int], ...]) -> RecordSurvey:
        """The survey; ``streams``: ``(role, topic, messages)`` from the record's index, main first."""
        still = (self.detector or StillDetector(channels=3)).finish()
        duration = still.duration_s
        listed = tuple(Stream(role, topic, count, count / duration if duration > 0.0 else 0.0)
                       for role, topic, count in streams if count)
        return RecordSurvey(
            kind=self.kind, streams=listed, duration_s=duration,
            temperature=(self.low, self.high) if self.low <= self.high else None, still=still,
            reference_directions=(len(self.references[0]) if self.references else 0) if self.reference_count else None,
            mean=self.total / self.finite if self.finite else np.zeros(3), samples=self.finite,
            shared_stamps=self.shared_stamps, temperature_problem=temperature_counts_problem(*self.unit_counts),
            rate_reference_moves=self.rate_reference_max > TURNING_RATE)
