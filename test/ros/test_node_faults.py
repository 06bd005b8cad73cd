"""The ``compensator`` under the faults an adversarial run found (issue 27), with the real rclpy.

A signal at any moment of start-up; two compensators in two namespaces on one /diagnostics; a
future-stamped Imu; a live parameter and an Imu value that make nonsense. (Losses under a burst
with the default executor: ``test/ros/test_node.py``; the pure rules: ``test/core/link/test_online.py``.)
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml
from rcl_interfaces.msg import Log
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from node_helpers import (
    NANOSECONDS,
    STARTED_GROUPS,
    Harness,
    NodeProcess,
    group_running,
    kill_leftovers,
    node_command,
    run_to_exit,
    stamp_of,
    start_process,
    status_values,
    wait_until,
)
from paths import TEST
from tak_thermo_ros.core.link.correction import UnitCorrector
from tak_thermo_ros.core.records.stamps import stamp_problems
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.formats.calibration_file import unit_to_mapping, unit_yaml, write_text_atomic

START_NS = 1_700_000_000 * NANOSECONDS
DRIVER_UNIT = Scenario(output='imu').driver_truth()  # 5..35 C
GOOD = (0.1, -0.2, 9.81, 0.01, -0.02, 0.03)
COMPENSATOR = Path(sys.executable).with_name('compensator')
"""The console script: what ``ros2 run tak_thermo_ros compensator`` and launch execute."""


def driver_params(path: Path, **parameters) -> Path:
    """A params file with the simulator's driver calibration and the node's parameters."""
    write_text_atomic(path, unit_yaml(DRIVER_UNIT, extra_parameters=parameters))
    return path


def values_of(message) -> tuple[float, ...]:
    """An Imu's accelerometer and gyroscope values."""
    a, w = message.linear_acceleration, message.angular_velocity
    return (a.x, a.y, a.z, w.x, w.y, w.z)


# -- 1. a signal while the node starts ------------------------------------------------------------

def _caught(pid: int, number: int) -> bool:
    """Whether process ``pid`` handles signal ``number`` (its SigCgt mask)."""
    status = Path(f'/proc/{pid}/status').read_text()
    mask = next(line for line in status.splitlines() if line.startswith('SigCgt:')).split()[1]
    return bool(int(mask, 16) >> (number - 1) & 1)


def _has_socket(pid: int) -> bool:
    """Whether process ``pid`` holds a socket: the middleware is up (``rclpy.init``)."""
    for fd in os.listdir(f'/proc/{pid}/fd'):
        try:
            if os.readlink(f'/proc/{pid}/fd/{fd}').startswith('socket:'):
                return True
        except OSError:
            continue
    return False


MOMENTS = [('importing', signal.SIGINT), ('importing', signal.SIGTERM), ('rclpy_up', signal.SIGTERM),
           ('rclpy_up', signal.SIGINT), ('ready', signal.SIGINT), ('ready', signal.SIGTERM)]


def test_a_signal_at_any_moment_of_start_up_ends_the_node_cleanly(tmp_path, ros_env):
    """SIGINT or SIGTERM at six moments of start-up: exit 0, no traceback.

    While the node imports, while rclpy is up and the node is built, and as it becomes ready.
    Each moment is reached by a condition on the process (its signal mask, its sockets, its log
    line), not by a sleep. Nothing else holds the start: the calibration and the learned file are
    only ever regular files, read at once (a FIFO, which held the node in ``open()`` deaf to both
    signals, is refused in one line: test/passes/test_pool_bad_input.py).
    """
    params = driver_params(tmp_path / 'params.yaml')
    for index, (moment, number) in enumerate(MOMENTS):
        log = tmp_path / f'node_{index}_{moment}.log'
        with NodeProcess([str(COMPENSATOR), '--ros-args', '--params-file', str(params)], ros_env, log) as node:
            pid = node.process.pid
            if moment == 'importing':  # the guard is in place; the imports take most of a second
                wait_until(lambda: _caught(pid, signal.SIGTERM), 20.0, what='the signal guard')
            elif moment == 'rclpy_up':
                wait_until(lambda: _has_socket(pid), 30.0, what='the middleware')
            else:
                wait_until(lambda: 'correcting' in node.log(), 30.0, what='the ready line')
            os.killpg(pid, number)
            node.process.wait(timeout=20.0)
            said = node.log()
            assert node.process.returncode == 0, (moment, number, said)
            assert 'Traceback' not in said and 'terminate called' not in said, (moment, said)
            if moment != 'ready':
                assert f'stopped by {signal.Signals(number).name} while starting' in said, (moment, said)


