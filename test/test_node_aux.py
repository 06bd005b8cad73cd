"""The real ``compensator`` node with a recorded-signal term (``aux:TOPIC``), against ``tak_calib apply``."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from sensor_msgs.msg import BatteryState

from node_helpers import (
    NANOSECONDS,
    RELIABLE,
    Harness,
    NodeProcess,
    domain_id,
    header_stamp,
    node_command,
    ros_environment,
    stamp_of,
    status_values,
)
from tak_thermo_ros import cli
from tak_thermo_ros.bagio import AUX_TYPES, read_imu, read_record, write_record
from tak_thermo_ros.core.calibration_file import calibration_yaml, write_text_atomic
from tak_thermo_ros.core.effects import aux_effect_class
from tak_thermo_ros.core.simulate import Scenario, simulate

SUPPLY = 'aux:/power/battery_state'
SHORT_RUN = Scenario(sample_rate_hz=10.0, plateaus_celsius=(10.0, 30.0), plateau_hours=0.01,
                     ramp_celsius_per_minute=10.0, board_lag_s=5.0, dwell_s=2.0, supply_voltage_drift=2.0,
                     record_supply='/power/battery_state', seed=5)
"""About 250 s of chamber run, 2521 counts messages, the supply voltage with every temperature code."""


@pytest.fixture
def ros_env(tmp_path, monkeypatch, request):
    """Environment of this test's ROS processes (also applied to the test process)."""
    index = sum(ord(c) for c in request.node.name)
    env = ros_environment(tmp_path, domain_id(index))
    for key in ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_DOMAIN_ID', 'ROS_HOME', 'ROS_LOG_DIR'):
        monkeypatch.setenv(key, env[key])
    return env


def test_node_with_a_supply_term_equals_apply_and_counts_a_missing_supply(tmp_path, ros_env):
    """The node subscribes the supply topic, waits for it (counted), then matches apply float64-equal."""
    run = simulate(SHORT_RUN)
    bag, params, corrected = tmp_path / 'run.mcap', tmp_path / 'tak_params.yaml', tmp_path / 'imu.mcap'
    write_record(bag, run.record, aux_types={SUPPLY: AUX_TYPES['battery_state']})
    # A lagged supply term (state from sample to sample) on top of the true link.
    supply = aux_effect_class(SUPPLY)(tau_s=3.0, reference=12.0, slope_x=10.0, slope_y=-7.0, slope_z=5.0)
    write_text_atomic(params, calibration_yaml(replace(run.truth, effects=(supply,)),
                                               extra_parameters={'qos': 'reliable'}))
    assert cli.main(['apply', str(bag), '--params', str(params), '-o', str(corrected), '--no-progress']) == 0
    stamps, expected, _, _ = read_imu(corrected)
    record = read_record(bag, progress=False)
    signal_stamps, volts = record.aux[SUPPLY]
    assert len(stamps) == len(record.counts)  # the supply is there from the first sample

    with Harness(int(ros_env['ROS_DOMAIN_ID'])) as ros:
        battery = ros.node.create_publisher(BatteryState, '/power/battery_state', RELIABLE)
        with NodeProcess(node_command('--params-file', str(params)), ros_env, tmp_path / 'node.log') as node:
            ros.wait_matched()
            ros.wait(lambda: battery.get_subscription_count() >= 1, 20.0, 'the node to subscribe the supply')
            assert f'subscribed /power/battery_state (sensor_msgs/msg/BatteryState.voltage) for {SUPPLY}' in node.log()

            # No supply value yet: the counts are dropped and counted, nothing is published.
            first = int(record.counts_stamp_ns[0])
            ros.send_temperature_and_wait(first - NANOSECONDS, record.temp_code[0])
            ros.send_counts(first - NANOSECONDS, *record.counts[0])
            ros.wait(lambda: ros.latest_status() is not None
                     and status_values(ros.latest_status())['dropped.waiting_for_signal'] == '1',
                     20.0, 'the diagnostics to count the counts waiting for the supply')
            values = status_values(ros.latest_status())
            assert values[f'signal {SUPPLY}'] == 'none' and values['published'] == '0'
            assert f'waiting for {SUPPLY}' in ros.latest_status().message

            # Then the bag, in its order: temperature, supply, counts (each signal before the counts
            # it is held for; the node's subscriptions are created in that order).
            events = sorted([(int(s), 0, i) for i, s in enumerate(record.temp_stamp_ns)]
                            + [(int(s), 1, i) for i, s in enumerate(signal_stamps)]
                            + [(int(s), 2, i) for i, s in enumerate(record.counts_stamp_ns)])
            sent = 0
            for stamp, stream, row in events:
                if stream == 0:
                    ros.wait(lambda: len(ros.imu) >= sent, 20.0, 'the node to catch up')
                    ros.send_temperature(stamp, record.temp_code[row])
                elif stream == 1:
                    message = BatteryState()
                    header_stamp(message, stamp)
                    message.voltage = float(volts[row])
                    battery.publish(message)
                else:
                    ros.wait(lambda: len(ros.imu) >= sent - 50, 20.0, 'the node to catch up')
                    ros.send_counts(stamp, *record.counts[row], frame_id=record.frame_id)
                    sent += 1
            ros.wait(lambda: len(ros.imu) >= sent, 30.0, 'the last Imu')
            ros.wait(lambda: int(status_values(ros.latest_status())[f'signal {SUPPLY} messages']) == len(volts),
                     20.0, 'the diagnostics to count every supply message')
            assert node.stop() == 0
    assert len(ros.imu) == len(stamps)
    np.testing.assert_array_equal([stamp_of(m) for m in ros.imu], stamps)
    got = np.array([(m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z) for m in ros.imu])
    assert np.array_equal(got, expected)
