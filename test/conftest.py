"""Shared simulated systems for the tests (short runs: seconds, not hours, of CPU)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from tak_thermo_ros.core.record import align
from tak_thermo_ros.core.simulate import Scenario, simulate

SHORT = Scenario(plateau_hours=0.5, ramp_celsius_per_minute=1.0, board_lag_s=300.0, dwell_s=30.0)
"""The paper's five plateaus, shortened: about 3 h of 1 Hz samples."""


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
