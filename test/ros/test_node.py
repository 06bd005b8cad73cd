"""The real ``compensator`` node, talked to with real rclpy from the test process."""

from __future__ import annotations

import ast
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from node_helpers import (
    NANOSECONDS,
    Harness,
    NodeProcess,
    node_command,
    play_driver,
    run_to_exit,
    stamp_of,
    status_values,
    wait_until,
)
from paths import REPO
from tak_thermo_ros import cli
from tak_thermo_ros.formats.bag import read_imu, read_imu_messages, read_record, write_driver_record, write_record
from tak_thermo_ros.formats.calibration_file import (
    calibration_yaml,
    load_calibration,
    load_unit,
    unit_yaml,
    write_text_atomic,
)
from tak_thermo_ros.core.link.model import InputKind
from tak_thermo_ros.core.link.correction import Corrector, OutOfRange, UnitCorrector
from tak_thermo_ros.core.link.online_rules import ONLINE_DROP_REASONS
from tak_thermo_ros.core.records.record import align
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.core.simulation.motion import HandheldMotion

START_NS = 1_700_000_000 * NANOSECONDS
CALIBRATION = Scenario().truth()  # temperature-code range 7600..8800, reference 8200


def write_params(path: Path, calibration=CALIBRATION, **parameters) -> Path:
    """A params file: the calibration and the node's parameters."""
    write_text_atomic(path, calibration_yaml(calibration, extra_parameters=parameters))
    return path


def acceleration(message) -> tuple[float, float, float]:
    """The linear acceleration of an Imu message."""
    a = message.linear_acceleration
    return a.x, a.y, a.z


def test_bad_input_cases_have_their_defined_behaviour(tmp_path, ros_env):
    """Waiting, bad counts, stamps out of order, out of range, stale: published or dropped, logged, counted."""
    params = write_params(tmp_path / 'params.yaml', qos='reliable', temp_timeout=30.0,
                          stale_temperature='drop')
    clamp = Corrector(CALIBRATION, out_of_range=OutOfRange.CLAMP)
    extrapolate = Corrector(CALIBRATION, out_of_range=OutOfRange.EXTRAPOLATE)
    with NodeProcess(node_command('--params-file', str(params)), ros_env, tmp_path / 'node.log') as node, \
            Harness(int(ros_env['ROS_DOMAIN_ID'])) as ros:
        ros.wait_matched()

        def status_with(condition):
            ros.wait(lambda: ros.latest_status() is not None and condition(status_values(ros.latest_status())),
                     10.0, 'a diagnostics status')
            return ros.latest_status()

        # No temperature code yet: nothing published, WARN naming the resolved topic.
        ros.send_counts(START_NS, 100.0, -50.0, 2500.0)
        status = status_with(lambda v: v['dropped.waiting_for_temperature'] == '1')
        assert status.level == b'\x01' and 'waiting for temperature code on /tak/temp_code' in status.message
        wait_until(lambda: 'waiting for temperature code on /tak/temp_code' in node.log(), 10.0, what='the WARN')
        assert '[WARN]' in next(line for line in node.log().splitlines() if 'waiting for temperature' in line)

        # A code in range; good counts, every kind of bad counts, a duplicate and a backwards stamp.
        ros.send_temperature_and_wait(START_NS, 8300.0)
        sent = [
            (START_NS + 1, (100.0, -50.0, 2500.0)),
            (START_NS + 2, (math.nan, 0.0, 0.0)),
            (START_NS + 3, (0.0, math.inf, 0.0)),
            (START_NS + 4, (0.0, 0.0, -math.inf)),
            (START_NS + 5, (1.5, 0.0, 0.0)),
            (START_NS + 6, (32767.0, 0.0, 0.0)),
            (START_NS + 7, (0.0, -32768.0, 0.0)),
            (START_NS + 7, (101.0, -51.0, 2501.0)),   # duplicate stamp (of a dropped message): dropped
            (START_NS + 3, (102.0, -52.0, 2502.0)),   # backwards: dropped
            (START_NS + 8, (103.0, -53.0, 2503.0)),   # later than the previous message's: published
        ]
        for stamp, (x, y, z) in sent:
            ros.send_counts(stamp, x, y, z)
        good = [(stamp, xyz) for stamp, xyz in sent if xyz[0] in (100.0, 103.0)]
        ros.wait(lambda: len(ros.imu) == len(good), 10.0, 'the Imu of the good counts')
        assert [stamp_of(m) for m in ros.imu] == [stamp for stamp, _ in good]
        for message, (_, xyz) in zip(ros.imu, good):
            assert acceleration(message) == clamp.correct_sample(*xyz, 8300.0, stamp_s=0.0)
            assert message.header.frame_id == 'tak_imu'
            assert all(math.isfinite(v) for v in acceleration(message))

        # Out of range: WARN with the code and the range, clamped by default, extrapolated on request.
        ros.send_temperature_and_wait(START_NS + 9, 9500.0)
        ros.send_counts(START_NS + 10, 200.0, 200.0, 200.0)
        ros.wait(lambda: len(ros.imu) == len(good) + 1, 10.0, 'the out-of-range Imu')
        assert acceleration(ros.imu[-1]) == clamp.correct_sample(200.0, 200.0, 200.0, 9500.0)
        assert acceleration(ros.imu[-1]) == clamp.correct_sample(200.0, 200.0, 200.0, 8800.0)
        wait_until(lambda: 'temperature code 9500 outside the calibrated range 7600..8800' in node.log(),
                   10.0, what='the out-of-range WARN')
        assert [r.successful for r in ros.set_parameters({'out_of_range': 'extrapolate'})] == [True]
        ros.send_temperature_and_wait(START_NS + 11, 9500.0)
        ros.send_counts(START_NS + 12, 200.0, 200.0, 200.0)
        ros.wait(lambda: len(ros.imu) == len(good) + 2, 10.0, 'the extrapolated Imu')
        assert acceleration(ros.imu[-1]) == extrapolate.correct_sample(200.0, 200.0, 200.0, 9500.0)
        assert acceleration(ros.imu[-1]) != acceleration(ros.imu[-2])
        rejected = ros.set_parameters({'out_of_range': 'wrap'})[0]
        assert not rejected.successful and 'out_of_range' in rejected.reason

        # Stale code (older than temp_timeout, now 0.3 s): diagnostics ERROR; 'drop' drops, 'hold' holds.
        assert [r.successful for r in ros.set_parameters({'temp_timeout': 0.3})] == [True]
        ros.send_temperature_and_wait(START_NS + 13, 8000.0)
        status = status_with(lambda v: 'stale' in ros.latest_status().message)
        assert status.level == b'\x02'
        ros.send_counts(START_NS + 14, 300.0, 300.0, 300.0)
        status_with(lambda v: v['dropped.stale_temperature'] == '1')
        assert len(ros.imu) == len(good) + 2
        assert [r.successful for r in ros.set_parameters({'stale_temperature': 'hold'})] == [True]
        ros.send_counts(START_NS + 15, 300.0, 300.0, 300.0)
        ros.wait(lambda: len(ros.imu) == len(good) + 3, 10.0, 'the Imu with the held code')
        assert acceleration(ros.imu[-1]) == extrapolate.correct_sample(300.0, 300.0, 300.0, 8000.0)
        status = status_with(lambda v: v['received'] == '15')
        assert status.level == b'\x02'
        assert 'is stale' in node.log() and '[ERROR]' in node.log()

        # Every counts message published or counted as dropped with its reason.
        values = status_values(status)
        dropped = {reason: int(values[f'dropped.{reason}']) for reason in ONLINE_DROP_REASONS}
        assert dropped == {'duplicate_stamp': 1, 'time_backwards': 1, 'non_finite': 3, 'non_integer': 1,
                           'saturated': 2, 'waiting_for_temperature': 1, 'stale_temperature': 1,
                           'correction_failed': 0, 'non_finite_output': 0, 'stamp_jump': 0, 'non_physical': 0}
        assert int(values['published']) == len(ros.imu) == 5
        assert int(values['received']) == int(values['published']) + sum(dropped.values())
        assert int(values['dropped']) == sum(dropped.values())
        assert values['out_of_range'] == '2' and values['message_lost'] == '0'
        assert 'header stamp equal to the previous one: dropped' in node.log()
        assert node.stop() == 0
    assert 'Traceback' not in node.log()


