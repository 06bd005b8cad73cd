"""The ``ros2 run`` contract, checked without ros2cli: colcon build, ament index, run, receive.

``ros2 run PKG EXE`` looks the package's prefix up in the ament index and executes
``<prefix>/lib/PKG/EXE``; that is what this test does, on a colcon build into a temporary
workspace, with the venv's colcon (colcon-common-extensions).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from node_helpers import Harness, NodeProcess, copy_package, domain_id, ros_environment, stamp_of

from tak_thermo_ros.formats.calibration_file import load_calibration
from tak_thermo_ros.core.link.correction import Corrector

PACKAGE = 'tak_thermo_ros'
START_NS = 1_700_000_000 * 1_000_000_000


def colcon_build(workspace: Path) -> Path:
    """Copy the package into ``workspace/src`` and build it with colcon; the install base."""
    copy_package(workspace)
    colcon = Path(sys.executable).parent / 'colcon'
    env = {**os.environ, 'COLCON_HOME': str(workspace / 'colcon_home')}
    result = subprocess.run(
        [str(colcon), '--log-base', str(workspace / 'log'), 'build', '--base-paths', str(workspace / 'src'),
         '--build-base', str(workspace / 'build'), '--install-base', str(workspace / 'install')],
        cwd=workspace, env=env, capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL)
    assert result.returncode == 0, result.stdout + result.stderr
    return workspace / 'install'


@pytest.fixture(scope='module')
def installed(tmp_path_factory) -> tuple[Path, Path]:
    """The package built once with colcon for this module: (workspace, install prefix)."""
    workspace = tmp_path_factory.mktemp('colcon')
    install = colcon_build(workspace)
    return workspace, install / PACKAGE  # colcon's default isolated layout: one prefix per package


def run_environment(tmp_path: Path, prefix: Path, monkeypatch: pytest.MonkeyPatch, index: int) -> dict[str, str]:
    """What sourcing install/setup.bash would add, confined to this test's domain and tmp_path."""
    site = prefix / 'lib' / f'python{sys.version_info.major}.{sys.version_info.minor}' / 'site-packages'
    env = ros_environment(tmp_path, domain_id(index))
    env.update(AMENT_PREFIX_PATH=str(prefix), PYTHONPATH=os.pathsep.join(
        p for p in (str(site), os.environ.get('PYTHONPATH', '')) if p))
    for key in ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_DOMAIN_ID', 'ROS_HOME', 'ROS_LOG_DIR'):
        monkeypatch.setenv(key, env[key])
    return env


