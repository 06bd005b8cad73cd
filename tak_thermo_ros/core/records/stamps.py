"""Header stamps: nanoseconds and seconds, and the stamp rule every reader and the node apply.

A stamp is int64 nanoseconds (:data:`NANOSECONDS` per second); :func:`seconds_from_ns` gives
the same floats offline as :func:`seconds` gives per message in the node. The stamp rule
(:func:`stamp_kept`, :func:`stamp_problems`) keeps a message whose stamp goes on from the last
kept one and drops the others, each for a reason of :data:`STAMP_DROP_REASONS`; ``align()``
(:mod:`tak_thermo_ros.core.records.record`) and the node's online pipeline share it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NANOSECONDS = 1_000_000_000
STAMP_DROP_REASONS = ('duplicate_stamp', 'time_backwards', 'stamp_jump')
"""Why a sample is left out for its header stamp, checked before :data:`~.drops.DROP_REASONS`."""
STAMP_JUMP_S = 10.0
"""A forward step of the header stamp from one message to the next that is taken as the stream
going on, whatever the stream: up to 10 s (a step beyond both this and :data:`STAMP_JUMP_STEPS`
steps of the stream is a ``stamp_jump``: a message stamped in the future, or the first after a
pause or a clock step, which the next message then confirms)."""
STAMP_JUMP_NS = int(STAMP_JUMP_S * NANOSECONDS)
STAMP_JUMP_STEPS = 100
"""A forward step also goes on when it is at most this many steps of the stream (the last kept
message's advance over the kept one before it): a stream with a message every 30 s goes on 30 s
at a time."""
_STEP_CAP_NS = np.iinfo(np.int64).max // STAMP_JUMP_STEPS
"""Steps beyond this make a limit beyond any step (stamps are within +-2**31 s): capped, for int64."""


def seconds_from_ns(stamp_ns: np.ndarray) -> np.ndarray:
    """Float seconds ``sec + nanosec * 1e-9`` of int64 nanosecond stamps, ``(k,)``.

    The same floats as :func:`seconds` gives per message, so that model terms with memory see
    identical stamps offline and in the node.
    """
    stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
    sec = stamp_ns // NANOSECONDS
    return sec.astype(float) + (stamp_ns - sec * NANOSECONDS).astype(float) * 1e-9


def seconds(sec: int, nanosec: int) -> float:
    """Float seconds of one ``builtin_interfaces/Time`` (``sec``, ``nanosec``)."""
    return float(sec) + float(nanosec) * 1e-9


def ns_from_seconds(time_s: np.ndarray) -> np.ndarray:
    """Int64 nanosecond stamps ``(k,)`` of float seconds, rounded to the nanosecond."""
    return np.round(np.asarray(time_s, dtype=float) * NANOSECONDS).astype(np.int64)


def stamp_problem(step_ns: int) -> str:
    """The reason a message whose stamp is ``step_ns`` after the previous message's is dropped.

    Only asked of a message :func:`stamp_kept` refuses: ``duplicate_stamp`` (equal),
    ``time_backwards`` (earlier) or ``stamp_jump`` (later by more than :func:`step_limit`).
    """
    if step_ns == 0:
        return 'duplicate_stamp'
    return 'time_backwards' if step_ns < 0 else 'stamp_jump'


def step_limit(stream_step_ns: int | None) -> int | None:
    """The largest forward step that goes on, in a stream stepping ``stream_step_ns``.

    :data:`STAMP_JUMP_S`, or :data:`STAMP_JUMP_STEPS` steps of the stream when more; ``None`` (no
    limit) while the stream's step is unknown (one message kept so far).
    """
    if stream_step_ns is None:
        return None
    return max(STAMP_JUMP_NS, STAMP_JUMP_STEPS * min(stream_step_ns, _STEP_CAP_NS))


@dataclass(frozen=True)
class StampHistory:
    """What the stamp rule knows of the messages before: for a run read in blocks, and the node.

    :param previous_ns: the previous message's stamp (whatever became of it).
    :param kept_ns: the stamp of the last message kept, or ``None``.
    :param stream_step_ns: the stream's step: the step by which the last kept message went on
        (:func:`going_on_step`, > 0), or ``None`` while unknown (one message kept so far).
    :param before_ns: the stamp of the message before the previous one (whatever became of it),
        or ``None``.
    """

    previous_ns: int
    kept_ns: int | None = None
    stream_step_ns: int | None = None
    before_ns: int | None = None

    def after(self, stamp_ns: int, kept: bool) -> StampHistory:
        """The history once a message stamped ``stamp_ns`` is kept, or dropped."""
        if not kept:
            return StampHistory(stamp_ns, self.kept_ns, self.stream_step_ns, self.previous_ns)
        return StampHistory(stamp_ns, stamp_ns, going_on_step(stamp_ns, self), self.previous_ns)


def going_on_step(stamp_ns: int, history: StampHistory | None) -> int | None:
    """The step by which a message stamped ``stamp_ns`` goes on, or ``None`` when it does not (dropped).

    From the previous message's stamp (whatever became of that one) when it goes on from it, else,
    when the previous one was dropped, from the one before it (whatever became of that one), else
    from the last kept message's: later by
    more than 0 and at most :func:`step_limit` of the stream's step (any forward step while that
    is unknown: one message kept so far). The step is then the stream's step: a lone message
    stamped far ahead is dropped and sets nothing, and the message after it goes on from the one
    before it.

    :param history: what is known of the messages before, ``None`` for the first message (kept,
        with no step).
    """
    if history is None:
        return None
    limit = step_limit(history.stream_step_ns)
    # the message before the previous one counts when the previous one was dropped (not the last kept)
    before = history.before_ns if history.previous_ns != history.kept_ns else None
    for start in (history.previous_ns, before, history.kept_ns):
        if start is not None:
            step = stamp_ns - start
            if 0 < step and (limit is None or step <= limit):
                return step
    return None


def stamp_kept(stamp_ns: int, history: StampHistory | None) -> bool:
    """The stamp rule, one message at a time (the node's, and :func:`stamp_problems`' own).

    A message is kept when its header stamp is later than the previous message's (whatever
    became of that one), or than the last kept message's, by at most :func:`step_limit` (10 s,
    or 100 steps of the stream; the stream's step is the step by which the last kept message
    went on, :func:`going_on_step`). So a stream 1, 2, 3, 10, 4, 5 s drops the 4 (the 10 was
    kept); a stream 1, 2, 3, 3603, 4, 5 s drops the 3603 alone (stamped an hour ahead), and the
    4 goes on from the 3, wherever the outlier comes (the second or third message after a pause
    too); after a real jump (1, 2, 3, 3603, 3604, ...: a pause or a clock step) the first message
    after it is dropped and the next one, going on from it, is kept; a stream of a message every
    30 s goes on. The first step of a stream is not judged (its step is not known yet): an
    outlier as the second message ever is kept, and the good message after it dropped.

    :param history: what is known of the messages before, ``None`` for the first message.
    """
    return history is None or going_on_step(stamp_ns, history) is not None


def stamp_problems(stamp_ns: np.ndarray, *, history: StampHistory | None = None
                   ) -> tuple[dict[str, np.ndarray], StampHistory | None]:
    """Masks ``(k,)`` per reason of :data:`STAMP_DROP_REASONS`, in bag (arrival) order; the history after.

    :func:`stamp_kept` on every message, vectorised: a stretch where each message steps forward
    by at most the limit its predecessor's step sets is kept whole; the messages around the others
    are taken one by one. The reason is :func:`stamp_problem`'s. The node applies the same rule
    per message.

    :param history: the messages before the first one (a run read in blocks), or ``None``.
    """
    stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
    count = len(stamp_ns)
    if not count:
        return {reason: np.zeros(0, dtype=bool) for reason in STAMP_DROP_REASONS}, history
    step = np.zeros(count, dtype=np.int64)
    step[1:] = stamp_ns[1:] - stamp_ns[:-1]
    if history is not None:
        step[0] = stamp_ns[0] - history.previous_ns
    # Where message i-1 went on from i-2 (both kept), the stream steps step[i-1]: i goes on when
    # 0 < step[i] <= step_limit(step[i-1]) (no limit after a step that was not forward).
    stream_step = np.zeros(count, dtype=np.int64)
    stream_step[1:] = step[:-1]
    limit = np.maximum(STAMP_JUMP_NS, STAMP_JUMP_STEPS * np.clip(stream_step, 0, _STEP_CAP_NS))
    goes_on = (step > 0) & ((stream_step <= 0) | (step <= limit))
    stops = np.flatnonzero(~goes_on)
    kept = np.zeros(count, dtype=bool)
    state = history
    index = 0
    while index < count:
        if (index > 0 and goes_on[index] and state.kept_ns == int(stamp_ns[index - 1])
                and state.stream_step_ns == (int(step[index - 1]) if step[index - 1] > 0 else None)):
            position = int(np.searchsorted(stops, index))
            stop = int(stops[position]) if position < len(stops) else count
            kept[index:stop] = True
            last = int(stamp_ns[stop - 1])
            state = StampHistory(last, last, int(step[stop - 1]), int(stamp_ns[stop - 2]))
            index = stop
            continue
        stamp = int(stamp_ns[index])
        kept[index] = stamp_kept(stamp, state)
        state = state.after(stamp, bool(kept[index])) if state is not None else StampHistory(stamp, stamp)
        index += 1
    dropped = ~kept
    return ({'duplicate_stamp': dropped & (step == 0), 'time_backwards': dropped & (step < 0),
             'stamp_jump': dropped & (step > 0)}, state)