def play(ros: Harness, record) -> None:
    """Publish a run in stamp order (codes before counts at equal stamps), losing nothing.

    Before each temperature code, every counts message sent so far has been answered, so the
    node has corrected it with the code in force when it was recorded.
    """
    events = sorted([(int(s), 0, i) for i, s in enumerate(record.temp_stamp_ns)]
                    + [(int(s), 2, i) for i, s in enumerate(record.counts_stamp_ns)])
    sent = 0
    for stamp, stream, row in events:
        if stream == 0:
            ros.wait(lambda: len(ros.imu) >= sent, 20.0, f'the node to catch up ({len(ros.imu)} of {sent})')
            ros.send_temperature(stamp, record.temp_code[row])
        else:
            ros.wait(lambda: len(ros.imu) >= sent - 50, 20.0, f"the node to catch up ({len(ros.imu)} of {sent})")
            ros.send_counts(stamp, *record.counts[row], frame_id=record.frame_id)
            sent += 1
    ros.wait(lambda: len(ros.imu) >= sent, 20.0, 'the last Imu')


SHORT_RUN = Scenario(sample_rate_hz=10.0, plateaus_celsius=(10.0, 30.0), plateau_hours=0.01,
                     ramp_celsius_per_minute=10.0, board_lag_s=5.0, dwell_s=2.0)
"""About 250 s of chamber run, 2521 counts messages."""


HIDDEN_EFFECTS = {'thermal_lag': {'tau_s': 30.0, 'slope_x': 0.05, 'slope_z': -0.04},
                  'warmup': {'tau_s': 40.0, 'amplitude_x': 20.0, 'amplitude_y': -15.0},
                  'cross_axis': {'c_xy': 2.0, 'c_zx': -1.5},
                  'step': {'origin_s': SHORT_RUN.start_time_s, 'at_s': 150.05, 'amplitude_x': 12.0,
                           'amplitude_z': -9.0}}
"""Effects with memory (lag, warm-up), an input effect and a step at a stamp, for the node's online state."""


HELD_EFFECT = {'thermal_lag[xz]': {'tau_s': 30.0, 'slope_x': 0.05, 'slope_z': -0.04}}
"""A lag fitted on x and z only (``core/effects/held.py``): the file's ``axes`` string parameter read by the node."""


