"""The node's Imu covariances come from the calibration's noise model; node == apply still (real rclpy)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ros.test_node import DRIVER_RUN, driver_params, node_and_apply
from tak_thermo_ros.formats.bag import write_driver_record
from tak_thermo_ros.core.noise.model import NoiseModel
from tak_thermo_ros.formats.calibration_file import load_unit
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.scenario import Scenario

UNIT = Scenario(output='imu').driver_truth()
ACCEL_NOISE = NoiseModel(white_noise_density=(2e-3, 1e-3, 3e-3), bias_instability=(1e-4, 1e-4, 2e-4),
                         bias_instability_tau=(50.0, 60.0, 70.0), random_walk=(1e-5, 2e-5, 3e-5), update_rate=200.0,
                         source='static_run')
GYRO_NOISE = replace(ACCEL_NOISE, white_noise_density=(1e-4, 2e-4, 1.5e-4), random_walk=(1e-6, 0.0, 2e-6),
                     bias_instability_tau=(50.0, float('inf'), 70.0), source='residual')


def test_node_covariances_follow_the_noise_model_and_equal_apply(tmp_path, ros_env):
    unit = replace(UNIT, accel=replace(UNIT.accel, noise=ACCEL_NOISE), gyro=replace(UNIT.gyro, noise=GYRO_NOISE))
    params, bag = tmp_path / 'params.yaml', tmp_path / 'run.mcap'
    driver_params(params, unit)
    loaded = load_unit(params)
    assert loaded.accel.noise == ACCEL_NOISE
    assert loaded.gyro.noise.bias_instability_tau[1] == float('inf')  # left out of the file, found again
    driver = replace(DRIVER_RUN, plateau_hours=0.002)
    record = simulate(driver).driver
    write_driver_record(bag, record)
    expected, imu = node_and_apply(bag, params, record, ros_env, tmp_path)
    assert len(imu) == len(expected.stamp_ns) > 100
    linear = np.array([m.linear_acceleration_covariance for m in imu])
    angular = np.array([m.angular_velocity_covariance for m in imu])
    assert np.array_equal(linear, expected.linear_acceleration_covariance)
    assert np.array_equal(angular, expected.angular_velocity_covariance)
    assert np.array_equal(np.array([(m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z)
                                    for m in imu]), expected.angular_velocity)
    per_sample = {name: model.allan_variance([1.0 / 200.0])[0]  # white^2 * 200 and the rest at 5 ms
                  for name, model in (('accel', ACCEL_NOISE), ('gyro', GYRO_NOISE))}
    assert np.allclose(per_sample['gyro'], np.array(GYRO_NOISE.white_noise_density) ** 2 * 200.0, rtol=0.01)
    assert np.allclose(linear[0].reshape(3, 3), np.diag(per_sample['accel']), rtol=1e-12, atol=0.0)
    assert np.allclose(angular[0].reshape(3, 3), np.diag(per_sample['gyro']), rtol=1e-12, atol=0.0)
