"""The ``ros2 run`` contract, checked without ros2cli: colcon build, ament index, run, receive.

``ros2 run PKG EXE`` looks the package's prefix up in the ament index and executes
``<prefix>/lib/PKG/EXE``; that is what this test does, on a colcon build into a temporary
workspace, with the venv's colcon (colcon-common-extensions).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

from node_helpers import Harness, NodeProcess, domain_id, ros_environment, stamp_of

from tak_thermo_ros.core.calibration_file import load_calibration
from tak_thermo_ros.core.correction import Corrector

REPO = Path(__file__).resolve().parent.parent
PACKAGE = 'tak_thermo_ros'
SOURCES = ('setup.py', 'setup.cfg', 'package.xml', 'resource', PACKAGE, 'config', 'launch')
START_NS = 1_700_000_000 * 1_000_000_000


def colcon_build(workspace: Path) -> Path:
    """Copy the package into ``workspace/src`` and build it with colcon; the install base."""
    source = workspace / 'src' / PACKAGE
    source.mkdir(parents=True)
    for name in SOURCES:
        if (REPO / name).is_dir():
            shutil.copytree(REPO / name, source / name, ignore=shutil.ignore_patterns('__pycache__', '*.pyc'))
        else:
            shutil.copy2(REPO / name, source / name)
    colcon = Path(sys.executable).parent / 'colcon'
    env = {**os.environ, 'COLCON_HOME': str(workspace / 'colcon_home')}
    result = subprocess.run(
        [str(colcon), '--log-base', str(workspace / 'log'), 'build', '--base-paths', str(workspace / 'src'),
         '--build-base', str(workspace / 'build'), '--install-base', str(workspace / 'install')],
        cwd=workspace, env=env, capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL)
    assert result.returncode == 0, result.stdout + result.stderr
    return workspace / 'install'


def test_colcon_build_ament_index_and_run(tmp_path, monkeypatch):
    """Built with colcon, found through the ament index like `ros2 run`, it corrects a sample."""
    install = colcon_build(tmp_path)
    prefix = install / PACKAGE  # colcon's default isolated layout: one prefix per package
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

    # What sourcing install/setup.bash would add; the script's interpreter must reach rclpy
    # and must load the package from the install, not from the source tree.
    site = prefix / 'lib' / f'python{sys.version_info.major}.{sys.version_info.minor}' / 'site-packages'
    env = ros_environment(tmp_path, domain_id(97))
    env.update(AMENT_PREFIX_PATH=str(prefix), PYTHONPATH=os.pathsep.join(
        p for p in (str(site), os.environ.get('PYTHONPATH', '')) if p))
    for key in ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_DOMAIN_ID', 'ROS_HOME', 'ROS_LOG_DIR'):
        monkeypatch.setenv(key, env[key])
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