@pytest.mark.parametrize('effects', [{}, HIDDEN_EFFECTS, HELD_EFFECT], ids=['base', 'with_effects', 'held_axes'])
def test_node_output_equals_tak_calib_apply(tmp_path, ros_env, effects):
    """A bag played into the node gives apply's Imu for every message, float64-equal, effects included."""
    bag, params, corrected = tmp_path / 'run.mcap', tmp_path / 'tak_params.yaml', tmp_path / 'imu.mcap'
    write_record(bag, simulate(replace(SHORT_RUN, effects=effects)).record)
    effect_options = ['--effects', ','.join(effects)] if effects else []
    assert cli.main(['fit', str(bag), '-o', str(params), '--no-progress', *effect_options]) == 0
    assert [e.name for e in load_calibration(params).effects] == list(effects)
    assert cli.main(['apply', str(bag), '--params', str(params), '-o', str(corrected), '--no-progress']) == 0
    stamps, expected, frames, covariances = read_imu(corrected)
    record = read_record(bag, progress=False)
    with NodeProcess(node_command('--params-file', str(params), '-p', 'qos:=reliable'), ros_env,
                     tmp_path / 'node.log') as node, Harness(int(ros_env['ROS_DOMAIN_ID'])) as ros:
        ros.wait_matched()
        play(ros, record)
        assert node.stop() == 0
    assert len(ros.imu) == len(stamps) == len(record.counts)
    np.testing.assert_array_equal([stamp_of(m) for m in ros.imu], stamps)
    got = np.array([acceleration(m) for m in ros.imu])
    assert got.dtype == np.float64 and np.array_equal(got, expected)
    assert [m.header.frame_id for m in ros.imu] == frames
    np.testing.assert_array_equal([m.linear_acceleration_covariance for m in ros.imu], covariances)
    first = ros.imu[0]
    assert (first.orientation.x, first.orientation.y, first.orientation.z, first.orientation.w) == (0, 0, 0, 1)
    assert first.orientation_covariance[0] == -1.0 and first.angular_velocity_covariance[0] == -1.0
    assert (first.angular_velocity.x, first.angular_velocity.y, first.angular_velocity.z) == (0, 0, 0)


def test_runtime_calibration_update_accepted_and_rejected(tmp_path, ros_env):
    """A valid update is swapped in for the next message; a bad one is refused with its key."""
    params = write_params(tmp_path / 'params.yaml', qos='reliable')
    x = CALIBRATION.axes[0]
    updated = replace(CALIBRATION, axes=(replace(x, offset=x.offset + 5.0), *CALIBRATION.axes[1:]))
    moved = replace(updated, temp_code_min=7000.0, temp_code_max=9400.0)
    with NodeProcess(node_command('--params-file', str(params)), ros_env, tmp_path / 'node.log') as node, \
            Harness(int(ros_env['ROS_DOMAIN_ID'])) as ros:
        ros.wait_matched()
        ros.send_temperature_and_wait(START_NS, 9000.0)

        def corrected(stamp_offset: int):
            ros.send_counts(START_NS + stamp_offset, 500.0, -500.0, 2500.0)
            ros.wait(lambda: len(ros.imu) == stamp_offset, 10.0, 'an Imu')
            return acceleration(ros.imu[-1])

        assert corrected(1) == Corrector(CALIBRATION).correct_sample(500.0, -500.0, 2500.0, 9000.0)
        results = ros.set_parameters({'calibration.x.offset': x.offset + 5.0})
        assert [r.successful for r in results] == [True]
        assert corrected(2) == Corrector(updated).correct_sample(500.0, -500.0, 2500.0, 9000.0)

        bad = ros.set_parameters({'calibration.x.scale': -1.0})[0]
        assert not bad.successful and 'calibration.x.scale' in bad.reason and '> 0' in bad.reason
        bad = ros.set_parameters({'calibration.y.scale_shape': [0.5]})[0]
        assert not bad.successful and 'calibration.y.scale_shape: F_c <= 0' in bad.reason
        bad = ros.set_parameters({'calibration.temp_code_min': 9000.0, 'calibration.temp_code_max': 7000.0},
                                 atomically=True)[0]
        assert not bad.successful and 'calibration.temp_code_min' in bad.reason
        assert corrected(3) == Corrector(updated).correct_sample(500.0, -500.0, 2500.0, 9000.0)

        both = ros.set_parameters({'calibration.temp_code_min': 7000.0, 'calibration.temp_code_max': 9400.0},
                                  atomically=True)[0]
        assert both.successful
        assert corrected(4) == Corrector(moved).correct_sample(500.0, -500.0, 2500.0, 9000.0)
        assert Corrector(moved).correct_sample(500.0, -500.0, 2500.0, 9000.0) != Corrector(
            updated).correct_sample(500.0, -500.0, 2500.0, 9000.0)
        read_only = ros.set_parameters({'qos': 'sensor_data'})[0]
        assert not read_only.successful
        ros.wait(lambda: ros.latest_status() is not None
                 and status_values(ros.latest_status())['calibration_updates'] == '2', 10.0, 'the diagnostics')
        assert status_values(ros.latest_status())['calibrated_range'] == '7000..9400'
        assert node.stop() == 0
    log = node.log()
    assert 'parameter update rejected' in log and 'Traceback' not in log