def test_a_node_dies_with_the_test_process_that_started_it(tmp_path, ros_env):
    """A test process that dies without its ``finally`` (a crashed pytest worker) takes its node with it.

    How a compensator outlived ``make test`` by 78 minutes: it runs in its own session, so only
    the test's own stop() ends it, and a test process killed (SIGKILL, the OOM killer, a worker
    crash) runs none. A helper process starts a node as the tests do and is killed at once.
    """
    params = driver_params(tmp_path / 'params.yaml')
    script = (f'import os, signal, sys\n'
              f'sys.path.insert(0, {str(TEST)!r})\n'
              f'from pathlib import Path\n'
              f'from node_helpers import NodeProcess\n'
              f'node = NodeProcess({node_command("--params-file", str(params))!r}, dict(os.environ), '
              f'Path({str(tmp_path / "node.log")!r}))\n'
              f'print(node.process.pid, flush=True)\n'
              f'os.kill(os.getpid(), signal.SIGKILL)\n')
    helper = start_process([sys.executable, '-c', script], env=ros_env, stdout=subprocess.PIPE, text=True)
    node_pid = int(helper.stdout.readline())
    try:
        assert helper.wait(timeout=30.0) == -signal.SIGKILL
        wait_until(lambda: not group_running(node_pid), 20.0, what='the node of the killed test process to die')
    finally:
        helper.stdout.close()
        with contextlib.suppress(ProcessLookupError):
            os.killpg(node_pid, signal.SIGKILL)


def test_a_node_its_test_left_running_is_found_and_killed(tmp_path, ros_env):
    """The guard of conftest.py: a group a test started and never stopped is killed at its end, and said."""
    since = len(STARTED_GROUPS)
    node = NodeProcess(node_command('--params-file', str(driver_params(tmp_path / 'params.yaml'))), ros_env,
                       tmp_path / 'node.log')  # never stopped: a test that forgot
    try:
        wait_until(lambda: 'correcting' in node.log(), 30.0, what='the node to start')
        assert group_running(node.process.pid)
        assert kill_leftovers(since) == [node.process.pid]
        assert not group_running(node.process.pid) and kill_leftovers(since) == []
    finally:
        node.stop()
    assert node.process.returncode == -signal.SIGKILL


def test_ctrl_c_logs_the_watch_verdict_to_rosout_and_no_rcl_error(tmp_path, ros_env):
    """A stop as Ctrl-C gives it, to the node as ``ros2 run`` starts it (issue 43): its last line reaches /rosout.

    With rclpy's own signal handlers the context was gone before the node said its watch's verdict:
    every stop printed ``Failed to publish log message to rosout: publisher's context is invalid``.
    """
    from everyday_watch import watch_unit  # the watch on: the node says its verdict at shutdown
    params = tmp_path / 'params.yaml'
    write_text_atomic(params, unit_yaml(watch_unit()))
    lines: list[str] = []
    rosout = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
    with Harness(int(ros_env['ROS_DOMAIN_ID']), driver=True) as ros:
        ros.node.create_subscription(Log, '/rosout', lambda m: lines.append(m.msg), rosout)
        with NodeProcess([str(COMPENSATOR), '--ros-args', '--params-file', str(params)], ros_env,
                         tmp_path / 'node.log') as node:
            wait_until(lambda: 'calibration watch on' in node.log(), 30.0, what='the ready lines')
            ros.wait(lambda: any('calibration watch on' in line for line in lines), 30.0, 'its lines on /rosout')
            os.killpg(node.process.pid, signal.SIGINT)
            node.process.wait(timeout=20.0)
            ros.wait(lambda: any('calibration watch at shutdown' in line for line in lines), 10.0,
                     'the verdict on /rosout')
            said = node.log()
    assert node.process.returncode == 0, said
    assert 'calibration watch at shutdown: calibration holds' in said
    assert 'Failed to publish' not in said and 'Traceback' not in said, said


