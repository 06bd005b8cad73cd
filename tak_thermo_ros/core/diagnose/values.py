"""The values :func:`~tak_thermo_ros.core.diagnose.diagnose` returns and passes between its steps."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tak_thermo_ros.core.link.model import AXES, Calibration


@dataclass(frozen=True)
class AxisSummary:
    """Residual RMS of the given calibration on this run against the noise floor, counts.

    :param rms: RMS of ``N - model`` over the whole run (the calibration as given).
    :param noise_floor: white noise plus code rounding, from successive differences.
    :param heldout_rms: held-out RMS of the same model structure refitted by cross-validation.
    :param excess_significant: whether ``heldout_rms`` lies significantly above the floor, and
        above what the same model shows on a copy of the run where it is true.
    :param null_heldout_rms: held-out RMS of the same model on a simulated copy of the run in
        which that model is true, with white noise at the floor (parameter-estimation error of
        held-out blocks included); the floor itself when the excess was too small to need it.
    :param white_floor: the per-sample white floor from successive differences. Judged against
        a noise model, ``noise_floor`` and ``heldout_rms`` are RMS values of means over the
        averaging bins (``noise_floor``: what copies of the run under the noise model show).
    """

    rms: float
    noise_floor: float
    heldout_rms: float
    excess_significant: bool
    null_heldout_rms: float = 0.0
    white_floor: float = 0.0


@dataclass(frozen=True)
class ModelScore:
    """Blocked cross-validation of one model.

    :param effects: effect names on top of the base model.
    :param fold_sse: ``(folds, 3)`` held-out sum of squared residuals per fold and axis.
    :param fold_samples: ``(folds,)`` held-out samples per fold.
    :param error: why the model could not be fitted (then the arrays are empty).
    :param failed_folds: folds that could not be fitted and were scored with the current model.
    :param block_sse: ``(blocks, 3)`` the same per contiguous time block (each block is held out
        with its fold), for paired comparisons of two models block by block.
    :param block_samples: ``(blocks,)`` held-out samples per block.
    :param heldout: ``(k, 3)`` the held-out residual itself (before whitening), when the scores
        are of a whitened residual.
    """

    effects: tuple[str, ...]
    fold_sse: np.ndarray
    fold_samples: np.ndarray
    error: str | None = None
    failed_folds: tuple[str, ...] = ()
    block_sse: np.ndarray | None = None
    block_samples: np.ndarray | None = None
    heldout: np.ndarray | None = None

    @property
    def ok(self) -> bool:
        """Whether every fold could be fitted."""
        return self.error is None

    @property
    def heldout_rms(self) -> np.ndarray:
        """``(3,)`` pooled held-out RMS per axis."""
        return np.sqrt(self.fold_sse.sum(axis=0) / self.fold_samples.sum())

    def excess(self, floor: np.ndarray) -> float:
        """Held-out variance above the floor, summed over axes in units of each axis' floor^2."""
        return float(np.sum(self.heldout_rms ** 2 / floor ** 2 - 1.0))

    @property
    def label(self) -> str:
        """``'base'`` or ``'base + a + b'``."""
        return ' + '.join(('base', *self.effects))


@dataclass(frozen=True)
class Candidate:
    """One library effect tried on top of the current model.

    :param effect: its name.
    :param rms_after: ``(3,)`` held-out RMS with the effect added, counts.
    :param explained: share of the current model's held-out excess variance it removes.
    :param significance: that improvement in standard errors of pure noise.
    :param evidence: one paragraph for a human.
    :param summary: the effect's physics, one sentence.
    :param confirm: which test run would confirm it.
    :param parameters: its fitted parameters.
    """

    effect: str
    rms_after: tuple[float, float, float]
    explained: float
    significance: float
    evidence: str
    summary: str = ''
    confirm: str = ''
    parameters: dict[str, float] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {'effect': self.effect, 'rms_after': dict(zip(AXES, self.rms_after)),
                'explained_fraction': self.explained, 'significance_sigmas': self.significance,
                'evidence': self.evidence, 'summary': self.summary, 'confirm': self.confirm,
                'parameters': dict(self.parameters)}


@dataclass(frozen=True)
class LadderStep:
    """One rung of the model ladder: a model and its held-out RMS per axis."""

    label: str
    effects: tuple[str, ...]
    heldout_rms: tuple[float, float, float]

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {'model': self.label, 'effects': list(self.effects),
                'heldout_rms': dict(zip(AXES, self.heldout_rms))}


@dataclass(frozen=True)
class Driver:
    """How much of the residual variance a binned mean of one quantity explains (eta^2)."""

    name: str
    fraction: tuple[float, float, float]

    @property
    def largest(self) -> float:
        """The largest fraction over the axes."""
        return max(self.fraction)