@pytest.mark.parametrize('case', ['params_file', 'calibration_file', 'missing', 'qos'])
def test_bad_calibration_refused_at_startup(tmp_path, ros_env, case):
    """A bad calibration (or parameter): exit code 2 and one line naming the key, no traceback."""
    bad = CALIBRATION.axes[1]
    text = calibration_yaml(CALIBRATION).replace(f'scale: {bad.scale!r}', 'scale: -3.0')
    path = tmp_path / 'bad.yaml'
    path.write_text(text, encoding='utf-8')
    args = {'params_file': ['--params-file', str(path)],
            'calibration_file': ['-p', f'calibration_file:={path}'],
            'missing': ['-p', 'qos:=reliable'],
            'qos': ['--params-file', str(write_params(tmp_path / 'good.yaml', qos='fast'))]}[case]
    result = run_to_exit(node_command(*args), ros_env)
    lines = (result.stdout + result.stderr).strip().splitlines()
    assert result.returncode == 2
    assert len(lines) == 1, lines
    assert 'Traceback' not in lines[0] and '[FATAL]' in lines[0]
    expected = {'missing': 'calibration: missing for node /compensator',
                'qos': "qos: expected one of 'sensor_data', 'reliable', got 'fast'"}.get(
        case, 'calibration.y.scale: must be > 0')
    assert expected in lines[0]


def test_launch_file_and_example_configs(tmp_path):
    """The launch file compiles, remaps driver -> compensator -> estimator.

    The example configs are valid calibrations (counts and driver) with the node's defaults.
    """
    import py_compile
    from tak_thermo_ros.ros.parameters import _tunables
    launch_file = REPO / 'launch' / 'compensator.launch.py'
    py_compile.compile(str(launch_file), cfile=str(tmp_path / 'launch.pyc'), doraise=True)
    tree = ast.parse(launch_file.read_text(encoding='utf-8'))
    assert any(isinstance(n, ast.FunctionDef) and n.name == 'generate_launch_description' for n in tree.body)
    constants = {n.targets[0].id: ast.literal_eval(n.value) for n in tree.body
                 if isinstance(n, ast.Assign) and isinstance(n.targets[0], ast.Name)
                 and n.targets[0].id.endswith('TOPICS')}
    from tak_thermo_ros.ros import node as node_module
    assert constants['DRIVER_TOPICS'] == (node_module.RAW_IMU_TOPIC, node_module.TEMPERATURE_TOPIC,
                                          node_module.COMPENSATED_IMU_TOPIC)
    assert constants['COUNTS_TOPICS'] == (node_module.COUNTS_TOPIC, node_module.TEMP_TOPIC, node_module.IMU_TOPIC)
    defaults = {name: default for name, (default, _, _) in _tunables().items()}
    for name, kind in (('compensator.yaml', InputKind.COUNTS), ('compensator_driver.yaml', InputKind.IMU)):
        config = REPO / 'config' / name
        assert load_unit(config).input_kind is kind
        parameters = yaml.safe_load(config.read_text(encoding='utf-8'))['/**/compensator']['ros__parameters']
        assert {k: v for k, v in parameters.items() if k != 'calibration'} == defaults


# -- driver input (a version-2 calibration): sensor_msgs/Imu and degrees C in -------------------

DRIVER_RUN = Scenario(output='imu', sample_rate_hz=10.0, plateaus_celsius=(10.0, 30.0), plateau_hours=0.01,
                      ramp_celsius_per_minute=10.0, board_lag_s=5.0, dwell_s=2.0,
                      gyro_effects={'thermal_lag': {'tau_s': 30.0, 'slope_x': 0.002, 'slope_z': -0.0015}})
"""About 250 s of a driver on a rate table, 2521 Imu messages, a hidden gyroscope thermal lag."""
DRIVER_UNIT = Scenario(output='imu').driver_truth()  # 5..35 C


def driver_params(path: Path, unit=DRIVER_UNIT, **parameters) -> Path:
    """A params file with a driver calibration and the node's parameters."""
    write_text_atomic(path, unit_yaml(unit, extra_parameters=parameters))
    return path


def node_and_apply(bag: Path, params: Path, driver, ros_env: dict[str, str], tmp_path: Path):
    """``tak_calib apply`` on ``bag`` and the node fed ``driver`` (the bag's record) with ``params``.

    :returns: ``(apply's Imu messages, the node's Imu messages)``; the node exits cleanly.
    """
    corrected = tmp_path / 'applied.mcap'
    assert cli.main(['apply', str(bag), '--params', str(params), '-o', str(corrected), '--no-progress']) == 0
    expected = read_imu_messages(corrected, topic='/imu/data_compensated')
    with NodeProcess(node_command('--params-file', str(params), '-p', 'qos:=reliable'), ros_env,
                     tmp_path / 'node.log') as node, \
            Harness(int(ros_env['ROS_DOMAIN_ID']), driver=True) as ros:
        ros.wait_matched()
        play_driver(ros, driver)
        assert node.stop() == 0
    return expected, list(ros.imu)


