"""The simulator's scenario file: a YAML of :class:`~tak_thermo_ros.core.simulation.imu.Scenario`'s keys."""

from __future__ import annotations

from pathlib import Path

from tak_thermo_ros.core.simulation.imu import Scenario, scenario_from_mapping
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
