"""What the package needs: a lean node, every third-party import declared, the optional ones named."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import pytest

from paths import REPO
from tak_thermo_ros.errors import DependencyError
from tak_thermo_ros.optional import OPTIONAL, require

OFFLINE = ('scipy', 'matplotlib', 'dask', 'distributed', 'rosbags', 'pandas', 'statsmodels', 'allantools')
ROS_MESSAGES = ('rclpy', 'rclpy.node', 'rclpy.executors', 'rclpy.experimental', 'rcl_interfaces.msg',
                'sensor_msgs.msg', 'geometry_msgs.msg', 'diagnostic_msgs.msg')
ROSDEP_KEYS = {
    'numpy': 'python3-numpy', 'yaml': 'python3-yaml', 'scipy': 'python3-scipy',
    'matplotlib': 'python3-matplotlib', 'rosbags': 'python3-rosbags-pip', 'pandas': 'python3-pandas',
    'tqdm': 'python3-tqdm', 'rich': 'python3-rich', 'pytest': 'python3-pytest',
    'hypothesis': 'python3-hypothesis',
}
"""Module -> rosdep key (ros/rosdistro rosdep/python.yaml) of the Python libraries; a ROS package's
module is its own key (rclpy, sensor_msgs, launch_ros, ament_flake8, ...)."""


def _loaded_after(statement: str) -> dict[str, list[str]]:
    """Top-level modules and tak_thermo_ros modules in ``sys.modules`` after ``statement``, fresh."""
    code = (f'import sys, json; {statement}; '
            'print(json.dumps({"top": sorted({m.split(".")[0] for m in sys.modules}), '
            '"own": sorted(m for m in sys.modules if m.startswith("tak_thermo_ros"))}))')
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def test_the_node_imports_no_offline_library():
    """`import tak_thermo_ros.ros.node` in a fresh interpreter: ROS, numpy, yaml and the correction only.

    Beyond what rclpy and the message packages load themselves, the node adds numpy, yaml and
    its own modules, of which none is a fit, diagnosis, bag, simulation or report module. The CDR
    codec (formats/cdr/, numpy and struct only) is the node's raw path: it may come, rosbags not.
    """
    node = _loaded_after('import tak_thermo_ros.ros.node')
    ros = _loaded_after('import ' + ', '.join(ROS_MESSAGES))
    assert not [name for name in OFFLINE if name in node['top']]
    added = set(node['top']) - set(ros['top']) - set(sys.stdlib_module_names)
    assert {name for name in added if not name.startswith('_')} <= {'numpy', 'yaml', 'tak_thermo_ros'}
    offline_modules = ('tak_thermo_ros.core.fit', 'tak_thermo_ros.core.diagnose', 'tak_thermo_ros.core.simulation',
                       'tak_thermo_ros.formats.bag', 'tak_thermo_ros.passes',
                       'tak_thermo_ros.cli', 'tak_thermo_ros.reports.diagnose', 'tak_thermo_ros.passes.fleet')
    assert not [m for m in node['own'] if m.startswith(offline_modules)], node['own']


def _package_xml() -> dict[str, set[str]]:
    root = ElementTree.parse(REPO / 'package.xml').getroot()
    kinds: dict[str, set[str]] = {}
    for element in root:
        if element.tag.endswith('depend'):
            kinds.setdefault(element.tag, set()).add(element.text.strip())
    return kinds


def _third_party_imports(directory: Path) -> dict[str, set[str]]:
    """Top-level module -> files importing it, for modules neither stdlib nor the repository's own.

    The repository's own: any module of the package, the tests, the benchmarks, the demo or the
    launch files (a benchmark may import a test's helpers), and the tests' packages (test/core/, ...).
    """
    local = {path.stem for folder in ('tak_thermo_ros', 'test', 'bench', 'demo', 'launch')
             for path in (REPO / folder).rglob('*.py')} | {'tak_thermo_ros'}
    local |= {path.parent.name for path in (REPO / 'test').rglob('__init__.py')}
    found: dict[str, set[str]] = {}
    for path in directory.rglob('*.py'):
        tree = ast.parse(path.read_text(encoding='utf-8'))
        written = {Path(node.value).stem for node in ast.walk(tree)  # modules a test writes and imports
                   if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value.endswith('.py')}
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.split('.')[0]
                if top not in sys.stdlib_module_names and top not in local and top not in written:
                    found.setdefault(top, set()).add(str(path.relative_to(REPO)))
    return found


def test_every_third_party_import_is_declared_in_package_xml_or_optional():
    """The package's (and launch file's) imports are exec_depends; tests' are test_ or exec_depends.

    dask, distributed, statsmodels and allantools have no rosdep key: optional, named in
    tak_thermo_ros.optional (and docs/manual.md). A recorded signal's message package is imported by
    name at run time: those packages are exec_depends too.
    """
    declared = _package_xml()
    exec_keys, test_keys = declared['exec_depend'], declared['test_depend']
    problems = []
    for directories, allowed in (((REPO / 'tak_thermo_ros', REPO / 'launch'), exec_keys),
                                 ((REPO / 'test', REPO / 'bench', REPO / 'demo'), exec_keys | test_keys)):
        for directory in directories:
            for module, files in sorted(_third_party_imports(directory).items()):
                key = ROSDEP_KEYS.get(module, module)
                if key not in allowed and module not in OPTIONAL:
                    problems.append(f'{module} (rosdep key {key}) imported by {sorted(files)[0]}')
    assert not problems, problems
    from tak_thermo_ros.core.effects.aux_signal import AUX_FIELDS
    assert {name.split('/')[0] for name in AUX_FIELDS} <= exec_keys
    # and nothing declared that nothing uses
    used = {ROSDEP_KEYS.get(m, m) for d in ('tak_thermo_ros', 'launch') for m in _third_party_imports(REPO / d)}
    assert exec_keys - used <= {'std_msgs'}  # std_msgs: the run-time import above


def test_optional_libraries_are_imported_inside_the_commands_only():
    """No module of the package imports an optional library at its top: only functions do."""
    top_level = []
    for path in (REPO / 'tak_thermo_ros').rglob('*.py'):
        tree = ast.parse(path.read_text(encoding='utf-8'))
        for node in tree.body:
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            else:
                continue
            top_level += [f'{path.relative_to(REPO)}: {name}' for name in names if name.split('.')[0] in OPTIONAL]
    assert not top_level, top_level


def test_package_xml_and_setup_py_say_what_the_package_is():
    """Both sensors, both inputs, the tool and model discovery: in package.xml and setup.py alike."""
    description = ' '.join(ElementTree.parse(REPO / 'package.xml').getroot().findtext('description').split())
    setup = (REPO / 'setup.py').read_text(encoding='utf-8')
    for words in (('accelerometer', 'gyroscope'), ('Imu', 'codes'), ('tak_calib', 'compensator')):
        assert all(word in description for word in words), (words, description)
        assert all(word in setup for word in words), words
    assert 'discover' in description and 'discover' in setup


def test_a_missing_optional_library_is_one_line_naming_the_pip_package(monkeypatch):
    """`require` of a library that is not installed: DependencyError naming its pip package."""
    monkeypatch.setitem(sys.modules, 'distributed', None)  # `import distributed` now fails
    with pytest.raises(DependencyError) as error:
        require('distributed', 'fit-fleet')
    assert str(error.value) == "fit-fleet needs the optional Python package dask[distributed]: " \
                               "pip install 'dask[distributed]'"
    assert require('json', 'anything') is json


def test_fit_fleet_without_dask_exits_2_in_one_line(tmp_path):
    """`tak_calib fit-fleet` where dask[distributed] is missing: one line, exit 2, no traceback."""
    from tak_thermo_ros.formats.bag import write_record
    from tak_thermo_ros.core.simulation.imu import simulate
    from tak_thermo_ros.core.simulation.scenario import Scenario
    bag = tmp_path / 'unit1'
    write_record(bag, simulate(Scenario(plateaus_celsius=(10.0, 30.0), plateau_hours=0.02, dwell_s=5.0,
                                        ramp_celsius_per_minute=5.0, board_lag_s=10.0)).record)
    code = ('import sys; sys.modules["distributed"] = None; sys.modules["dask.distributed"] = None; '
            'from tak_thermo_ros.cli import main; '
            f'sys.exit(main(["fit-fleet", {str(bag)!r}, "-o", {str(tmp_path / "out")!r}]))')
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 2, result.stderr
    assert result.stderr.strip().splitlines()[-1] == (
        "tak_calib: error: fit-fleet needs the optional Python package dask[distributed]: "
        "pip install 'dask[distributed]'")
    assert 'Traceback' not in result.stderr