def imu_equal_to_applied(imu: list, expected) -> dict[str, np.ndarray]:
    """Assert the node's Imu messages equal apply's (``read_imu_messages``), float64 for float64, every field.

    :returns: the node's fields as arrays (``stamp``, ``accel``, ``gyro``, ``orientation`` and the three covariances).
    """
    got = {
        'stamp': np.array([stamp_of(m) for m in imu]),
        'accel': np.array([(m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z)
                           for m in imu]),
        'gyro': np.array([(m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z) for m in imu]),
        'orientation': np.array([(m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w)
                                 for m in imu]),
        'orientation_covariance': np.array([m.orientation_covariance for m in imu]),
        'angular_velocity_covariance': np.array([m.angular_velocity_covariance for m in imu]),
        'linear_acceleration_covariance': np.array([m.linear_acceleration_covariance for m in imu]),
    }
    assert got['accel'].dtype == got['gyro'].dtype == np.float64
    assert np.array_equal(got['stamp'], expected.stamp_ns)
    assert np.array_equal(got['accel'], expected.linear_acceleration)
    assert np.array_equal(got['gyro'], expected.angular_velocity)
    assert np.array_equal(got['orientation'], expected.orientation)
    assert np.array_equal(got['orientation_covariance'], expected.orientation_covariance)
    assert np.array_equal(got['angular_velocity_covariance'], expected.angular_velocity_covariance)
    assert np.array_equal(got['linear_acceleration_covariance'], expected.linear_acceleration_covariance)
    assert [m.header.frame_id for m in imu] == expected.frame_ids
    return got


def test_driver_node_output_equals_tak_calib_apply_on_both_sensors(tmp_path, ros_env):
    """A driver bag (gyro thermal lag fitted) played into the node: apply's Imu, float64-equal, every field."""
    run = simulate(DRIVER_RUN)
    rng = np.random.default_rng(5)
    quaternions = rng.normal(size=(len(run.driver.stamp_ns), 4))
    quaternions /= np.linalg.norm(quaternions, axis=1, keepdims=True)
    driver = replace(run.driver, orientation=quaternions,
                     orientation_covariance=rng.uniform(0.0, 1e-3, (len(quaternions), 9)))
    bag, params = tmp_path / 'driver.mcap', tmp_path / 'tak_params.yaml'
    write_driver_record(bag, driver)
    assert cli.main(['fit', str(bag), '-o', str(params), '--no-progress', '--gyro-effects', 'thermal_lag']) == 0
    unit = load_unit(params)
    assert unit.input_kind is InputKind.IMU and [e.name for e in unit.gyro.effects] == ['thermal_lag']
    expected, imu = node_and_apply(bag, params, driver, ros_env, tmp_path)
    assert len(imu) == len(expected.stamp_ns) == len(driver.stamp_ns)
    got = imu_equal_to_applied(imu, expected)
    assert np.array_equal(got['orientation'], quaternions)
    assert got['angular_velocity_covariance'][0, 0] > 0.0  # from the gyroscope's fit, not the driver's
    # The lag's state matters: the same link without the effect differs by far more than the noise.
    samples = align(driver.six_channels(), use_reference=False)
    without_lag = UnitCorrector(replace(unit, gyro=replace(unit.gyro, effects=()))).correct(
        samples.counts, samples.temp_code, stamp_s=samples.stamp_s)
    assert np.max(np.abs(without_lag[:, 3:] - got['gyro'])) > 10.0 * unit.gyro.axes[0].residual_rms


HANDHELD_RUN = Scenario(output='imu', sample_rate_hz=10.0, start_celsius=10.0,
                        effects={'cross_axis': {'c_yx': 0.002, 'c_zx': -0.003, 'c_zy': 0.0015}},
                        gyro_effects={'cross_axis': {'c_xy': 0.002, 'c_xz': -0.003, 'c_zy': 0.004}},
                        handheld=HandheldMotion(orientations=24, still_s=6.0, turn_s=1.5, final_celsius=30.0,
                                                warmup_tau_s=60.0))
"""About 180 s of a unit turned by hand while it warms: 24 rests, 1800 Imu messages, no reference topics."""


def test_node_equals_apply_with_a_hand_held_calibration(tmp_path, ros_env):
    """A hand-held fit (both sensors' misalignment in the file) corrects in the node as in apply, float64-equal."""
    driver = simulate(HANDHELD_RUN).driver
    bag, params = tmp_path / 'handheld.mcap', tmp_path / 'tak_params.yaml'
    write_driver_record(bag, driver)
    assert cli.main(['fit', str(bag), '-o', str(params), '--no-progress']) == 0
    unit = load_unit(params)
    assert [e.name for e in unit.accel.effects] == [e.name for e in unit.gyro.effects] == ['cross_axis']
    assert unit.accel.effects[0]['c_xy'] == unit.accel.effects[0]['c_xz'] == unit.accel.effects[0]['c_yz'] == 0.0
    expected, imu = node_and_apply(bag, params, driver, ros_env, tmp_path)
    assert len(imu) == len(expected.stamp_ns) == len(driver.stamp_ns)
    accel = np.array([(m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z) for m in imu])
    gyro = np.array([(m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z) for m in imu])
    assert np.array_equal(np.array([stamp_of(m) for m in imu]), expected.stamp_ns)
    assert np.array_equal(accel, expected.linear_acceleration)
    assert np.array_equal(gyro, expected.angular_velocity)
    # The misalignment matters: the same link without it differs by far more than rounding.
    samples = align(driver.six_channels(), use_reference=False)
    plain = UnitCorrector(replace(unit, accel=replace(unit.accel, effects=()), gyro=replace(unit.gyro, effects=())))
    without = plain.correct(samples.counts, samples.temp_code, stamp_s=samples.stamp_s)
    assert np.max(np.abs(without[:, :3] - accel)) > 1e-3


