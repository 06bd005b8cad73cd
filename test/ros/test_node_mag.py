"""The node's magnetometer channel with the real rclpy: MagneticField in, corrected MagneticField out.

The node's output equals ``tak_calib apply``'s ``/imu/mag_compensated``, float64 for float64;
bad magnetometer input is dropped and counted in its own diagnostics status, with the Imu's rules.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sensor_msgs.msg import MagneticField

from conftest import examples
from node_helpers import RELIABLE, Harness, NodeProcess, header_stamp, node_command, stamp_of, status_values
from paths import REPO
from tak_thermo_ros import cli
from tak_thermo_ros.formats.bag import MAGNETIC_FIELD, iter_topic_arrays, write_driver_record
from tak_thermo_ros.core.link.online import OnlineCompensator
from tak_thermo_ros.core.link.online_rules import ONLINE_DROP_REASONS
from tak_thermo_ros.core.magnetometer.channel import MagCorrector
from tak_thermo_ros.formats.calibration_file import load_unit
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.core.simulation.magnetometer import MagnetometerTruth, rotation_record
from tak_thermo_ros.errors import CalibrationError

RUN = Scenario(output='imu', sample_rate_hz=10.0, plateaus_celsius=(10.0, 30.0), plateau_hours=0.01,
               ramp_celsius_per_minute=10.0, board_lag_s=5.0, positions=((0.0, 0.0, 1.0),), record_references=False,
               magnetometer=MagnetometerTruth(), seed=7)
"""About 250 s of a static driver at 10 Hz with a drifting magnetometer (2500 Imu and MagneticField)."""


class MagHarness(Harness):
    """The driver harness plus the magnetometer's topics."""

    def __init__(self, domain: int) -> None:
        super().__init__(domain, driver=True)
        self.mag_publisher = self.node.create_publisher(MagneticField, '/imu/mag', RELIABLE)
        self.mag: list[MagneticField] = []
        self.mag_subscription = self.node.create_subscription(MagneticField, '/imu/mag_compensated',
                                                              self.mag.append, RELIABLE)

    def wait_mag_matched(self) -> None:
        self.wait_matched()
        self.wait(lambda: self.mag_publisher.get_subscription_count() >= 1
                  and self.mag_subscription.get_publisher_count() >= 1, 30.0, 'the magnetometer topics to match')
        self.wait(lambda: self.mag_status() is not None
                  and int(status_values(self.mag_status()).get('imu_subscribers', '0')) >= 1, 30.0,
                  'the node\'s MagneticField publisher to match')

    def send_mag(self, stamp_ns: int, values, frame_id: str = 'tak_imu') -> None:
        message = MagneticField()
        header_stamp(message, stamp_ns)
        message.header.frame_id = frame_id
        message.magnetic_field.x, message.magnetic_field.y, message.magnetic_field.z = (float(v) for v in values)
        message.magnetic_field_covariance = [7.0] * 9
        self.mag_publisher.publish(message)

    def mag_status(self):
        for array_message in reversed(self.diagnostics):
            for status in array_message.status:
                if 'magnetometer compensation' in status.name:
                    return status
        return None


