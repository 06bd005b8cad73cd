"""The real ``ros2`` command line on the colcon-built package, as a ROS 2 user drives it.

``ros2 launch tak_thermo_ros compensator.launch.py namespace:=imu0 params_file:=<the file
tak_calib fit wrote>``, then ``ros2 node list``, ``ros2 topic echo`` of the corrected Imu, and
``ros2 param set`` of a bad value at run time (refused; the node keeps publishing).

The tools: a system ``ros2`` (and ``colcon``) on PATH, as on a robot with ROS 2 Jazzy sourced;
else the build of ``../shared/ros2cli/build.sh`` under ``$ROSCLI_PREFIX`` (default
``~/.cache/ros2cli-jazzy``), which ``make test`` makes when it is missing. Without either, these
tests are skipped with a reason saying how to get them. The package is colcon-built with the
tools' own colcon and Python: the node then runs with what that ROS environment has (the
ros2cli build: rclpy, the messages, numpy and yaml; no scipy, matplotlib or rosbags).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest
import yaml

from node_helpers import (Harness, NodeProcess, copy_package, fitted_driver_params, run_to_exit, start_process,
                          wait_until)
from tak_thermo_ros.core.link.correction import UnitCorrector
from tak_thermo_ros.formats.calibration_file import load_unit

PACKAGE = 'tak_thermo_ros'
START_NS = 1_700_000_000 * 1_000_000_000
SAMPLE = (0.1, -0.2, 9.81, 0.01, -0.02, 0.03)
HOW_TO_GET = ('no ros2 command: source ROS 2 Jazzy (/opt/ros/jazzy/setup.bash) or build the tools with '
              '`bash ../shared/ros2cli/build.sh --no-verify` (2-3 min; `make test` does it when '
              '../shared/ros2cli exists)')


def ros2_prelude() -> str | None:
    """Shell lines that put ``ros2`` and ``colcon`` on PATH; ``None`` when neither source has them."""
    if shutil.which('ros2') and shutil.which('colcon'):
        return ':'  # a sourced ROS 2 installation
    prefix = Path(os.environ.get('ROSCLI_PREFIX', Path.home() / '.cache' / 'ros2cli-jazzy'))
    if (prefix / 'env.sh').is_file() and (prefix / 'venv' / 'bin' / 'ros2').is_file():
        return f'. {prefix / "env.sh"}'
    return None


PRELUDE = ros2_prelude()
pytestmark = pytest.mark.skipif(PRELUDE is None, reason=HOW_TO_GET)


def clean_environment() -> dict[str, str]:
    """This process's environment without the test venv's Python settings."""
    return {key: value for key, value in os.environ.items()
            if key not in ('VIRTUAL_ENV', 'PYTHONPATH', 'PYTHONHOME')}


@pytest.fixture(scope='module')
def workspace(tmp_path_factory) -> Path:
    """The package colcon-built with the tools' colcon; a script running a command in its environment."""
    workspace = tmp_path_factory.mktemp('ros2_ws')
    copy_package(workspace)
    build = subprocess.run(
        ['bash', '-c', f'{PRELUDE} && cd {workspace} && colcon build --event-handlers console_direct-'],
        env={**clean_environment(), 'COLCON_HOME': str(workspace / 'colcon_home')},
        capture_output=True, text=True, timeout=600, stdin=subprocess.DEVNULL)
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr[-3000:]
    # What a user types: source the tools, then the workspace; ROS_HOME etc. are the test's own.
    (workspace / 'run.sh').write_text(
        f'{PRELUDE}\n. {workspace}/install/setup.bash\n'
        'export ROS_HOME="$TEST_ROS_HOME" ROS_LOG_DIR="$TEST_ROS_HOME/log"\nexec "$@"\n', encoding='utf-8')
    return workspace


