"""Fitting the base model together with effects: the shape search on top of the pipeline.

Per axis the model is linear in the base coefficients, the input effects' amplitudes and the
offset effects' amplitudes once the offset effects' shape parameters are fixed: the columns of
:mod:`~tak_thermo_ros.core.fit.design`, one solve (:mod:`~tak_thermo_ros.core.fit.solve`), a
model (:mod:`~tak_thermo_ros.core.fit.model`). Only the shapes need a search. So:

1. the run is set up as for the paper's model alone (:class:`~tak_thermo_ros.core.fit.design.FitRun`:
   the same checks, reference code and held axes as a plain fit);
2. each offset effect's shape parameter is searched on a coarse log grid, then refined by a
   bounded Brent search, minimising ``sum_axes ln RSS_axis`` with every amplitude profiled out
   by least squares (QR projection onto the fixed columns);
3. a discrete complexity (the number of knots of ``temperature_shape``) is chosen by blocked
   cross-validation: the training samples cut into contiguous blocks, dealt round-robin into
   folds, each fold predicted from a fit on the others;
4. with several searched effects, step 2-3 is repeated once with all the others in place;
5. the final least squares (the pipeline with every shape fixed) gives every amplitude;
   standard errors come from the Fisher information of amplitudes and shape parameters
   together (shape derivatives numerically) and the residual's own correlation: a sandwich
   with the scores' long-run covariance (:mod:`~tak_thermo_ros.core.fit.uncertainty`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np
from scipy.optimize import minimize_scalar

from tak_thermo_ros.core.effects import held_of, resolve_effect
from tak_thermo_ros.core.effects.base import AXIS_NAMES, INPUT, Effect, call_effect
from tak_thermo_ros.core.fit.base import fit_run, model_run, solve_run
from tak_thermo_ros.core.fit.design import Column, FitRun, not_excited
from tak_thermo_ros.core.fit.model import FitResult, amplitude_errors
from tak_thermo_ros.core.fit.solve import Solution, unit_norms
from tak_thermo_ros.core.fit.uncertainty import ErrorBasis, Sandwich
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.errors import CalibrationError, FitError

GRID_POINTS = 9
"""Coarse grid of a shape-parameter search before the bounded refinement."""
CV_BLOCKS = 20
CV_FOLDS = 5
RANK_TOLERANCE = 1e-9
SCAN_POINTS = 200
"""A scanned shape parameter (:meth:`~tak_thermo_ros.core.effects.base.Effect.search_values`): this many
values first, then each one around the best."""
SHAPE_STEP = 0.01
"""Step (in the searched coordinate: ln of the parameter on a log scale) of the numerical shape derivative."""


@dataclass
class _Offset:
    """An offset effect during the fit."""

    effect: Effect
    mode: str  # 'fixed', 'search' or 'structure'
    searched: tuple[tuple[str, float, float, bool], ...] = ()
    structures: Sequence[Effect] = ()
    basis: np.ndarray | None = None  # whole series
    inputs: np.ndarray | None = None  # what drives the effect: the temperature code or its recorded signal
    done: bool = False
    cache: dict = field(default_factory=dict)


def _template(cls: type[Effect]) -> Effect | None:
    try:
        return cls.from_values({}, complete=False)
    except CalibrationError:
        return None


class _Projection:
    """Least squares with fixed columns per axis, and the profiled RSS for extra columns."""

    def __init__(self, fixed: list[np.ndarray], targets: list[np.ndarray], names: list[list[str]]) -> None:
        self.fixed = fixed
        self.targets = targets
        self.names = names
        self.bases = []
        for i, (design, target) in enumerate(zip(fixed, targets)):
            q, r = np.linalg.qr(design / unit_norms(design))
            diagonal = np.abs(np.diag(r))
            if diagonal.size and diagonal.min() < RANK_TOLERANCE * diagonal.max():
                raise not_excited(i, names[i][int(np.argmin(diagonal))])
            perpendicular = target - q @ (q.T @ target)
            self.bases.append((q, perpendicular, float(perpendicular @ perpendicular)))

    def rss(self, extra: np.ndarray | Sequence[np.ndarray] | None) -> tuple[np.ndarray, list[np.ndarray]]:
        """Per-axis RSS with ``extra`` columns ``(k, b)`` added (one array shared by the axes, or one per axis).

        Per axis the least-squares coefficients of those columns.
        """
        out = np.empty(3)
        coefficients = []
        for i, (q, perpendicular, total) in enumerate(self.bases):
            extra_i = _axis_part(extra, i)
            if extra_i is None or extra_i.shape[1] == 0:
                out[i] = total
                coefficients.append(np.zeros(0))
                continue
            residual = extra_i - q @ (q.T @ extra_i)
            gram = residual.T @ residual
            z = residual.T @ perpendicular
            solution = np.linalg.pinv(gram, rcond=1e-12, hermitian=True) @ z
            out[i] = max(total - float(z @ solution), 1e-300)
            coefficients.append(solution)
        return out, coefficients


def _axis_part(extra: np.ndarray | Sequence[np.ndarray] | None, axis: int) -> np.ndarray | None:
    """The extra columns of one axis: ``extra`` itself when shared, else its ``axis``-th entry."""
    if extra is None or isinstance(extra, np.ndarray):
        return extra
    return extra[axis]


def _normalised(columns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    norms = unit_norms(columns)
    return columns / norms, norms


INVALID = 1e300
"""Objective of a shape whose amplitudes leave their bounds (the search stays inside them)."""
VISIBLE = 0.05
"""A shape is searched only where the training samples see at least this fraction of each basis
signal's largest magnitude over the whole series (else its amplitude would be extrapolation,
e.g. a warm-up that decayed before the first training sample)."""


def _amplitudes_within_bounds(effect: Effect, amplitudes: list[np.ndarray]) -> bool:
    """Whether least-squares amplitudes (per axis, in basis order) respect the effect's bounds."""
    bounds = {parameter.name: (parameter.min, parameter.max) for parameter in effect.parameters}
    for names, values in zip(effect.amplitude_names(), amplitudes):
        for name, value in zip(names, values):
            low, high = bounds[name]
            if not low <= float(value) <= high:
                return False
    return True


