"""The calibration watch over a recorded run: the node's own code on the record's messages, the node's verdict.

``tak_calib validate REC --params P`` replays the record as ``tak_calib play`` publishes it to
the node (block by block, in stamp order, the temperature before the Imu at equal stamps)
through :class:`~tak_thermo_ros.core.link.online.OnlineCompensator` with the watch on: the
same corrections, the same rests, the same tests, hence the node's verdict. The record is read
once, in bounded memory (the watch keeps a window of samples and a bounded list of rests).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from tak_thermo_ros.core.link.correction import NOT_PROVIDED, OutOfRange
from tak_thermo_ros.core.link.model import InputKind, UnitCalibration
from tak_thermo_ros.core.link.online import OnlineCompensator
from tak_thermo_ros.core.link.online_rules import StaleTemperature
from tak_thermo_ros.core.link.watch import CalibrationWatch, WatchSettings, watch_unavailable
from tak_thermo_ros.core.records.record import DriverRecord
from tak_thermo_ros.core.records.stamps import NANOSECONDS
from tak_thermo_ros.passes.run import StreamOptions

if TYPE_CHECKING:
    from tak_thermo_ros.formats.records import Record


@dataclass(frozen=True)
class Watched:
    """What the watch said of a record.

    :param watch: the watch at the end (its verdict, findings, figures), or ``None`` when it was off.
    :param off: why it was off, else ``''``.
    :param messages: Imu messages replayed; ``published`` those the node would have published.
    """

    watch: CalibrationWatch | None
    off: str
    messages: int
    published: int

    def lines(self) -> list[str]:
        """What ``validate`` prints: ``calibration watch (the node's, on this record): ...``."""
        if self.watch is None:
            return [f'calibration watch: {self.off}']
        return [f'calibration watch over {self.messages} Imu messages (the node\'s code):', *self.watch.lines()]


def watch_bag(record: Record, unit: UnitCalibration, options: StreamOptions, *, settings: WatchSettings,
              out_of_range: OutOfRange = OutOfRange.CLAMP) -> Watched:
    """The node's watch over a driver record (the node's temperature timeout: none; stale temperatures held)."""
    from tak_thermo_ros.formats.bag import imu_messages, play_order
    reason = watch_unavailable(unit)
    if reason:
        return Watched(None, f'off: {reason}', 0, 0)
    streams = record.streams
    if streams.kind is not InputKind.IMU:
        return Watched(None, 'off: the watch takes a driver\'s Imu', 0, 0)
    core = OnlineCompensator(unit, out_of_range=out_of_range, stale_temperature=StaleTemperature.HOLD,
                             temp_timeout_s=1e9, temp_topic=options.topics.temperature, watch=settings)
    first: int | None = None
    for block in record.blocks(kind=streams.kind, references=False, progress=options.progress):
        assert isinstance(block, DriverRecord)
        messages = imu_messages(block)
        names = sorted(block.aux)
        events = play_order(block.temp_stamp_ns, messages.stamp_ns, *(block.aux[name][0] for name in names))
        values = np.hstack([block.accel[messages.accel_row] if len(block.accel) else np.zeros((0, 3)),
                            block.gyro[messages.gyro_row] if len(block.gyro) else np.zeros((0, 3))]).tolist()
        accel_mark = np.where(messages.accel_row >= 0, 0.0, NOT_PROVIDED).tolist()
        gyro_mark = np.where(messages.gyro_row >= 0, 0.0, NOT_PROVIDED).tolist()
        for stamp, stream, row in events:
            first = stamp if first is None else first
            now = (stamp - first) * 1e-9
            if stream == 0:
                core.process_temperature(float(block.temperature[row]), now)
            elif stream == 1:
                core.process_values(*divmod(stamp, NANOSECONDS), tuple(values[row]), now, accel_mark[row],
                                    gyro_mark[row])
            else:
                name = names[stream - 2]
                core.process_signal(name, float(block.aux[name][1][row]), now)
            if core.watch is not None and core.watch.pending:
                core.judge_watch()
    core.judge_watch(finish=True)
    return Watched(core.watch, core.watch_off, core.received, core.published)