def test_the_node_publishes_the_corrected_field_equal_to_apply(tmp_path, ros_env):
    driver = simulate(RUN).driver
    bag, iron, params, out = tmp_path / 'run', tmp_path / 'iron', tmp_path / 'p.yaml', tmp_path / 'out'
    write_driver_record(bag, driver)
    write_driver_record(iron, rotation_record(RUN.magnetometer, samples=1000, seed=8))
    assert cli.main(['fit', str(bag), '-o', str(params), '--iron-run', str(iron), '--no-progress']) == 0
    assert cli.main(['apply', str(bag), '--params', str(params), '-o', str(out), '--no-progress']) == 0
    arrays = list(iter_topic_arrays(out, '/imu/mag_compensated', MAGNETIC_FIELD))
    expected = np.concatenate([a['magnetic_field'] for a in arrays])
    expected_stamps = np.concatenate([a['stamp_ns'] for a in arrays])
    expected_covariance = arrays[0]['magnetic_field_covariance'][0]
    events = sorted([(int(s), 0, i) for i, s in enumerate(driver.temp_stamp_ns)]
                    + [(int(s), 1, i) for i, s in enumerate(driver.stamp_ns)]
                    + [(int(s), 2, i) for i, s in enumerate(driver.mag_stamp_ns)])
    with NodeProcess(node_command('--params-file', str(params), '-p', 'qos:=reliable'), ros_env,
                     tmp_path / 'node.log') as node, MagHarness(int(ros_env['ROS_DOMAIN_ID'])) as ros:
        ros.wait_mag_matched()
        sent = 0
        for stamp, stream, row in events:
            if stream == 0:
                # The temperature and the next field travel on different topics: let the node catch up.
                ros.wait(lambda: len(ros.mag) >= sent and len(ros.imu) >= sent, 20.0, 'the node to catch up')
                ros.send_temperature(stamp, driver.temperature[row])
            elif stream == 1:
                ros.send_imu(stamp, (*driver.accel[row], *driver.gyro[row]), frame_id=driver.frame_id)
            else:
                ros.wait(lambda: len(ros.mag) >= sent - 50, 20.0, 'the node to catch up')
                ros.send_mag(stamp, driver.mag[row], frame_id=driver.mag_frame_id)
                sent += 1
        ros.wait(lambda: len(ros.mag) >= sent, 20.0, 'the last MagneticField')
        ros.wait(lambda: ros.mag_status() is not None
                 and status_values(ros.mag_status())['received'] == str(sent), 10.0, 'the magnetometer status')
        values = status_values(ros.mag_status())
        assert node.stop() == 0
    got = np.array([(m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z) for m in ros.mag])
    assert got.dtype == np.float64 and len(got) == len(expected) == len(driver.mag_stamp_ns)
    assert np.array_equal(np.array([stamp_of(m) for m in ros.mag]), expected_stamps)
    assert np.array_equal(got, expected)
    assert all(np.array_equal(np.array(m.magnetic_field_covariance), expected_covariance) for m in ros.mag)
    assert expected_covariance[0] > 0.0 and {m.header.frame_id for m in ros.mag} == {driver.mag_frame_id}
    assert values['published'] == values['received'] == str(sent) and values['dropped'] == '0'
    # The correction matters: the raw field differs from it by the iron, far beyond the noise.
    assert np.max(np.abs(got - driver.mag)) > 10 * RUN.magnetometer.noise


def test_bad_magnetometer_input_is_dropped_and_counted_like_the_imu(tmp_path, ros_env):
    unit = Scenario(output='imu', magnetometer=MagnetometerTruth()).driver_truth()
    params = tmp_path / 'p.yaml'
    from tak_thermo_ros.formats.calibration_file import unit_yaml, write_text_atomic
    write_text_atomic(params, unit_yaml(unit, extra_parameters={'qos': 'reliable', 'temp_timeout': 30.0}))
    corrector = MagCorrector(load_unit(params).mag)
    start = 1_700_000_000 * 1_000_000_000
    good = (2.1e-5, 1.5e-6, 4.5e-5)
    with NodeProcess(node_command('--params-file', str(params)), ros_env, tmp_path / 'node.log') as node, \
            MagHarness(int(ros_env['ROS_DOMAIN_ID'])) as ros:
        ros.wait_mag_matched()
        ros.send_mag(start, good)  # no temperature yet
        ros.wait(lambda: ros.mag_status() is not None
                 and status_values(ros.mag_status())['dropped.waiting_for_temperature'] == '1', 10.0, 'waiting')
        ros.send_temperature_and_wait(start, 21.5)
        sent = [(start + 1, good, True), (start + 2, (good[0], math.nan, good[2]), False),
                (start + 2, good, False), (start + 1, good, False), (start + 3, (3e-5, -1e-6, 4e-5), True)]
        for stamp, values, _ in sent:
            ros.send_mag(stamp, values)
        published = [(stamp, values) for stamp, values, kept in sent if kept]
        ros.wait(lambda: len(ros.mag) == len(published), 10.0, 'the good fields')
        for message, (stamp, values) in zip(ros.mag, published):
            assert stamp_of(message) == stamp
            assert (message.magnetic_field.x, message.magnetic_field.y,
                    message.magnetic_field.z) == corrector.correct_sample(values, 21.5)
        ros.send_temperature_and_wait(start + 4, 60.0)  # out of range: clamped to 35
        ros.send_mag(start + 5, good)
        ros.wait(lambda: len(ros.mag) == 3, 10.0, 'the out-of-range field')
        assert ros.mag[-1].magnetic_field.z == corrector.correct_sample(good, 35.0)[2]
        ros.wait(lambda: status_values(ros.mag_status())['received'] == '7', 10.0, 'the status')
        values = status_values(ros.mag_status())
        dropped = {reason: int(values[f'dropped.{reason}']) for reason in ONLINE_DROP_REASONS}
        assert dropped['non_finite'] == 1 and dropped['duplicate_stamp'] == 1 and dropped['time_backwards'] == 1
        assert dropped['waiting_for_temperature'] == 1
        assert int(values['received']) == int(values['published']) + sum(dropped.values()) == 3 + 4
        assert values['out_of_range'] == '1' and values['calibrated_range'] == '5..35'
        assert node.stop() == 0
    log = node.log()
    assert 'Traceback' not in log and 'MagneticField' in log


