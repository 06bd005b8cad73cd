"""Experiment design: the chamber run that would tell the top two candidates apart.

When two effects explain a run about equally (a thermal lag and a hysteresis both open loops
between heating and cooling), another run must settle it. :func:`design_run` fits the current
model plus each of the two candidates on the diagnosed run, then for each of a few candidate
temperature profiles (plateaus visited from both sides, ramp rates, dwell times):

1. simulates the chamber, the board's lag and the turntable of that profile
   (:func:`tak_thermo_ros.core.simulation.imu.simulate`, for the stamps, temperature codes and inputs);
2. predicts the counts under candidate A with its fitted parameters, and fits the model with
   candidate B to them (noise-free: the best B can do to mimic A), and the other way round;
3. measures the separation: what the other model cannot absorb, in units of the noise floor.
   ``separation_sigmas = sqrt(n * mean(r^2 / floor^2))`` over the axes, with ``n`` samples at
   the diagnosed run's sample rate (the evidence a run of that rate would collect), the smaller
   of the two directions.

The profile with the largest separation is written as a simulator scenario (YAML,
:func:`tak_thermo_ros.formats.scenario.load_scenario` format) and as a chamber schedule (CSV of
``time_s, setpoint_C``). Temperatures in Celsius map to temperature codes through the scenario's
sensor gain (``temp_code_ref``, ``codes_per_celsius``; the simulator's defaults unless given).

Driver bags (:func:`design_driver_run`): the same per sensor, in the sensor's units and with the
temperature in degrees C (no gain), each profile simulated once as a driver run on the diagnosed
run's table; one run serves both sensors, so the proposed profile is the one whose weaker sensor
separation is largest (:data:`COMBINATION_RULE`). A recorded signal (``aux:``) among the two best
candidates is not separated by any temperature profile (:func:`recorded_signal_note`). Effects of
the current model that follow a recorded signal are left out of the simulated runs (the simulator
records none; a steady signal adds a constant the bias absorbs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import yaml

from tak_thermo_ros.core.link.correction import Corrector
from tak_thermo_ros.core.diagnose.crossval import _effect_specs, _settings_of, _with_range, decimate, fit_with
from tak_thermo_ros.core.diagnose.values import Diagnosis
from tak_thermo_ros.core.diagnose.verdict import VERDICT_NONE
from tak_thermo_ros.core.values import SENSOR_NAMES
from tak_thermo_ros.core.effects import AUX_PREFIX, resolve_effect
from tak_thermo_ros.core.fit import residual_counts
from tak_thermo_ros.core.link.model import AXES, Calibration
from tak_thermo_ros.core.records.record import AlignedSamples, align
from tak_thermo_ros.core.simulation.imu import chamber_profile, simulate
from tak_thermo_ros.core.simulation.scenario import Scenario
from tak_thermo_ros.core.simulation.truth import DEFAULT_POSITIONS, RATE_TABLE_POSITIONS, RATE_TABLE_RATES
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
        return _corners(_scenario(self.best.scenario, sensor))

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


@dataclass(frozen=True)
class _CandidateFits:
    """Each of the two candidates fitted (on top of the current model) to the diagnosed run."""

    names: tuple[str, str]
    models: dict[str, tuple[Any, ...]]
    fitted: dict[str, Calibration]
    settings: Any

    def steady_signals(self) -> _CandidateFits:
        """The same fits without the effects that follow a recorded signal (``aux:``), for simulated runs.

        The simulator records no such signal: held steady, it adds a constant that the bias absorbs.
        """
        def follows_signal(spec: Any) -> bool:
            return getattr(spec, 'needs_signal', None) is not None

        models = {name: tuple(spec for spec in specs if not follows_signal(spec))
                  for name, specs in self.models.items()}
        fitted = {name: replace(cal, effects=tuple(e for e in cal.effects if not follows_signal(e)))
                  for name, cal in self.fitted.items()}
        return replace(self, models=models, fitted=fitted)

    def parameters(self) -> dict[str, dict[str, float]]:
        """``candidate -> {effect.parameter: value}`` of the fitted effects."""
        return {name: {f'{e.name}.{k}': float(v) for e in cal.effects for k, v in e.values.items()}
                for name, cal in self.fitted.items()}


def _fit_candidates(diagnosis: Diagnosis, samples: AlignedSamples, names: Sequence[str],
                    say: Callable[[str], None]) -> _CandidateFits:
    """Fit the current model plus each of the two named candidates on (a decimated copy of) the run."""
    settings = _settings_of(diagnosis.calibration, None, None)
    present = _effect_specs(diagnosis.calibration)
    fit_on = decimate(samples, diagnosis.cv_stride)
    models: dict[str, tuple[Any, ...]] = {}
    fitted: dict[str, Calibration] = {}
    for name in names[:2]:
        cls = resolve_effect(name)
        shared = getattr(cls, 'shared', None)
        effects = tuple(cls if spec is shared else spec for spec in present)
        if cls not in effects:
            effects = (*effects, cls)
        models[name] = effects
        say(f'fit base + {name} on the diagnosed run')
        fitted[name] = fit_with(fit_on, effects, settings, errors=True).calibration
    return _CandidateFits(names=(names[0], names[1]), models=models, fitted=fitted, settings=settings)


def _weakest_direction(fits: _CandidateFits, simulated: AlignedSamples, floor: np.ndarray) -> np.ndarray:
    """Per axis RMS / floor of what the other model cannot absorb, the weaker direction."""
    a_name, b_name = fits.names
    settings = fits.settings
    directions = []
    for truth_name, model_name in ((a_name, b_name), (b_name, a_name)):
        counts = _predicted(fits.fitted[truth_name], simulated)
        copy = replace(simulated, counts=counts)
        try:
            mimic = fit_with(copy, fits.models[model_name], settings, errors=True).calibration
            residual = residual_counts(_with_range(mimic, float(simulated.temp_code.min()),
                                                   float(simulated.temp_code.max())), copy)
        except TakError:
            residual = counts - counts.mean(axis=0)
        directions.append(np.sqrt(np.mean(residual ** 2, axis=0)) / floor)
    return min(directions, key=lambda r: float(np.sum(r ** 2)))


def _sample_rate(samples: AlignedSamples) -> float:
    """Samples per second of a run (over its whole span)."""
    duration = float(samples.time_s[-1] - samples.time_s[0]) if len(samples) > 1 else 1.0
    return max((len(samples) - 1) / max(duration, 1e-9), 1e-6)


def _score(label: str, profile: dict[str, Any], weakest: np.ndarray, hours: float, rate: float) -> ProfileScore:
    evidence = math.sqrt(hours * 3600.0 * rate * float(np.sum(weakest ** 2)))
    return ProfileScore(label=label, scenario={**profile}, hours=hours, separation_sigmas=evidence,
                        rms_over_floor=(float(weakest[0]), float(weakest[1]), float(weakest[2])))


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
    fits = _fit_candidates(diagnosis, samples, names, say)
    floor = np.maximum(diagnosis.noise_floor, 1e-12)
    sensor = sensor or Scenario()
    codes = (float(samples.temp_code.min()), float(samples.temp_code.max()))
    temps = sorted(sensor.reference_celsius + (code - sensor.temp_code_ref) / sensor.codes_per_celsius
                   for code in codes)
    rate = sample_rate_hz or _sample_rate(samples)

    say('separation on the diagnosed run itself')
    own = _weakest_direction(fits, decimate(samples, diagnosis.cv_stride), floor)
    baseline = math.sqrt(len(samples) * float(np.sum(own ** 2)))
    scores = []
    for label, profile in candidate_profiles(temps[0], temps[1]):
        scenario = _scenario({**profile, 'sample_rate_hz': DESIGN_RATE_HZ, 'effects': {}}, sensor)
        say(f'simulate: {label}')
        weakest = _weakest_direction(fits.steady_signals(), align(simulate(scenario).record), floor)
        scores.append(_score(label, profile, weakest, scenario.duration_s() / 3600.0, rate))
    best = max(scores, key=lambda s: s.separation_sigmas)
    return RunDesign(candidates=fits.names, best=best, tried=tuple(scores), sample_rate_hz=float(rate),
                     fitted=fits.parameters(), baseline_sigmas=baseline,
                     baseline_rms_over_floor=(float(own[0]), float(own[1]), float(own[2])))


COMBINATION_RULE = 'the profile whose weaker sensor separation is largest'
"""How the sensors' proposals become one chamber run (a single run serves both sensors)."""
TURNING_RATE = 1e-3
"""A rate reference above this (rad/s; the Earth rate is 7.3e-5) means the diagnosed run was on a rate table."""


