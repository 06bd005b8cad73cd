"""The fit's pipeline: a run's columns -> one solve per axis -> the model.

Every in-memory fit ends here, the paper's model alone (:func:`fit_calibration`) and the
effects' final solve with their shapes fixed (:mod:`~tak_thermo_ros.core.fit.effects`):
:meth:`FitRun.design <tak_thermo_ros.core.fit.design.FitRun.design>` gives the columns (the
paper's ``f u^j`` and ``u^j``, then each effect's), :func:`solve_run` solves each axis
(:func:`~tak_thermo_ros.core.fit.solve.least_squares`), :func:`model_run` turns the solutions
into the calibration and its statistics (:mod:`~tak_thermo_ros.core.fit.model`). The model is
linear in ``(K0, K0 a1..ap, dNs0, c1..cq)`` with ``c_k = D b_k``; the columns are built in
``u = n / max|n|`` for conditioning and converted back to raw code powers afterwards.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.effects.base import Effect
from tak_thermo_ros.core.fit.design import Column, FitRun, not_excited
from tak_thermo_ros.core.fit.model import (
    FitResult,
    calibration_from,
    finish_fit,
    fitted_effects,
    held_notes,
    residual_counts,
)
from tak_thermo_ros.core.fit.solve import Solution, least_squares
from tak_thermo_ros.core.fit.uncertainty import ErrorBasis
from tak_thermo_ros.core.link.model import AXES
from tak_thermo_ros.core.records.record import AlignedSamples
from tak_thermo_ros.errors import FitError


@dataclass(frozen=True)
class Solved:
    """The solve of the three axes: per axis the solution, its columns' labels, the held scale."""

    solutions: tuple[Solution, ...]
    columns: tuple[tuple[Column, ...], ...]
    held_scales: tuple[float | None, ...]


def fit_calibration(samples: AlignedSamples, *, bias_order: int = 3, scale_order: int = 2,
                    temp_code_ref: float | None = None,
                    nominal_scale: tuple[float, float, float] | None = None) -> FitResult:
    """Fit the paper's model to aligned calibration samples.

    :param samples: counts with held temperature code and reference.
    :param bias_order: ``q``, order of ``F_s`` (>= 1).
    :param scale_order: ``p``, order of ``F_c`` (>= 0; 0 fits no scale change).
    :param temp_code_ref: ``N_t,ref``; default the middle of the calibrated range, rounded.
    :param nominal_scale: ``K0`` per axis, counts per m/s^2. Used, and required, only for an
        axis that sees a single input: there scale and offset cannot be told apart, so the
        scale is held at nominal (``F_c = 1``), the offset shape is fitted, and the axis is
        marked ``scale_observable = False``.
    :raises FitError: when the data cannot determine the model.
    """
    run = FitRun.prepare(samples, bias_order=bias_order, scale_order=scale_order, temp_code_ref=temp_code_ref,
                         nominal_scale=nominal_scale)
    return fit_run(run)


def fit_run(run: FitRun) -> FitResult:
    """The paper's model over a prepared run: :func:`solve_run`, then :func:`model_run`."""
    solved = solve_run(run)
    return model_run(run, solved)


def solve_run(run: FitRun, *, input_effects: Sequence[Effect] = (),
              offset_bases: Sequence[tuple[Effect, np.ndarray]] = ()) -> Solved:
    """One least squares per axis over the training rows: the paper's columns, then each effect's.

    :param offset_bases: ``(effect, basis)`` of each offset effect over the training rows.
    :raises FitError: a held axis without a nominal scale, or columns the data cannot separate
        (the paper's model alone: which orders; with effects: the first such column).
    """
    solutions, columns, held_scales = [], [], []
    for i, name in enumerate(AXES):
        held = run.held_scale(i)
        design = run.design(i, held, input_effects, offset_bases)
        with_effects = any(column.effect for column in design.columns)
        # The effects' errors need the raw columns (an axis where every effect is held too: it shares
        # their shape parameters); the paper's model alone may have millions of rows.
        keep = bool(offset_bases or input_effects)
        solution = least_squares(*design.system(), in_place=not keep)
        if not with_effects:
            check_separated(solution, name, run.bias_order, run.scale_order, held=held is not None)
        elif not solution.full_rank():
            raise not_excited(i, solution.first_dependent(design.terms))
        solutions.append(solution if keep else solution.without_design())
        columns.append(design.columns)
        held_scales.append(held)
    return Solved(tuple(solutions), tuple(columns), tuple(held_scales))


def model_run(run: FitRun, solved: Solved, *, effects: Sequence[Effect] = (),
              shape_parameters: Sequence[int] = (0, 0, 0),
              parameter_errors: dict[str, float] | None = None, error_basis: ErrorBasis | None = None) -> FitResult:
    """The calibration of the solved axes, its residual through the correction path, its statistics.

    :param effects: the effects in the calibration's order, shapes as solved (amplitudes are read
        from the solution).
    :param shape_parameters: per axis the searched shape parameters it depends on.
    """
    held = solved.held_scales
    betas = [solution.coefficients for solution in solved.solutions]
    fitted = fitted_effects(effects, solved.columns, betas)
    calibration = calibration_from(run.frame, betas, bias_order=run.bias_order, scale_order=run.scale_order,
                                   held_scales=held, notes=held_notes(held, run.first_input), effects=fitted)
    # Effects with memory run over the whole series from their initial state.
    residual = (residual_counts(calibration, run.samples)[run.mask] if fitted
                else residual_counts(calibration, run.train))
    parameters = [solution.width + shapes for solution, shapes in zip(solved.solutions, shape_parameters)]
    return finish_fit(calibration, residual, parameters, dropped=run.samples.dropped, parameter_errors=parameter_errors,
                      error_basis=error_basis)


def check_separated(solution: Solution, name: str, bias_order: int, scale_order: int, *, held: bool) -> None:
    """The paper's model determined on one axis (else a :class:`FitError` saying which orders fail)."""
    if held:
        if not solution.full_rank():
            msg = f'axis {name}: the temperature codes do not cover bias order {bias_order}'
            raise FitError(msg)
        return
    if not solution.separated():
        msg = (f'axis {name}: the data cannot separate the model terms '
               f'(rank {solution.rank} of {solution.width}); the inputs and temperatures do not '
               f'cover bias order {bias_order} and scale order {scale_order}')
        raise FitError(msg)