def test_driver_bad_input_and_time_backwards(tmp_path, ros_env):
    """Imu input.

    NaN anywhere drops the message, NaN temperature ignored, backwards/duplicate stamps dropped, out of range clamped,
    stale held; all counted in /diagnostics.
    """
    params = driver_params(tmp_path / 'params.yaml', qos='reliable', temp_timeout=30.0)
    corrector = UnitCorrector(DRIVER_UNIT)
    good = (0.1, -0.2, 9.81, 0.01, -0.02, 0.03)
    with NodeProcess(node_command('--params-file', str(params)), ros_env, tmp_path / 'node.log') as node, \
            Harness(int(ros_env['ROS_DOMAIN_ID']), driver=True) as ros:
        ros.wait_matched()

        def status_with(condition):
            ros.wait(lambda: ros.latest_status() is not None and condition(status_values(ros.latest_status())),
                     10.0, 'a diagnostics status')
            return status_values(ros.latest_status())

        ros.send_imu(START_NS, good)  # no temperature yet
        status_with(lambda v: v['dropped.waiting_for_temperature'] == '1')
        assert 'waiting for temperature on /imu/temperature' in ros.latest_status().message
        ros.send_temperature_and_wait(START_NS, 21.5)
        ros.send_temperature_and_wait(START_NS, math.nan)  # ignored: 21.5 stays
        sent = [(START_NS + 1, good, True), (START_NS + 2, (*good[:4], math.nan, good[5]), False),
                (START_NS + 3, (math.inf, *good[1:]), False), (START_NS + 3, good, False),  # duplicate
                (START_NS + 2, good, False),  # backwards
                (START_NS + 4, (0.2, 0.3, 9.7, -0.01, 0.02, 0.05), True)]
        for stamp, values, _ in sent:
            ros.send_imu(stamp, values, orientation=(0.1, 0.2, 0.3, 0.9273618495495704))
        published = [(stamp, values) for stamp, values, kept in sent if kept]
        ros.wait(lambda: len(ros.imu) == len(published), 10.0, 'the Imu of the good messages')
        for message, (stamp, values) in zip(ros.imu, published):
            assert stamp_of(message) == stamp and message.header.frame_id == 'imu_link'
            result = corrector.correct_sample(values, 21.5)  # no effects: the stamp does not matter
            assert (message.linear_acceleration.x, message.linear_acceleration.y, message.linear_acceleration.z,
                    message.angular_velocity.x, message.angular_velocity.y, message.angular_velocity.z) == result
            assert (message.orientation.x, message.orientation.w) == (0.1, 0.9273618495495704)
            assert message.orientation_covariance[0] == -1.0 and message.linear_acceleration_covariance[0] != 7.0
        ros.send_temperature_and_wait(START_NS + 5, 60.0)  # out of range: clamped to 35
        ros.send_imu(START_NS + 6, good)
        ros.wait(lambda: len(ros.imu) == 3, 10.0, 'the out-of-range Imu')
        assert ros.imu[-1].angular_velocity.x == corrector.correct_sample(good, 35.0)[3]
        values = status_with(lambda v: v['received'] == '8')
        dropped = {reason: int(values[f'dropped.{reason}']) for reason in ONLINE_DROP_REASONS}
        assert dropped == {'duplicate_stamp': 1, 'time_backwards': 1, 'non_finite': 2, 'non_integer': 0,
                           'saturated': 0, 'waiting_for_temperature': 1, 'stale_temperature': 0,
                           'correction_failed': 0, 'non_finite_output': 0, 'stamp_jump': 0, 'non_physical': 0}
        assert int(values['received']) == int(values['published']) + sum(dropped.values()) == 3 + 5
        assert values['temperature_rejected'] == '1' and values['out_of_range'] == '1'
        assert values['input'] == 'imu' and values['calibrated_range'] == '5..35'
        assert values['message_lost'] == '0'
        assert node.stop() == 0
    log = node.log()
    assert 'temperature 60 outside the calibrated range 5..35' in log and 'Traceback' not in log


