"""The still-interval detector: its threshold follows the record's own noise; quantised channels rest too."""

from __future__ import annotations

import numpy as np
import pytest

from tak_thermo_ros.core.records.still import find_still

RATE_HZ = 50.0
REST_S = 6.0
TURN_S = 2.0
GRAVITY = 9.80665


def hand_record(noise_accel: float, noise_gyro: float, seed: int, rests: int = 12):
    """Rests in random orientations joined by 90 deg/s turns; white noise of the given size on every channel.

    The turns' rate (1.57 rad/s) stands far above either noise level, so every rest is found at
    any noise the test uses; the rests' count and the noise estimate are what the detector
    must get right.
    """
    rng = np.random.default_rng(seed)
    per_rest, per_turn = int(REST_S * RATE_HZ), int(TURN_S * RATE_HZ)
    accel, gyro = [], []
    for _ in range(rests):
        up = rng.standard_normal(3)
        up /= np.linalg.norm(up)
        accel.append(np.tile(GRAVITY * up, (per_rest, 1)))
        gyro.append(np.zeros((per_rest, 3)))
        axis = rng.standard_normal(3)
        axis /= np.linalg.norm(axis)
        accel.append(np.tile(GRAVITY * up, (per_turn, 1)) + rng.standard_normal((per_turn, 3)))
        gyro.append(np.tile(np.radians(90.0) * axis, (per_turn, 1)))
    accel, gyro = np.vstack(accel), np.vstack(gyro)
    accel += noise_accel * rng.standard_normal(accel.shape)
    gyro += noise_gyro * rng.standard_normal(gyro.shape)
    stamp_ns = np.round(np.arange(len(accel)) / RATE_HZ * 1e9).astype(np.int64)
    return stamp_ns, np.hstack([accel, gyro])


@pytest.mark.parametrize('scale', [1.0, 10.0, 100.0])
def test_the_threshold_follows_the_records_own_noise(scale):
    """The same rests are found at 1x, 10x and 100x the noise, and the noise is read from the record."""
    for seed in range(5):
        noise = np.array([2e-3] * 3 + [2e-4] * 3) * scale
        stamp_ns, values = hand_record(noise[0], noise[3], seed)
        still = find_still(stamp_ns, values)
        assert len(still) == 12, (scale, seed, len(still))
        # The noise estimate: the mean of half the squared successive differences over the quiet
        # windows: within 10 % of the truth (thousands of differences per channel).
        np.testing.assert_allclose(still.noise, noise, rtol=0.1)


def test_a_quantised_or_constant_channel_at_rest_is_still():
    """A gyroscope axis coarser than its noise (it dithers between two levels) or constant does not move the unit."""
    stamp_ns, values = hand_record(2e-3, 2e-4, seed=7)
    quantum = 1e-3  # five times the gyroscope's noise
    values[:, 3] = np.round((values[:, 3] + 0.4e-3) / quantum) * quantum  # near a level's edge: it dithers
    values[:, 4] = 0.002  # constant (a channel stuck, or an axis far coarser than anything it sees)
    still = find_still(stamp_ns, values)
    assert len(still) == 12