# -- 2. two compensators on one /diagnostics --------------------------------------------------------

def test_two_compensators_in_two_namespaces_are_told_apart_in_diagnostics(tmp_path, ros_env):
    """The manual's two-IMU set-up, one file: each status names its node and carries its unit's id.

    /imu0/compensator and /imu1/compensator, with their hardware_id, before the first Imu already.
    """
    params = driver_params(tmp_path / 'params.yaml')
    domain = int(ros_env['ROS_DOMAIN_ID'])
    with NodeProcess(node_command('-r', '__ns:=/imu0', '--params-file', str(params), '-p', 'hardware_id:=SN-0'),
                     ros_env, tmp_path / 'imu0.log') as imu0, \
            NodeProcess(node_command('-r', '__ns:=/imu1', '--params-file', str(params), '-p', 'hardware_id:=SN-1'),
                        ros_env, tmp_path / 'imu1.log') as imu1, \
            Harness(domain, namespace='imu0', driver=True) as ros:
        def seen() -> dict[str, str]:
            return {s.name: s.hardware_id for array in ros.diagnostics for s in array.status}

        names = {'/imu0/compensator: temperature compensation': 'SN-0',
                 '/imu1/compensator: temperature compensation': 'SN-1'}
        ros.wait(lambda: names.items() <= seen().items(), 30.0, 'a status of each compensator')
        assert {name for name in seen() if 'compensation' in name} == set(names)
        for array in ros.diagnostics:
            for status in array.status:  # each says what it waits for, in its own namespace
                assert f'{status.name[:5]}/imu/temperature' in status.message, status
        assert imu0.stop() == 0 and imu1.stop() == 0


# -- 4 and 5. a future-stamped Imu, a non-physical one, a nonsense parameter ----------------------

def test_a_future_stamped_imu_costs_only_itself_and_nonsense_is_refused(tmp_path, ros_env):
    """An Imu stamped an hour ahead costs only itself; 1e308 m/s^2 is dropped; a nonsense update is refused.

    The outlier is dropped and said, the good Imu after it published (the offline rule drops the
    same); the 1e308 one dropped and counted; a live offset_shape that makes the gyroscope read
    31 rad/s refused, the old correction still published.
    """
    params = driver_params(tmp_path / 'params.yaml', qos='reliable')
    corrector = UnitCorrector(DRIVER_UNIT)
    hour = 3600 * NANOSECONDS
    sent = [(START_NS + 1_000_000, GOOD), (START_NS + 2_000_000, GOOD),
            (START_NS + 2_000_000 + hour, GOOD),  # a driver glitch: stamped an hour ahead
            (START_NS + 3_000_000, GOOD), (START_NS + 4_000_000, GOOD),
            (START_NS + 5_000_000, (1e308, *GOOD[1:])),  # non-physical
            (START_NS + 6_000_000, GOOD)]
    stamps = np.array([stamp for stamp, _ in sent], dtype=np.int64)
    offline, _ = stamp_problems(stamps)
    assert offline['stamp_jump'].tolist() == [False, False, True, False, False, False, False]
    expected = [stamp for (stamp, values), jump in zip(sent, offline['stamp_jump']) if not jump and values == GOOD]
    with NodeProcess(node_command('--params-file', str(params)), ros_env, tmp_path / 'node.log') as node, \
            Harness(int(ros_env['ROS_DOMAIN_ID']), driver=True) as ros:
        ros.wait_matched()
        ros.send_temperature_and_wait(START_NS, 20.0)
        for stamp, values in sent:
            ros.send_imu(stamp, values)
        ros.wait(lambda: len(ros.imu) == len(expected), 10.0, 'the good Imu')
        ros.wait(lambda: status_values(ros.latest_status())['received'] == str(len(sent)), 10.0, 'the counters')
        assert [stamp_of(m) for m in ros.imu] == expected
        assert all(values_of(m) == corrector.correct_sample(GOOD, 20.0) for m in ros.imu)
        values = status_values(ros.latest_status())
        assert (values['dropped.stamp_jump'], values['dropped.non_physical'], values['dropped.time_backwards']) == (
            '1', '1', '0')
        assert int(values['received']) == int(values['published']) + int(values['dropped'])
        wait_until(lambda: 'header stamp 3600.000000 s (> 10 s) after the previous one: dropped' in node.log(), 10.0,
                   what='the stamp-jump warning')

        refused = ros.set_parameters({'calibration.gyro.z.offset_shape': [1.0, 2.0, 3.0]})[0]
        assert not refused.successful and refused.reason.startswith('calibration.gyro.z.offset_shape: the offset')
        assert 'beyond what was fitted' in refused.reason
        ros.send_imu(START_NS + 7_000_000, GOOD)
        ros.wait(lambda: len(ros.imu) == len(expected) + 1, 10.0, 'an Imu after the refusal')
        assert values_of(ros.imu[-1]) == corrector.correct_sample(GOOD, 20.0)
        assert node.stop() == 0
    assert 'Traceback' not in node.log()


