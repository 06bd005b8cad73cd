"""The maths: model, correction link, fit, simulator, validation. No rclpy, no rosbags."""

from tak_thermo_ros.core.calibration_file import (
    calibration_from_mapping,
    calibration_to_mapping,
    load_calibration,
    save_calibration,
)
from tak_thermo_ros.core.correction import Corrector, OutOfRange, acceleration_variance
from tak_thermo_ros.core.fit import FitResult, fit_calibration, fit_model, residual_counts
from tak_thermo_ros.core.model import AXES, AxisModel, Calibration
from tak_thermo_ros.core.plus_minus import fit_plus_minus, plus_minus
from tak_thermo_ros.core.record import AlignedSamples, ChannelRecord, align
from tak_thermo_ros.core.simulate import Scenario, SimulatedRun, load_scenario, simulate
from tak_thermo_ros.core.validate import GravityValidation, validate_gravity

__all__ = [
    'AXES',
    'AlignedSamples',
    'AxisModel',
    'Calibration',
    'ChannelRecord',
    'Corrector',
    'FitResult',
    'GravityValidation',
    'OutOfRange',
    'Scenario',
    'SimulatedRun',
    'acceleration_variance',
    'align',
    'calibration_from_mapping',
    'calibration_to_mapping',
    'fit_calibration',
    'fit_model',
    'fit_plus_minus',
    'load_calibration',
    'load_scenario',
    'plus_minus',
    'residual_counts',
    'save_calibration',
    'simulate',
    'validate_gravity',
]
