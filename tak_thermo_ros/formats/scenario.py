"""The simulator's scenario file: a YAML of :class:`~tak_thermo_ros.core.simulation.imu.Scenario`'s keys.

A powered board (a flight log: :class:`~tak_thermo_ros.core.simulation.powered.PoweredRun`) is its
``powered:`` section, the same keys as that class's (``ambient_knots`` a list of ``[t, celsius]``).
"""

from __future__ import annotations

from pathlib import Path

from tak_thermo_ros.core.simulation.imu import Scenario
from tak_thermo_ros.core.simulation.scenario import scenario_from_mapping
from tak_thermo_ros.errors import ScenarioError
from tak_thermo_ros.formats.files import read_yaml


def load_scenario(path: str | Path) -> Scenario:
    """Read a scenario YAML; a missing key keeps its default."""
    raw = read_yaml(path, 'scenario file', ScenarioError)
    try:
        return scenario_from_mapping(raw or {})
    except ScenarioError as err:
        msg = f'{path}: {err}'
        raise ScenarioError(msg) from None


def load_powered(path: str | Path | None):
    """The ``powered:`` section of a scenario YAML as a :class:`~tak_thermo_ros.core.simulation.powered.PoweredRun`.

    No file: the defaults (PX4's procedure). A missing key keeps its default
    (:func:`~tak_thermo_ros.core.simulation.powered.powered_from_mapping`, its words after the file's name).
    """
    from tak_thermo_ros.core.simulation.powered import PoweredRun, powered_from_mapping
    if path is None:
        return PoweredRun()
    raw = read_yaml(path, 'scenario file', ScenarioError) or {}
    try:
        return powered_from_mapping(raw.get('powered', {}) if isinstance(raw, dict) else None)
    except ScenarioError as err:
        msg = f'{path}: {err}'
        raise ScenarioError(msg) from None


def load_everyday(path: str | Path | None):
    """A scenario YAML with an ``everyday:`` section as ``(Scenario, Everyday)``, or ``None`` without one.

    The other keys override :data:`~tak_thermo_ros.core.simulation.everyday.EVERYDAY_SCENARIO`
    (:func:`~tak_thermo_ros.core.simulation.everyday.everyday_scenario`).
    """
    from tak_thermo_ros.core.simulation.everyday import everyday_scenario
    if path is None:
        return None
    raw = read_yaml(path, 'scenario file', ScenarioError) or {}
    if not isinstance(raw, dict) or 'everyday' not in raw:
        return None
    try:
        return everyday_scenario({key: value for key, value in raw.items() if key != 'fleet'})
    except ScenarioError as err:
        msg = f'{path}: {err}'
        raise ScenarioError(msg) from None


def load_fleet(path: str | Path | None):
    """A scenario YAML's ``fleet:`` section (units of one part, each with its everyday records), or ``None``.

    :raises ScenarioError: a ``fleet`` without ``everyday``, or a bad key (naming the file).
    """
    from tak_thermo_ros.core.simulation.fleet import fleet_from_mapping
    if path is None:
        return None
    raw = read_yaml(path, 'scenario file', ScenarioError) or {}
    if not isinstance(raw, dict) or 'fleet' not in raw:
        return None
    if 'everyday' not in raw:
        msg = f'{path}: fleet: needs an everyday: section (each unit lives through its everyday records)'
        raise ScenarioError(msg)
    try:
        return fleet_from_mapping(raw['fleet'] or {})
    except ScenarioError as err:
        msg = f'{path}: {err}'
        raise ScenarioError(msg) from None