def test_a_record_with_its_own_stamps_per_sensor_equals_apply_marks_included(tmp_path, ros_env):
    """A bag whose Imu messages carry one sensor or both, played into the node: apply's Imu, float64-equal.

    Every field, the absent sensor's mark (covariance[0] = -1, values zero) included; each sensor's
    effect with memory (accelerometer hysteresis, gyroscope thermal lag) on its own samples; the
    faults on one sensor's own samples (a NaN gyroscope sample beside a good accelerometer one, a
    non-physical accelerometer sample, a duplicate accelerometer stamp) as apply treats them; the
    diagnostics count every message.
    """
    from own_stamps import core_output, own_stamps_record, own_stamps_unit, play_order
    bag, params, applied = tmp_path / 'apart.mcap', tmp_path / 'tak_params.yaml', tmp_path / 'applied.mcap'
    write_driver_record(bag, own_stamps_record())
    unit = own_stamps_unit()
    driver_params(params, unit)
    assert cli.main(['apply', str(bag), '--params', str(params), '-o', str(applied), '--no-progress']) == 0
    expected = read_imu_messages(applied, topic='/imu/data_compensated')
    raw, record, events = play_order(bag)
    # Pacing only (the assertions hold the node to apply): how many Imu the node publishes so far.
    _, _, results = core_output(bag, load_unit(params))
    published_after = np.cumsum([not isinstance(result, str) for result in results])
    with NodeProcess(node_command('--params-file', str(params), '-p', 'qos:=reliable'), ros_env,
                     tmp_path / 'node.log') as node, \
            Harness(int(ros_env['ROS_DOMAIN_ID']), driver=True) as ros:
        ros.wait_matched()
        sent = 0
        for stamp, stream, row in events:
            answered = int(published_after[sent - 1]) if sent else 0
            if stream == 0:  # before a temperature, the node has corrected everything sent
                ros.wait(lambda: len(ros.imu) >= answered, 20.0, f'the node to catch up ({len(ros.imu)})')
                ros.send_temperature(stamp, record.temperature[row])
                continue
            ros.send_imu(stamp, (*raw.linear_acceleration[row], *raw.angular_velocity[row]),
                         frame_id=raw.frame_ids[row], orientation=raw.orientation[row],
                         orientation_covariance=raw.orientation_covariance[row],
                         linear_acceleration_covariance=raw.linear_acceleration_covariance[row],
                         angular_velocity_covariance=raw.angular_velocity_covariance[row])
            sent += 1
        ros.wait(lambda: len(ros.imu) >= int(published_after[-1]), 20.0, 'the last Imu')
        ros.wait(lambda: ros.latest_status() is not None
                 and status_values(ros.latest_status())['received'] == str(sent), 10.0, 'the final status')
        values = status_values(ros.latest_status())
        assert node.stop() == 0
    imu = ros.imu
    assert len(imu) == len(expected.stamp_ns) < len(raw.stamp_ns)
    got = imu_equal_to_applied(imu, expected)
    # The marks: a message without the accelerometer (gyroscope) says so, its values zero; the other's covariance
    # is the fit's.
    accel_absent = got['linear_acceleration_covariance'][:, 0] == -1.0
    gyro_absent = got['angular_velocity_covariance'][:, 0] == -1.0
    assert accel_absent.sum() > 30 and gyro_absent.sum() > 10 and not np.any(accel_absent & gyro_absent)
    assert not got['accel'][accel_absent].any() and not got['gyro'][gyro_absent].any()
    assert np.all(got['linear_acceleration_covariance'][~accel_absent, 0] > 0.0)
    assert np.all(got['angular_velocity_covariance'][~gyro_absent, 0] > 0.0)
    assert int(values['received']) == int(values['published']) + int(values['dropped']) == len(raw.stamp_ns)
    assert (values['dropped.duplicate_stamp'], values['dropped.non_physical']) == ('1', '1')
    assert values['sensor_dropped.gyro.non_finite'] == '1' and values['sensor_stamps'].startswith('own')
    assert int(values['one_sensor_messages']) == int(np.count_nonzero(
        (raw.linear_acceleration_covariance[:, 0] == -1.0) | (raw.angular_velocity_covariance[:, 0] == -1.0)))
    log = node.log()
    assert 'marks the accelerometer absent (covariance[0] = -1)' in log and 'Traceback' not in log


def test_absurd_parameter_updates_refused_and_the_node_keeps_publishing(tmp_path, ros_env):
    """residual_rms 1e200, offset 1e308, a tiny scale, a string, an input-kind change.

    Each refused with its reason; a valid update in between is taken; the node publishes throughout.
    """
    params = driver_params(tmp_path / 'params.yaml', qos='reliable')
    good = (0.1, -0.2, 9.81, 0.01, -0.02, 0.03)
    with NodeProcess(node_command('--params-file', str(params)), ros_env, tmp_path / 'node.log') as node, \
            Harness(int(ros_env['ROS_DOMAIN_ID']), driver=True) as ros:
        ros.wait_matched()
        ros.send_temperature_and_wait(START_NS, 20.0)
        stamp = START_NS

        def corrected():
            nonlocal stamp
            stamp += 1
            count = len(ros.imu)
            ros.send_imu(stamp, good)
            ros.wait(lambda: len(ros.imu) == count + 1, 10.0, 'an Imu')
            imu = ros.imu[-1]
            return imu.angular_velocity.x, imu.angular_velocity_covariance[0]

        before = corrected()
        absurd = [({'calibration.gyro.x.residual_rms': 1e200}, 'calibration.gyro.x.residual_rms'),
                  ({'calibration.accel.x.offset': 1e308}, 'calibration.accel.x.offset'),
                  ({'calibration.gyro.y.scale': 1e-300}, 'calibration.gyro.y.scale'),
                  ({'calibration.gyro.z.offset_shape': [1e300, 1e300]}, 'calibration.gyro.z.offset_shape'),
                  ({'calibration.accel.temperature_max': 1e9}, 'calibration.accel.temperature_max'),
                  ({'calibration.gyro.x.offset': 'zero'}, 'calibration.gyro.x.offset'),
                  ({'calibration.version': 1}, 'calibration'),
                  ({'temp_timeout': -1.0}, 'temp_timeout')]
        for change, key in absurd:
            result = ros.set_parameters(change)[0]
            assert not result.successful and key in result.reason, (change, result.reason)
            assert corrected() == before
        x = DRIVER_UNIT.gyro.axes[0]
        assert ros.set_parameters({'calibration.gyro.x.offset': x.offset + 0.01})[0].successful
        after = corrected()
        assert after[0] == UnitCorrector(replace(DRIVER_UNIT, gyro=replace(DRIVER_UNIT.gyro, axes=(
            replace(x, offset=x.offset + 0.01), *DRIVER_UNIT.gyro.axes[1:])))).correct_sample(good, 20.0)[3]
        assert after[0] != before[0]
        assert node.process.poll() is None and node.stop() == 0
    log = node.log()
    assert log.count('parameter update rejected') == len(absurd) and 'Traceback' not in log


