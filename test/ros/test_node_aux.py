"""The real ``compensator`` node with a recorded-signal term (``aux:TOPIC``), against ``tak_calib apply``."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from sensor_msgs.msg import BatteryState
from std_msgs.msg import Float64

from node_helpers import (
    NANOSECONDS,
    RELIABLE,
    Harness,
    NodeProcess,
    header_stamp,
    node_command,
    stamp_of,
    status_values,
)
from tak_thermo_ros import cli
from tak_thermo_ros.formats.bag import (
    AUX_TYPES,
    read_driver_record,
    read_imu,
    read_imu_messages,
    read_record,
    write_driver_record,
    write_record,
)
from tak_thermo_ros.formats.calibration_file import unit_yaml, write_text_atomic
from tak_thermo_ros.core.link.online_rules import as_unit
from tak_thermo_ros.core.effects import aux_effect_class
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario

SUPPLY = 'aux:/power/battery_state'
SHORT_RUN = Scenario(sample_rate_hz=10.0, plateaus_celsius=(10.0, 30.0), plateau_hours=0.01,
                     ramp_celsius_per_minute=10.0, board_lag_s=5.0, dwell_s=2.0, supply_voltage_drift=2.0,
                     record_supply='/power/battery_state', seed=5)
"""About 250 s of chamber run, 2521 counts messages, the supply voltage with every temperature code."""


DRIVER_RUN = replace(SHORT_RUN, output='imu', supply_voltage_drift=0.01, record_supply_type='float64')
"""The same run from a driver (Imu in SI units), the supply as a std_msgs/Float64 (held by bag time)."""


def _unit(run, supply):
    """The true link of the run with the supply term on the accelerometer (and the gyroscope for a driver)."""
    if run.unit_truth is None:
        return replace(run.truth, effects=(supply,))
    return replace(run.unit_truth, accel=replace(run.unit_truth.accel, effects=(supply,)),
                   gyro=replace(run.unit_truth.gyro,
                                effects=(supply.replace(slope_x=0.001, slope_y=0.0, slope_z=0.0),)))


@pytest.mark.parametrize('driver', [False, True], ids=['counts', 'driver'])
def test_node_with_a_supply_term_equals_apply_and_counts_a_missing_supply(tmp_path, ros_env, driver):
    """The node subscribes the supply topic, waits for it (counted), then matches apply float64-equal."""
    run = simulate(DRIVER_RUN if driver else SHORT_RUN)
    bag, params, corrected = tmp_path / 'run.mcap', tmp_path / 'tak_params.yaml', tmp_path / 'imu.mcap'
    kind = 'float64' if driver else 'battery_state'
    msgtype = AUX_TYPES[kind]
    if driver:
        write_driver_record(bag, run.driver, aux_types={SUPPLY: msgtype})
    else:
        write_record(bag, run.record, aux_types={SUPPLY: msgtype})
    # A lagged supply term (state from sample to sample) on top of the true link.
    scale = 0.01 if driver else 1.0
    supply = aux_effect_class(SUPPLY)(tau_s=3.0, reference=12.0, slope_x=10.0 * scale, slope_y=-7.0 * scale,
                                      slope_z=5.0 * scale)
    write_text_atomic(params, unit_yaml(as_unit(_unit(run, supply)), extra_parameters={'qos': 'reliable'}))
    assert cli.main(['apply', str(bag), '--params', str(params), '-o', str(corrected), '--no-progress']) == 0
    if driver:
        expected_imu = read_imu_messages(corrected, topic='/imu/data_compensated')
        stamps = expected_imu.stamp_ns
        expected = np.hstack([expected_imu.linear_acceleration, expected_imu.angular_velocity])
        record = read_driver_record(bag, progress=False)
        input_stamps, temp_stamps, temperatures = record.stamp_ns, record.temp_stamp_ns, record.temperature
        inputs = np.hstack([record.accel, record.gyro])
    else:
        stamps, expected, _, _ = read_imu(corrected)
        record = read_record(bag, progress=False)
        input_stamps, temp_stamps, temperatures = record.counts_stamp_ns, record.temp_stamp_ns, record.temp_code
        inputs = record.counts
    signal_stamps, volts = record.aux[SUPPLY]
    assert len(stamps) == len(input_stamps)  # the supply is there from the first sample
    message_class = BatteryState if kind == 'battery_state' else Float64

    def send(ros, row: int) -> None:
        if driver:
            ros.send_imu(int(input_stamps[row]), inputs[row], frame_id=record.frame_id)
        else:
            ros.send_counts(int(input_stamps[row]), *inputs[row], frame_id=record.frame_id)

    with Harness(int(ros_env['ROS_DOMAIN_ID']), driver=driver) as ros:
        publisher = ros.node.create_publisher(message_class, '/power/battery_state', RELIABLE)
        with NodeProcess(node_command('--params-file', str(params)), ros_env, tmp_path / 'node.log') as node:
            ros.wait_matched()
            ros.wait(lambda: publisher.get_subscription_count() >= 1, 20.0, 'the node to subscribe the supply')
            assert f'subscribed /power/battery_state ({msgtype}.{"data" if driver else "voltage"}) for {SUPPLY}' \
                in node.log()

            # No supply value yet: the input is dropped and counted, nothing is published.
            first = int(input_stamps[0])
            ros.send_temperature_and_wait(first - NANOSECONDS, temperatures[0])
            if driver:
                ros.send_imu(first - NANOSECONDS, inputs[0], frame_id=record.frame_id)
            else:
                ros.send_counts(first - NANOSECONDS, *inputs[0])
            ros.wait(lambda: ros.latest_status() is not None
                     and status_values(ros.latest_status())['dropped.waiting_for_signal'] == '1',
                     20.0, 'the diagnostics to count the input waiting for the supply')
            values = status_values(ros.latest_status())
            assert values[f'signal {SUPPLY}'] == 'none' and values['published'] == '0'
            assert f'waiting for {SUPPLY}' in ros.latest_status().message

            # Then the bag, in its order: temperature, supply, input (each held value before the
            # input it is held for).
            events = sorted([(int(t), 0, i) for i, t in enumerate(temp_stamps)]
                            + [(int(t), 1, i) for i, t in enumerate(signal_stamps)]
                            + [(int(t), 2, i) for i, t in enumerate(input_stamps)])
            sent = 0
            for stamp, stream, row in events:
                if stream == 0:
                    ros.wait(lambda: len(ros.imu) >= sent, 20.0, 'the node to catch up')
                    ros.send_temperature(stamp, temperatures[row])
                elif stream == 1:
                    message = message_class()
                    if driver:
                        message.data = float(volts[row])
                    else:
                        header_stamp(message, stamp)
                        message.voltage = float(volts[row])
                    publisher.publish(message)
                else:
                    ros.wait(lambda: len(ros.imu) >= sent - 50, 20.0, 'the node to catch up')
                    send(ros, row)
                    sent += 1
            ros.wait(lambda: len(ros.imu) >= sent, 30.0, 'the last Imu')
            ros.wait(lambda: int(status_values(ros.latest_status())[f'signal {SUPPLY} messages']) == len(volts),
                     20.0, 'the diagnostics to count every supply message')
            assert node.stop() == 0
    assert len(ros.imu) == len(stamps)
    np.testing.assert_array_equal([stamp_of(m) for m in ros.imu], stamps)
    got = np.array([(m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z)
                    + ((m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z) if driver else ())
                    for m in ros.imu])
    assert np.array_equal(got, expected)
