"""The fit of the correction link: the one entry, :func:`fit_model`.

The fit's data flows one way: samples -> each term's columns (:mod:`~.design`: the paper's
polynomials, then each effect's columns) -> one solve (:mod:`~.solve`: least squares in
memory, or from a triangular factor accumulated over blocks) -> a model (:mod:`~.model`: the
calibration, its residual through the one correction path, its statistics and errors).
:mod:`~.base` runs that pipeline for the paper's model; :mod:`~.effects` searches the effects'
shapes on top of it and ends with the same pipeline (variable projection); :mod:`~.stream`
runs it over a run that arrives in blocks. The names users need are importable from here.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from tak_thermo_ros.core.effects.base import Effect
from tak_thermo_ros.core.fit.base import fit_calibration
from tak_thermo_ros.core.fit.design import INPUT_RESOLUTION, MIN_SAMPLES_PER_PARAMETER, ShortRecord, single_input_axes
from tak_thermo_ros.core.fit.effects import fit_with_effects
from tak_thermo_ros.core.fit.model import (
    AxisFit,
    FitResult,
    finish_fit,
    finish_fit_from_sums,
    held_scale_note,
    residual_counts,
)
from tak_thermo_ros.core.records.record import AlignedSamples

__all__ = ['INPUT_RESOLUTION', 'MIN_SAMPLES_PER_PARAMETER', 'AxisFit', 'FitResult', 'ShortRecord', 'finish_fit',
           'finish_fit_from_sums', 'fit_calibration', 'fit_model', 'fit_with_effects', 'held_scale_note',
           'residual_counts', 'single_input_axes']


def fit_model(samples: AlignedSamples, *, effects: Sequence[str | type[Effect] | Effect] = (),
              bias_order: int = 3, scale_order: int = 2, temp_code_ref: float | None = None,
              nominal_scale: tuple[float, float, float] | None = None,
              train_mask: np.ndarray | None = None, errors: bool = True) -> FitResult:
    """Fit the paper's model plus effects (``tak_thermo_ros.core.effects``).

    Amplitudes (linear) are solved by least squares together with the base model; shape
    parameters (time constants, widths) are searched by a bounded 1-D search of the profiled
    residual (variable projection); a discrete complexity (number of knots) is chosen by
    blocked cross-validation inside the training samples. An effect given as an *instance*
    keeps its shape parameters; only its amplitudes are refitted.

    :param effects: library names, ``'module:Class'`` specs, classes or instances.
    :param train_mask: ``(k,)`` booleans: the least squares uses only these samples; effects
        with memory still run over the whole series in time order (blocked cross-validation).
    :param errors: compute the effects' standard errors (``False``: a cross-validation's fits,
        which use none of them, skip their cost).
    :raises FitError: when the data cannot determine the model or an effect (naming it).
    """
    return fit_with_effects(samples, effects=effects, bias_order=bias_order, scale_order=scale_order,
                            temp_code_ref=temp_code_ref, nominal_scale=nominal_scale, train_mask=train_mask,
                            errors=errors)
