"""Simulated runs: the IMU's chamber and rate-table runs with hidden effects (:mod:`.imu`).

A run's numbers are a :class:`~.scenario.Scenario`, its true axes in :mod:`.truth`.

A scenario file is read by :func:`tak_thermo_ros.formats.scenario.load_scenario`.
"""

from tak_thermo_ros.core.simulation.imu import SimulatedRun, simulate
from tak_thermo_ros.core.simulation.scenario import Scenario

__all__ = ['Scenario', 'SimulatedRun', 'simulate']
