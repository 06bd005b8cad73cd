"""Shared simulated systems for the tests (short runs: seconds, not hours, of CPU)."""

from __future__ import annotations

import math
import os
from dataclasses import replace

# As tak_calib does (tak_thermo_ros/cli/__init__.py): small least-squares problems run fastest on
# one BLAS thread, and the tests call the commands in this process, where numpy loads first.
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

import numpy as np  # noqa: E402
import pytest  # noqa: E402

import node_helpers  # noqa: E402
from node_helpers import domain_id, ros_environment  # noqa: E402
from tak_thermo_ros.core.records.record import align  # noqa: E402
from tak_thermo_ros.core.simulation.imu import Scenario, simulate  # noqa: E402

SHORT = Scenario(plateau_hours=0.5, ramp_celsius_per_minute=1.0, board_lag_s=300.0, dwell_s=30.0)
"""The paper's five plateaus, shortened: about 3 h of 1 Hz samples."""

EXAMPLES = {
    'thermal_lag': {'tau_s': 300.0, 'slope_x': 0.02, 'slope_z': -0.03},
    'hysteresis': {'width_codes': 30.0, 'amplitude_y': 5.0, 'amplitude_z': -2.0},
    'warmup': {'tau_s': 900.0, 'amplitude_x': 10.0, 'amplitude_z': -4.0},
    'temperature_shape': {'knot_1': 8000.0, 'knot_2': 8400.0, 'slope_x_1': 0.01, 'slope_y_2': -0.02},
    'cross_axis': {'c_xy': 0.3, 'c_zx': -0.5, 'c_yz': 0.2},
    'scale_nonlinearity': {'k2_x': 0.05, 'k2_y': -0.03, 'k2_z': 0.02},
    'step': {'origin_s': 1.7e9, 'at_s': 1500.25, 'amplitude_x': 6.0, 'amplitude_z': -4.0},
}
"""Each library effect with example parameters (the library and block-correction tests)."""


CREEP_MODULE = '''
from tak_thermo_ros.core.effects import Effect, ParameterSpec


class Creep(Effect):
    """Offset creeping linearly with time since power-on: rate_i counts per hour."""

    name = 'creep'
    summary = 'The offset creeps linearly with time since power-on, whatever the temperature.'
    confirm = 'A long run at constant temperature: the offset keeps moving at a constant rate.'
    needs_stamps = True
    amplitude = ParameterSpec('rate', 0.0, -100.0, 100.0, 'counts/h')

    def start(self, stamp_s, temp_code):
        return stamp_s

    def step(self, state, stamp_s, temp_code):
        return state, ((stamp_s - state) / 3600.0,)
'''
"""Source of a user-defined effect module (docs/effects.md's worked example) for the tests to write."""


def noise_floor(scenario: Scenario) -> np.ndarray:
    """Per-axis RMS of white noise plus code rounding, counts."""
    return np.array([math.sqrt(axis.noise_counts ** 2 + 1.0 / 12.0) for axis in scenario.unit])


@pytest.fixture(scope='session')
def short_run():
    """A short calibration run of the default unit."""
    return simulate(replace(SHORT, seed=11))


@pytest.fixture(scope='session')
def short_samples(short_run):
    """The short run aligned on counts stamps."""
    return align(short_run.record)


# ----- Hypothesis: one profile for `make test`, a longer one for `make fuzz` ---------------------

from hypothesis import HealthCheck, settings  # noqa: E402

_SUPPRESSED = [HealthCheck.too_slow, HealthCheck.function_scoped_fixture, HealthCheck.data_too_large,
               HealthCheck.filter_too_much]
settings.register_profile('ci', deadline=None, derandomize=True, database=None, print_blob=True,
                          suppress_health_check=_SUPPRESSED)
settings.register_profile('long', deadline=None, database=None, print_blob=True, suppress_health_check=_SUPPRESSED)
HYPOTHESIS_PROFILE = os.environ.get('TAK_HYPOTHESIS_PROFILE', 'ci')
settings.load_profile(HYPOTHESIS_PROFILE)
FUZZ_SCALE = int(os.environ.get('TAK_FUZZ_SCALE', '25' if HYPOTHESIS_PROFILE == 'long' else '1'))
"""Examples per property test = its base budget times this (the 'long' profile: 25x)."""


def examples(base: int) -> int:
    """The example budget of a property test: ``base`` in ``make test`` (all together < 60 s)."""
    return base * FUZZ_SCALE


@pytest.fixture(autouse=True, scope='session')
def _no_process_outlives_the_session():
    """Every process a test module started (``node_helpers.start_process``) is gone when the session ends."""
    yield
    left = node_helpers.kill_leftovers()
    assert not left, f'process groups left running at the end of the session (killed now): {left}'


@pytest.fixture(autouse=True)
def _no_process_outlives_its_test():
    """A test stops what it starts, whatever the outcome: a group it left running is killed and the test fails."""
    since = len(node_helpers.STARTED_GROUPS)
    yield
    left = node_helpers.kill_leftovers(since)
    assert not left, f'the test left process groups running (killed now): {left}'


@pytest.fixture
def ros_env(tmp_path, monkeypatch, request):
    """Environment of this test's ROS processes (also applied to the test process)."""
    index = sum(ord(c) for c in request.node.name)
    env = ros_environment(tmp_path, domain_id(index))
    for key in ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_DOMAIN_ID', 'ROS_HOME', 'ROS_LOG_DIR'):
        monkeypatch.setenv(key, env[key])
    return env