def recorded_signal_note(diagnosis: Diagnosis, label: str = '') -> str | None:
    """The one line that says a temperature profile cannot separate a recorded-signal candidate.

    :param label: ``'accelerometer: '`` and the like, or ``''``.
    :returns: ``None`` when neither of the two best candidates is an ``aux:`` signal.
    """
    names = [c.effect for c in diagnosis.candidates[:2]]
    signals = [name for name in names if name.startswith(AUX_PREFIX)]
    if not signals:
        return None
    others = [name for name in names if name not in signals]
    topics = ', '.join(name[len(AUX_PREFIX):].split(':')[0] for name in signals)
    against = f'from {others[0]}' if others else 'from each other'
    verb = 'is' if len(signals) == 1 else 'are'
    return (f'{label}no chamber run designed: {" and ".join(signals)} {verb} among the two best candidates, '
            f'and a temperature profile cannot tell a recorded signal {against} by temperature alone; what separates '
            f'them is a run in which {topics} varies independently of the temperature (e.g. the supply voltage '
            f'stepped at a constant chamber temperature)')


def _nothing_to_separate(diagnosis: Diagnosis, label: str) -> str | None:
    """Why a sensor's diagnosis has no two candidates worth a run, or ``None``."""
    names = [c.effect for c in diagnosis.candidates[:2]]
    if diagnosis.verdict == VERDICT_NONE:
        return f'{label}nothing to separate (verdict none)'
    if len(names) < 2:
        found = f'only one candidate, {names[0]}' if names else 'no candidate'
        return f'{label}nothing to separate ({found})'
    note = recorded_signal_note(diagnosis, label)
    if note is None and diagnosis.candidates[1].explained <= 0.0:
        return f'{label}nothing to separate ({names[1]} explains none of the excess over the floor)'
    return note


