"""The calibration watch in the real node (rclpy): the verdict validate gives, apply's turn-on, learning across starts.

The statistics over seeds run through the core (``test/core/link/test_watch.py``: the same code); here a few
everyday runs go through the real node, its parameters and ``/diagnostics``.
"""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np

from everyday_watch import HABITS, LATITUDE, everyday_runs, watch_unit
from node_helpers import Harness, NodeProcess, node_command, play_driver, run_to_exit, status_values, wait_until
from tak_thermo_ros import cli
from tak_thermo_ros.formats.bag import read_imu_messages, write_driver_record
from tak_thermo_ros.formats.calibration_file import load_unit, save_unit
from tak_thermo_ros.formats.learned_file import load_learned

UNIT = watch_unit()
SHORT = replace(HABITS, record_minutes=4.0)
"""Four minutes of everyday use at 10 Hz (about 2,500 Imu messages, 3 to 6 rests)."""
WATCH = 'calibration watch'
"""The name of the calibration watch's diagnostics status (``<node>: calibration watch``)."""


def validate_verdict(bag, params, capsys) -> str:
    """The verdict line ``tak_calib validate`` prints for the record."""
    assert cli.main(['validate', str(bag), '--params', str(params), '--latitude', str(LATITUDE),
                     '--no-progress']) == 0
    lines = capsys.readouterr().out.splitlines()
    return lines[lines.index(next(line for line in lines if line.startswith('calibration watch over'))) + 1]


def test_the_node_says_stale_as_validate_does_and_takes_the_turn_on_as_apply(tmp_path, ros_env, capsys):
    """A moved gyro x offset: the node's WARN is validate's line; its Imu with turn_on are apply's, float for float.

    /diagnostics at WARN "calibration stale: gyro x offset +N deg/h (at rest 1)", the line
    ``validate`` prints; with ``turn_on: first_rest`` the node's Imu equal ``apply --turn-on
    first-rest``'s (the x offset refused as a turn-on, y and z taken).
    """
    record = everyday_runs(2, ('offset',), habits=SHORT)['offset'].record
    bag, params = tmp_path / 'moved.mcap', tmp_path / 'unit.yaml'
    write_driver_record(bag, record)
    save_unit(params, UNIT)
    verdict = validate_verdict(bag, params, capsys)
    assert verdict.startswith('calibration stale: gyro x offset +') and verdict.endswith('(at rest 1)')
    applied = tmp_path / 'applied.mcap'
    assert cli.main(['apply', str(bag), '--params', str(params), '-o', str(applied), '--turn-on', 'first-rest',
                     '--latitude', str(LATITUDE), '--no-progress']) == 0
    expected = read_imu_messages(applied, topic='/imu/data_compensated')
    with NodeProcess(node_command('-p', f'calibration_file:={params}', '-p', 'qos:=reliable', '-p',
                                  f'latitude:={LATITUDE}', '-p', 'turn_on:=first_rest'), ros_env,
                     tmp_path / 'node.log') as node, Harness(int(ros_env['ROS_DOMAIN_ID']), driver=True) as ros:
        ros.wait_matched()
        play_driver(ros, record)
        ros.wait(lambda: ros.latest_status(WATCH) is not None and ros.latest_status(WATCH).level == b'\x01', 10.0,
                 'a stale verdict')
        status = ros.latest_status(WATCH)
        assert status.message == verdict and 'calibration' in status.message and 'stale' in status.message
        values = status_values(status)
        assert float(values['gyro_x.bias_deg_h']) > 500.0 and int(values['rests']) >= 1
        assert 'turn-on offset not taken' in values['turn_on'] and 'gyro x' in values['turn_on']
        assert node.stop() == 0
    assert 'calibration stale at rest 1: gyro x offset +' in node.log()
    got = np.array([(m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z) for m in ros.imu])
    assert np.array_equal(got, expected.angular_velocity)
    assert np.array_equal(np.array([(m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z)
                                    for m in ros.imu]), expected.linear_acceleration)