def test_a_lone_imu_stamped_an_hour_ahead_costs_itself_alone_wherever_it_comes(tmp_path, ros_env):
    """An Imu an hour ahead as the second, and as the third, message after a pause: each costs itself alone.

    A steady 100 Hz stream with two pauses of 1000 s: the outliers are dropped (stamp_jump),
    every good Imu published but the first after each pause (a real jump's own cost,
    docs/node.md); ``apply``'s rule (``stamp_problems``) drops the same messages. Before, the
    good Imu after each outlier was dropped as well (and the third-after-pause outlier published).
    """
    params = driver_params(tmp_path / 'params.yaml', qos='reliable')
    hour, step, pause = 3600 * NANOSECONDS, 10_000_000, 1000 * NANOSECONDS
    stamps = [START_NS + part * pause + i * step for part in range(3) for i in range(20)]
    outliers = (21, 42)  # the second message after the first pause; the third after the second
    for index in outliers:
        stamps[index] += hour
    offline, _ = stamp_problems(np.array(stamps, dtype=np.int64))
    dropped = np.flatnonzero(offline['stamp_jump'] | offline['time_backwards'] | offline['duplicate_stamp'])
    assert dropped.tolist() == [20, 21, 40, 42] and offline['stamp_jump'][list(outliers)].all()  # 20, 40: the pauses
    expected = [stamp for i, stamp in enumerate(stamps) if i not in dropped]
    with NodeProcess(node_command('--params-file', str(params)), ros_env, tmp_path / 'node.log') as node, \
            Harness(int(ros_env['ROS_DOMAIN_ID']), driver=True) as ros:
        ros.wait_matched()
        ros.send_temperature_and_wait(START_NS, 20.0)
        for stamp in stamps:
            ros.send_imu(stamp, GOOD)
        ros.wait(lambda: ros.latest_status() is not None
                 and status_values(ros.latest_status()).get('received') == str(len(stamps)), 10.0, 'the counters')
        ros.wait(lambda: len(ros.imu) >= len(expected), 10.0, 'the good Imu')
        assert [stamp_of(m) for m in ros.imu] == expected
        values = status_values(ros.latest_status())
        assert (values['dropped.stamp_jump'], values['dropped.time_backwards'], values['published']) == (
            '4', '0', str(len(expected)))
        assert node.stop() == 0
    assert 'Traceback' not in node.log()


def test_an_implausible_calibration_file_is_refused_in_one_line(tmp_path, ros_env):
    """The same nonsense from the file: exit 2, one FATAL line naming the key."""
    mapping = unit_to_mapping(DRIVER_UNIT)
    mapping['gyro']['z']['offset_shape'] = [1.0, 2.0, 3.0]
    path = tmp_path / 'implausible.yaml'
    path.write_text(yaml.safe_dump({'/**/compensator': {'ros__parameters': {'calibration': mapping}}}))
    result = run_to_exit(node_command('--params-file', str(path)), ros_env)
    lines = (result.stdout + result.stderr).strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1, lines
    assert '[FATAL]' in lines[0] and 'calibration.gyro.z.offset_shape: the offset drifts by' in lines[0]
