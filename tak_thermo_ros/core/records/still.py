"""Still intervals: where a unit turned by hand rested, found from the record itself.

The record is cut into short windows of consecutive samples (:data:`WINDOW_S`, never across a
gap in the stamps). For each window and channel (the accelerometer's three, the gyroscope's
three when there is one): the variance about the window's mean, and half the mean square of
successive differences. The noise of each channel is the mean of the latter over the quiet
windows (those whose variance stays within ten times the channel's tenth percentile): slow
drift cancels in a difference, so this is the channel's white noise whatever share of the
record moves (never below half a quantisation step: a quantised channel at rest may dither
between two adjacent levels). A window is *still* when on every channel its variance stays below the noise
times the chi-square quantile of :data:`FALSE_MOVE_PROBABILITY` (the threshold follows the
data's own noise, as imu_tk's follows its initial rest), and its specific force points one way
(:data:`AGREEMENT`). Consecutive still windows form a run
while each window's mean agrees with the run's recent mean within :data:`MEAN_SIGMAS` standard
errors on every channel (a slow tilt, or a knock that leaves the unit in a new pose, starts a
new run). A run loses its first and last window (the start and end of a turn are slow), and
what remains is a still interval when it lasts :data:`MIN_STILL_S` or more.

The detector takes the record in blocks (:meth:`StillDetector.push`) and keeps one small row
per window, so a long record costs memory in proportion to its duration over the window.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

WINDOW_S = 0.5
"""Length of a detection window, seconds (at least :data:`MIN_WINDOW_SAMPLES` samples)."""
MIN_WINDOW_SAMPLES = 8
"""Fewest samples in a window (a variance needs some)."""
MIN_STILL_S = 2.0
"""Shortest still interval kept, seconds (after its edge windows are left out)."""
FALSE_MOVE_PROBABILITY = 1e-4
"""Chance that a still window's variance exceeds the threshold on one channel by noise alone."""
MEAN_SIGMAS = 5.0
"""A still window joins the current run when its mean lies within this many standard errors of the run's."""
RECENT_WINDOWS = 8
"""The run's mean that a new window is compared with: over at most this many windows before it."""
GAP_PERIODS = 5.0
"""A step between stamps longer than this many typical periods is a gap: no window and no interval crosses it."""
AGREEMENT = 0.95
"""A still window's specific force points one way: its mean's magnitude is at least this share of
the mean magnitude of its samples (a unit turning, or samples that are not a continuous signal,
fail it whatever their noise)."""
ORIENTATION_DEG = 10.0
"""Two still intervals whose gravity directions lie further apart than this are two orientations."""
FACE_DEG = 30.0
"""A face (+x, -x, ... up) counts as seen when a still interval's up direction lies within this of it."""
FACES = ('+x', '-x', '+y', '-y', '+z', '-z')


