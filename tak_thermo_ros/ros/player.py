"""``tak_calib play``: a recorded bag published into a running ``compensator``, its answers taken back.

The one module besides the node's (:mod:`tak_thermo_ros.ros.node`, :mod:`tak_thermo_ros.ros.main`)
that imports rclpy (the node never imports this one, so its import path stays free of the bag
reader). The bag is read block by block through its :class:`~tak_thermo_ros.formats.records.Record`,
as every command reads it, and each block's
messages are published in stamp order, a temperature before the Imu of the same stamp, paced
by the node's answers: before a temperature every message sent so far has been answered (so
the node corrects each message with the temperature in force when it was recorded), and at
most :data:`AHEAD` messages are ever unanswered (reliable QoS does not stop a faster publisher
from overrunning a history depth). A message the node does not answer within the answer
timeout (it dropped it: bad input, no temperature yet) is counted, and the play goes on.

A driver record whose sensors have their own stamps (Imu messages that carry one sensor, the
other marked absent by its covariance[0] = -1) is published as ``apply``'s writer writes it
(:func:`~tak_thermo_ros.formats.bag.imu_messages`): per message the sensors it carries, the
other marked absent. The reader keeps each sensor's samples and stamps, not the messages, so
the messages are rebuilt by that rule: two messages with one stamp, each carrying one sensor,
are published as one that carries both (as ``apply`` writes them; a bag ``apply`` or
``simulate`` wrote never holds such a pair, and is published message for message; a pair split
across two blocks stays two messages).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Vector3Stamped
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, MagneticField, Temperature

from tak_thermo_ros.core.link.correction import NOT_PROVIDED, NOT_PROVIDED_COVARIANCE
from tak_thermo_ros.core.link.model import InputKind
from tak_thermo_ros.core.records.stamps import NANOSECONDS
from tak_thermo_ros.errors import TakError
from tak_thermo_ros.formats.bag import ImuRows, imu_messages, play_order

if TYPE_CHECKING:
    from tak_thermo_ros.formats.records import Record

AHEAD = 50
"""At most this many messages sent and not yet answered."""
RELIABLE = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)


@dataclass
class Played:
    """What a play sent and received.

    :param sent: messages published per stream (``imu`` or ``counts``, ``temperature``, ``mag``).
    :param stamp_ns: ``(k,)`` stamps of the corrected Imu received, in arrival order.
    :param accel: ``(k, 3)`` their linear acceleration; ``gyro`` ``(k, 3)`` their angular velocity.
    :param accel_absent: ``(k,)`` whether each marks its accelerometer absent (covariance[0] = -1);
        ``gyro_absent`` its gyroscope.
    :param mag: ``(g, 3)`` the corrected magnetic field received (``mag_stamp_ns`` its stamps).
    :param unanswered: messages the node did not answer within the answer timeout.
    :param seconds: wall time of the play.
    :param not_played: recorded signals of the bag that are not published (``aux:`` topics).
    """

    sent: dict[str, int] = field(default_factory=dict)
    stamp_ns: list[int] = field(default_factory=list)
    accel: list[tuple[float, float, float]] = field(default_factory=list)
    gyro: list[tuple[float, float, float]] = field(default_factory=list)
    accel_absent: list[bool] = field(default_factory=list)
    gyro_absent: list[bool] = field(default_factory=list)
    mag_stamp_ns: list[int] = field(default_factory=list)
    mag: list[tuple[float, float, float]] = field(default_factory=list)
    unanswered: int = 0
    seconds: float = 0.0
    not_played: tuple[str, ...] = ()


def _stamp(message, stamp_ns: int) -> None:
    message.header.stamp.sec, message.header.stamp.nanosec = divmod(int(stamp_ns), NANOSECONDS)


def _stamp_of(message) -> int:
    return message.header.stamp.sec * NANOSECONDS + message.header.stamp.nanosec


class _Player:
    """The ROS side: publishers of the bag's input topics, subscribers of the node's outputs."""

    def __init__(self, kind: InputKind, topics, *, mag: bool) -> None:
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('tak_calib_play', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.kind = kind
        driver = kind is InputKind.IMU
        self.input_topic = topics.raw_imu if driver else topics.counts
        self.output_topic = topics.compensated_imu if driver else topics.imu
        self.input = self.node.create_publisher(Imu if driver else Vector3Stamped, self.input_topic, RELIABLE)
        self.temperature = self.node.create_publisher(
            Temperature, topics.temperature if driver else topics.temp_code, RELIABLE)
        self.played = Played()
        self.output = self.node.create_subscription(Imu, self.output_topic, self._on_imu, RELIABLE)
        self.mag = self.mag_output = None
        if mag:
            self.mag = self.node.create_publisher(MagneticField, topics.mag, RELIABLE)
            self.mag_output = self.node.create_subscription(MagneticField, topics.compensated_mag, self._on_mag,
                                                            RELIABLE)
        self.statuses: list[DiagnosticArray] = []
        self.diagnostics = self.node.create_subscription(DiagnosticArray, '/diagnostics', self.statuses.append, 10)

    def _on_imu(self, message: Imu) -> None:
        self.played.stamp_ns.append(_stamp_of(message))
        a, w = message.linear_acceleration, message.angular_velocity
        self.played.accel.append((a.x, a.y, a.z))
        self.played.gyro.append((w.x, w.y, w.z))
        self.played.accel_absent.append(message.linear_acceleration_covariance[0] == NOT_PROVIDED)
        self.played.gyro_absent.append(message.angular_velocity_covariance[0] == NOT_PROVIDED)

    def _on_mag(self, message: MagneticField) -> None:
        self.played.mag_stamp_ns.append(_stamp_of(message))
        b = message.magnetic_field
        self.played.mag.append((b.x, b.y, b.z))

    def wait(self, condition: Callable[[], bool], timeout_s: float) -> bool:
        """Spin until ``condition()`` holds or ``timeout_s`` passes; whether it holds."""
        deadline = time.monotonic() + timeout_s
        while not condition():
            if time.monotonic() > deadline:
                return False
            self.executor.spin_once(timeout_sec=0.01)
        return True

    def matched(self) -> bool:
        """The node subscribes our inputs, publishes our output, and its Imu writer has matched our reader."""
        ours = (self.input.get_subscription_count() >= 1 and self.temperature.get_subscription_count() >= 1
                and self.output.get_publisher_count() >= 1)
        if self.mag is not None:
            ours = ours and self.mag.get_subscription_count() >= 1
        # Discovery is not symmetric: the node says in /diagnostics how many readers its Imu has.
        return ours and any(int(value.value) >= 1 for array in self.statuses for status in array.status
                            for value in status.values if value.key == 'imu_subscribers')

    def close(self) -> None:
        """Tear the node and the context down."""
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def play(record: Record, options, *, wait_s: float = 30.0, answer_s: float = 5.0) -> Played:
    """Publish a bag's input streams into a running compensator and take its answers back.

    :param options: the commands' stream options (the topics; the bag's input kind follows from them).
    :param wait_s: how long to wait for the node's endpoints to match ours.
    :param answer_s: how long to wait for the node to answer a message before counting it unanswered.
    :raises TakError: no node matched within ``wait_s``.
    """
    streams = record.streams
    kind = streams.kind
    with_mag = kind is InputKind.IMU and streams.mag > 0
    player = _Player(kind, options.topics, mag=with_mag)
    played = player.played
    sent = {'input': 0, 'temperature': 0, 'mag': 0}
    started = time.monotonic()
    try:
        if not player.wait(player.matched, wait_s):
            msg = (f'no compensator answered on {player.input_topic} -> {player.output_topic} within {wait_s:g} s: '
                   f'is it running, with the same ROS_DOMAIN_ID, for this kind of bag?')
            raise TakError(msg)
        aux: set[str] = set()
        for block in record.blocks(kind=kind, references=False, progress=options.progress):
            aux.update(block.aux)
            _play_block(player, block, kind, sent, answer_s)
        answered = (lambda: len(played.stamp_ns) >= sent['input'] - played.unanswered
                    and len(played.mag_stamp_ns) >= sent['mag'])
        player.wait(answered, answer_s)
    finally:
        player.close()
    played.sent = {('imu' if kind is InputKind.IMU else 'counts'): sent['input'], 'temperature': sent['temperature'],
                   **({'mag': sent['mag']} if with_mag else {})}
    played.seconds = time.monotonic() - started
    played.not_played = tuple(sorted(aux))
    return played


def _play_block(player: _Player, block, kind: InputKind, sent: dict[str, int], answer_s: float) -> None:
    """One block's messages in stamp order: the temperature first at equal stamps, then the input, then the field."""
    driver = kind is InputKind.IMU
    messages = imu_messages(block) if driver else None
    input_stamps = messages.stamp_ns if driver else block.counts_stamp_ns
    temperatures = block.temperature if driver else block.temp_code
    mag_stamps = block.mag_stamp_ns if driver else np.zeros(0, dtype=np.int64)
    events = play_order(block.temp_stamp_ns, input_stamps, mag_stamps)
    played = player.played

    def caught_up(ahead: int) -> None:
        if not player.wait(lambda: len(played.stamp_ns) + played.unanswered >= sent['input'] - ahead, answer_s):
            played.unanswered = sent['input'] - ahead - len(played.stamp_ns)

    for stamp, stream, row in events:
        if stream == 0:
            caught_up(0)
            message = Temperature()
            _stamp(message, stamp)
            message.temperature = float(temperatures[row])
            player.temperature.publish(message)
            sent['temperature'] += 1
        elif stream == 1:
            caught_up(AHEAD)
            player.input.publish(_imu(block, messages, row) if driver else _counts(block, row))
            sent['input'] += 1
        else:
            message = MagneticField()
            _stamp(message, stamp)
            message.header.frame_id = block.mag_frame_id
            message.magnetic_field.x, message.magnetic_field.y, message.magnetic_field.z = (
                float(v) for v in block.mag[row])
            player.mag.publish(message)
            sent['mag'] += 1


