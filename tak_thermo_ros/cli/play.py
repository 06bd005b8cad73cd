"""``tak_calib play``: publish a bag into a running ``compensator`` and compare its answers with ``apply``'s.

Start the node first (``ros2 run tak_thermo_ros compensator --ros-args --params-file P.yaml -p
qos:=reliable``), then ``tak_calib play BAG --compare APPLIED``: the bag's Imu (or codes), its
temperature and its magnetometer are published in stamp order, paced by the node's answers
(:mod:`tak_thermo_ros.ros.player`), and what the node publishes is compared, float64 for float64,
with what ``tak_calib apply BAG --params P.yaml -o APPLIED`` wrote. ``rosbag2``'s ``ros2 bag
play`` would do the publishing where it is installed, but it paces by the clock, not by the
node, and compares nothing.
"""

from __future__ import annotations

import argparse

import numpy as np

from tak_thermo_ros.cli import common, options
from tak_thermo_ros.errors import TakError

NAME = 'play'
OUTPUTS: tuple[tuple[str, str, str], ...] = ()
"""This command writes no file."""


def add_parser(commands) -> argparse.ArgumentParser:
    """Add the command to ``tak_calib``'s subcommands."""
    parser = commands.add_parser('play', help="publish a bag into a running compensator; compare with apply's output")
    parser.add_argument('bag', metavar='BAG')
    parser.add_argument('--compare', metavar='APPLIED_BAG',
                        help="a bag tak_calib apply wrote from BAG: the node's output must equal it, float64 for "
                             'float64 (exit 1 if not)')
    parser.add_argument('--wait', type=options.seconds_not_negative, default=30.0, metavar='SECONDS',
                        help='how long to wait for the node to match the topics (default 30)')
    parser.add_argument('--answer-timeout', type=options.seconds_not_negative, default=5.0, metavar='SECONDS',
                        help='how long to wait for the node to answer a message before counting it '
                             'unanswered (default 5)')
    options.add_topic_options(parser, imu=True)
    parser.set_defaults(handler=run)
    return parser


def run(args: argparse.Namespace) -> int:
    """Play the bag into the node; say what was sent, received and whether it equals ``apply``'s output."""
    from tak_thermo_ros.formats.records import open_record
    from tak_thermo_ros.ros.player import play
    stream_options = common.stream_options(args)
    expected = _applied(args.compare, stream_options.topics) if args.compare else None
    played = play(open_record(args.bag, topics=stream_options.topics), stream_options, wait_s=args.wait,
                  answer_s=args.answer_timeout)
    types = {'imu': 'Imu', 'counts': 'counts', 'temperature': 'Temperature', 'mag': 'MagneticField'}
    sent = ', '.join(f'{count} {types[name]}' for name, count in played.sent.items())
    print(f'played {args.bag}: {sent} messages in {played.seconds:.0f} s')
    if played.not_played:
        print(f'not played: {", ".join(played.not_played)} (recorded signals; a node that needs one waits for it)')
    output = stream_options.topics
    imu_topic = output.compensated_imu if 'imu' in played.sent else output.imu
    print(f'received {len(played.stamp_ns)} Imu on {imu_topic}'
          + (f' and {len(played.mag_stamp_ns)} MagneticField on {output.compensated_mag}' if 'mag' in played.sent
             else ''))
    if played.unanswered:
        print(f'{played.unanswered} messages were not answered within {args.answer_timeout:g} s '
              f'(dropped by the node: see its log and /diagnostics)')
    if expected is None:
        return 0
    return _compare(played, expected, args.compare)


def _applied(path: str, topics) -> dict[str, np.ndarray]:
    """The corrected Imu (and field) that ``apply`` wrote, as arrays."""
    from tak_thermo_ros.core.link.correction import NOT_PROVIDED
    from tak_thermo_ros.errors import BagError
    from tak_thermo_ros.formats.bag import read_imu_messages
    for topic in (topics.compensated_imu, topics.imu):
        try:
            messages = read_imu_messages(path, topic=topic)
        except BagError:
            continue
        found = {'stamp_ns': messages.stamp_ns, 'accel': messages.linear_acceleration,
                 'gyro': messages.angular_velocity,
                 'absent': np.column_stack([messages.linear_acceleration_covariance[:, 0] == NOT_PROVIDED,
                                            messages.angular_velocity_covariance[:, 0] == NOT_PROVIDED])}
        found.update(_applied_field(path, topics.compensated_mag))
        return found
    msg = f'--compare {path}: holds neither {topics.compensated_imu} nor {topics.imu} (not written by apply?)'
    raise TakError(msg)


def _applied_field(path: str, topic: str) -> dict[str, np.ndarray]:
    """``apply``'s corrected magnetic field, when it wrote one."""
    from tak_thermo_ros.formats.bag import iter_topic_arrays
    try:
        arrays = list(iter_topic_arrays(path, topic, 'sensor_msgs/msg/MagneticField'))
    except TakError:
        return {}
    if not arrays:
        return {}
    return {'mag_stamp_ns': np.concatenate([a['stamp_ns'] for a in arrays]),
            'mag': np.concatenate([a['magnetic_field'] for a in arrays])}


def _compare(played, expected: dict[str, np.ndarray], path: str) -> int:
    """Whether the node's output equals ``apply``'s, float64 for float64: one line each way; exit 0 or 1."""
    received = {'stamp_ns': np.asarray(played.stamp_ns, dtype=np.int64),
                'accel': np.asarray(played.accel, dtype=float).reshape(-1, 3),
                'gyro': np.asarray(played.gyro, dtype=float).reshape(-1, 3)}
    same = {name: bool(np.array_equal(received[name], expected[name])) for name in received}
    words = {'stamp_ns': 'stamps', 'accel': 'linear_acceleration', 'gyro': 'angular_velocity'}
    absent = np.column_stack([np.asarray(played.accel_absent, dtype=bool), np.asarray(played.gyro_absent, dtype=bool)])
    if absent.any() or expected['absent'].any():  # messages that carry one sensor: the marks too
        same['absent'] = bool(np.array_equal(absent, expected['absent']))
        words['absent'] = 'absent marks'
    if 'mag' in expected:
        field = np.asarray(played.mag, dtype=float).reshape(-1, 3)
        same['mag'] = bool(np.array_equal(field, expected['mag']))
        words['mag'] = 'magnetic_field'
    if all(same.values()):
        print(f'equal to {path}, float64 for float64: all {len(received["stamp_ns"])} messages')
        print(f'  compared: {", ".join(words.values())}')
        return 0
    differ = [words[name] for name, equal in same.items() if not equal]
    print(f'NOT equal to {path}: {", ".join(differ)} differ ({len(received["stamp_ns"])} messages received, '
          f'{len(expected["stamp_ns"])} in {path})')
    return 1