def ros2(workspace: Path, env: dict[str, str], *args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    """``ros2 ARGS`` in the workspace's environment, run to its exit."""
    return run_to_exit(['bash', str(workspace / 'run.sh'), 'ros2', *args], env, timeout=timeout)


@pytest.fixture
def cli_env(ros_env) -> dict[str, str]:
    """The test's ROS environment (domain, localhost, ROS_HOME) for the command-line tools."""
    env = {**clean_environment(), **{key: ros_env[key] for key in (
        'ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_DOMAIN_ID', 'RCUTILS_COLORIZED_OUTPUT', 'PYTHONUNBUFFERED')}}
    env['TEST_ROS_HOME'] = ros_env['ROS_HOME']
    return env


@pytest.fixture(scope='module')
def fitted(tmp_path_factory) -> Path:
    """The params file `tak_calib fit` wrote from a short driver bag."""
    return fitted_driver_params(tmp_path_factory.mktemp('fitted'), 'imu0.yaml')


def send(ros: Harness, index: int, temperature: float) -> None:
    """One temperature and one Imu (the Imu stamped just after)."""
    ros.send_temperature(START_NS + 10 * index, temperature)
    ros.send_imu(START_NS + 10 * index + 1, SAMPLE)


def corrected_values(message) -> tuple[float, ...]:
    """An Imu's accelerometer and gyroscope values."""
    a, w = message.linear_acceleration, message.angular_velocity
    return (a.x, a.y, a.z, w.x, w.y, w.z)


def exchange(ros: Harness, index: int, temperature: float) -> tuple[float, ...]:
    """Send until a new corrected Imu comes back (the node's input is best effort); its values."""
    count = len(ros.imu)
    for attempt in range(20):
        send(ros, index * 100 + attempt, temperature)
        try:
            ros.wait(lambda: len(ros.imu) > count, 2.0, 'a corrected Imu')
            return corrected_values(ros.imu[-1])
        except AssertionError:
            continue
    msg = 'no corrected Imu after 20 tries'
    raise AssertionError(msg)


def test_ros2_launch_in_a_namespace_with_the_fitted_file(workspace, fitted, cli_env, tmp_path):
    """`ros2 launch ... namespace:=imu0 params_file:=<fit's file>`: corrected Imu in /imu0.

    `ros2 node list` shows /imu0/compensator, `ros2 topic echo` prints the corrected Imu,
    `ros2 param set` of a zero scale is refused with the reason and the node keeps publishing
    the same correction, which `ros2 param get` confirms.
    """
    corrector = UnitCorrector(load_unit(fitted))
    expected = corrector.correct_sample(SAMPLE, 20.0)
    command = ['bash', str(workspace / 'run.sh'), 'ros2', 'launch', PACKAGE, 'compensator.launch.py',
               'namespace:=imu0', f'params_file:={fitted}']
    with NodeProcess(command, cli_env, tmp_path / 'launch.log') as launch, \
            Harness(int(cli_env['ROS_DOMAIN_ID']), namespace='imu0', driver=True) as ros:
        ros.wait_matched(timeout=60.0)
        assert exchange(ros, 1, 20.0) == expected

        def node_listed() -> bool:
            listed = ros2(workspace, cli_env, 'node', 'list', '--no-daemon', '--spin-time', '2')
            return '/imu0/compensator' in listed.stdout.split()
        wait_until(node_listed, 30.0, what='ros2 node list to show /imu0/compensator')

        echo = start_process(['bash', str(workspace / 'run.sh'), 'ros2', 'topic', 'echo', '--once', '--no-daemon',
                              '/imu0/imu/data_compensated', 'sensor_msgs/msg/Imu'],
                             env=cli_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             stdin=subprocess.DEVNULL)
        try:
            deadline = time.monotonic() + 60.0
            index = 2
            while echo.poll() is None and time.monotonic() < deadline:
                send(ros, index, 20.0)
                index += 1
                ros.spin_once()
                time.sleep(0.05)
        finally:
            if echo.poll() is None:
                os.killpg(echo.pid, 9)
            out, err = echo.communicate()
        assert echo.returncode == 0, err
        printed = next(d for d in yaml.safe_load_all(out) if d)
        assert corrected_values_from(printed) == pytest.approx(expected, rel=1e-12, abs=0.0)
        assert printed['header']['frame_id'] == 'imu_link'

        refused = ros2(workspace, cli_env, 'param', 'set', '--no-daemon', '--timeout', '20',
                       '/imu0/compensator', 'calibration.accel.x.scale', '0.0')
        said = refused.stdout + refused.stderr
        assert said.strip() == 'Setting parameter failed: calibration.accel.x.scale: must be > 0, got 0.0', said
        assert exchange(ros, 50, 20.0) == expected  # still publishing, the same correction
        scale = ros2(workspace, cli_env, 'param', 'get', '--no-daemon', '--timeout', '20',
                     '/imu0/compensator', 'calibration.accel.x.scale')
        assert float(scale.stdout.split()[-1]) == load_unit(fitted).accel.axes[0].scale, scale.stdout
        launch.stop()
    log = launch.log()
    assert 'correcting /imu0/imu/data_raw with /imu0/imu/temperature -> /imu0/imu/data_compensated' in log
    assert 'FATAL' not in log and 'Traceback' not in log and 'process has died' not in log, log


def corrected_values_from(printed: dict) -> tuple[float, ...]:
    """The accelerometer and gyroscope values of an Imu as ``ros2 topic echo`` prints it."""
    a, w = printed['linear_acceleration'], printed['angular_velocity']
    return (a['x'], a['y'], a['z'], w['x'], w['y'], w['z'])
