"""Simulated runs: the IMU's chamber and rate-table runs with hidden effects (:mod:`.imu`)."""

from tak_thermo_ros.core.simulation.imu import Scenario, SimulatedRun, load_scenario, simulate

__all__ = ['Scenario', 'SimulatedRun', 'load_scenario', 'simulate']
