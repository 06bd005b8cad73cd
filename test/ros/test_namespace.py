"""The node in a namespace with the file `tak_calib fit` wrote: what `ros2 launch namespace:=imu0` passes.

The real rclpy, no ros2 command line (test/ros/test_ros2_cli.py runs those): the node started with
``--ros-args -r __ns:=/imu0 --params-file FILE``, exactly the arguments launch_ros gives it.
"""

from __future__ import annotations

import pytest
import yaml

from node_helpers import Harness, NodeProcess, fitted_driver_params, node_command, run_to_exit
from tak_thermo_ros.core.link.correction import UnitCorrector
from tak_thermo_ros.formats.calibration_file import load_unit

START_NS = 1_700_000_000 * 1_000_000_000
SAMPLE = (0.1, -0.2, 9.81, 0.01, -0.02, 0.03)


@pytest.fixture(scope='module')
def fitted(tmp_path_factory):
    """A params file `tak_calib fit` wrote from a short driver bag."""
    return fitted_driver_params(tmp_path_factory.mktemp('fitted'), 'P.yaml')


def exchange(ros: Harness, temperature: float) -> tuple[float, ...]:
    """Send a temperature and an Imu until a corrected Imu comes back (best-effort input); its values."""
    for attempt in range(1, 11):
        count = len(ros.imu)
        ros.send_temperature(START_NS + 10 * attempt, temperature)
        ros.send_imu(START_NS + 10 * attempt + 1, SAMPLE)
        try:
            ros.wait(lambda: len(ros.imu) > count, 3.0, 'a corrected Imu')
            break
        except AssertionError:
            if attempt == 10:
                raise
    m = ros.imu[-1]
    return (m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z,
            m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z)


def test_the_fitted_file_gives_the_node_in_imu0_its_calibration(fitted, tmp_path, ros_env):
    """`-r __ns:=/imu0 --params-file FILE`: topics in /imu0, the output is the file's correction."""
    assert list(yaml.safe_load(fitted.read_text())) == ['/**/compensator']
    corrector = UnitCorrector(load_unit(fitted))
    command = node_command('-r', '__ns:=/imu0', '--params-file', str(fitted))
    with NodeProcess(command, ros_env, tmp_path / 'node.log') as node, \
            Harness(int(ros_env['ROS_DOMAIN_ID']), namespace='imu0', driver=True) as ros:
        ros.wait_matched()
        assert exchange(ros, 20.0) == corrector.correct_sample(SAMPLE, 20.0)
        assert node.stop() == 0
    log = node.log()
    assert '/imu0/imu/data_raw with /imu0/imu/temperature -> /imu0/imu/data_compensated' in log
    assert 'from parameters calibration.*' in log and 'Traceback' not in log


def test_an_old_file_in_a_namespace_is_a_fatal_line_and_calibration_file_loads_it(fitted, tmp_path, ros_env):
    """A file with the old root key `compensator:` in /imu0: rcl gives it to no node, one FATAL line.

    `-p calibration_file:=FILE` reads any key: the same file serves the node in /imu0 (and a
    renamed node).
    """
    old = tmp_path / 'old.yaml'
    document = yaml.safe_load(fitted.read_text())
    old.write_text(yaml.safe_dump({'compensator': document['/**/compensator']}, sort_keys=False))
    refused = run_to_exit(node_command('-r', '__ns:=/imu0', '--params-file', str(old)), ros_env)
    assert refused.returncode == 2
    fatal = [line for line in (refused.stdout + refused.stderr).splitlines() if 'FATAL' in line]
    assert len(fatal) == 1 and "'/**/compensator:' in any" in fatal[0], refused.stderr
    corrector = UnitCorrector(load_unit(old))
    command = node_command('-r', '__ns:=/imu0', '-r', '__node:=imu0_compensator', '-p', f'calibration_file:={old}')
    with NodeProcess(command, ros_env, tmp_path / 'node.log') as node, \
            Harness(int(ros_env['ROS_DOMAIN_ID']), namespace='imu0', driver=True) as ros:
        ros.wait_matched()
        assert exchange(ros, 25.0) == corrector.correct_sample(SAMPLE, 25.0)
        assert node.stop() == 0
    assert f'from {old}' in node.log()