class _CrossValidation:
    """Blocked cross-validation: ``sum_axes ln(held-out SSE)`` for extra columns.

    The training samples are cut into contiguous blocks dealt round-robin into folds; each fold
    is predicted from the normal equations of the other blocks. The per-block Gram matrices of
    the fixed columns are computed once; a candidate adds only its own products.
    """

    def __init__(self, fixed: list[np.ndarray], targets: list[np.ndarray]) -> None:
        count = len(targets[0])
        self.blocks = [slice(int(b[0]), int(b[-1]) + 1) for b in
                       np.array_split(np.arange(count), min(CV_BLOCKS, max(count // 10, CV_FOLDS)))]
        self.axes = []
        for design, target in zip(fixed, targets):
            design = _normalised(design)[0]
            grams = [design[b].T @ design[b] for b in self.blocks]
            moments = [design[b].T @ target[b] for b in self.blocks]
            self.axes.append((design, target, grams, moments))

    def score(self, extra: np.ndarray | Sequence[np.ndarray]) -> tuple[float, list[np.ndarray]]:
        """The cross-validation score with ``extra`` (normalised) columns added (shared, or one array per axis).

        Per axis the coefficients of those columns fitted on all training samples.
        """
        score = 0.0
        full_coefficients = []
        for axis, (design, target, grams, moments) in enumerate(self.axes):
            extra_axis = _axis_part(extra, axis)
            width = extra_axis.shape[1]
            fixed_width = design.shape[1]
            block_grams, block_moments = [], []
            for b, gram_ff, moment_f in zip(self.blocks, grams, moments):
                columns = extra_axis[b]
                cross = design[b].T @ columns
                gram = np.block([[gram_ff, cross], [cross.T, columns.T @ columns]])
                block_grams.append(gram)
                block_moments.append(np.concatenate([moment_f, columns.T @ target[b]]))
            gram_total, moment_total = sum(block_grams), sum(block_moments)
            full_coefficients.append(np.linalg.lstsq(gram_total, moment_total, rcond=1e-13)[0][fixed_width:])
            sse = 0.0
            for fold in range(CV_FOLDS):
                held = range(fold, len(self.blocks), CV_FOLDS)
                gram = gram_total - sum(block_grams[i] for i in held)
                moment = moment_total - sum(block_moments[i] for i in held)
                beta = np.linalg.lstsq(gram, moment, rcond=1e-13)[0]
                for i in held:
                    b = self.blocks[i]
                    error = target[b] - design[b] @ beta[:fixed_width]
                    if width:
                        error = error - extra_axis[b] @ beta[fixed_width:]
                    sse += float(error @ error)
            score += math.log(max(sse, 1e-300))
        return score, full_coefficients


def fit_with_effects(samples: AlignedSamples, *, effects: Sequence = (), bias_order: int = 3,
                     scale_order: int = 2, temp_code_ref: float | None = None,
                     nominal_scale: tuple[float, float, float] | None = None,
                     train_mask: np.ndarray | None = None, errors: bool = True) -> FitResult:
    """The implementation of :func:`tak_thermo_ros.core.fit.fit_model`.

    The steps: the run set up (:meth:`FitRun.prepare`: the training rows, checks, frame); each
    offset effect's shapes searched on the profiled residual (variable projection; structures
    by cross-validation), with the columns of the paper's model and the input effects fixed;
    then the pipeline with every shape fixed (:func:`~tak_thermo_ros.core.fit.base.solve_run`,
    :func:`~tak_thermo_ros.core.fit.base.model_run`) and the standard errors (:class:`_EffectFit`).
    Without effects, the pipeline alone (:func:`~tak_thermo_ros.core.fit.base.fit_run`).
    """
    run = FitRun.prepare(samples, bias_order=bias_order, scale_order=scale_order, temp_code_ref=temp_code_ref,
                         nominal_scale=nominal_scale, train_mask=train_mask)
    chosen = _resolve_specs(effects)
    if not chosen:
        return fit_run(run)
    fit = _EffectFit(run, chosen)
    fit.search_shapes()
    return fit.result(errors=errors)


_Chosen = tuple[Effect | None, type[Effect], bool]
"""An effect to fit: its instance (given, or its defaults; ``None`` without), its class, whether its shape is fixed."""


def _resolve_specs(effects: Sequence) -> list[_Chosen]:
    """The effects to fit, each once, never with its per-axis form."""
    chosen: list[_Chosen] = []
    names_seen: set[str] = set()
    given_as: dict[str, str] = {}  # each effect's name as given (thermal_lag[xz] for thermal_lag)
    for spec in effects:
        if isinstance(spec, Effect):
            cls, effect, fixed = resolve_effect(type(spec)), spec, True
        else:
            cls = resolve_effect(spec)
            effect, fixed = _template(cls), False
        if cls.name in names_seen:
            msg = f'effect {cls.name}: given twice'
            raise FitError(msg)
        twin = given_as.setdefault(held_of(cls).name, cls.name)
        if twin != cls.name:
            msg = f'effect {cls.name}: give either {twin} or {cls.name}, not both (the same effect on other axes)'
            raise FitError(msg)
        shared = getattr(cls, 'shared', None)
        related = [name for name in names_seen
                   if shared is not None and name == shared.name or name == f'{cls.name}_per_axis']
        if related:
            msg = f'effect {cls.name}: give either {related[0]} or {cls.name}, not both (one is the per-axis form)'
            raise FitError(msg)
        names_seen.add(cls.name)
        chosen.append((effect, cls, fixed))
    return chosen


class _EffectFit:
    """One fit of the paper's model plus effects, step by step (see :func:`fit_with_effects`).

    :param run: the prepared run (every sample: effects with memory run over the whole series;
        the least squares over its training rows).
    """

    def __init__(self, run: FitRun, chosen: list[_Chosen]) -> None:
        self.run, self.chosen = run, chosen
        self.mask = run.mask
        self.held_scales = [run.held_scale(i) for i in range(3)]
        self.input_effects = [effect or cls() for effect, cls, _ in chosen if cls.kind == INPUT]
        fixed = [run.design(i, self.held_scales[i], self.input_effects) for i in range(3)]
        self.fixed = [design.matrix for design in fixed]
        self.targets = [design.target for design in fixed]
        self.names = [design.terms for design in fixed]
        self.projection = _Projection(self.fixed, self.targets, self.names)
        self.offsets = [self._offset_entry(effect, cls, fixed_shape)
                        for effect, cls, fixed_shape in chosen if cls.kind != INPUT]

    # ----- the design ------------------------------------------------------------------------

    def _offset_entry(self, effect: Effect | None, cls: type[Effect], fixed_shape: bool) -> _Offset:
        """An offset effect: fixed, its shapes to search, or a structure to choose."""
        mask = self.mask
        time_train = self.run.train.stamp_s
        inputs_all = self.run.effect_input(effect if effect is not None else cls)
        if fixed_shape:
            entry = _Offset(effect=effect, mode='fixed')  # type: ignore[arg-type]
        else:
            structures = call_effect(cls, 'structures', cls.structures, time_train, inputs_all[mask])
            if structures is not None:
                if not structures:
                    msg = f'effect {cls.name}: the temperature codes of this run do not span a range'
                    raise FitError(msg)
                entry = _Offset(effect=structures[0], mode='structure', structures=structures,
                                searched=_searched(cls, structures[0], time_train, inputs_all[mask]))
            else:
                if effect is None:
                    msg = f'effect {cls.name}: its parameters have no defaults to start a search from'
                    raise FitError(msg)
                searched = _searched(cls, effect, time_train, inputs_all[mask])
                entry = _Offset(effect=effect, mode='search' if searched else 'fixed', searched=searched)
        entry.inputs = inputs_all
        if entry.mode == 'fixed':
            entry.basis = self.run.basis(entry.effect, inputs_all)
            entry.done = True
        return entry

    def _extra_and_norms(self, skip: _Offset | None = None, with_basis: np.ndarray | None = None,
                         with_effect: Effect | None = None) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Per axis the normalised columns of the done offset effects (then ``with_basis``) and their norms.

        Each effect contributes the basis signals its amplitudes on that axis use.
        """
        mask = self.mask
        parts = [(entry.basis, entry.effect) for entry in self.offsets if entry is not skip and entry.done]
        if with_basis is not None:
            parts.append((with_basis, with_effect))
        columns, norms = [], []
        for i in range(3):
            blocks = [phi[mask][:, list(effect.axis_columns()[i])] for phi, effect in parts]
            if not blocks:
                columns.append(np.zeros((int(mask.sum()), 0)))
                norms.append(np.zeros(0))
                continue
            normalised, norm = _normalised(np.column_stack(blocks))
            columns.append(normalised)
            norms.append(norm)
        return columns, norms

    def _visible(self, phi: np.ndarray) -> bool:
        mask = self.mask
        whole = np.max(np.abs(phi), axis=0)
        seen = np.max(np.abs(phi[mask]), axis=0) if mask.any() else np.zeros_like(whole)
        return bool(np.all(seen >= VISIBLE * whole))

    def _basis_of(self, entry: _Offset, effect: Effect, *, exact: bool = False) -> np.ndarray:
        key = (exact, tuple(sorted(effect.values.items())))
        if key not in entry.cache:
            entry.cache[key] = self.run.basis(effect, entry.inputs, search=not exact)
        return entry.cache[key]

    # ----- the shapes ------------------------------------------------------------------------

    def _profiled(self, entry: _Offset, candidate: Effect) -> float:
        """``sum_axes ln RSS`` with the candidate's basis, or INVALID when its amplitudes leave their bounds."""
        phi = self._basis_of(entry, candidate)
        if not self._visible(phi):
            return INVALID
        columns, norms = self._extra_and_norms(skip=entry, with_basis=phi, with_effect=candidate)
        rss, coefficients = self.projection.rss(columns)
        widths = [len(c) for c in candidate.axis_columns()]
        amplitudes = [c[-w:] / n[-w:] for c, n, w in zip(coefficients, norms, widths)]
        if not _amplitudes_within_bounds(candidate, amplitudes):
            return INVALID
        return float(np.sum(np.log(rss)))

    def search_shapes(self) -> None:
        """Search every offset effect's shape, twice over when there are several (each sees the others)."""
        pending = [entry for entry in self.offsets if entry.mode != 'fixed']
        for entry in pending:
            self._search(entry)
        if len(pending) > 1:
            for entry in pending:
                self._search(entry)

    def _search(self, entry: _Offset) -> None:
        if entry.mode == 'structure':
            self._choose_structure(entry)
            if not entry.searched:
                return
        scanned = call_effect(entry.effect, 'search_values', entry.effect.search_values, self.run.train.stamp_s,
                              entry.inputs[self.mask], self._residual_without(entry))
        for name, low_value, high_value, log in entry.searched:
            if name in scanned:
                self._scan_parameter(entry, name, np.asarray(scanned[name], dtype=float))
            else:
                self._search_parameter(entry, name, low_value, high_value, log)
        entry.basis = self._basis_of(entry, entry.effect, exact=True)
        entry.done = True

    def _choose_structure(self, entry: _Offset) -> None:
        """The structure (e.g. the knots of a shape) with the best blocked cross-validation score."""
        validation = _CrossValidation(self.fixed, self.targets)
        best = None
        for candidate in entry.structures:
            phi = self._basis_of(entry, candidate)
            if not self._visible(phi):
                continue
            columns, norms = self._extra_and_norms(skip=entry, with_basis=phi, with_effect=candidate)
            score, coefficients = validation.score(columns)
            widths = [len(c) for c in candidate.axis_columns()]
            if not _amplitudes_within_bounds(candidate, [c[-w:] / n[-w:] for c, n, w
                                                         in zip(coefficients, norms, widths)]):
                continue
            if best is None or score < best[0]:
                best = (score, candidate, phi)
        if best is None:
            msg = f'effect {entry.effect.name}: no candidate keeps its amplitudes within their bounds'
            raise FitError(msg)
        entry.effect, entry.basis = best[1], self._basis_of(entry, best[1], exact=True)
        entry.done = True

    def _search_parameter(self, entry: _Offset, name: str, low_value: float, high_value: float, log: bool) -> None:
        """One shape parameter: a coarse grid, then a bounded refinement around its best point."""
        to_value = (lambda s: math.exp(s)) if log else (lambda s: s)
        a, b = (math.log(low_value), math.log(high_value)) if log else (low_value, high_value)

        def objective(s: float) -> float:
            return self._profiled(entry, entry.effect.replace(**{name: to_value(s)}))

        grid = np.linspace(a, b, GRID_POINTS)
        values = [objective(s) for s in grid]
        j = int(np.argmin(values))
        if values[j] >= INVALID:
            msg = (f'effect {entry.effect.name}: no {name} in {low_value:g}..{high_value:g} keeps its '
                   f'amplitudes within their bounds on these samples')
            raise FitError(msg)
        best_s, best_value = float(grid[j]), values[j]
        lo, hi = float(grid[max(j - 1, 0)]), float(grid[min(j + 1, GRID_POINTS - 1)])
        result = minimize_scalar(objective, bounds=(lo, hi), method='bounded',
                                 options={'xatol': 1e-3 if log else 1e-3 * (b - a)})
        if result.fun < best_value:
            best_s = float(result.x)
        entry.effect = entry.effect.replace(**{name: to_value(best_s)})

    def _residual_without(self, entry: _Offset) -> np.ndarray:
        """``(k, 3)`` the training samples' residual of the model with every other done effect, without ``entry``."""
        columns, _ = self._extra_and_norms(skip=entry)
        out = np.empty((int(self.mask.sum()), 3))
        for i, (q, perpendicular, _) in enumerate(self.projection.bases):
            extra = columns[i]
            if extra.shape[1] == 0:
                out[:, i] = perpendicular
                continue
            remaining = extra - q @ (q.T @ extra)
            coefficients = np.linalg.lstsq(remaining, perpendicular, rcond=1e-12)[0]
            out[:, i] = perpendicular - remaining @ coefficients
        return out

    def _scan_parameter(self, entry: _Offset, name: str, values: np.ndarray) -> None:
        """One shape parameter over given values: every ``n / SCAN_POINTS``-th, then each one around the best."""
        if not len(values):
            msg = f'effect {entry.effect.name}: too few samples to place {name}'
            raise FitError(msg)

        def objective(index: int) -> float:
            return self._profiled(entry, entry.effect.replace(**{name: float(values[index])}))

        stride = max(1, math.ceil(len(values) / SCAN_POINTS))
        coarse = list(range(0, len(values), stride))
        scores = {index: objective(index) for index in coarse}
        best = min(scores, key=scores.__getitem__)
        for index in range(max(best - stride + 1, 0), min(best + stride, len(values))):
            if index not in scores:
                scores[index] = objective(index)
        best = min(scores, key=scores.__getitem__)
        if scores[best] >= INVALID:
            msg = f'effect {entry.effect.name}: no {name} keeps its amplitudes within their bounds on these samples'
            raise FitError(msg)
        entry.effect = entry.effect.replace(**{name: float(values[best])})

    # ----- the result ------------------------------------------------------------------------

    def result(self, *, errors: bool = True) -> FitResult:
        """The pipeline with every shape fixed.

        The final least squares over the training rows, the calibration and (``errors``) its errors.
        """
        offsets = self.offsets
        solved = solve_run(self.run, input_effects=self.input_effects,
                           offset_bases=[(entry.effect, entry.basis[self.mask]) for entry in offsets])
        by_name = {entry.effect.name: entry.effect for entry in offsets}
        by_name.update((effect.name, effect) for effect in self.input_effects)
        found, basis = (_standard_errors(self.run, offsets, solved.solutions, solved.columns, self.targets)
                        if errors else ({}, None))
        return model_run(self.run, solved, effects=[by_name[cls.name] for _, cls, _ in self.chosen],
                         shape_parameters=[self._shape_count(i) for i in range(3)], parameter_errors=found,
                         error_basis=basis)

    def _shape_count(self, axis: int) -> int:
        """Searched shape parameters that axis ``axis`` depends on (a per-axis form: its own only)."""
        count = 0
        for entry in self.offsets:
            own = [name for name, *_ in entry.searched]
            if getattr(entry.effect, 'shared', None) is not None:  # a per-axis form
                own = [name for name in own if name.endswith(f'_{AXIS_NAMES[axis]}')]
            count += len(own) + (1 if entry.mode == 'structure' else 0)
        return count


def _searched(cls: type[Effect], effect: Effect, time_s: np.ndarray,
              inputs: np.ndarray) -> tuple[tuple[str, float, float, bool], ...]:
    """The shape parameters the fit searches, with their ranges on these training samples."""
    space = call_effect(cls, 'search_space', cls.search_space, time_s, inputs)
    varies = effect.shape_varies()
    return tuple((name, *space[name]) for name in effect.shape_names()
                 if varies.get(name, True) and name in space
                 and all(math.isfinite(v) for v in space[name][:2]))


def _standard_errors(run: FitRun, offsets: list[_Offset], solutions: Sequence[Solution],
                     columns: Sequence[tuple[Column, ...]], targets: Sequence[np.ndarray]
                     ) -> tuple[dict[str, float], ErrorBasis]:
    """Standard errors of amplitudes and shape parameters together, from the residual's own correlation.

    The sandwich of :mod:`~tak_thermo_ros.core.fit.uncertainty`: the Fisher information of every
    axis's amplitudes and the shared shape parameters (shape derivatives numerically), and the
    covariance of each axis's noise from the model of its residual.

    :param solutions: per axis the final solve; ``columns``: per axis its column labels;
        ``targets``: per axis the target over the training rows.
    """
    mask = run.mask
    count = int(mask.sum())
    shape_parameters = []  # (entry index, name, log, value)
    for index, entry in enumerate(offsets):
        for name, _, _, log in entry.searched:
            shape_parameters.append((index, name, log, entry.effect[name]))
    blocks = [solution.width for solution in solutions]
    size = sum(blocks) + len(shape_parameters)
    # Derivatives of every axis's model with respect to each searched shape coordinate.
    derivatives = np.zeros((3, count, len(shape_parameters)))
    for column, (index, name, log, value) in enumerate(shape_parameters):
        entry = offsets[index]
        step = SHAPE_STEP if log else SHAPE_STEP * max(abs(value), 1.0)
        values = [(value * math.exp(h) if log else value + h) for h in (step, -step)]
        upper, lower = (run.basis(entry.effect.replace(**{name: v}), entry.inputs)[mask]
                        for v in values)
        slope = (upper - lower) / (2.0 * step)
        for i in range(3):
            used = list(entry.effect.axis_columns()[i])
            own = [k for k, label in enumerate(columns[i]) if label.effect == entry.effect.name]
            derivatives[i, :, column] = slope[:, used] @ solutions[i].coefficients[own]
    # The shape columns scaled like the amplitudes' (to unit norm over the axes): the Fisher
    # matrix's conditioning then does not depend on the sensor's unit (tesla or counts).
    shape_norms = np.sqrt(np.sum(derivatives ** 2, axis=(0, 1)))
    shape_norms = np.where(shape_norms > 0.0, shape_norms, 1.0)
    stamps = run.train.stamp_s
    sandwich = Sandwich(size, float(np.median(np.diff(stamps))) if len(stamps) > 1 else 1.0)
    offset = 0
    for i, (solution, target) in enumerate(zip(solutions, targets)):
        dof = max(count - solution.width - len(shape_parameters), 1)
        jacobian = np.column_stack([solution.scaled, derivatives[i] / shape_norms])
        residual = target - solution.scaled @ (solution.coefficients * solution.norms)
        rows = list(range(offset, offset + solution.width)) + list(range(sum(blocks), size))
        sandwich.add(jacobian, residual, solution.rss / dof, rows)
        offset += solution.width
    found = []
    for covariance in (sandwich.covariance(), sandwich.covariance(correlated_only=True)):
        deviation = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
        errors: dict[str, float] = {}
        offset = 0
        for solution, labels in zip(solutions, columns):
            errors.update(amplitude_errors(labels, deviation[offset:offset + solution.width] / solution.norms))
            offset += solution.width
        for column, (index, name, log, value) in enumerate(shape_parameters):
            sigma = float(deviation[sum(blocks) + column] / shape_norms[column])
            errors[f'{offsets[index].effect.name}.{name}'] = value * sigma if log else sigma
        found.append(errors)
    return found[0], replace(sandwich.basis(), correlated_errors=found[1])