def test_colcon_build_ament_index_and_run(installed, tmp_path, monkeypatch):
    """Built with colcon, found through the ament index like `ros2 run`, it corrects a sample."""
    _, prefix = installed
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(prefix))
    from ament_index_python.packages import get_package_prefix, get_package_share_directory
    from ament_index_python.resources import get_resource
    assert get_resource('packages', PACKAGE) == ('', str(prefix))
    assert Path(get_package_prefix(PACKAGE)) == prefix
    executable = Path(get_package_prefix(PACKAGE)) / 'lib' / PACKAGE / 'compensator'
    assert executable.is_file() and os.access(executable, os.X_OK)
    share = Path(get_package_share_directory(PACKAGE))
    config = share / 'config' / 'compensator.yaml'
    assert config.is_file() and (share / 'launch' / 'compensator.launch.py').is_file()
    assert (share / 'config' / 'compensator_driver.yaml').is_file()

    # The script's interpreter must reach rclpy and must load the package from the install,
    # not from the source tree.
    site = prefix / 'lib' / f'python{sys.version_info.major}.{sys.version_info.minor}' / 'site-packages'
    env = run_environment(tmp_path, prefix, monkeypatch, 97)
    interpreter = executable.read_text(encoding='utf-8').splitlines()[0].removeprefix('#!').strip()
    probe = subprocess.run([interpreter, '-c', 'import rclpy, tak_thermo_ros; print(tak_thermo_ros.__file__)'],
                           env=env, cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert probe.returncode == 0, probe.stderr
    assert Path(probe.stdout.strip()).is_relative_to(site)

    # ros2 run tak_thermo_ros compensator --ros-args -r __ns:=/contract --params-file <share>/config/...
    command = [str(executable), '--ros-args', '-r', '__ns:=/contract', '--params-file', str(config)]
    corrector = Corrector(load_calibration(config))
    with NodeProcess(command, env, tmp_path / 'node.log', cwd=tmp_path) as node, \
            Harness(int(env['ROS_DOMAIN_ID']), namespace='contract') as ros:
        ros.wait_matched()
        # The default input QoS is best effort: send again until one sample comes back.
        for attempt in range(1, 6):
            ros.send_temperature(START_NS, 8500.0)
            ros.send_counts(START_NS + attempt, 1000.0, -1000.0, 2600.0)
            try:
                ros.wait(lambda: len(ros.imu) > 0, 5.0, 'a corrected Imu')
                break
            except AssertionError:
                if attempt == 5:
                    raise
        imu = ros.imu[0]
        a = imu.linear_acceleration
        assert (a.x, a.y, a.z) == corrector.correct_sample(1000.0, -1000.0, 2600.0, 8500.0)
        assert stamp_of(imu) > START_NS and imu.header.frame_id == 'tak_imu'
        assert node.stop() == 0
    log = node.log()
    assert '/contract/tak/counts' in log and 'Traceback' not in log


def test_ros2_run_with_a_driver_calibration(installed, tmp_path, monkeypatch):
    """`ros2 run tak_thermo_ros compensator --ros-args --params-file P.yaml`, P fitted from a driver bag.

    Nothing else: imu/data_raw + imu/temperature in, imu/data_compensated out, as apply.
    """
    from tak_thermo_ros import cli
    from tak_thermo_ros.formats.bag import read_imu_messages, write_driver_record
    from tak_thermo_ros.core.simulation.imu import simulate
    from tak_thermo_ros.core.simulation.scenario import Scenario
    _, prefix = installed
    run = simulate(Scenario(output='imu', sample_rate_hz=10.0, plateaus_celsius=(10.0, 30.0), plateau_hours=0.005,
                            ramp_celsius_per_minute=10.0, board_lag_s=5.0, dwell_s=1.0))
    bag, params, corrected = tmp_path / 'driver.mcap', tmp_path / 'P.yaml', tmp_path / 'apply.mcap'
    write_driver_record(bag, run.driver)
    assert cli.main(['fit', str(bag), '-o', str(params), '--no-progress']) == 0
    assert cli.main(['apply', str(bag), '--params', str(params), '-o', str(corrected), '--no-progress']) == 0
    expected = read_imu_messages(corrected, topic='/imu/data_compensated')
    driver = run.driver
    env = run_environment(tmp_path, prefix, monkeypatch, 98)
    command = [str(prefix / 'lib' / PACKAGE / 'compensator'), '--ros-args', '--params-file', str(params),
               '-p', 'qos:=reliable']
    rows = range(0, len(driver.stamp_ns), len(driver.stamp_ns) // 5)  # across the run, a temperature before each
    with NodeProcess(command, env, tmp_path / 'node.log', cwd=tmp_path) as node, \
            Harness(int(env['ROS_DOMAIN_ID']), driver=True) as ros:
        ros.wait_matched()
        for count, row in enumerate(rows, start=1):
            held = int(np.searchsorted(driver.temp_stamp_ns, driver.stamp_ns[row], side='right')) - 1
            ros.send_temperature_and_wait(int(driver.temp_stamp_ns[held]), float(driver.temperature[held]))
            ros.send_imu(int(driver.stamp_ns[row]), (*driver.accel[row], *driver.gyro[row]),
                         frame_id=driver.frame_id, orientation=driver.orientation[row],
                         orientation_covariance=driver.orientation_covariance[row])
            ros.wait(lambda: len(ros.imu) >= count, 10.0, 'a corrected Imu')
        assert node.stop() == 0
    got = np.array([(m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z,
                     m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z) for m in ros.imu])
    want = np.hstack([expected.linear_acceleration, expected.angular_velocity])[list(rows)]
    assert np.array_equal(got, want)  # no effects with memory: each sample alone equals apply's
    assert [stamp_of(m) for m in ros.imu] == expected.stamp_ns[list(rows)].tolist()
    log = node.log()
    assert '/imu/data_raw with /imu/temperature -> /imu/data_compensated' in log and 'Traceback' not in log