@dataclass(frozen=True)
class Plateau:
    """A stretch of steady temperature code.

    :param start: index of its first sample; ``stop`` one past the last.
    :param temp_code: mean temperature code.
    :param approach: ``+1`` reached by heating, ``-1`` by cooling, ``0`` at the start.
    """

    start: int
    stop: int
    temp_code: float
    approach: int


@dataclass(frozen=True)
class Views:
    """The quantities the residual is viewed against, one value per sample.

    :param time_s: ``(k,)`` seconds since the first sample.
    :param temp_code: ``(k,)`` held temperature code.
    :param rate: ``(k,)`` ``dN_t/dt`` in codes per second (central difference over a window).
    :param direction: ``(k,)`` ``+1`` heating, ``-1`` cooling, ``0`` steady.
    :param specific_force: ``(k, 3)`` the reference input, m/s^2.
    :param plateaus: the steady stretches, in time order.
    :param breaks: ``(k,)`` True where the sample starts a new segment (turntable move, gap).
    """

    time_s: np.ndarray
    temp_code: np.ndarray
    rate: np.ndarray
    direction: np.ndarray
    specific_force: np.ndarray
    plateaus: tuple[Plateau, ...]
    breaks: np.ndarray


@dataclass(frozen=True)
class Diagnosis:
    """What :func:`diagnose` found.

    :param verdict: an effect name, ``'none'`` or ``'unexplained'``.
    :param message: the verdict in two or three sentences.
    :param axes: per axis x, y, z.
    :param candidates: effects tried on the current model, best first.
    :param skipped: effect -> why it could not be tried on this run.
    :param ladder: the current model, then each effect added while it explained the rest.
    :param drivers: what the final residual follows (eta^2 per quantity), largest first.
    :param base_drivers: the same for the current model's residual.
    :param residual: ``(k, 3)`` residual of the given calibration.
    :param residual_after: ``(k, 3)`` residual after the ladder's effects, or ``None``.
    :param calibration: the calibration as given.
    :param calibration_after: the calibration refitted with the ladder's effects, or ``None``.
    :param views: the quantities the residual is viewed against.
    :param folds: cross-validation folds; ``blocks`` contiguous time blocks in all.
    :param cv_stride: every this many samples were used in the cross-validation fits.
    :param present_effects: the effects the given calibration holds already.
    :param explained: share of the current model's held-out excess that the ladder removes.
    :param unresolved: ladder effect -> its shape parameters fitted at the edge of the searched
        range (the run does not identify it; it is then not the verdict).
    :param per_axis_forms: per-axis forms tried in place of a shared form that joined the ladder
        (``explained`` and ``significance`` against the rung below); the ladder holds the
        per-axis form when held-out blocks preferred it by more than noise could.
    :param pruned: effects the forward ladder took that the final model does not need (held-out
        blocks do not notice their removal once the later effects are in).
    :param noise: the noise model the run was judged against (or fitted to its residual), or ``None``.
    :param allan: per ladder rung, its label and the Allan test of its residual
        (:class:`~tak_thermo_ros.core.diagnose.yardstick.AllanCheck`); empty without a noise model.
    :param averaging_time_s: the averaging bins of the cross-validation, judged against a noise
        model from a file or a static run; 0 otherwise (per sample).
    :param yardstick_replicates: simulated copies of the run under the noise model.
    :param steps: the sudden level changes of the residual as given
        (:class:`~tak_thermo_ros.core.records.steps.LevelChange`), largest first;
        ``steps_offset_s`` the first sample's time after the record's start (their moments count from it).
    :param statements: ``message`` one sentence at a time
        (:class:`~tak_thermo_ros.core.diagnose.verdict.Statement`: its text, and whether it is a
        detail that only ``--verbose`` prints).
    :param excursions: the ladder judged on held-out thermal excursions
        (:class:`~tak_thermo_ros.core.diagnose.heldout.ExcursionVerdict`), ``None`` when not judged.
    """

    verdict: str
    message: str
    axes: tuple[AxisSummary, AxisSummary, AxisSummary]
    candidates: tuple[Candidate, ...]
    skipped: dict[str, str]
    ladder: tuple[LadderStep, ...]
    drivers: tuple[Driver, ...]
    base_drivers: tuple[Driver, ...]
    residual: np.ndarray
    residual_after: np.ndarray | None
    calibration: Calibration
    calibration_after: Calibration | None
    views: Views
    folds: int
    blocks: int
    cv_stride: int
    present_effects: tuple[str, ...] = ()
    explained: float = 0.0
    unresolved: dict[str, str] = field(default_factory=dict)
    pruned: tuple[str, ...] = ()
    per_axis_forms: tuple[Candidate, ...] = ()
    noise: Any = None
    allan: tuple[tuple[str, Any], ...] = ()
    averaging_time_s: float = 0.0
    yardstick_replicates: int = 0
    statements: tuple[Any, ...] = ()
    steps: tuple[Any, ...] = ()
    steps_offset_s: float = 0.0
    excursions: Any = None

    @property
    def noise_floor(self) -> np.ndarray:
        """``(3,)`` the noise floor per axis, counts (the yardstick of the held-out RMS values)."""
        return np.array([axis.noise_floor for axis in self.axes])

    @property
    def white_floor(self) -> np.ndarray:
        """``(3,)`` the per-sample white floor from successive differences, counts."""
        return np.array([axis.white_floor or axis.noise_floor for axis in self.axes])

    def summary(self, unit: str, *, label: str = '', verbose: bool = False, driver_words: bool = False) -> str:
        """The diagnosis's report, one statement per line (:func:`~tak_thermo_ros.core.diagnose.summary.summary_lines`).

        :param unit: the unit of the calibration's output (``'counts'``, ``'m/s^2'``, ``'rad/s'``, ``'T'``).
        """
        from tak_thermo_ros.core.diagnose.summary import summary_lines
        return '\n'.join(summary_lines(self, unit, label=label, verbose=verbose, driver_words=driver_words))

    def as_dict(self) -> dict[str, Any]:
        """The JSON document of ``tak_calib diagnose --json``."""
        return {
            'verdict': self.verdict,
            'message': self.message,
            'axes': {name: {'rms': a.rms, 'noise_floor': a.noise_floor, 'heldout_rms': a.heldout_rms,
                            'excess_significant': a.excess_significant,
                            'null_heldout_rms': a.null_heldout_rms, 'white_floor': a.white_floor or a.noise_floor}
                     for name, a in zip(AXES, self.axes)},
            'candidates': [c.as_dict() for c in self.candidates],
            'skipped': dict(self.skipped),
            'unresolved': dict(self.unresolved),
            'pruned': list(self.pruned),
            'per_axis_forms': [c.as_dict() for c in self.per_axis_forms],
            'ladder': [step.as_dict() for step in self.ladder],
            'residual_follows': [{'quantity': d.name, 'variance_fraction': dict(zip(AXES, d.fraction))}
                                 for d in self.drivers],
            'ladder_explained_fraction': self.explained,
            'model_effects': list(self.present_effects),
            'cross_validation': {'folds': self.folds, 'blocks': self.blocks, 'stride': self.cv_stride},
            'samples': int(len(self.views.time_s)),
            'averaging_time_s': self.averaging_time_s,
            **({'noise': noise_document(self.noise)} if self.noise is not None else {}),
            'allan': [{'model': label, **check.as_dict()} for label, check in self.allan],
            'steps': [self.step_document(step) for step in self.steps],
            **({'held_out_excursions': self.excursions.as_dict()} if self.excursions is not None else {}),
        }

    def step_document(self, step: Any) -> dict[str, Any]:
        """A step in ``--json``: its moment (seconds since the record's start), temperature, per axis its change."""
        views = self.views
        return {'time_s': step_time_s(views, step, self.steps_offset_s), 'sample': int(step.index),
                'temperature': float(views.temp_code[step.index]),
                'scale_samples': int(step.scale), 'axes': [AXES[c] for c in step.named],
                'change': dict(zip(AXES, (float(v) for v in step.amplitude))),
                'sigma': dict(zip(AXES, (float(v) for v in step.sigma)))}


def step_time_s(views: Views, step: Any, offset_s: float = 0.0) -> float:
    """A step's moment: midway between the samples either side of it, ``offset_s`` after the views' time."""
    return float(views.time_s[step.index] + views.time_s[step.index - 1]) / 2.0 + offset_s


def noise_document(noise: Any) -> dict[str, Any]:
    """The JSON form of a noise model in ``diagnose --json``.

    Three numbers per term, one per axis (``bias_instability_tau`` null where the model has no
    floor).
    """
    def triple(name: str) -> list[float | None]:
        values = np.broadcast_to(np.asarray(getattr(noise, name, 0.0), dtype=float).reshape(-1), (3,))
        # A floor time at infinity (nothing rises within the averaging times) is null in strict JSON.
        return [float(v) if np.isfinite(v) else None for v in values]
    return {'white_noise_density': triple('white_noise_density'), 'bias_instability': triple('bias_instability'),
            'bias_instability_tau': triple('bias_instability_tau'), 'random_walk': triple('random_walk'),
            'source': str(getattr(noise, 'source', 'residual'))}
