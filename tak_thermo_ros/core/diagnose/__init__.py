"""Model discovery: where the fitted model fails, and which physical effect it is missing.

Pure maths on aligned samples and a calibration; no plotting (see ``tak_thermo_ros.reports.diagnose``).

The steps of :func:`diagnose`:

1. **Noise floor** per axis, from the data itself: the RMS of successive differences of the
   residual divided by sqrt(2) (the Allan deviation at the shortest interval). Slow structure
   cancels in a difference, white noise does not; the code rounding (uniform, 1/12 count^2)
   is in the residual and therefore in the floor. Differences across a turntable move or a
   gap in the samples are left out, as are isolated jumps (more than 8 robust sigmas).
2. **Residual views**: the residual against time, the temperature code ``N_t``, its rate
   ``dN_t/dt``, the own input and the other axes' inputs, heating versus cooling and per
   temperature plateau; for each, the fraction of the residual variance that a binned mean
   of that quantity explains (the correlation ratio, eta^2).
3. **Blocked cross-validation** of the current model and of the current model plus each
   library effect it does not hold yet: the run is cut into contiguous time blocks, dealt
   round-robin into folds (so every fold holds early and late, hot and cold blocks; the first
   block is cut into one piece per fold, so every fold holds the first minutes too); each
   model is fitted on the other folds and scored on the held-out one, with stateful effects
   run over the whole series. An effect that merely overfits scores worse, not better.
4. **Model ladder and verdict**: ``'none'`` when the held-out residual of the current model
   is at the noise floor, or no further above it than the same model on a simulated copy of
   the run in which that model is true (:func:`null_heldout`: the cost of parameters
   estimated without the held-out block). Otherwise the best effect joins the ladder when it
   removes at least :data:`MIN_STEP_FRACTION` of the held-out excess variance over the floor,
   by far more than noise could (:data:`SIGNIFICANCE_SIGMAS`), and the ladder climbs (current
   model + effect + next effect ...) while structure remains. The verdict is the ladder's first effect when the
   ladder removes at least :data:`MIN_TOTAL_FRACTION` of the excess and the run resolves its
   shape (a fitted time constant or width not at the edge of the range searched on this run,
   see :func:`unresolved_shapes`); ``'unexplained'`` otherwise, with what the residual still
   follows. When the ladder stops, each effect it added is removed in turn and dropped when
   the held-out blocks do not notice (an early effect that stood in for two later ones); the
   verdict is then the remaining effect that scored best alone. A shared effect that joins the
   ladder is also tried in its per-axis form (``thermal_lag_per_axis``), which takes its place
   only when held-out blocks prefer it by more than noise could and, while structure remains
   after it, by more than the gain's own spread from block to block (:data:`PER_AXIS_ALPHA`).

All residuals and RMS values are in counts.

The package is split by responsibility: :mod:`.values` (the returned values),
:mod:`.views` (noise floor, residual views, drivers, plateaus), :mod:`.crossval` (folds,
blocked cross-validation, scores), :mod:`.verdict` (the rule and the messages) and
:mod:`.discover` (the steps put together) and :mod:`.design` (the chamber run that would
separate the top two candidates).
"""

from tak_thermo_ros.core.diagnose.crossval import (
    EDGE_FRACTION,
    cross_validate,
    decimate,
    fold_labels,
    unresolved_shapes,
)
from tak_thermo_ros.core.diagnose.design import (
    DriverRunDesign,
    RunDesign,
    SensorDesign,
    design_driver_run,
    design_files,
    driver_design_files,
    design_run,
    recorded_signal_note,
)
from tak_thermo_ros.core.diagnose.crossval import null_heldout
from tak_thermo_ros.core.diagnose.discover import diagnose
from tak_thermo_ros.core.diagnose.values import (
    AxisSummary,
    Candidate,
    Diagnosis,
    Driver,
    LadderStep,
    ModelScore,
    Plateau,
    Views,
)
from tak_thermo_ros.core.diagnose.verdict import (
    MIN_STEP_FRACTION,
    MIN_TOTAL_FRACTION,
    MIN_VARIANCE_EXCESS,
    PER_AXIS_ALPHA,
    SIGNIFICANCE_SIGMAS,
    VERDICT_NONE,
    VERDICT_UNEXPLAINED,
)
from tak_thermo_ros.core.diagnose.views import (
    EFFECT_VIEWS,
    JUMP_SIGMAS,
    RATE_WINDOW_S,
    VIEW_BINS,
    binned_means,
    build_views,
    explained_fraction,
    noise_floor,
    residual_drivers,
    segment_breaks,
    temperature_rate,
)

__all__ = [
    'EDGE_FRACTION',
    'EFFECT_VIEWS',
    'JUMP_SIGMAS',
    'MIN_STEP_FRACTION',
    'MIN_TOTAL_FRACTION',
    'MIN_VARIANCE_EXCESS',
    'PER_AXIS_ALPHA',
    'RATE_WINDOW_S',
    'SIGNIFICANCE_SIGMAS',
    'VERDICT_NONE',
    'VERDICT_UNEXPLAINED',
    'VIEW_BINS',
    'AxisSummary',
    'Candidate',
    'Diagnosis',
    'Driver',
    'DriverRunDesign',
    'LadderStep',
    'ModelScore',
    'Plateau',
    'RunDesign',
    'SensorDesign',
    'Views',
    'binned_means',
    'build_views',
    'cross_validate',
    'decimate',
    'design_driver_run',
    'design_files',
    'driver_design_files',
    'design_run',
    'diagnose',
    'explained_fraction',
    'fold_labels',
    'noise_floor',
    'recorded_signal_note',
    'null_heldout',
    'residual_drivers',
    'segment_breaks',
    'temperature_rate',
    'unresolved_shapes',
]