def _imu(block, messages: ImuRows, row: int) -> Imu:
    """The ``row``-th Imu message as ``apply``'s writer writes it: the sensors it carries, an absent one marked."""
    message = Imu()
    _stamp(message, messages.stamp_ns[row])
    message.header.frame_id = block.frame_id
    rows = (messages.message_row, messages.accel_row, messages.gyro_row)
    message_row, accel_row, gyro_row = (int(at[row]) for at in rows)
    a, w, q = message.linear_acceleration, message.angular_velocity, message.orientation
    if accel_row >= 0:
        a.x, a.y, a.z = (float(v) for v in block.accel[accel_row])
    else:
        message.linear_acceleration_covariance = NOT_PROVIDED_COVARIANCE
    if gyro_row >= 0:
        w.x, w.y, w.z = (float(v) for v in block.gyro[gyro_row])
    else:
        message.angular_velocity_covariance = NOT_PROVIDED_COVARIANCE
    if message_row >= 0:
        q.x, q.y, q.z, q.w = (float(v) for v in block.orientation[message_row])
        message.orientation_covariance = [float(v) for v in block.orientation_covariance[message_row]]
    else:
        message.orientation_covariance = NOT_PROVIDED_COVARIANCE
    return message


def _counts(block, row: int) -> Vector3Stamped:
    message = Vector3Stamped()
    _stamp(message, block.counts_stamp_ns[row])
    message.header.frame_id = block.frame_id
    message.vector.x, message.vector.y, message.vector.z = (float(v) for v in block.counts[row])
    return message
