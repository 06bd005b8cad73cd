"""The node's two message paths: raw bytes (the default) and rclpy's messages publish and count the same.

Every other node test runs the default, the raw path (``message_path: raw``); here the decoded
path is held to it, message for message and counter for counter, and the raw path's own failure,
bytes that are no message, is counted and said in one line.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from everyday_watch import HABITS, LATITUDE, everyday_runs, watch_unit
from node_helpers import NANOSECONDS, Harness, NodeProcess, node_command, status_values
from tak_thermo_ros.core.link.correction import Corrector
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.formats.bag import play_order
from tak_thermo_ros.formats.calibration_file import calibration_yaml, save_unit, write_text_atomic
from tak_thermo_ros.formats.cdr.encoder import encode_messages

WATCH = 'calibration watch'
COUNTERS = ('received', 'published', 'dropped', 'sequence_gap', 'temperature_messages', 'temperature_rejected',
            'out_of_range', 'one_sensor_messages', 'sensor_dropped', 'sensor_stamps')


def imu_fields(message) -> tuple:
    """Every field of an Imu, numbers as float64 bit patterns (NaN equals the same NaN)."""
    numbers = [message.orientation.x, message.orientation.y, message.orientation.z, message.orientation.w,
               *message.orientation_covariance, message.angular_velocity.x, message.angular_velocity.y,
               message.angular_velocity.z, *message.angular_velocity_covariance, message.linear_acceleration.x,
               message.linear_acceleration.y, message.linear_acceleration.z, *message.linear_acceleration_covariance]
    stamp = message.header.stamp
    return stamp.sec, stamp.nanosec, message.header.frame_id, tuple(np.array(numbers).view(np.uint64).tolist())


def play_both(harnesses: list[Harness], record) -> int:
    """Publish a driver record into each node in turn, message by message, none lost; the Imu messages sent."""
    sent = 0
    for stamp, stream, row in play_order(record.temp_stamp_ns, record.stamp_ns):
        for ros in harnesses:
            ros.wait(lambda: len(ros.imu) >= sent - 50 * (stream == 1), 20.0, f'the node to catch up ({sent})')
            if stream == 0:
                ros.send_temperature(stamp, record.temperature[row])
            else:
                ros.send_imu(stamp, (*record.accel[row], *record.gyro[row]), frame_id=record.frame_id,
                             orientation=record.orientation[row],
                             orientation_covariance=record.orientation_covariance[row])
        sent += stream == 1
    return sent


def test_raw_and_decoded_paths_publish_the_same_messages_counts_and_watch(tmp_path, ros_env):
    """Everyday use with a moved gyro offset, then bad input: both paths, side by side, publish and say the same.

    Every field of every Imu bit for bit, every counter of the status (drops by reason, sequence
    gaps, one-sensor marks), and the calibration watch's verdict.
    """
    record = everyday_runs(2, ('offset',), habits=replace(HABITS, record_minutes=3.0))['offset'].record
    params = tmp_path / 'unit.yaml'
    save_unit(params, watch_unit())
    paths = ('raw', 'decoded')
    nodes, harnesses = [], []
    try:
        for path in paths:
            nodes.append(NodeProcess(node_command('-r', f'__ns:=/{path}', '-p', f'calibration_file:={params}', '-p',
                                                  'qos:=reliable', '-p', f'latitude:={LATITUDE}', '-p',
                                                  f'message_path:={path}'), ros_env, tmp_path / f'{path}.log'))
            harnesses.append(Harness(int(ros_env['ROS_DOMAIN_ID']), namespace=path, driver=True))
        for ros in harnesses:
            ros.wait_matched()
        sent = play_both(harnesses, record)
        verdicts = []
        for ros in harnesses:  # every rest that closed judged: a watch status after the last message was counted
            ros.wait(lambda: int(status_values(ros.latest_status())['received']) == sent, 10.0, 'the last Imu counted')
            ticks = len(ros.diagnostics)
            ros.wait(lambda: len(ros.diagnostics) > ticks, 10.0, 'the next status')
            verdicts.append((ros.latest_status(WATCH).message, status_values(ros.latest_status(WATCH))))
        last = int(record.stamp_ns[-1])
        accel_only, gyro_only = ({'angular_velocity_covariance': (-1.0,) + (0,) * 8},
                                 {'linear_acceleration_covariance': (-1.0,) + (0,) * 8})
        bad = [(last, (0.0, 0.0, 9.8, 0.0, 0.0, 0.0), {}),  # a duplicate stamp
               (last + 10**7, (math.nan, 0.0, 9.8, 0.0, 0.0, 0.0), {}),
               (last - 10**9, (0.0, 0.0, 9.8, 0.0, 0.0, 0.0), {}),  # backwards
               (last + 2 * 10**7, (1e308, 0.0, 9.8, 0.0, 0.0, 0.0), {}),
               (last + 3 * 10**7, (0.1, 0.2, 9.8, 0.0, 0.0, 0.0), accel_only),  # from here each sensor apart
               (last + 4 * 10**7, (0.0, 0.0, 0.0, 0.01, 0.02, 0.03), gyro_only),
               (last + 5 * 10**7, (0.1, 0.2, 9.8, math.nan, 0.0, 0.0), {})]  # published with the accelerometer
        for ros in harnesses:
            for stamp, values, marks in bad:
                ros.send_imu(stamp, values, frame_id=record.frame_id, **marks)
        for ros in harnesses:
            ros.wait(lambda: len(ros.imu) >= sent + 3, 20.0, 'the messages carrying one sensor')
            ros.wait(lambda: int(status_values(ros.latest_status())['received']) == sent + len(bad), 10.0,
                     'a status after the bad input')
        statuses = [status_values(ros.latest_status()) for ros in harnesses]
        for node in nodes:
            assert node.stop() == 0
    finally:
        for ros in harnesses:
            ros.close()
        for node in nodes:
            node.stop()
    raw, decoded = harnesses
    assert len(raw.imu) == len(decoded.imu) == sent + 3
    assert [imu_fields(m) for m in raw.imu] == [imu_fields(m) for m in decoded.imu]
    counters = [{key: value for key, value in status.items() if key.startswith(COUNTERS)} for status in statuses]
    assert counters[0] == counters[1]
    raw_counts = counters[0]
    assert int(raw_counts['published']) == sent + 3 and int(raw_counts['dropped.duplicate_stamp']) == 1
    assert int(raw_counts['dropped.time_backwards']) == int(raw_counts['dropped.non_physical']) == 1
    assert int(raw_counts['dropped.non_finite']) == 1 and int(raw_counts['sensor_dropped.gyro.non_finite']) == 1
    assert int(raw_counts['dropped.malformed']) == 0 and raw_counts['sequence_gap'] == '0'
    # The watch: the rests judged alike (a moved gyro x offset said stale), then off from the first mark on.
    assert verdicts[0] == verdicts[1] and verdicts[0][0].startswith('calibration stale')
    assert statuses[0]['calibration_watch'] == statuses[1]['calibration_watch'] != 'on'
    assert 'calibration stale at rest 1: gyro x offset +' in nodes[0].log()
    assert 'raw messages' in nodes[0].log() and 'decoded messages' in nodes[1].log()


def test_bytes_that_are_no_message_are_counted_dropped_in_one_line_and_the_node_goes_on(tmp_path, ros_env):
    """Truncated bytes and a bad encapsulation on the raw path: dropped (``malformed``), one WARN line, no traceback.

    A big-endian message (valid CDR) is read and answered in its byte order; a malformed
    temperature is rejected and the last good one kept; good messages go on being corrected.
    """
    calibration = Scenario().truth()
    params = tmp_path / 'tak_params.yaml'
    write_text_atomic(params, calibration_yaml(calibration, extra_parameters={'qos': 'reliable'}))
    start = 1_700_000_000 * NANOSECONDS
    big_endian = encode_messages('geometry_msgs/msg/Vector3Stamped', np.array([start + 3 * 10**6]),
                                 {'vector': np.array([[120.0, -40.0, 2600.0]])}, {'frame_id': 'odd_frame'},
                                 little_endian=False)[0]
    little_endian = encode_messages('geometry_msgs/msg/Vector3Stamped', np.array([start]), {'vector': np.zeros(3)},
                                    {'frame_id': 'tak_imu'})[0]
    with NodeProcess(node_command('--params-file', str(params)), ros_env, tmp_path / 'node.log') as node, \
            Harness(int(ros_env['ROS_DOMAIN_ID'])) as ros:
        ros.wait_matched()
        ros.send_temperature_and_wait(start, 8300.0)
        ros.send_counts(start + 10**6, 100.0, -200.0, 2500.0)
        ros.counts.publish(little_endian[:28])  # truncated (the middleware pads a payload to 4 bytes: cut there)
        ros.counts.publish(b'\x07\x01\x00\x00' + bytes(40))  # no CDR encapsulation
        ros.counts.publish(big_endian)
        ros.temperature.publish(b'\x00\x01\x00\x00\x01\x00\x00\x00')  # cut short: the last good one stays
        ros.send_counts(start + 4 * 10**6, 100.0, -200.0, 2500.0)
        ros.wait(lambda: len(ros.imu) >= 3, 10.0, 'the messages after the malformed ones')
        ros.wait(lambda: int(status_values(ros.latest_status())['received']) == 5, 10.0, 'a status counting them')
        values = status_values(ros.latest_status())
        assert node.stop() == 0
    assert int(values['dropped.malformed']) == 2 and int(values['dropped']) == 2 and int(values['published']) == 3
    assert int(values['temperature_rejected']) == 1 and values['temperature_code'] == '8300'
    assert values['sequence_gap'] == '0'  # every one of them arrived, and is counted where it went
    corrector = Corrector(calibration)
    got = [(m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z) for m in ros.imu]
    assert got == [corrector.correct_sample(100.0, -200.0, 2500.0, 8300.0),
                   corrector.correct_sample(120.0, -40.0, 2600.0, 8300.0),
                   corrector.correct_sample(100.0, -200.0, 2500.0, 8300.0)]
    assert ros.imu[1].header.frame_id == 'odd_frame' and ros.imu[1].header.stamp.nanosec == 3 * 10**6
    log = node.log()
    assert 'Traceback' not in log
    warned = [line for line in log.splitlines() if 'malformed geometry_msgs/msg/Vector3Stamped' in line]
    assert len(warned) == 1 and '[WARN]' in warned[0] and '/tak/counts: malformed' in warned[0]
    assert '(28 bytes): truncated: vector at byte' in warned[0] and warned[0].endswith(': dropped (1 so far)')
    assert any('/tak/temp_code: malformed sensor_msgs/msg/Temperature (8 bytes)' in line for line in log.splitlines())
