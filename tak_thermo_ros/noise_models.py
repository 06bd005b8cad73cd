"""Per-sensor noise models for ``diagnose`` and ``validate``: a file, a static run, or the residual.

In this order of preference: a Kalibr-style ``imu.yaml`` the user gives (``--noise FILE``,
``source='file'``), a static run at constant temperature (``--noise-run BAG``: the Allan variance
of each sensor's signal about its mean, ``source='static_run'``), else the diagnosed run's own
residual after the calibration (``source='residual'``, said as such).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from tak_thermo_ros.core.link.model import Calibration, InputKind
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.errors import NoiseError, TakError

RESIDUAL_LONGEST_TAU_S = 30.0
"""A noise model from the diagnosed run's own residual is fitted to its Allan variance at
averaging times up to this (half a minute): a thermal effect acts over the minutes a temperature
ramp takes, so what the residual shows at shorter averaging times is the sensor's own noise;
longer, the residual holds whatever the model misses besides the wander, and no run can tell
them apart without a static run or a data sheet."""
NOISE_RUN_MAX_SAMPLES = 4_000_000
"""A static noise run is read whole up to about this many samples (then 1 in n, said in one line)."""


def _period(samples: AlignedSamples) -> float:
    return max(float(np.median(np.diff(samples.stamp_ns))) * 1e-9, 1e-9) if len(samples) > 1 else 1.0


def in_counts(model: Any, calibration: Calibration) -> Any:
    """A noise model in SI (a file) expressed in the channel codes of a counts calibration."""
    scale = np.array([axis.scale for axis in calibration.axes], dtype=float)

    def scaled(name: str) -> tuple[float, float, float]:
        values = np.asarray(getattr(model, name), dtype=float) * scale
        return float(values[0]), float(values[1]), float(values[2])
    terms = ('white_noise_density', 'bias_instability', 'random_walk', 'quantization', 'rate_ramp')
    return replace(model, **{name: scaled(name) for name in terms})


def model_from_signal(signal: np.ndarray, sample_period_s: float, source: str, *,
                      longest_s: float | None = None) -> Any:
    """The five-term noise model of a ``(k, 3)`` signal (its overlapping Allan variance, fitted;
    up to ``longest_s`` of averaging when given, two averaging times per octave)."""
    from tak_thermo_ros.core.noise.allan import allan_variance, cluster_sizes, largest_cluster
    from tak_thermo_ros.core.noise.model import fit_noise_model
    signal = np.asarray(signal, dtype=float)
    largest = largest_cluster(len(signal))
    if longest_s is not None:
        largest = min(largest, int(longest_s / sample_period_s))
    allan = allan_variance(signal - signal.mean(axis=0), 1.0 / sample_period_s, clusters=cluster_sizes(largest, 2))
    return fit_noise_model(allan, source=source)


def models_from_file(path: str | Path, sensors: tuple[str, ...], kind: InputKind,
                     calibrations: dict[str, Calibration]) -> dict[str, Any]:
    """The sensors' noise models from a Kalibr-style file (counts: converted to codes)."""
    from tak_thermo_ros.core.noise.kalibr import read_kalibr
    found = read_kalibr(path)
    models = {}
    for sensor in sensors:
        if sensor not in found:
            msg = f'{path}: no noise model for the {"gyroscope" if sensor == "gyro" else "accelerometer"}'
            raise NoiseError(msg)
        models[sensor] = in_counts(found[sensor], calibrations[sensor]) if kind is InputKind.COUNTS else found[sensor]
    return models


def models_from_static_run(path: str | Path, options: Any, *, gravity: float) -> tuple[dict[str, Any], list[str]]:
    """The sensors' noise models from a static run at constant temperature (``source='static_run'``).

    :returns: the models and the lines to print.
    """
    from tak_thermo_ros.streaming import bounded_run
    run = bounded_run(path, options, gravity=gravity, max_samples=NOISE_RUN_MAX_SAMPLES)
    models, lines = {}, []
    if run.stride > 1:
        lines.append(f'noise run {path}: 1 sample in {run.stride} (at most about {NOISE_RUN_MAX_SAMPLES:,})')
    for sensor, samples in run.samples.items():
        try:
            models[sensor] = model_from_signal(samples.counts, _period(samples), 'static_run')
        except NoiseError as err:
            msg = f'{path}: cannot estimate a noise model from this run: {err}'
            raise NoiseError(msg) from None
    return models, lines


def model_from_residual(residual: np.ndarray, samples: AlignedSamples) -> Any | None:
    """The noise model of the run's own residual at averaging times up to
    :data:`RESIDUAL_LONGEST_TAU_S` (``source='residual'``), or ``None`` when the run is too short
    for five averaging times."""
    try:
        return model_from_signal(residual, _period(samples), 'residual', longest_s=RESIDUAL_LONGEST_TAU_S)
    except TakError:
        return None
