"""Experiment design: the chamber run that would tell the top two candidates apart.

When two effects explain a run about equally (a thermal lag and a hysteresis both open loops
between heating and cooling), another run must settle it. :func:`design_run` fits the current
model plus each of the two candidates on the diagnosed run, then for each of a few candidate
temperature profiles (plateaus visited from both sides, ramp rates, dwell times):

1. simulates the chamber, the board's lag and the turntable of that profile
   (:func:`tak_thermo_ros.core.simulate.simulate`, for the stamps, temperature codes and inputs);
2. predicts the counts under candidate A with its fitted parameters, and fits the model with
   candidate B to them (noise-free: the best B can do to mimic A), and the other way round;
3. measures the separation: what the other model cannot absorb, in units of the noise floor.
   ``separation_sigmas = sqrt(n * mean(r^2 / floor^2))`` over the axes, with ``n`` samples at
   the diagnosed run's sample rate (the evidence a run of that rate would collect), the smaller
   of the two directions.

The profile with the largest separation is written as a simulator scenario (YAML,
:func:`tak_thermo_ros.core.simulate.load_scenario` format) and as a chamber schedule (CSV of
``time_s, setpoint_C``). Temperatures in Celsius map to temperature codes through the scenario's
sensor gain (``temp_code_ref``, ``codes_per_celsius``; the simulator's defaults unless given).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import yaml

from tak_thermo_ros.core.calibration_file import write_text_atomic
from tak_thermo_ros.core.correction import Corrector
from tak_thermo_ros.core.diagnose.crossval import _effect_specs, _settings_of, _with_range, decimate
from tak_thermo_ros.core.diagnose.values import Diagnosis
from tak_thermo_ros.core.effects import resolve_effect
from tak_thermo_ros.core.fit import fit_model, residual_counts
from tak_thermo_ros.core.model import AXES, Calibration
from tak_thermo_ros.core.record import AlignedSamples, align
from tak_thermo_ros.core.simulate import Scenario, chamber_profile, simulate
from tak_thermo_ros.errors import FitError, TakError

DESIGN_RATE_HZ = 0.1
"""Sample rate of the design simulations (the separation is scaled to the run's own rate)."""


@dataclass(frozen=True)
class ProfileScore:
    """One candidate profile and how far apart the two candidates land on it.

    :param label: what the profile does, in words.
    :param hours: its duration.
    :param separation_sigmas: the smaller of the two directions, see the module docstring.
    :param rms_over_floor: ``(3,)`` per axis, RMS of what the other model cannot absorb / floor
        (the smaller direction).
    """

    label: str
    scenario: dict[str, Any]
    hours: float
    separation_sigmas: float
    rms_over_floor: tuple[float, float, float]

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {'label': self.label, 'hours': self.hours, 'separation_sigmas': self.separation_sigmas,
                'rms_over_floor': dict(zip(AXES, self.rms_over_floor)), 'scenario': dict(self.scenario)}


@dataclass(frozen=True)
class RunDesign:
    """The proposed run: the profile that separates the two candidates best, and the others tried.

    :param baseline_sigmas: the same separation on the diagnosed run itself (its samples).
    """

    candidates: tuple[str, str]
    best: ProfileScore
    tried: tuple[ProfileScore, ...]
    sample_rate_hz: float
    fitted: dict[str, dict[str, float]] = field(default_factory=dict)
    baseline_sigmas: float = 0.0
    baseline_rms_over_floor: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {'candidates': list(self.candidates), 'best': self.best.as_dict(),
                'tried': [p.as_dict() for p in self.tried], 'sample_rate_hz': self.sample_rate_hz,
                'fitted_parameters': {k: dict(v) for k, v in self.fitted.items()},
                'diagnosed_run': {'separation_sigmas': self.baseline_sigmas,
                                  'rms_over_floor': dict(zip(AXES, self.baseline_rms_over_floor))}}

    def schedule(self, sensor: Scenario | None = None) -> list[tuple[float, float]]:
        """The chamber set-points ``(time_s, setpoint_C)`` at every corner of the best profile."""
        scenario = _scenario(self.best.scenario, sensor)
        corners = [0.0]
        temperature = scenario.start_celsius
        for plateau in scenario.plateaus_celsius:
            ramp = abs(plateau - temperature) / scenario.ramp_celsius_per_minute * 60.0
            corners += [corners[-1] + ramp, corners[-1] + ramp + scenario.plateau_hours * 3600.0]
            temperature = plateau
        values = chamber_profile(scenario, np.array(corners))
        return [(float(t), float(c)) for t, c in zip(corners, values)]

    def message(self) -> str:
        """The proposal in two sentences."""
        a, b = self.candidates
        best = self.best
        return (f'To tell {a} from {b}: {best.label} ({best.hours:.1f} h). Simulated with each candidate\'s '
                f'fitted parameters, the other cannot absorb {best.separation_sigmas:.0f} noise sigmas of it '
                f'at {self.sample_rate_hz:.3g} Hz (what it cannot absorb, RMS in units of the floor: '
                f'{", ".join(f"{n} {v:.2f}" for n, v in zip(AXES, best.rms_over_floor))}); '
                f'on the diagnosed run itself: {self.baseline_sigmas:.0f} sigmas.')


def _scenario(mapping: dict[str, Any], sensor: Scenario | None) -> Scenario:
    base = sensor or Scenario()
    return replace(base, **{k: (tuple(v) if isinstance(v, list) else v) for k, v in mapping.items()})


def candidate_profiles(low_celsius: float, high_celsius: float) -> list[tuple[str, dict[str, Any]]]:
    """A few profiles over ``low..high``: plateaus from both sides, ramp rates, dwell times."""
    middle = round((low_celsius + high_celsius) / 2.0, 1)
    low, high = round(low_celsius, 1), round(high_celsius, 1)
    both_sides = [middle, high, middle, low, middle]
    return [
        ('the middle plateau reached from above and from below, 30-minute dwell, 1 C/min',
         {'start_celsius': low, 'plateaus_celsius': both_sides, 'plateau_hours': 0.5, 'ramp_celsius_per_minute': 1.0}),
        ('the middle plateau reached from above and from below, 2-hour dwell, 1 C/min',
         {'start_celsius': low, 'plateaus_celsius': both_sides, 'plateau_hours': 2.0, 'ramp_celsius_per_minute': 1.0}),
        ('full-range ramps at 2 C/min, 30-minute dwell',
         {'start_celsius': low, 'plateaus_celsius': [high, low, high, low], 'plateau_hours': 0.5,
          'ramp_celsius_per_minute': 2.0}),
        ('full-range ramps at 0.25 C/min, 30-minute dwell',
         {'start_celsius': low, 'plateaus_celsius': [high, low, high], 'plateau_hours': 0.5,
          'ramp_celsius_per_minute': 0.25}),
        ('plateaus middle, high, middle, low at 0.5 C/min, 1-hour dwell',
         {'start_celsius': low, 'plateaus_celsius': [middle, high, middle, low], 'plateau_hours': 1.0,
          'ramp_celsius_per_minute': 0.5}),
    ]


def _predicted(calibration: Calibration, samples: AlignedSamples) -> np.ndarray:
    low, high = float(samples.temp_code.min()), float(samples.temp_code.max())
    corrector = Corrector(_with_range(calibration, low, high))
    return corrector.predict_counts(samples.reference, samples.temp_code, stamp_s=samples.stamp_s,
                                     aux=samples.aux)


def design_run(diagnosis: Diagnosis, samples: AlignedSamples, *, pair: Sequence[str] | None = None,
               sensor: Scenario | None = None, sample_rate_hz: float | None = None,
               progress: Callable[[str], None] | None = None) -> RunDesign:
    """Propose the chamber run that separates the top two candidates of a diagnosis.

    :param diagnosis: what :func:`~tak_thermo_ros.core.diagnose.diagnose` found on ``samples``.
    :param samples: the diagnosed run.
    :param pair: the two effects to separate; default the diagnosis's two best candidates.
    :param sensor: scenario whose sensor gain, unit, turntable and board lag the simulations use
        (default the simulator's); its profile keys are replaced by each candidate profile.
    :param sample_rate_hz: rate of the proposed run; default that of the diagnosed run.
    :raises FitError: with fewer than two candidates, or when a candidate cannot be fitted.
    """
    say = progress or (lambda text: None)
    names = list(pair) if pair is not None else [c.effect for c in diagnosis.candidates[:2]]
    if len(names) < 2:
        msg = 'run design needs two candidate effects to separate; the diagnosis has fewer'
        raise FitError(msg)
    a_name, b_name = names[0], names[1]
    settings = _settings_of(diagnosis.calibration, None, None)
    present = _effect_specs(diagnosis.calibration)
    fit_on = decimate(samples, diagnosis.cv_stride)
    models: dict[str, tuple[Any, ...]] = {}
    fitted: dict[str, Calibration] = {}
    for name in (a_name, b_name):
        cls = resolve_effect(name)
        shared = getattr(cls, 'shared', None)
        effects = tuple(cls if spec is shared else spec for spec in present)
        if cls not in effects:
            effects = (*effects, cls)
        models[name] = effects
        say(f'fit base + {name} on the diagnosed run')
        fitted[name] = fit_model(fit_on, effects=effects, bias_order=settings.bias_order,
                                 scale_order=settings.scale_order, temp_code_ref=settings.temp_code_ref,
                                 nominal_scale=settings.nominal_scale).calibration
    floor = np.maximum(diagnosis.noise_floor, 1e-12)
    sensor = sensor or Scenario()
    to_celsius = lambda code: sensor.reference_celsius + (code - sensor.temp_code_ref) / sensor.codes_per_celsius  # noqa: E731
    temps = sorted((to_celsius(float(samples.temp_code.min())), to_celsius(float(samples.temp_code.max()))))
    duration = float(samples.time_s[-1] - samples.time_s[0]) if len(samples) > 1 else 1.0
    rate = sample_rate_hz or max((len(samples) - 1) / max(duration, 1e-9), 1e-6)

    def weakest_direction(simulated: AlignedSamples) -> np.ndarray:
        """Per axis RMS / floor of what the other model cannot absorb, the weaker direction."""
        directions = []
        for truth_name, model_name in ((a_name, b_name), (b_name, a_name)):
            counts = _predicted(fitted[truth_name], simulated)
            copy = replace(simulated, counts=counts)
            try:
                mimic = fit_model(copy, effects=models[model_name], bias_order=settings.bias_order,
                                  scale_order=settings.scale_order, temp_code_ref=settings.temp_code_ref,
                                  nominal_scale=settings.nominal_scale).calibration
                residual = residual_counts(_with_range(mimic, float(simulated.temp_code.min()),
                                                       float(simulated.temp_code.max())), copy)
            except TakError:
                residual = counts - counts.mean(axis=0)
            directions.append(np.sqrt(np.mean(residual ** 2, axis=0)) / floor)
        return min(directions, key=lambda r: float(np.sum(r ** 2)))

    say('separation on the diagnosed run itself')
    own = weakest_direction(fit_on)
    baseline = math.sqrt(len(samples) * float(np.sum(own ** 2)))
    scores = []
    for label, profile in candidate_profiles(temps[0], temps[1]):
        scenario = _scenario({**profile, 'sample_rate_hz': DESIGN_RATE_HZ, 'effects': {}}, sensor)
        say(f'simulate: {label}')
        weakest = weakest_direction(align(simulate(scenario).record))
        hours = scenario.duration_s() / 3600.0
        evidence = math.sqrt(hours * 3600.0 * rate * float(np.sum(weakest ** 2)))
        scores.append(ProfileScore(label=label, scenario={**profile}, hours=hours, separation_sigmas=evidence,
                                   rms_over_floor=(float(weakest[0]), float(weakest[1]), float(weakest[2]))))
    best = max(scores, key=lambda s: s.separation_sigmas)
    parameters = {name: {f'{e.name}.{k}': float(v) for e in cal.effects for k, v in e.values.items()}
                  for name, cal in fitted.items()}
    return RunDesign(candidates=(a_name, b_name), best=best, tried=tuple(scores), sample_rate_hz=float(rate),
                     fitted=parameters, baseline_sigmas=baseline,
                     baseline_rms_over_floor=(float(own[0]), float(own[1]), float(own[2])))


def write_design(design: RunDesign, directory: str | Path, *, sensor: Scenario | None = None) -> tuple[Path, Path, Path]:
    """Write ``scenario.yaml`` (the simulator runs it), ``schedule.csv`` and ``design.json``.

    :returns: the three paths.
    """
    import json
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    scenario = {**design.best.scenario, 'sample_rate_hz': design.sample_rate_hz}
    header = (f'# chamber run proposed by tak_calib diagnose --design-run to tell {design.candidates[0]} from '
              f'{design.candidates[1]}\n# {design.best.label}; simulated separation '
              f'{design.best.separation_sigmas:.0f} noise sigmas\n')
    scenario_path = directory / 'scenario.yaml'
    write_text_atomic(scenario_path, header + yaml.safe_dump(scenario, sort_keys=False))
    schedule_path = directory / 'schedule.csv'
    rows = ''.join(f'{t:.1f},{c:.3f}\n' for t, c in design.schedule(sensor))
    write_text_atomic(schedule_path, 'time_s,setpoint_C\n' + rows)
    json_path = directory / 'design.json'
    write_text_atomic(json_path, json.dumps(design.as_dict(), indent=2) + '\n')
    return scenario_path, schedule_path, json_path
