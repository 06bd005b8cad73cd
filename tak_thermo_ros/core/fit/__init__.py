"""The fit of the correction link: the one entry, :func:`fit_model`.

Two rooms, one direction: :mod:`tak_thermo_ros.core.fit.base` solves the paper's model by least
squares (linear in ``(K0, K0 a1..ap, dNs0, c1..cq)``); :mod:`tak_thermo_ros.core.fit.effects`
adds the effects on top of it (variable projection). This module calls the second, which calls
the first; neither imports this one. The base fit's names are importable from here too.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from tak_thermo_ros.core.fit.base import (  # noqa: F401 (the base fit's names, importable from the entry)
    INPUT_RESOLUTION,
    MIN_SAMPLES_PER_PARAMETER,
    AxisFit,
    FitResult,
    finish_fit,
    finish_fit_from_sums,
    fit_calibration,
    held_scale_note,
    residual_counts,
    single_input_axes,
)
from tak_thermo_ros.core.effects.base import Effect
from tak_thermo_ros.core.fit.effects import fit_with_effects
from tak_thermo_ros.core.records.record import AlignedSamples


def fit_model(samples: AlignedSamples, *, effects: Sequence[str | type[Effect] | Effect] = (),
              bias_order: int = 3, scale_order: int = 2, temp_code_ref: float | None = None,
              nominal_scale: tuple[float, float, float] | None = None,
              train_mask: np.ndarray | None = None) -> FitResult:
    """Fit the paper's model plus effects (``tak_thermo_ros.core.effects``).

    Amplitudes (linear) are solved by least squares together with the base model; shape
    parameters (time constants, widths) are searched by a bounded 1-D search of the profiled
    residual (variable projection); a discrete complexity (number of knots) is chosen by
    blocked cross-validation inside the training samples. An effect given as an *instance*
    keeps its shape parameters; only its amplitudes are refitted.

    :param effects: library names, ``'module:Class'`` specs, classes or instances.
    :param train_mask: ``(k,)`` booleans: the least squares uses only these samples; effects
        with memory still run over the whole series in time order (blocked cross-validation).
    :raises FitError: when the data cannot determine the model or an effect (naming it).
    """
    return fit_with_effects(samples, effects=effects, bias_order=bias_order, scale_order=scale_order,
                            temp_code_ref=temp_code_ref, nominal_scale=nominal_scale, train_mask=train_mask)