@dataclass(frozen=True)
class StillIntervals:
    """The still intervals of a record and how they were found.

    :param start_ns: ``(k,)`` stamp of each interval's first sample.
    :param end_ns: ``(k,)`` stamp of each interval's last sample.
    :param samples: ``(k,)`` samples in each interval.
    :param mean: ``(k, c)`` each interval's mean per channel (accelerometer first).
    :param noise: ``(c,)`` the white noise per channel (standard deviation of one sample).
    :param window_samples: samples per detection window.
    :param period_s: the typical step between stamps, seconds.
    :param windows: detection windows in the record.
    :param still_windows: those found still.
    :param gaps: ``(g, 2)`` stamps before and after each gap.
    :param first_ns: the record's first stamp (``None``: no sample).
    :param last_ns: its last stamp.
    :param count: samples read.
    :param short_allan: ``(k, 2, c)`` per interval and channel the sums of the Allan variance's terms
        at one sample (half the squared step between successive samples) and at one window (half the
        squared step between the means of successive windows); ``short_terms``: ``(k, 2)`` how many
        terms each sum holds. From every sample of the interval (not only those a fit keeps): the
        white noise within the rests (:mod:`tak_thermo_ros.core.noise.rests`). ``None``: not gathered.
    :param moved_deg: the largest angle between a window's mean specific force and the intervals' mean
        up direction, degrees (0 without an interval): how far the unit turned away from its rests.
    """

    start_ns: np.ndarray
    end_ns: np.ndarray
    samples: np.ndarray
    mean: np.ndarray
    noise: np.ndarray
    window_samples: int
    period_s: float
    windows: int
    still_windows: int
    gaps: np.ndarray
    first_ns: int | None
    last_ns: int | None
    count: int
    short_allan: np.ndarray | None = None
    short_terms: np.ndarray | None = None
    moved_deg: float = 0.0

    def __len__(self) -> int:
        return len(self.start_ns)

    @property
    def duration_s(self) -> float:
        """From the first stamp to the last, seconds."""
        return 0.0 if self.first_ns is None else (self.last_ns - self.first_ns) * 1e-9  # type: ignore[operator]

    @property
    def interval_s(self) -> np.ndarray:
        """``(k,)`` each interval's length, seconds."""
        return (self.end_ns - self.start_ns) * 1e-9

    @property
    def still_fraction(self) -> float:
        """The share of the record's windows found still (0 without windows)."""
        return self.still_windows / self.windows if self.windows else 0.0

    @property
    def directions(self) -> np.ndarray:
        """``(k, 3)`` each interval's measured up direction (its mean specific force, normalised)."""
        accel = self.mean[:, :3]
        norms = np.linalg.norm(accel, axis=1, keepdims=True)
        return accel / np.where(norms > 0.0, norms, 1.0)

    def orientations(self) -> int:
        """How many distinct orientations the intervals hold (up directions :data:`ORIENTATION_DEG` apart)."""
        return len(distinct_directions(self.directions))

    def faces(self) -> tuple[str, ...]:
        """Each face up (``+x``, ``-x``, ...) that some interval's up direction lies within :data:`FACE_DEG` of."""
        if not len(self):
            return ()
        cosine = math.cos(math.radians(FACE_DEG))
        axes = np.vstack([np.eye(3), -np.eye(3)])[[0, 3, 1, 4, 2, 5]]
        seen = (self.directions @ axes.T).max(axis=0) >= cosine
        return tuple(face for face, ok in zip(FACES, seen) if ok)

    def index_of(self, stamp_ns: np.ndarray) -> np.ndarray:
        """``(n,)`` the interval each stamp lies in, ``-1`` outside every interval."""
        stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
        position = np.searchsorted(self.start_ns, stamp_ns, side='right') - 1
        inside = (position >= 0) & (stamp_ns <= self.end_ns[np.maximum(position, 0)]) if len(self) else \
            np.zeros(len(stamp_ns), dtype=bool)
        return np.where(inside, position, -1)


def distinct_directions(directions: np.ndarray, *, degrees: float = ORIENTATION_DEG) -> list[int]:
    """Indices of directions each more than ``degrees`` from every one kept before it (greedy, in order)."""
    cosine = math.cos(math.radians(degrees))
    kept: list[int] = []
    for index, direction in enumerate(np.asarray(directions, dtype=float)):
        if not kept or float(np.max(directions[kept] @ direction)) < cosine:
            kept.append(index)
    return kept


def _quantile(dof: int) -> float:
    """``chi2.ppf(1 - FALSE_MOVE_PROBABILITY, dof) / dof``: the threshold on a variance over its expectation."""
    from scipy.special import chdtri
    return float(chdtri(dof, FALSE_MOVE_PROBABILITY) / dof)