def test_the_online_core_corrects_the_magnetometer_as_the_vectorised_path():
    run = simulate(replace(RUN, plateau_hours=0.002))
    driver, unit = run.driver, run.unit_truth
    core = OnlineCompensator(unit, channel='mag')
    core.process_temperature(float(driver.temperature[0]), 0.0)
    results = [core.process_values(int(s) // 10**9, int(s) % 10**9, tuple(v), 0.1)
               for s, v in zip(driver.mag_stamp_ns[:200], driver.mag[:200].tolist())]
    expected = MagCorrector(unit.mag).correct(driver.mag[:200], np.full(200, driver.temperature[0]))
    assert np.array_equal(np.array(results), expected)
    assert core.covariances[2][0] > 0.0 and core.status(0.2).value('published') == '200'


def test_the_launch_file_remaps_the_magnetometer_topics():
    import ast
    from tak_thermo_ros.ros import node as node_module
    tree = ast.parse((REPO / 'launch' / 'compensator.launch.py').read_text())
    constants = {n.targets[0].id: ast.literal_eval(n.value) for n in tree.body
                 if isinstance(n, ast.Assign) and isinstance(n.targets[0], ast.Name)
                 and n.targets[0].id == 'MAG_TOPICS'}
    assert constants['MAG_TOPICS'] == (node_module.MAG_TOPIC, node_module.COMPENSATED_MAG_TOPIC)


_EVENT = st.one_of(
    st.tuples(st.just('temperature'), st.sampled_from([0.0, 20.0, 40.0, math.nan, 2e7])),
    st.tuples(st.just('mag'), st.tuples(st.integers(-2, 3), st.sampled_from([2e-5, -4e-5, 1e-4, math.nan, math.inf]))))
_UNIT = Scenario(output='imu', magnetometer=MagnetometerTruth()).driver_truth()


@settings(max_examples=examples(60), deadline=None)
@given(st.lists(_EVENT, min_size=1, max_size=80))
def test_every_magnetometer_message_is_published_or_dropped_and_published_ones_equal_the_vectorised_path(events):
    core = OnlineCompensator(_UNIT, channel='mag')
    corrector = MagCorrector(_UNIT.mag)
    stamp, now, temperature = 10**18, 0.0, None
    for kind, value in events:
        now += 0.01
        if kind == 'temperature':
            if core.process_temperature(value, now):
                temperature = value
            continue
        step, field = value
        stamp += step
        values = (field, 3e-6, -field / 2)
        result = core.process_values(stamp // 10**9, stamp % 10**9, values, now)
        if isinstance(result, tuple):
            assert temperature is not None and all(math.isfinite(v) for v in result)
            assert result == tuple(corrector.correct(np.array([values]), np.array([temperature]))[0])
    assert core.received == core.published + core.dropped_total()
    assert core.received == sum(1 for kind, _ in events if kind == 'mag')


def test_magnetometer_calibration_updates_at_run_time_are_checked_and_put_in_force(tmp_path, ros_env):
    from tak_thermo_ros.formats.calibration_file import unit_yaml, write_text_atomic
    params = tmp_path / 'p.yaml'
    write_text_atomic(params, unit_yaml(_UNIT, extra_parameters={'qos': 'reliable'}))
    start = 1_700_000_000 * 1_000_000_000
    field = (2.1e-5, 1.5e-6, 4.5e-5)
    with NodeProcess(node_command('--params-file', str(params)), ros_env, tmp_path / 'node.log') as node, \
            MagHarness(int(ros_env['ROS_DOMAIN_ID'])) as ros:
        ros.wait_mag_matched()
        ros.send_temperature_and_wait(start, 20.0)

        def corrected(stamp: int) -> tuple[float, float, float]:
            count = len(ros.mag)
            ros.send_mag(stamp, field)
            ros.wait(lambda: len(ros.mag) == count + 1, 10.0, 'a corrected field')
            return tuple(getattr(ros.mag[-1].magnetic_field, axis) for axis in 'xyz')

        assert corrected(start + 1) == MagCorrector(_UNIT.mag).correct_sample(field, 20.0)
        moved = replace(_UNIT.mag, hard_iron=(1e-6, -2e-6, 3e-6))
        results = ros.set_parameters({'calibration.mag.hard_iron': list(moved.hard_iron)})
        assert results[0].successful, results[0].reason
        assert corrected(start + 2) == MagCorrector(moved).correct_sample(field, 20.0)
        crooked = [1.0, 0.1, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        results = ros.set_parameters({'calibration.mag.soft_iron': crooked})
        assert not results[0].successful and 'calibration.mag.soft_iron' in results[0].reason
        assert corrected(start + 3) == MagCorrector(moved).correct_sample(field, 20.0)
        assert node.stop() == 0
    assert 'Traceback' not in node.log()


def test_the_magnetometer_channel_refuses_a_calibration_without_it():
    core = OnlineCompensator(_UNIT, channel='mag')
    with pytest.raises(CalibrationError, match='calibration.mag: missing'):
        core.prepare(calibration=replace(_UNIT, mag=None))
    with pytest.raises(CalibrationError, match='calibration.mag: missing'):
        OnlineCompensator(replace(_UNIT, mag=None), channel='mag')


def test_a_calibration_without_temperature_terms_corrects_with_no_temperature_topic(tmp_path, ros_env):
    """A rotation record without a temperature: its file (thermal: none) loads through rcl.

    The node publishes the Imu and the field without ever waiting for a temperature, equal to the
    offline correction.
    """
    from tak_thermo_ros.core.link.correction import UnitCorrector
    record = rotation_record(MagnetometerTruth(), samples=400, seed=81)
    record = replace(record, temp_stamp_ns=np.zeros(0, dtype=np.int64), temperature=np.zeros(0))
    write_driver_record(tmp_path / 'turned', record)
    params = tmp_path / 'p.yaml'
    assert cli.main(['fit', str(tmp_path / 'turned'), '-o', str(params), '--no-progress']) == 0
    unit = load_unit(params)
    assert not unit.needs_temperature and not unit.mag.thermal.needs_temperature
    start = 1_700_000_000 * 1_000_000_000
    with NodeProcess(node_command('--params-file', str(params), '-p', 'qos:=reliable'), ros_env,
                     tmp_path / 'node.log') as node, MagHarness(int(ros_env['ROS_DOMAIN_ID'])) as ros:
        ros.wait_mag_matched()
        for row in range(3):
            ros.send_imu(start + row, (*record.accel[row], *record.gyro[row]))
            ros.send_mag(start + row, record.mag[row])
        ros.wait(lambda: len(ros.imu) == 3 and len(ros.mag) == 3, 10.0, 'three corrected messages of each')
        ros.wait(lambda: status_values(ros.mag_status())['received'] == '3', 10.0, 'the magnetometer status')
        for status in (ros.latest_status(), ros.mag_status()):
            values = status_values(status)
            assert values['dropped'] == '0' and 'waiting' not in status.message, status.message
        assert node.stop() == 0
    imu = UnitCorrector(unit)
    for row, message in enumerate(ros.imu):
        got = (message.linear_acceleration.x, message.linear_acceleration.y, message.linear_acceleration.z,
               message.angular_velocity.x, message.angular_velocity.y, message.angular_velocity.z)
        assert got == imu.correct_sample((*record.accel[row], *record.gyro[row]), 0.0)
    for row, message in enumerate(ros.mag):
        got = (message.magnetic_field.x, message.magnetic_field.y, message.magnetic_field.z)
        assert got == MagCorrector(unit.mag).correct_sample(tuple(record.mag[row]), 0.0)