def driver_table(accel: AlignedSamples, gyro: AlignedSamples | None) -> dict[str, Any]:
    """Scenario keys of the table the diagnosed driver run was recorded on.

    A rate reference that turns: the simulator's rate table (:data:`RATE_TABLE_POSITIONS`);
    several attitudes: its tilt table; one attitude: that attitude, static, without reference
    topics (as a static run records them). The dwell is the run's median time between
    reference changes.
    """
    reference = accel.reference if accel.reference is not None else np.zeros((len(accel), 3))
    norms = np.linalg.norm(reference, axis=1)
    directions = np.unique(np.round(reference[norms > 0] / norms[norms > 0, None], 3), axis=0)
    rates = None if gyro is None else gyro.reference
    turning = rates is not None and len(rates) > 0 and float(np.max(np.abs(rates))) > TURNING_RATE
    if not turning and len(directions) <= 1:
        up = reference[norms > 0].mean(axis=0) if np.any(norms > 0) else np.array([0.0, 0.0, 1.0])
        up = up / np.linalg.norm(up)
        return {'positions': ((float(up[0]), float(up[1]), float(up[2])),), 'table_rates': (),
                'record_references': False}
    changes = np.flatnonzero(np.any(np.diff(reference, axis=0) != 0.0, axis=1)) + 1
    if rates is not None and len(rates) == len(reference):
        changes = np.union1d(changes, np.flatnonzero(np.any(np.diff(rates, axis=0) != 0.0, axis=1)) + 1)
    intervals = np.diff(accel.time_s[changes]) if len(changes) > 1 else np.zeros(0)
    dwell = float(np.median(intervals)) if len(intervals) else Scenario.dwell_s
    table: dict[str, Any] = {'dwell_s': max(round(dwell, 1), 1.0)}
    if turning:
        table.update(positions=RATE_TABLE_POSITIONS, table_rates=RATE_TABLE_RATES)
    else:
        table.update(positions=DEFAULT_POSITIONS, table_rates=())
    return table


