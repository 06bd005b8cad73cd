"""The maths: model, correction link, fit, simulator, validation. No rclpy, no rosbags."""

from tak_thermo_ros.core.calibration_file import (
    calibration_from_mapping,
    calibration_to_mapping,
    load_calibration,
    load_unit,
    save_calibration,
    save_unit,
    unit_from_mapping,
    unit_to_mapping,
)
from tak_thermo_ros.core.correction import Corrector, OutOfRange, UnitCorrector, acceleration_variance
from tak_thermo_ros.core.fit import FitResult, fit_calibration, fit_model, residual_counts
from tak_thermo_ros.core.model import AXES, SENSORS, AxisModel, Calibration, InputKind, UnitCalibration
from tak_thermo_ros.core.plus_minus import fit_plus_minus, plus_minus
from tak_thermo_ros.core.record import AlignedSamples, ChannelRecord, DriverRecord, align
from tak_thermo_ros.core.simulate import Scenario, SimulatedRun, load_scenario, simulate
from tak_thermo_ros.core.validate import GravityValidation, RateValidation, validate_gravity, validate_rate

__all__ = [
    'AXES',
    'AlignedSamples',
    'AxisModel',
    'Calibration',
    'ChannelRecord',
    'Corrector',
    'DriverRecord',
    'FitResult',
    'GravityValidation',
    'InputKind',
    'OutOfRange',
    'RateValidation',
    'SENSORS',
    'Scenario',
    'SimulatedRun',
    'UnitCalibration',
    'UnitCorrector',
    'acceleration_variance',
    'align',
    'calibration_from_mapping',
    'calibration_to_mapping',
    'fit_calibration',
    'fit_model',
    'fit_plus_minus',
    'load_calibration',
    'load_scenario',
    'load_unit',
    'plus_minus',
    'residual_counts',
    'save_calibration',
    'save_unit',
    'simulate',
    'unit_from_mapping',
    'unit_to_mapping',
    'validate_gravity',
    'validate_rate',
]