def test_learning_is_written_read_by_validate_and_by_the_next_start(tmp_path, ros_env, capsys):
    """Learning writes learned_file at shutdown; validate and the next start read it; learn false returns to the file.

    The original file is untouched; the healthy run's verdict at shutdown is ``validate``'s.
    """
    record = everyday_runs(3, ('healthy',), habits=SHORT)['healthy'].record
    bag, params, learned = tmp_path / 'run.mcap', tmp_path / 'unit.yaml', tmp_path / 'learned.yaml'
    write_driver_record(bag, record)
    save_unit(params, UNIT)
    original = params.read_text()
    verdict = validate_verdict(bag, params, capsys)
    assert verdict.startswith('calibration holds at')
    arguments = ('-p', f'calibration_file:={params}', '-p', 'qos:=reliable', '-p', f'latitude:={LATITUDE}',
                 '-p', 'learn:=true', '-p', f'learned_file:={learned}')
    with NodeProcess(node_command(*arguments), ros_env, tmp_path / 'first.log') as node, \
            Harness(int(ros_env['ROS_DOMAIN_ID']), driver=True) as ros:
        ros.wait_matched()
        play_driver(ros, record)
        assert node.stop() == 0
    assert f'calibration watch at shutdown: {verdict}' in node.log()
    state = load_learned(learned)
    assert state.runs == 1 and state.rests >= 2 and params.read_text() == original
    assert 'learned by the calibration watch' in load_unit(learned).gyro.notes[-1]
    assert validate_verdict(bag, learned, capsys).startswith('calibration holds at')
    with NodeProcess(node_command(*arguments), ros_env, tmp_path / 'second.log') as node, \
            Harness(int(ros_env['ROS_DOMAIN_ID']), driver=True) as ros:
        ros.wait_matched()
        wait_until(lambda: f'learning into {learned} (from 1 earlier runs)' in node.log(), 10.0, what='the start line')
        results = ros.set_parameters({'learn': False})
        assert results[0].successful, results[0].reason
        wait_until(lambda: re.search(r'calibration watch on: .*latitude 45$', node.log(), re.MULTILINE) is not None,
                   10.0, what='the watch without learning')
        assert node.stop() == 0


def test_the_node_refuses_what_the_watch_cannot_do(tmp_path, ros_env):
    """turn_on without the file's turn-on repeatability, learning into the calibration file: one line, exit 2."""
    bare = tmp_path / 'bare.yaml'
    save_unit(bare, replace(UNIT, gyro=replace(UNIT.gyro, turn_on=None)))
    result = run_to_exit(node_command('-p', f'calibration_file:={bare}', '-p', 'turn_on:=first_rest'), ros_env)
    assert result.returncode == 2
    assert "turn_on: first_rest needs the calibration's gyro turn_on section" in result.stderr
    result = run_to_exit(node_command('-p', f'calibration_file:={bare}', '-p', 'learn:=true', '-p',
                                      f'learned_file:={bare}'), ros_env)
    assert result.returncode == 2 and 'is the calibration file itself' in result.stderr


def test_learn_set_true_with_a_corrupt_learned_file_is_refused_and_the_node_runs_on(tmp_path, ros_env):
    """``learn`` set true at run time reads learned_file in its check: a corrupt one refuses the change, saying why."""
    params, learned = tmp_path / 'unit.yaml', tmp_path / 'learned.yaml'
    save_unit(params, UNIT)
    with NodeProcess(node_command('-p', f'calibration_file:={params}', '-p', f'learned_file:={learned}'), ros_env,
                     tmp_path / 'node.log') as node, Harness(int(ros_env['ROS_DOMAIN_ID']), driver=True) as ros:
        ros.wait_matched()
        learned.write_text('compensator: [not, a, learned, file\n')
        results = ros.set_parameters({'learn': True})
        assert not results[0].successful and str(learned) in results[0].reason
        assert node.process.poll() is None
        learned.unlink()
        results = ros.set_parameters({'learn': True})
        assert results[0].successful, results[0].reason
        wait_until(lambda: f'learning into {learned} (from 0 earlier runs)' in node.log(), 10.0, what='learning')
        assert node.stop() == 0


def test_a_calibration_change_while_learning_writes_the_learned_file_first(tmp_path, ros_env):
    """A ``calibration.*`` change while learning writes the learned file first; later learning holds the new one.

    The file written at the change holds the calibration the rests were learned against; what the
    new watch learns is written with the new calibration.
    """
    record = everyday_runs(3, ('healthy',), habits=SHORT)['healthy'].record
    params, learned = tmp_path / 'unit.yaml', tmp_path / 'learned.yaml'
    save_unit(params, UNIT)
    rms = UNIT.accel.axes[0].residual_rms
    with NodeProcess(node_command('-p', f'calibration_file:={params}', '-p', 'qos:=reliable', '-p',
                                  f'latitude:={LATITUDE}', '-p', 'learn:=true', '-p', f'learned_file:={learned}'),
                     ros_env, tmp_path / 'node.log') as node, \
            Harness(int(ros_env['ROS_DOMAIN_ID']), driver=True) as ros:
        ros.wait_matched()
        play_driver(ros, record)
        results = ros.set_parameters({'calibration.accel.x.residual_rms': 2.0 * rms})
        assert results[0].successful, results[0].reason
        wait_until(lambda: learned.exists() and load_learned(learned).rests >= 2, 10.0, what='the learned file')
        assert load_unit(learned).accel.axes[0].residual_rms == rms
        later = int(record.stamp_ns[-1] - record.stamp_ns[0]) + 1_000_000_000
        ros.imu.clear()
        play_driver(ros, replace(record, stamp_ns=record.stamp_ns + later, temp_stamp_ns=record.temp_stamp_ns + later))
        assert node.stop() == 0
    assert load_unit(learned).accel.axes[0].residual_rms == 2.0 * rms
    assert load_learned(learned).rests >= 2