@dataclass(frozen=True)
class SensorDesign:
    """One sensor's two candidates scored on every profile tried.

    :param sensor: ``'accel'`` or ``'gyro'``.
    :param tried: one score per profile, in the order of :func:`candidate_profiles`.
    :param baseline_sigmas: the separation on the diagnosed run itself.
    """

    sensor: str
    candidates: tuple[str, str]
    tried: tuple[ProfileScore, ...]
    baseline_sigmas: float
    baseline_rms_over_floor: tuple[float, float, float]
    fitted: dict[str, dict[str, float]] = field(default_factory=dict)

    @property
    def own_best(self) -> ProfileScore:
        """The profile this sensor alone would choose."""
        return max(self.tried, key=lambda s: s.separation_sigmas)

    def as_dict(self, choice: int) -> dict[str, Any]:
        """JSON-ready form; ``choice`` is the index of the proposed profile."""
        return {'candidates': list(self.candidates), 'proposed': self.tried[choice].as_dict(),
                'own_best': self.own_best.as_dict(), 'tried': [p.as_dict() for p in self.tried],
                'fitted_parameters': {k: dict(v) for k, v in self.fitted.items()},
                'diagnosed_run': {'separation_sigmas': self.baseline_sigmas,
                                  'rms_over_floor': dict(zip(AXES, self.baseline_rms_over_floor))}}


@dataclass(frozen=True)
class DriverRunDesign:
    """One chamber run for a driver bag's two sensors.

    :param sensors: the sensors with two candidates worth separating.
    :param notes: sensor -> the one line why it has no design (nothing to separate, or a
        recorded-signal candidate that no temperature profile separates).
    :param table: scenario keys of the table (positions, rates, dwell) the run is simulated on.
    :param choice: index of the proposed profile in :func:`candidate_profiles` (``-1``: none,
        no sensor had anything to separate); the one maximising the smallest of the
        sensors' separations (:data:`COMBINATION_RULE`).
    """

    sensors: tuple[SensorDesign, ...]
    notes: dict[str, str]
    table: dict[str, Any]
    sample_rate_hz: float
    choice: int = -1

    @property
    def designed(self) -> bool:
        """Whether a run is proposed."""
        return self.choice >= 0 and bool(self.sensors)

    @property
    def best(self) -> ProfileScore:
        """The proposed profile (scored for the sensor it separates least)."""
        return min((s.tried[self.choice] for s in self.sensors), key=lambda p: p.separation_sigmas)

    def scenario(self) -> dict[str, Any]:
        """The proposed run as ``tak_calib simulate --scenario`` keys (``output: imu``)."""
        def plain(value: Any) -> Any:
            if isinstance(value, tuple):
                return [plain(v) for v in value]
            return float(value) + 0.0 if isinstance(value, float) else value  # + 0.0: no -0.0 in the file

        table = {key: plain(value) for key, value in self.table.items()}
        return {'output': 'imu', **self.best.scenario, 'sample_rate_hz': self.sample_rate_hz, **table}

    def schedule(self) -> list[tuple[float, float]]:
        """The chamber set-points ``(time_s, setpoint_C)`` at every corner, strictly later each."""
        rows: list[tuple[float, float]] = []
        for time_s, celsius in _corners(_scenario(self.best.scenario, Scenario(output='imu'))):
            if not rows or time_s > rows[-1][0]:
                rows.append((time_s, celsius))
        return rows

    def lines(self) -> list[str]:
        """What the command prints: the proposed run, one line per sensor."""
        out = []
        if self.designed:
            best = self.best
            out.append(f'proposed chamber run for both sensors ({COMBINATION_RULE}): {best.label} ({best.hours:.1f} h)')
        for sensor in ('accel', 'gyro'):
            design = next((d for d in self.sensors if d.sensor == sensor), None)
            if design is None:
                if sensor in self.notes:
                    out.append(self.notes[sensor])
                continue
            a, b = design.candidates
            score, own = design.tried[self.choice], design.own_best
            alone = '' if own is score else f'; its own best profile, {own.label}: {own.separation_sigmas:.0f}'
            out.append(f'{SENSOR_NAMES[sensor]}: to tell {a} from {b}: {score.separation_sigmas:.0f} noise sigmas '
                       f'on the proposed run at {self.sample_rate_hz:.3g} Hz (RMS the other cannot absorb, in '
                       f'units of the floor: {", ".join(f"{n} {v:.2f}" for n, v in zip(AXES, score.rms_over_floor))}); '
                       f'{design.baseline_sigmas:.0f} on the diagnosed run itself{alone}')
        return out

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {'input': 'imu', 'combination': COMBINATION_RULE,
                'proposed': self.best.as_dict() if self.designed else None,
                'scenario': self.scenario() if self.designed else None, 'sample_rate_hz': self.sample_rate_hz,
                'sensors': {d.sensor: d.as_dict(self.choice) for d in self.sensors}, 'notes': dict(self.notes)}


