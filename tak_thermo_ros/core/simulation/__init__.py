"""Simulated runs: the IMU's chamber and rate-table runs with hidden effects (:mod:`.imu`).

A scenario file is read by :func:`tak_thermo_ros.formats.scenario.load_scenario`.
"""

from tak_thermo_ros.core.simulation.imu import Scenario, SimulatedRun, simulate

__all__ = ['Scenario', 'SimulatedRun', 'simulate']