@pytest.mark.parametrize('executor', ['events', 'single_threaded'])
def test_shutdown_on_sigint_and_sigterm_within_a_time_limit(tmp_path, ros_env, executor):
    """Either executor: the diagnostics timer runs, and SIGINT or SIGTERM ends the node (exit 0) in < 5 s."""
    import os
    import signal
    import time
    params = driver_params(tmp_path / 'params.yaml', executor=executor)
    for number in (signal.SIGINT, signal.SIGTERM):
        with NodeProcess(node_command('--params-file', str(params)), ros_env,
                         tmp_path / f'node_{number}.log') as node, \
                Harness(int(ros_env['ROS_DOMAIN_ID']), driver=True) as ros:
            ros.wait(lambda: len(ros.diagnostics) >= 1, 20.0, 'a diagnostics message (the timer runs)')
            assert f'executor {executor}' in node.log()
            started = time.monotonic()
            os.killpg(node.process.pid, number)
            node.process.wait(timeout=5.0)
            assert time.monotonic() - started < 5.0 and node.process.returncode == 0, node.log()
        assert 'Traceback' not in node.log()


def test_transport_losses_counted_from_message_lost_events(tmp_path, ros_env):
    """Bursts of Imu at full speed into a reliable node of depth 1 from a writer of depth 1.

    What Fast DDS reports lost is counted in /diagnostics (message_lost) and logged; received == published + dropped
    still holds, and received + lost never exceeds what was sent.
    """
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    params = driver_params(tmp_path / 'params.yaml', qos='reliable', qos_depth=1)
    burst = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE)
    with NodeProcess(node_command('--params-file', str(params)), ros_env, tmp_path / 'node.log') as node, \
            Harness(int(ros_env['ROS_DOMAIN_ID']), driver=True, input_qos=burst) as ros:
        ros.wait_matched()
        ros.send_temperature_and_wait(START_NS, 20.0)
        sent = 0
        for _ in range(8):  # bursts of 5,000 until Fast DDS reports a loss (the first one, usually)
            for _ in range(5_000):
                sent += 1
                ros.send_imu(START_NS + sent, (0.1, -0.2, 9.81, 0.01, -0.02, 0.03))
            try:
                ros.wait(lambda: int(status_values(ros.latest_status())['message_lost']) > 0, 3.0,
                         'a transport loss in the diagnostics')
                break
            except AssertionError:
                continue
        values = status_values(ros.latest_status())
        received, published, lost = int(values['received']), int(values['published']), int(values['message_lost'])
        # Whether Fast DDS reports a loss at all depends on the machine's timing (an idle machine
        # may report none in 40,000 messages); what it reports is counted, per input and in all,
        # and never more than what was neither received nor sent.
        assert lost == int(values.get('message_lost.imu', '0'))  # the per-input key appears with the first loss
        assert received == published + int(values['dropped']) and received + lost <= sent
        assert received + int(values['sequence_gap']) <= sent  # the MessageInfo, with the EventsExecutor too
        assert node.stop() == 0
    assert ('imu messages lost in transport' in node.log()) == (lost > 0)


@pytest.mark.parametrize('executor', ['events', 'single_threaded'])
def test_either_executor_counts_every_message_never_received(tmp_path, ros_env, executor):
    """With either executor (events: the default) the publication sequence numbers show every lost message.

    After a burst of 5,000 into a node of depth 1, received + sequence_gap == sent, exactly.
    """
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    params = driver_params(tmp_path / 'params.yaml', qos='reliable', qos_depth=1, executor=executor)
    burst = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE)
    with NodeProcess(node_command('--params-file', str(params)), ros_env, tmp_path / 'node.log') as node, \
            Harness(int(ros_env['ROS_DOMAIN_ID']), driver=True, input_qos=burst) as ros:
        ros.wait_matched()
        ros.send_temperature_and_wait(START_NS, 20.0)
        ros.send_imu(START_NS + 1, (0.1, -0.2, 9.81, 0.01, -0.02, 0.03))  # sequence number 1, received
        ros.wait(lambda: status_values(ros.latest_status())['received'] == '1', 10.0, 'the first Imu taken')
        sent = 1
        for _ in range(5_000):
            sent += 1
            ros.send_imu(START_NS + sent, (0.1, -0.2, 9.81, 0.01, -0.02, 0.03))

        def accounted() -> bool:
            values = status_values(ros.latest_status())
            return int(values['received']) + int(values['sequence_gap']) == sent

        ros.wait(accounted, 20.0, 'received + sequence_gap == sent')
        values = status_values(ros.latest_status())
        assert int(values['sequence_gap']) > 0 and int(values['received']) < sent
        assert int(values['received']) == int(values['published']) + int(values['dropped'])
        assert node.stop() == 0
    assert 'imu messages never received' in node.log()