def design_driver_run(diagnoses: Mapping[str, Diagnosis], samples: Mapping[str, AlignedSamples], *,
                      sample_rate_hz: float | None = None,
                      progress: Callable[[str], None] | None = None) -> DriverRunDesign:
    """Propose one chamber run that separates each sensor's top two candidates (driver bags).

    Temperatures are the driver's degrees C (no sensor gain). Each profile is simulated once
    (``output: imu``, on the table of the diagnosed run, :func:`driver_table`); each sensor's
    two candidates, fitted on the diagnosed run in that sensor's units, predict its channels
    from the simulated temperature and inputs (specific force or rate), and the separation is
    measured as for counts (module docstring). A sensor whose verdict is ``none``, with fewer
    than two candidates, or with a recorded signal (``aux:``) among the two gets a note instead.
    The proposed profile maximises the smaller of the sensors' separations.

    :param diagnoses: sensor (``'accel'``, ``'gyro'``) -> its diagnosis.
    :param samples: sensor -> the diagnosed samples (the reference: specific force or rate).
    :param sample_rate_hz: rate of the proposed run; default that of the diagnosed run.
    """
    say = progress or (lambda text: None)
    notes: dict[str, str] = {}
    fits: dict[str, _CandidateFits] = {}
    for sensor, diagnosis in diagnoses.items():
        label = f'{SENSOR_NAMES[sensor]}: '
        note = _nothing_to_separate(diagnosis, label)
        if note is not None:
            notes[sensor] = note
            continue
        names = [c.effect for c in diagnosis.candidates[:2]]
        fits[sensor] = _fit_candidates(diagnosis, samples[sensor], names, lambda text, lab=label: say(lab + text))
    accel = samples['accel']
    rate = sample_rate_hz or _sample_rate(accel)
    table = driver_table(accel, samples.get('gyro'))
    if not fits:
        return DriverRunDesign(sensors=(), notes=notes, table=table, sample_rate_hz=float(rate))
    low = min(float(samples[s].temp_code.min()) for s in fits)
    high = max(float(samples[s].temp_code.max()) for s in fits)
    floors = {s: np.maximum(diagnoses[s].noise_floor, 1e-12) for s in fits}
    scores: dict[str, list[ProfileScore]] = {s: [] for s in fits}
    baselines = {}
    for sensor in fits:
        say(f'{SENSOR_NAMES[sensor]}: separation on the diagnosed run itself')
        own = _weakest_direction(fits[sensor], decimate(samples[sensor], diagnoses[sensor].cv_stride), floors[sensor])
        baselines[sensor] = (math.sqrt(len(samples[sensor]) * float(np.sum(own ** 2))), own)
    for label, profile in candidate_profiles(low, high):
        scenario = _scenario({**profile, 'sample_rate_hz': DESIGN_RATE_HZ, 'effects': {}, 'gyro_effects': {},
                              **table, 'record_references': True}, Scenario(output='imu'))
        say(f'simulate: {label}')
        driver = simulate(scenario).driver
        for sensor in fits:
            simulated = align(driver.channel(sensor))  # type: ignore[union-attr]
            weakest = _weakest_direction(fits[sensor].steady_signals(), simulated, floors[sensor])
            scores[sensor].append(_score(label, profile, weakest, scenario.duration_s() / 3600.0, rate))
    count = len(next(iter(scores.values())))
    choice = max(range(count), key=lambda i: min(scores[s][i].separation_sigmas for s in fits))
    designs = tuple(SensorDesign(sensor=s, candidates=fits[s].names, tried=tuple(scores[s]),
                                 baseline_sigmas=baselines[s][0],
                                 baseline_rms_over_floor=tuple(
                                     float(v) for v in baselines[s][1]),  # type: ignore[arg-type]
                                 fitted=fits[s].parameters())
                    for s in ('accel', 'gyro') if s in fits)
    return DriverRunDesign(sensors=designs, notes=notes, table=table, sample_rate_hz=float(rate), choice=choice)


