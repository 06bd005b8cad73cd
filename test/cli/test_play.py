"""``tak_calib play``: the user's way to publish a bag into a running node and check it against ``apply``.

The docs' node transcripts use it (issue 26: the play-back is a user command, not a test helper).
Real rclpy, the node as a process, a short driver run with a gyroscope lag (an effect with memory).
"""

from __future__ import annotations

from dataclasses import replace

import pytest

from tak_thermo_ros import cli
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.formats.bag import read_imu_messages, write_driver_record
from tak_thermo_ros.formats.calibration_file import unit_yaml, write_text_atomic
from node_helpers import NodeProcess, node_command

RUN = Scenario(output='imu', sample_rate_hz=10.0, plateaus_celsius=(10.0, 30.0), plateau_hours=0.005,
               ramp_celsius_per_minute=10.0, board_lag_s=5.0, dwell_s=1.0, seed=6,
               gyro_effects={'thermal_lag': {'tau_s': 20.0, 'slope_x': 0.01, 'slope_z': -0.01}})
"""About three minutes at 10 Hz: some 1,900 Imu and 380 temperature messages."""


def test_play_publishes_a_bag_into_the_node_and_finds_it_equal_to_apply(tmp_path, ros_env, capsys):
    bag, params, applied, other = (tmp_path / name for name in ('run', 'params.yaml', 'applied', 'other'))
    write_driver_record(bag, simulate(RUN).driver)
    assert cli.main(['fit', str(bag), '-o', str(params), '--gyro-effects', 'thermal_lag', '--no-progress']) == 0
    assert cli.main(['apply', str(bag), '--params', str(params), '-o', str(applied), '--no-progress']) == 0
    assert cli.main(['fit', str(bag), '-o', str(tmp_path / 'base.yaml'), '--no-progress']) == 0
    assert cli.main(['apply', str(bag), '--params', str(tmp_path / 'base.yaml'), '-o', str(other),
                     '--no-progress']) == 0
    capsys.readouterr()
    with NodeProcess(node_command('--params-file', str(params), '-p', 'qos:=reliable'), ros_env,
                     tmp_path / 'node.log') as node:
        assert cli.main(['play', str(bag), '--compare', str(applied), '--no-progress']) == 0, node.log()
        printed = ' '.join(capsys.readouterr().out.split())  # long paths wrap the statements
        sent = len(simulate(RUN).driver.stamp_ns)
        assert f'received {sent} Imu on /imu/data_compensated' in printed
        assert f'equal to {applied}, float64 for float64: all {sent} messages' in printed
        # The node corrects with the lag: apply's output without it differs, and play says so (exit 1).
        assert cli.main(['play', str(bag), '--compare', str(other), '--no-progress']) == 1, node.log()
        assert 'NOT equal to' in capsys.readouterr().out
        assert node.stop() == 0
    assert 'Traceback' not in node.log()


def test_play_without_a_node_is_one_line_and_exit_2(tmp_path, ros_env, capsys):
    write_driver_record(tmp_path / 'run', simulate(RUN).driver)
    assert cli.main(['play', str(tmp_path / 'run'), '--wait', '1', '--no-progress']) == 2
    err = capsys.readouterr().err
    assert err.startswith('tak_calib: error: no compensator answered') and len(err.splitlines()) == 1


def test_play_of_messages_that_carry_one_sensor_equals_apply_marks_included(tmp_path, ros_env, capsys):
    """A bag whose Imu messages carry one sensor or both: each published as recorded, the node's output apply's.

    The record's faults on one sensor's own samples (a NaN gyroscope sample, a non-physical
    accelerometer sample, a duplicate accelerometer stamp) are treated by the node as by apply.
    """
    from own_stamps import absent_marks, own_stamps_record, own_stamps_unit
    bag, params, applied = tmp_path / 'apart.mcap', tmp_path / 'params.yaml', tmp_path / 'applied.mcap'
    write_driver_record(bag, own_stamps_record())
    write_text_atomic(params, unit_yaml(own_stamps_unit()))
    assert cli.main(['apply', str(bag), '--params', str(params), '-o', str(applied), '--no-progress']) == 0
    raw = read_imu_messages(bag, topic='/imu/data_raw')
    written = len(read_imu_messages(applied, topic='/imu/data_compensated').stamp_ns)
    assert absent_marks(raw) > 40 and written < len(raw.stamp_ns)
    capsys.readouterr()
    with NodeProcess(node_command('--params-file', str(params), '-p', 'qos:=reliable'), ros_env,
                     tmp_path / 'node.log') as node:
        assert cli.main(['play', str(bag), '--compare', str(applied), '--answer-timeout', '2',
                         '--no-progress']) == 0, node.log()
        printed = ' '.join(capsys.readouterr().out.split())
        assert f'{len(raw.stamp_ns)} Imu' in printed and f'received {written} Imu' in printed
        assert f'equal to {applied}, float64 for float64: all {written} messages' in printed
        assert 'compared: stamps, linear_acceleration, angular_velocity, absent marks' in printed
        assert node.stop() == 0
    log = node.log()
    assert 'marks the accelerometer absent (covariance[0] = -1)' in log and 'Traceback' not in log


@pytest.mark.parametrize('case', ['no Imu messages', 'no bag'])
def test_a_bag_the_player_cannot_play_is_one_line_and_exit_2(case, tmp_path, ros_env, capsys):
    from own_stamps import own_stamps_record
    bag = tmp_path / 'run'
    if case == 'no bag':
        bag.write_text('not a bag')
    else:
        record = own_stamps_record()
        write_driver_record(bag, replace(record, stamp_ns=record.stamp_ns[:0], accel=record.accel[:0],
                                         gyro=record.gyro[:0], accel_stamp_ns=None, gyro_stamp_ns=None,
                                         orientation=record.orientation[:0],
                                         orientation_covariance=record.orientation_covariance[:0]))
    assert cli.main(['play', str(bag), '--wait', '1', '--no-progress']) == 2
    err = capsys.readouterr().err
    assert err.startswith(f'tak_calib: error: {bag}') and len(err.splitlines()) == 1, err
