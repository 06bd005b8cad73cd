"""Issue 31: thermal excursions as the held-out unit, and the judgement of a rung on them."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter
from scipy.stats import binom

from tak_thermo_ros.core.diagnose.excursions import COOLING, HEATING, PLATEAU, excursion_labels, excursions
from tak_thermo_ros.core.diagnose.heldout import HeldOut, compare, sensor_noise
from tak_thermo_ros.core.fit.uncertainty import ResidualNoise

TIME = np.arange(6000.0)
COURSE = np.interp(TIME, [0, 1000, 2000, 3000, 4000, 5000, 6000], [20, 5, 5, 35, 35, 5, 5])
"""A cooling, a plateau, a heating, a plateau, a cooling, a plateau (one sample a second)."""


def test_a_course_is_cut_at_its_turns_and_plateaus():
    found = excursions(TIME, COURSE)
    assert [e.kind for e in found] == [COOLING, PLATEAU, HEATING, PLATEAU, COOLING, PLATEAU]
    labels = excursion_labels(len(TIME), found)
    assert np.all(np.diff(labels) >= 0) and labels[0] == 0 and labels[-1] == len(found) - 1
    # each ramp ends within a minute (the smoothing window) of where the chamber turned
    assert abs(found[2].start - 2000) < 60 and abs(found[4].start - 4000) < 60


def test_small_wiggles_and_one_ramp_are_one_excursion():
    """A ramp with noise and wiggles smaller than a tenth of its range is one excursion; so is a flat record."""
    rng = np.random.default_rng(1)
    ramp = np.linspace(50.0, -17.0, 3000) + 0.3 * rng.standard_normal(3000) + 2.0 * np.sin(TIME[:3000] / 40.0)
    found = excursions(TIME[:3000], ramp)
    assert [e.kind for e in found] == [COOLING]
    assert [e.kind for e in excursions(TIME[:100], np.full(100, 20.0))] == [PLATEAU]


def _judge(before: np.ndarray, after: np.ndarray, noise=None):
    found = excursions(TIME, COURSE)
    return compare(HeldOut('before', before), HeldOut('after', after), excursion_labels(len(TIME), found), found,
                   np.ones(3), 'lag', noise=noise)


def test_a_rung_that_helps_everywhere_holds_and_one_that_hurts_an_axis_does_not():
    rng = np.random.default_rng(2)
    noise = 0.5 * rng.standard_normal((len(TIME), 3))
    signal = np.column_stack([np.gradient(COURSE)] * 3) * 20.0  # a lag-like error on every ramp
    white = [ResidualNoise.white_only(0.25, 1.0)] * 3  # what diagnose takes without a noise model
    better = _judge(noise + signal, noise, white)
    # better on the ramps (on the plateaus the lag-like error is nil: a coin toss there)
    assert better.kept and better.judged == 6 and better.better >= 3 and better.sigmas > 10.0
    hurt = noise + signal
    hurt[:, 2] = noise[:, 2] + 3.0 * signal[:, 2]  # z made worse
    worse = _judge(noise + signal, hurt, white)
    assert not worse.kept and {axis for _, axis in worse.worse} == {'z'}
    assert 'worse on z' in worse.line('held-out excursions')


def _coloured(rng: np.random.Generator, decay: float) -> np.ndarray:
    drive = rng.standard_normal((len(TIME), 3))
    return 0.5 * rng.standard_normal((len(TIME), 3)) + lfilter([1.0], [1.0, -decay], drive, axis=0) * np.sqrt(
        1.0 - decay * decay)


@pytest.mark.parametrize('decay', [0.99, 0.999])
def test_a_rung_that_only_follows_wander_is_rarely_kept(decay):
    """A rung that adds a slow curve the data do not hold is kept about as rarely as the 1 % threshold says.

    Over 60 seeds of a residual that wanders for 100 s or 1000 s (an excursion's length), judged with
    the rung's own residual as the noise (binomial bound, 1 % chance of more).
    """
    kept = 0
    for seed in range(60):
        rng = np.random.default_rng(seed)
        residual = _coloured(rng, decay)
        curve = np.column_stack([np.sin(TIME / 900.0 + rng.uniform(0.0, 6.3)) for _ in range(3)]) * 0.3
        kept += _judge(residual, residual - curve).kept  # the rung subtracts a curve the data do not hold
    assert kept <= binom.isf(0.01, 60, 0.01)


def test_the_sensor_noise_model_weighs_a_wandering_gain():
    """Judged against a noise model with a random walk, the same gain stands fewer sigmas than against white noise."""
    rng = np.random.default_rng(3)
    noise = _coloured(rng, 0.999)
    signal = np.column_stack([np.gradient(COURSE)] * 3) * 40.0
    white = [ResidualNoise.white_only(0.25, 1.0)] * 3

    class Walking:
        bias_instability = (0.0, 0.0, 0.0)
        bias_instability_tau = (100.0, 100.0, 100.0)
        random_walk = (0.02, 0.02, 0.02)

    walking = sensor_noise(Walking(), np.full(3, 0.5), 1.0, 1.0, 6000.0)
    assert walking[0].walk > 0.0 and walking[0].white == pytest.approx(0.25)
    against_white = _judge(noise + signal, noise, white)
    against_walk = _judge(noise + signal, noise, walking)
    assert 0.0 < against_walk.sigmas < 0.5 * against_white.sigmas


def test_the_json_of_a_judgement_is_strict():
    """No NaN or infinity in ``diagnose --json``'s ``held_out_excursions`` (a rung judged on no sample)."""
    import json
    from tak_thermo_ros.core.diagnose.heldout import ExcursionVerdict
    nothing = np.full((len(TIME), 3), np.nan)
    rung = _judge(nothing, nothing)
    verdict = ExcursionVerdict(excursions(TIME, COURSE), False, (rung,))
    text = json.dumps(verdict.as_dict(), allow_nan=False)
    assert '"judged": 0' in text and '"decided": false' in text