def _corners(scenario: Scenario) -> list[tuple[float, float]]:
    """``(time_s, chamber C)`` at the start and at both ends of every plateau."""
    corners = [0.0]
    temperature = scenario.start_celsius
    for plateau in scenario.plateaus_celsius:
        ramp = abs(plateau - temperature) / scenario.ramp_celsius_per_minute * 60.0
        corners += [corners[-1] + ramp, corners[-1] + ramp + scenario.plateau_hours * 3600.0]
        temperature = plateau
    values = chamber_profile(scenario, np.array(corners))
    return [(float(t), float(c)) for t, c in zip(corners, values)]


def _texts(scenario: dict[str, Any], header: str, schedule: list[tuple[float, float]], document: dict[str, Any],
           flow_lists: bool = False) -> dict[str, str]:
    import json
    rows = ''.join(f'{t:.1f},{c:.3f}\n' for t, c in schedule)
    return {'scenario.yaml': header + yaml.safe_dump(scenario, sort_keys=False,
                                                     default_flow_style=None if flow_lists else False),
            'schedule.csv': 'time_s,setpoint_C\n' + rows,
            'design.json': json.dumps(document, indent=2) + '\n'}


def driver_design_files(design: DriverRunDesign) -> dict[str, str]:
    """A driver bag's proposal as files: ``scenario.yaml`` (``output: imu``), ``schedule.csv``, ``design.json``.

    Each file's name and text (:func:`tak_thermo_ros.formats.files.write_texts` writes them).

    :raises FitError: when no run was designed (no sensor had anything to separate).
    """
    if not design.designed:
        msg = 'no chamber run was designed: no sensor has two candidates a temperature profile separates'
        raise FitError(msg)
    pairs = '; '.join(f'{SENSOR_NAMES[d.sensor]}: {d.candidates[0]} from {d.candidates[1]} '
                      f'({d.tried[design.choice].separation_sigmas:.0f} noise sigmas)' for d in design.sensors)
    header = (f'# chamber run proposed by tak_calib diagnose --design-run to tell {pairs}\n'
              f'# {design.best.label}; one run for both sensors: {COMBINATION_RULE}\n')
    return _texts(design.scenario(), header, design.schedule(), design.as_dict(), flow_lists=True)


def design_files(design: RunDesign, *, sensor: Scenario | None = None) -> dict[str, str]:
    """The proposal as files: ``scenario.yaml`` (the simulator runs it), ``schedule.csv`` and ``design.json``.

    Each file's name and text (:func:`tak_thermo_ros.formats.files.write_texts` writes them).
    """
    scenario = {**design.best.scenario, 'sample_rate_hz': design.sample_rate_hz}
    header = (f'# chamber run proposed by tak_calib diagnose --design-run to tell {design.candidates[0]} from '
              f'{design.candidates[1]}\n# {design.best.label}; simulated separation '
              f'{design.best.separation_sigmas:.0f} noise sigmas\n')
    return _texts(scenario, header, design.schedule(sensor), design.as_dict())
