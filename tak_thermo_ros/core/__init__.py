"""The maths, grouped by what it does; imports neither rclpy nor rosbags.

- :mod:`~tak_thermo_ros.core.link`: the correction link per sensor (model, correction, the node's logic);
- :mod:`~tak_thermo_ros.core.fit`: samples -> each effect's columns -> one solve -> a model;
- :mod:`~tak_thermo_ros.core.effects`: one class per physical effect;
- :mod:`~tak_thermo_ros.core.diagnose`: residual views, cross-validation, verdicts, run design;
- :mod:`~tak_thermo_ros.core.simulation`: simulated runs;
- :mod:`~tak_thermo_ros.core.records`: streams as arrays, their alignment, static runs.

Files (bags, CSV, the calibration file, Kalibr) are read and written by :mod:`tak_thermo_ros.formats`.

The names below are importable from here, but nothing is imported until one is asked for
(PEP 562), so that the node, which needs only the link, does not load the fit's libraries.
"""

from __future__ import annotations

import importlib
from typing import Any

_HOMES = {
    'tak_thermo_ros.core.link.correction': ('Corrector', 'OutOfRange', 'UnitCorrector', 'acceleration_variance'),
    'tak_thermo_ros.core.fit': ('FitResult', 'fit_calibration', 'fit_model', 'residual_counts'),
    'tak_thermo_ros.core.link.model': ('AXES', 'SENSORS', 'AxisModel', 'Calibration', 'InputKind', 'UnitCalibration'),
    'tak_thermo_ros.core.fit.plus_minus': ('fit_plus_minus', 'plus_minus'),
    'tak_thermo_ros.core.records.record': ('AlignedSamples', 'ChannelRecord', 'DriverRecord', 'align'),
    'tak_thermo_ros.core.simulation': ('Scenario', 'SimulatedRun', 'simulate'),
    'tak_thermo_ros.core.link.validate': ('GravityValidation', 'RateValidation', 'validate_gravity', 'validate_rate'),
}
_MODULE_OF = {name: module for module, names in _HOMES.items() for name in names}

__all__ = sorted(_MODULE_OF)


def __getattr__(name: str) -> Any:
    """Import a re-exported name from its home module on first use."""
    module = _MODULE_OF.get(name)
    if module is None:
        msg = f'module {__name__!r} has no attribute {name!r}'
        raise AttributeError(msg)
    return getattr(importlib.import_module(module), name)
