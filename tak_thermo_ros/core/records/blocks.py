"""Alignment of a run that arrives in blocks, the held streams carried across block edges; its evenly spread subsample.

A bag is read in log order, one block of main-stream messages (counts, or a driver's Imu) at
a time, together with the temperature and reference messages logged in between.
:func:`align_block` aligns one block by :func:`~tak_thermo_ros.core.records.record.align` itself, on a
small record made of the carried state and the block: the last held temperature and reference
messages (and the reference's last change, for ``settle_time_s``), plus the tail of main
samples whose held values may still arrive (a sample is aligned once a temperature, and a
reference where there is one, stamped at or after it has been read, or once more than
``max_pending`` samples wait). Concatenating the blocks' results equals ``align`` of the whole
record when each stream's stamps do not go backwards across block edges and no held message
is logged more than ``max_pending`` main samples after a main sample stamped later than it.

Main's reliability rules hold across block edges: a temperature or reference message that
``align`` ignores is counted when read and never carried (``ignored_temp_codes``,
``ignored_references``); the stamp rule (``duplicate_stamp``, ``time_backwards``) compares a
block's first sample with the last one aligned before it; recorded signals (``aux``) are
carried like the temperature and waited for like it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from tak_thermo_ros.core.records.drops import reference_problems, temp_code_problems
from tak_thermo_ros.core.records.record import AlignedSamples, ChannelRecord, align, hold_last_index
from tak_thermo_ros.core.records.stamps import StampHistory
from tak_thermo_ros.errors import TakError

NEVER = np.iinfo(np.int64).max
"""Stamp of a placeholder reference that no sample reaches (no reference read yet)."""


def _empty_stamps() -> np.ndarray:
    return np.zeros(0, dtype=np.int64)


@dataclass(frozen=True)
class AlignState:
    """What one block's alignment hands to the next.

    :param temp_stamp_ns: carried temperature messages' stamps (log order).
    :param temp_code: their values.
    :param reference_stamp_ns: carried reference messages' stamps (log order).
    :param reference: ``(r, 3)`` their values.
    :param pending_stamp_ns: main samples read but not aligned yet.
    :param pending_values: ``(p, c)`` their values.
    :param rows_done: main samples aligned (kept or dropped) before the pending ones.
    :param last_stamp_ns: the largest stamp among the aligned main samples, or ``None``.
    :param temp_seen_ns: the largest temperature stamp read, or ``None``.
    :param reference_seen_ns: the largest reference stamp read, or ``None``.
    :param stamp_history: what the stamp rule (:func:`~tak_thermo_ros.core.records.stamps.stamp_kept`)
        knows of the main samples aligned so far (the last one's stamp and step, the last kept
        one's stamp), across block edges, or ``None``.
    :param aux: carried recorded signals, name -> ``(stamp_ns, values)`` (finite values only).
    :param aux_seen_ns: per recorded signal the largest stamp read, or ``None``.
    """

    temp_stamp_ns: np.ndarray = field(default_factory=_empty_stamps)
    temp_code: np.ndarray = field(default_factory=lambda: np.zeros(0))
    reference_stamp_ns: np.ndarray = field(default_factory=_empty_stamps)
    reference: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    pending_stamp_ns: np.ndarray = field(default_factory=_empty_stamps)
    pending_values: np.ndarray | None = None
    rows_done: int = 0
    last_stamp_ns: int | None = None
    temp_seen_ns: int | None = None
    reference_seen_ns: int | None = None
    stamp_history: StampHistory | None = None
    aux: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    aux_seen_ns: dict[str, int | None] = field(default_factory=dict)


def _count_problems(problems: dict[str, np.ndarray]) -> tuple[dict[str, int], np.ndarray]:
    """Counts per reason (reasons with none left out) and the mask of messages without a problem."""
    counts: dict[str, int] = {}
    usable = None
    for reason, mask in problems.items():
        usable = ~mask if usable is None else usable & ~mask
        if mask.any():
            counts[reason] = int(np.count_nonzero(mask))
    return counts, usable if usable is not None else np.zeros(0, dtype=bool)


def _carried_signal(stamps: np.ndarray, values: np.ndarray, horizon: int | None) -> np.ndarray:
    """The held value of a recorded signal at ``horizon`` plus those stamped later."""
    if horizon is None or not len(stamps):
        return _kept_held(stamps, None, [])
    held = int(hold_last_index(stamps, np.array([horizon], dtype=np.int64))[0])
    return _kept_held(stamps, horizon, [held])


def _latest(current: int | None, stamps: np.ndarray) -> int | None:
    if not len(stamps):
        return current
    top = int(stamps.max())
    return top if current is None else max(current, top)


def _kept_held(stamps: np.ndarray, horizon: int | None, extra: list[int]) -> np.ndarray:
    """Indices (log order) of held messages still needed after main samples up to ``horizon``."""
    if horizon is None:
        return np.arange(len(stamps))
    keep = stamps > horizon
    for index in extra:
        if index >= 0:
            keep[index] = True
    return np.flatnonzero(keep)


def _carried_temperatures(stamps: np.ndarray, values: np.ndarray, horizon: int | None) -> np.ndarray:
    """The held temperature at ``horizon`` (and the last finite one) plus those stamped later."""
    if horizon is None or not len(stamps):
        return _kept_held(stamps, None, [])
    at = np.array([horizon], dtype=np.int64)
    held = int(hold_last_index(stamps, at)[0])
    finite = np.flatnonzero(np.isfinite(values))
    position = int(hold_last_index(stamps[finite], at)[0]) if len(finite) else -1
    held_finite = int(finite[position]) if position >= 0 else -1
    return _kept_held(stamps, horizon, [held, held_finite])


def _carried_references(stamps: np.ndarray, values: np.ndarray, horizon: int | None) -> np.ndarray:
    """The held reference at ``horizon``, the message that last changed it, and later ones."""
    if horizon is None or not len(stamps):
        return _kept_held(stamps, None, [])
    held = int(hold_last_index(stamps, np.array([horizon], dtype=np.int64))[0])
    if held < 0:
        return _kept_held(stamps, horizon, [])
    order = np.argsort(stamps, kind='stable')
    position = int(np.flatnonzero(order == held)[0])
    sorted_values = values[order[:position + 1]]
    changed = np.ones(position + 1, dtype=bool)
    changed[1:] = np.any(sorted_values[1:] != sorted_values[:-1], axis=1)
    last_change = int(order[np.flatnonzero(changed)[-1]])
    return _kept_held(stamps, horizon, [held, last_change])


def align_block(state: AlignState, block: ChannelRecord, *, final: bool, use_reference: bool = True,
                reference_expected: bool = False, settle_time_s: float = 0.0, drop_saturated: bool = True,
                max_pending: int = 262_144, temperature_expected: bool = True) -> tuple[AlignedSamples, AlignState]:
    """Align one block of a run read in log order (see the module's description).

    :param state: what the previous block handed on (``AlignState()`` for the first block).
    :param block: the block's main samples and the held messages read with them.
    :param final: the last block: every pending sample is aligned.
    :param use_reference: hold the reference (as :func:`align`).
    :param reference_expected: the run has a reference stream (its topic holds messages):
        samples before its first message are dropped as ``before_first_reference``, also in
        blocks that carry no reference message yet.
    :param max_pending: at most this many main samples wait for their held values.
    :param temperature_expected: the pass reads a temperature (``False``: the record holds none,
        or the correction has no temperature terms): samples neither wait for one nor are left
        out before the first (they hold NaN there; see :func:`align`).
    :returns: the block's aligned samples (``rows`` index the whole stream, ``dropped``
        counts this block only) and the state for the next block.
    """
    width = block.counts.shape[1] if block.counts.ndim == 2 else 3
    pending_values = state.pending_values if state.pending_values is not None else np.zeros((0, width))
    stamps = np.concatenate([state.pending_stamp_ns, block.counts_stamp_ns])
    values = np.concatenate([pending_values, block.counts]) if len(block.counts) else pending_values
    # A temperature or reference message that align() would ignore (never hold) is counted
    # when it is read and not carried: the held values are the same without it.
    block_temp = np.asarray(block.temp_code, dtype=float)
    ignored_temp_codes, temp_usable = _count_problems(temp_code_problems(block_temp, block.input_kind))
    temp_stamps = np.concatenate([state.temp_stamp_ns, block.temp_stamp_ns[temp_usable]])
    temp_values = np.concatenate([state.temp_code, block_temp[temp_usable]])
    holding_reference = use_reference and reference_expected
    ignored_references: dict[str, int] = {}
    if holding_reference:
        block_reference = np.asarray(block.reference, dtype=float).reshape(-1, 3)
        ignored_references, reference_usable = _count_problems(reference_problems(block_reference))
        reference_stamps = np.concatenate([state.reference_stamp_ns, block.reference_stamp_ns[reference_usable]])
        reference_values = np.concatenate([state.reference, block_reference[reference_usable]])
    else:
        reference_stamps, reference_values = _empty_stamps(), np.zeros((0, 3))
    temp_seen = _latest(state.temp_seen_ns, block.temp_stamp_ns)
    reference_seen = _latest(state.reference_seen_ns, block.reference_stamp_ns)
    aux: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    aux_seen: dict[str, int | None] = {}
    for name in sorted(set(state.aux) | set(block.aux)):
        carried_stamps, carried_values = state.aux.get(name, (_empty_stamps(), np.zeros(0)))
        new_stamps, new_values = block.aux.get(name, (_empty_stamps(), np.zeros(0)))
        new_stamps = np.asarray(new_stamps, dtype=np.int64)
        new_values = np.asarray(new_values, dtype=float)
        finite = np.isfinite(new_values)
        aux[name] = (np.concatenate([carried_stamps, new_stamps[finite]]),
                     np.concatenate([carried_values, new_values[finite]]))
        aux_seen[name] = _latest(state.aux_seen_ns.get(name), new_stamps)

    ready = len(stamps)
    if not final:
        horizons = [*([temp_seen] if temperature_expected else []), *aux_seen.values()]
        if holding_reference:
            horizons.append(reference_seen)
        if not horizons:  # nothing held to wait for
            ready = len(stamps)
        elif any(h is None for h in horizons):
            ready = 0
        else:
            late = np.flatnonzero(stamps > min(horizons))  # type: ignore[type-var]
            ready = int(late[0]) if len(late) else len(stamps)
        ready = max(ready, len(stamps) - max_pending)

    if holding_reference and not len(reference_stamps):
        # a placeholder (finite, so not an ignored message) that no sample reaches
        part_reference_stamps = np.array([NEVER], dtype=np.int64)
        part_reference = np.zeros((1, 3))
    else:
        part_reference_stamps, part_reference = reference_stamps, reference_values
    part = ChannelRecord(counts_stamp_ns=stamps[:ready], counts=values[:ready], temp_stamp_ns=temp_stamps,
                         temp_code=temp_values, reference_stamp_ns=part_reference_stamps,
                         reference=part_reference, frame_id=block.frame_id, nominal_scale=block.nominal_scale,
                         input_kind=block.input_kind, aux=aux)
    aligned = align(part, use_reference=use_reference, settle_time_s=settle_time_s, drop_saturated=drop_saturated,
                    stamp_history=state.stamp_history, require_temperature=temperature_expected)
    rows = aligned.rows + state.rows_done if aligned.rows is not None else None
    aligned = replace(aligned, rows=rows, ignored_temp_codes=ignored_temp_codes,
                      ignored_references=ignored_references)
    if holding_reference and aligned.reference is None:
        aligned = replace(aligned, reference=np.zeros((len(aligned), 3)))

    horizon = state.last_stamp_ns if not ready else _latest(state.last_stamp_ns, stamps[:ready])
    temp_keep = _carried_temperatures(temp_stamps, temp_values, horizon)
    reference_keep = _carried_references(reference_stamps, reference_values, horizon)
    carried_aux = {}
    for name, (signal_stamps, signal_values) in aux.items():
        keep = _carried_signal(signal_stamps, signal_values, horizon)
        carried_aux[name] = (signal_stamps[keep], signal_values[keep])
    next_state = AlignState(temp_stamp_ns=temp_stamps[temp_keep], temp_code=temp_values[temp_keep],
                            reference_stamp_ns=reference_stamps[reference_keep],
                            reference=reference_values[reference_keep],
                            pending_stamp_ns=stamps[ready:].copy(), pending_values=values[ready:].copy(),
                            rows_done=state.rows_done + ready, last_stamp_ns=horizon,
                            temp_seen_ns=temp_seen, reference_seen_ns=reference_seen,
                            stamp_history=aligned.stamp_history,
                            aux=carried_aux, aux_seen_ns=aux_seen)
    return aligned, next_state


def add_counts(total: dict[str, int], part: dict[str, int]) -> None:
    """Add one block's counts per reason to ``total``."""
    for reason, count in part.items():
        total[reason] = total.get(reason, 0) + count


def concatenate(parts: list[AlignedSamples]) -> AlignedSamples:
    """The blocks' aligned samples as one, drop and ignored counts summed (for tests and small runs)."""
    dropped: dict[str, int] = {}
    ignored_temp_codes: dict[str, int] = {}
    ignored_references: dict[str, int] = {}
    for part in parts:
        add_counts(dropped, part.dropped)
        add_counts(ignored_temp_codes, part.ignored_temp_codes)
        add_counts(ignored_references, part.ignored_references)
    names = sorted({name for part in parts for name in part.aux})
    with_reference = [p for p in parts if p.reference is not None]
    reference = np.concatenate([p.reference for p in with_reference]) if with_reference else None
    width = parts[0].counts.shape[1] if parts else 3
    return AlignedSamples(stamp_ns=np.concatenate([p.stamp_ns for p in parts]) if parts else _empty_stamps(),
                          counts=np.concatenate([p.counts for p in parts]) if parts else np.zeros((0, width)),
                          temp_code=np.concatenate([p.temp_code for p in parts]) if parts else np.zeros(0),
                          reference=reference, dropped=dropped,
                          rows=np.concatenate([p.rows for p in parts]) if parts else _empty_stamps(),
                          ignored_temp_codes=ignored_temp_codes, ignored_references=ignored_references,
                          aux={name: np.concatenate([p.aux[name] for p in parts]) for name in names})


class BlockAligner:
    """:func:`align_block` with its state held: ``push`` each block, then ``finish``.

    :param reference_expected: the run has a reference stream (see :func:`align_block`).
    :param temperature_expected: the pass reads a temperature (see :func:`align_block`).
    """

    def __init__(self, *, use_reference: bool = True, reference_expected: bool = False,
                 settle_time_s: float = 0.0, drop_saturated: bool = True, max_pending: int = 262_144,
                 temperature_expected: bool = True) -> None:
        self.state = AlignState()
        self.options = dict(use_reference=use_reference, reference_expected=reference_expected,
                            settle_time_s=settle_time_s, drop_saturated=drop_saturated, max_pending=max_pending,
                            temperature_expected=temperature_expected)
        self.dropped: dict[str, int] = {}
        self.ignored_temp_codes: dict[str, int] = {}
        self.ignored_references: dict[str, int] = {}
        self.kept = 0
        self._template: ChannelRecord | None = None

    def push(self, block: ChannelRecord, *, final: bool = False) -> AlignedSamples:
        """Aligned samples that became ready with this block."""
        self._template = block
        aligned, self.state = align_block(self.state, block, final=final, **self.options)  # type: ignore[arg-type]
        add_counts(self.dropped, aligned.dropped)
        add_counts(self.ignored_temp_codes, aligned.ignored_temp_codes)
        add_counts(self.ignored_references, aligned.ignored_references)
        self.kept += len(aligned)
        return aligned

    def finish(self) -> AlignedSamples:
        """The samples still pending at the end of the run."""
        template = self._template
        width = template.counts.shape[1] if template is not None else 3
        empty = ChannelRecord(counts_stamp_ns=_empty_stamps(), counts=np.zeros((0, width)),
                              temp_stamp_ns=_empty_stamps(), temp_code=np.zeros(0),
                              frame_id=template.frame_id if template else '',
                              input_kind=template.input_kind if template else 'counts',
                              aux={name: (_empty_stamps(), np.zeros(0)) for name in (template.aux if template else {})})
        return self.push(empty, final=True)


def stride_for(messages: int, max_samples: int) -> int:
    """Every how many main-stream messages one is kept so that at most ``max_samples`` remain."""
    return max(1, math.ceil(messages / max(max_samples, 1)))


def every_nth(samples: AlignedSamples, stride: int) -> AlignedSamples:
    """The samples whose stream row is a multiple of ``stride`` (spread evenly over the run)."""
    if stride <= 1 or samples.rows is None:
        return samples
    keep = samples.rows % stride == 0
    return AlignedSamples(stamp_ns=samples.stamp_ns[keep], counts=samples.counts[keep],
                          temp_code=samples.temp_code[keep],
                          reference=None if samples.reference is None else samples.reference[keep],
                          dropped=samples.dropped, rows=samples.rows[keep],
                          ignored_temp_codes=samples.ignored_temp_codes, ignored_references=samples.ignored_references,
                          aux={name: values[keep] for name, values in samples.aux.items()})


class Subsample:
    """Every ``stride``-th stream row of the aligned blocks, copied into arrays that grow by doubling.

    One set of arrays for the whole run (about ``expected`` rows, known from the bag's index),
    filled block by block: no list of per-block pieces to join at the end, which would hold the
    subsample twice.
    """

    def __init__(self, stride: int, expected: int = 0) -> None:
        self.stride = stride
        self.usable = 0
        self.count = 0
        self.capacity = max(expected, 1)
        self.arrays: dict[str, np.ndarray] | None = None
        self.ignored_temp_codes: dict[str, int] = {}
        self.ignored_references: dict[str, int] = {}

    def __call__(self, aligned: AlignedSamples) -> None:
        self.usable += len(aligned)
        add_counts(self.ignored_temp_codes, aligned.ignored_temp_codes)
        add_counts(self.ignored_references, aligned.ignored_references)
        if not len(aligned):
            return
        part = every_nth(aligned, self.stride)
        columns = {'stamp_ns': part.stamp_ns, 'counts': part.counts, 'temp_code': part.temp_code,
                   'rows': part.rows if part.rows is not None else np.full(len(part), -1, dtype=np.int64),
                   **({} if part.reference is None else {'reference': part.reference}),
                   **{f'aux:{name}': values for name, values in part.aux.items()}}
        if self.arrays is None:
            self.arrays = {key: np.empty((self.capacity, *values.shape[1:]), dtype=values.dtype)
                           for key, values in columns.items()}
        if columns.keys() != self.arrays.keys():
            msg = 'a block of the run holds other streams than the first one (reference or recorded signals)'
            raise TakError(msg)
        end = self.count + len(part)
        if end > self.capacity:
            self.capacity = max(end, 2 * self.capacity)
            for key, values in self.arrays.items():
                grown = np.empty((self.capacity, *values.shape[1:]), dtype=values.dtype)
                grown[:self.count] = values[:self.count]
                self.arrays[key] = grown
        for key, values in columns.items():
            self.arrays[key][self.count:end] = values
        self.count = end

    def samples(self, dropped: dict[str, int]) -> AlignedSamples:
        """The subsample (views of the filled rows), the whole run's drop and ignored counts."""
        if self.arrays is None:
            return AlignedSamples(stamp_ns=np.zeros(0, dtype=np.int64), counts=np.zeros((0, 3)),
                                  temp_code=np.zeros(0), reference=None, dropped=dict(dropped),
                                  rows=np.zeros(0, dtype=np.int64), ignored_temp_codes=dict(self.ignored_temp_codes),
                                  ignored_references=dict(self.ignored_references))
        filled = {key: values[:self.count] for key, values in self.arrays.items()}
        return AlignedSamples(stamp_ns=filled['stamp_ns'], counts=filled['counts'], temp_code=filled['temp_code'],
                              reference=filled.get('reference'), dropped=dict(dropped), rows=filled['rows'],
                              ignored_temp_codes=dict(self.ignored_temp_codes),
                              ignored_references=dict(self.ignored_references),
                              aux={key[4:]: values for key, values in filled.items() if key.startswith('aux:')})