class StillDetector:
    """Still intervals of a record read in blocks (see the module's description).

    :param channels: values per sample (3: an accelerometer; 6: with a gyroscope).
    :param window_s: the detection window, seconds.
    :param min_still_s: the shortest still interval kept, seconds.
    """

    def __init__(self, *, channels: int = 6, window_s: float = WINDOW_S, min_still_s: float = MIN_STILL_S) -> None:
        self.channels = channels
        self.window_s = window_s
        self.min_still_s = min_still_s
        self.window_samples = 0
        self.period_s = 0.0
        self.count = 0
        self._first: int | None = None
        self._last: int | None = None
        self._pending_stamps = np.zeros(0, dtype=np.int64)
        self._pending = np.zeros((0, 0))
        self._rows: list[np.ndarray] = []
        self._stamps: list[np.ndarray] = []
        self._gaps: list[tuple[int, int]] = []
        self._after_gap = False
        self._quantum = np.full(channels, np.inf)

    def push(self, stamp_ns: np.ndarray, values: np.ndarray) -> None:
        """Add samples ``(k,)`` stamps and ``(k, c)`` values in log order.

        A sample that is not finite, or not stamped later than every sample before it, is left out.
        """
        stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
        values = np.asarray(values, dtype=float)
        if not len(stamp_ns):
            return
        before = np.iinfo(np.int64).min if self._last is None else self._last
        latest = np.maximum.accumulate(np.concatenate([[before], stamp_ns]))[:-1]
        keep = (stamp_ns > latest) & np.all(np.isfinite(values), axis=1)
        stamp_ns, values = stamp_ns[keep], values[keep]
        if not len(stamp_ns):
            return
        self.count += len(stamp_ns)
        self._first = int(stamp_ns[0]) if self._first is None else self._first
        self._last = int(stamp_ns[-1])
        if len(self._pending_stamps):
            stamp_ns = np.concatenate([self._pending_stamps, stamp_ns])
            values = np.vstack([self._pending, values])
        if not self.window_samples:
            steps = np.diff(stamp_ns)
            steps = steps[steps > 0]
            if len(steps) < 2:
                self._pending_stamps, self._pending = stamp_ns, values
                return
            self.period_s = float(np.median(steps)) * 1e-9
            self.window_samples = max(MIN_WINDOW_SAMPLES, int(round(self.window_s / self.period_s)))
        self._windows(stamp_ns, values)

    def _windows(self, stamp_ns: np.ndarray, values: np.ndarray) -> None:
        """Cut whole windows out of the samples (none across a gap); keep the rest for the next block."""
        limit = int(GAP_PERIODS * self.period_s * 1e9)
        breaks = np.flatnonzero(np.diff(stamp_ns) > limit)
        starts = np.concatenate([[0], breaks + 1])
        ends = np.concatenate([breaks + 1, [len(stamp_ns)]])
        w = self.window_samples
        for segment, (start, end) in enumerate(zip(starts, ends)):
            if segment:
                self._gaps.append((int(stamp_ns[start - 1]), int(stamp_ns[start])))
                self._after_gap = True  # the partial window before the gap is left out
            whole = (end - start) // w
            if whole:
                self._add_rows(stamp_ns[start:start + whole * w], values[start:start + whole * w])
        self._pending_stamps = stamp_ns[starts[-1] + whole * w:].copy()
        self._pending = values[starts[-1] + whole * w:].copy()

    def _add_rows(self, stamp_ns: np.ndarray, values: np.ndarray) -> None:
        """One row per window: first and last stamp, after-a-gap flag, mean, variance, difference variance."""
        w = self.window_samples
        channels = values.shape[1]
        shaped = values.reshape(-1, w, channels)
        mean = shaped.mean(axis=1)
        variance = shaped.var(axis=1, ddof=1)
        steps = np.abs(np.diff(shaped, axis=1))
        differences = 0.5 * np.mean(steps ** 2, axis=1)
        # The smallest step between successive samples: a quantised channel's resolution.
        nonzero = np.where(steps > 0.0, steps, np.inf).min(axis=(0, 1))
        self._quantum = np.minimum(self._quantum[:channels], nonzero)
        magnitude = np.linalg.norm(shaped[:, :, :3], axis=2).mean(axis=1, keepdims=True)
        stamps = stamp_ns.reshape(-1, w)
        gap = np.zeros((len(mean), 1))
        gap[0, 0] = 1.0 if self._after_gap else 0.0
        self._after_gap = False
        self._stamps.append(np.column_stack([stamps[:, 0], stamps[:, -1]]))
        self._rows.append(np.hstack([gap, mean, variance, differences, magnitude]))

    def finish(self) -> StillIntervals:
        """The still intervals of everything pushed."""
        rows = np.vstack(self._rows) if self._rows else np.zeros((0, 2 + 3 * self.channels))
        stamps = np.vstack(self._stamps) if self._stamps else np.zeros((0, 2), dtype=np.int64)
        channels = (rows.shape[1] - 2) // 3
        first, last = stamps[:, 0], stamps[:, 1]
        after_gap = rows[:, 0] > 0.5
        mean = rows[:, 1:1 + channels]
        variance = rows[:, 1 + channels:1 + 2 * channels]
        differences = rows[:, 1 + 2 * channels:1 + 3 * channels]
        agree = np.linalg.norm(mean[:, :3], axis=1) >= AGREEMENT * rows[:, -1]
        # A still channel quantised coarser than its noise dithers between two adjacent levels:
        # its standard deviation reaches half a step, which its difference variance can miss.
        quantum = self._quantum[:channels] if len(self._quantum) >= channels else np.full(channels, np.inf)
        noise = np.maximum(_channel_noise(variance, differences), np.where(np.isfinite(quantum), 0.5 * quantum, 0.0))
        if len(rows):  # a constant channel: its variance is the arithmetic's rounding, not zero
            noise = np.maximum(noise, 16.0 * np.spacing(np.abs(mean).max(axis=0)))
        w = self.window_samples
        still = np.zeros(len(rows), dtype=bool)
        if len(rows):
            still = np.all(variance <= noise ** 2 * _quantile(w - 1), axis=1) & agree
        runs = self._runs(still, after_gap, mean, noise)
        intervals = []
        for run in runs:
            run = run[1:-1]  # leave the edges of a turn out
            if not len(run) or (last[run[-1]] - first[run[0]]) * 1e-9 < self.min_still_s:
                continue
            # The Allan variance's terms at one sample and at one window (successive windows are adjacent)
            short = np.vstack([differences[run].sum(axis=0) * (w - 1),
                               0.5 * np.sum(np.diff(mean[run], axis=0) ** 2, axis=0)])
            intervals.append((first[run[0]], last[run[-1]], len(run) * w, mean[run].mean(axis=0), short,
                              (len(run) * (w - 1), len(run) - 1)))
        gaps = np.array(self._gaps, dtype=np.int64).reshape(-1, 2)
        moved = 0.0
        if intervals:
            up = np.mean([i[3][:3] / max(float(np.linalg.norm(i[3][:3])), 1e-300) for i in intervals], axis=0)
            norms = np.linalg.norm(mean[:, :3], axis=1) * max(float(np.linalg.norm(up)), 1e-300)
            cosine = np.clip(mean[:, :3] @ up / np.where(norms > 0.0, norms, np.inf), -1.0, 1.0)
            moved = float(np.degrees(np.arccos(cosine)).max())
        return StillIntervals(
            start_ns=np.array([i[0] for i in intervals], dtype=np.int64),
            end_ns=np.array([i[1] for i in intervals], dtype=np.int64),
            samples=np.array([i[2] for i in intervals], dtype=np.int64),
            mean=np.array([i[3] for i in intervals]).reshape(-1, channels),
            noise=noise, window_samples=w, period_s=self.period_s, windows=len(rows),
            still_windows=int(np.count_nonzero(still)), gaps=gaps, first_ns=self._first, last_ns=self._last,
            count=self.count, short_allan=np.array([i[4] for i in intervals]).reshape(-1, 2, channels),
            short_terms=np.array([i[5] for i in intervals], dtype=np.int64).reshape(-1, 2), moved_deg=moved)

    def _runs(self, still: np.ndarray, after_gap: np.ndarray, mean: np.ndarray, noise: np.ndarray) -> list[np.ndarray]:
        """Runs of consecutive still windows whose means agree (indices of windows)."""
        w = self.window_samples
        runs: list[list[int]] = []
        current: list[int] = []
        for index in range(len(still)):
            if not still[index] or after_gap[index]:
                if len(current):
                    runs.append(current)
                current = [index] if still[index] else []
                continue
            if current:
                recent = mean[current[-RECENT_WINDOWS:]]
                error = noise * math.sqrt(1.0 / w + 1.0 / (w * len(recent)))
                if np.any(np.abs(mean[index] - recent.mean(axis=0)) > MEAN_SIGMAS * np.maximum(error, 1e-300)):
                    runs.append(current)
                    current = []
            current.append(index)
        if current:
            runs.append(current)
        return [np.array(run) for run in runs]


def _channel_noise(variance: np.ndarray, differences: np.ndarray) -> np.ndarray:
    """The white noise per channel: the mean difference variance over the quiet windows, as a standard deviation."""
    if not len(variance):
        return np.zeros(variance.shape[1])
    low = np.percentile(differences, 10.0, axis=0)
    quiet = np.all(variance <= 10.0 * np.maximum(low, 1e-300), axis=1)
    if not quiet.any():
        quiet = np.ones(len(variance), dtype=bool)
    return np.sqrt(differences[quiet].mean(axis=0))


def find_still(stamp_ns: np.ndarray, values: np.ndarray, **options) -> StillIntervals:
    """The still intervals of a record held in memory (:class:`StillDetector` in one block)."""
    detector = StillDetector(channels=np.asarray(values).shape[1], **options)
    detector.push(stamp_ns, values)
    return detector.finish()
