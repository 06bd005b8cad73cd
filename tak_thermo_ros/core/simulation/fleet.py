"""A fleet of units of one part: each unit's curves drawn around the part's, each with its everyday records.

A production run's boards share their part's temperature curves to a degree: each unit's offset,
slope, curvature and cubic term of every axis is the part's plus a draw of the fleet's spread
(``Fleet.gyro`` / ``Fleet.accel``: one standard deviation per power of ``T - T_ref``, the same on
every axis), and each unit lives through its own everyday records
(:mod:`~tak_thermo_ros.core.simulation.everyday`): the same habits, its own days and ambients.
``groups`` splits the units into groups whose slopes differ by ``group_slope`` (times the
gyroscope's slope spread, alternately up and down: Reginya et al. 2018's clusters of slopes);
``other_part`` names units of another part (their slopes ``other_part_slope`` times the spread off).

Every unit is drawn from its own streams (the fleet's seed and its index), so a unit is the same
whatever the fleet's size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from tak_thermo_ros.core.simulation.everyday import Everyday, everyday_truth, section_from_mapping
from tak_thermo_ros.core.simulation.imu import AxisTruth, Scenario
from tak_thermo_ros.core.link.model import UnitCalibration
from tak_thermo_ros.core.simulation.mapping import first_failed
from tak_thermo_ros.errors import ScenarioError


@dataclass(frozen=True)
class Fleet:
    """How the units of a fleet differ (scenario key ``fleet``, every key optional).

    :param units: how many units.
    :param gyro: the units' spread of each gyroscope axis's offset polynomial, per power of ``T - T_ref``:
        rad/s, rad/s/C, rad/s/C^2, rad/s/C^3 (default: 100 deg/h of offset, a fifth of the part's slope,
        a tenth of its curvature and cubic term: units of one part differ most in their slopes).
    :param accel: the accelerometer's, m/s^2 per power of C (2 mg of offset; a fifth of the part's slope at
        1 g, a tenth of its curvature and cubic term).
    :param groups: the units fall in this many groups of slopes (1: one).
    :param group_slope: the groups' slopes lie this many gyroscope slope spreads apart.
    :param other_part: units (numbers from 0) of another part.
    :param other_part_slope: their slopes lie this many spreads off the part's.
    """

    units: int = 8
    gyro: tuple[float, float, float, float] = (5.0e-4, 6.5e-5, 2.0e-7, 3.0e-9)
    accel: tuple[float, float, float, float] = (0.02, 4.0e-4, 1.8e-6, 2.4e-8)
    groups: int = 1
    group_slope: float = 6.0
    other_part: tuple[int, ...] = ()
    other_part_slope: float = 20.0

    def __post_init__(self) -> None:
        def spreads(values: tuple[float, ...]) -> bool:
            return len(values) == 4 and all(math.isfinite(v) and v >= 0.0 for v in values)

        checks = (
            (isinstance(self.units, int) and not isinstance(self.units, bool) and self.units >= 1,
             'units', 'must be a whole number >= 1'),
            (spreads(self.gyro), 'gyro', 'expected four finite numbers >= 0 (offset, slope, curvature, cubic)'),
            (spreads(self.accel), 'accel', 'expected four finite numbers >= 0 (offset, slope, curvature, cubic)'),
            (isinstance(self.groups, int) and not isinstance(self.groups, bool) and 1 <= self.groups <= self.units,
             'groups', 'must be a whole number within 1..units'),
            (math.isfinite(self.group_slope) and math.isfinite(self.other_part_slope), 'group_slope',
             'must be finite'),
            (all(isinstance(i, int) and 0 <= i < self.units for i in self.other_part), 'other_part',
             'expected unit numbers within 0..units-1'),
        )
        first_failed(checks, 'fleet')


def fleet_from_mapping(raw: Any) -> Fleet:
    """A :class:`Fleet` from a scenario's ``fleet`` mapping.

    :raises ScenarioError: naming the key.
    """
    return section_from_mapping(Fleet, raw, 'fleet', whole_lists=('other_part',))


def unit_seed(seed: int, index: int) -> int:
    """The scenario seed of unit ``index`` of a fleet drawn with ``seed`` (its own streams)."""
    words = np.random.SeedSequence([int(seed), int(index), 40]).generate_state(2, dtype=np.uint32)
    return int((int(words[0]) << 31) ^ int(words[1])) & ((1 << 63) - 1)


def _drawn(axes: tuple[AxisTruth, ...], spread: tuple[float, ...], rng: np.random.Generator,
           slope_shift: float) -> tuple[AxisTruth, ...]:
    out = []
    for axis in axes:
        draw = rng.standard_normal(4) * np.asarray(spread)
        coeffs = list(axis.offset_coeffs) + [0.0] * max(0, 3 - len(axis.offset_coeffs))
        coeffs = [c + d for c, d in zip(coeffs, draw[1:])] + coeffs[3:]
        coeffs[0] += slope_shift * spread[1]
        out.append(replace(axis, offset=axis.offset + float(draw[0]), offset_coeffs=tuple(float(c) for c in coeffs)))
    return tuple(out)


def fleet_unit(scenario: Scenario, fleet: Fleet, index: int) -> Scenario:
    """Unit ``index`` of the fleet: the part's scenario with its own curves and its own seed."""
    if not 0 <= index < fleet.units:
        msg = f'fleet: unit {index} of {fleet.units} (0 .. {fleet.units - 1})'
        raise ScenarioError(msg)
    seed = unit_seed(scenario.seed, index)
    rng = np.random.default_rng([seed, 9])
    shift = 0.0
    if fleet.groups > 1:
        group = index % fleet.groups
        shift = fleet.group_slope * (group - 0.5 * (fleet.groups - 1))
    if index in fleet.other_part:
        shift += fleet.other_part_slope
    return replace(scenario, seed=seed,
                   gyro_unit=_drawn(scenario.gyro_unit, fleet.gyro, rng, shift),  # type: ignore[arg-type]
                   accel_unit=_drawn(scenario.accel_unit, fleet.accel, rng, 0.0))  # type: ignore[arg-type]


def unit_truth(scenario: Scenario, fleet: Fleet, habits: Everyday, index: int) -> UnitCalibration:
    """Unit ``index``'s true links over the temperatures its records can reach."""
    return everyday_truth(fleet_unit(scenario, fleet, index), habits)
