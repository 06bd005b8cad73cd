"""The paper's least squares: the correction link without effects, over a whole calibration run.

The fit's one way, with no effect: samples -> the paper's columns (:mod:`~.design`) -> one
solve (:mod:`~.solve`) -> a model (:mod:`~.model`). The model is linear in
``(K0, K0 a1..ap, dNs0, c1..cq)`` with ``c_k = D b_k``: per axis the design matrix has the
columns ``f n^j`` (j = 0..p) and ``n^j`` (j = 0..q), built in ``u = n / max|n|`` for
conditioning and converted back to raw code powers afterwards.
"""

from __future__ import annotations

from tak_thermo_ros.core.fit.design import (
    Frame,
    axis_design,
    check_observable,
    check_orders,
    held_scale,
    single_input_axes,
)
from tak_thermo_ros.core.fit.model import (
    FitResult,
    calibration_from,
    check_separated,
    finish_fit,
    held_notes,
    residual_counts,
)
from tak_thermo_ros.core.fit.solve import least_squares
from tak_thermo_ros.core.link.model import AXES
from tak_thermo_ros.core.records.record import AlignedSamples


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
    check_orders(bias_order, scale_order)
    check_observable(samples, bias_order, scale_order)
    frame = Frame.of_samples(samples, temp_code_ref)
    powers = frame.powers(samples.temp_code, max(bias_order, scale_order))
    first_input = [float(v) for v in samples.reference[0]]
    single = single_input_axes(samples)
    held: list[float | None] = []
    coefficients = []
    for i, name in enumerate(AXES):
        held.append(held_scale(i, single, nominal_scale, first_input))
        # One axis's design at a time: a 15-hour run at 100 Hz has 5.4 million rows.
        solution = least_squares(*axis_design(i, powers, samples.reference, samples.counts, bias_order=bias_order,
                                              scale_order=scale_order, held_scale=held[i]).system())
        check_separated(solution, name, bias_order, scale_order, held=held[i] is not None)
        coefficients.append(solution.coefficients)
        del solution
    calibration = calibration_from(frame, coefficients, bias_order=bias_order, scale_order=scale_order,
                                   held_scales=held, notes=held_notes(held, first_input))
    residual = residual_counts(calibration, samples)
    parameters = [len(beta) for beta in coefficients]
    return finish_fit(calibration, residual, parameters, dropped=samples.dropped)

