"""Three layers: the maths imports no file format, no command and no ROS; formats and the node stay in their rooms."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / 'tak_thermo_ros'

BLOCKER = '''
import importlib.abc, sys
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ('rclpy', 'rosbags'):
            raise ImportError(f'{name} is blocked for this test')
        return None
sys.meta_path.insert(0, Block())
import pkgutil, importlib
import tak_thermo_ros.core as core
for module in pkgutil.walk_packages(core.__path__, 'tak_thermo_ros.core.'):
    importlib.import_module(module.name)
import tak_thermo_ros.cli
assert 'rclpy' not in sys.modules and 'rosbags' not in sys.modules
print('ok')
'''


def test_core_imports_without_rclpy_and_rosbags():
    """Every core module (and the CLI's top level) imports with rclpy and rosbags unavailable."""
    result = subprocess.run([sys.executable, '-c', BLOCKER], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().endswith('ok')


def _imported_roots(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding='utf-8'))
    roots = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            roots.update(alias.name.split('.')[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            roots.add(node.module.split('.')[0])
    return roots


def test_only_the_bag_format_imports_rosbags_and_only_node_imports_rclpy():
    """`rosbags` appears in formats/bag.py alone; rclpy and ROS message packages in node.py and player.py alone.

    player.py (``tak_calib play``) publishes a bag into a running node: it needs rclpy and reads
    the bag through formats/; node.py never imports it (test_dependencies holds the node's path).
    """
    for path in PACKAGE.rglob('*.py'):
        roots = _imported_roots(path)
        relative = path.relative_to(PACKAGE).as_posix()
        if 'rosbags' in roots:
            assert relative == 'formats/bag.py', f'{relative} imports rosbags'
        ros_runtime = roots & {'rclpy', 'sensor_msgs', 'geometry_msgs', 'diagnostic_msgs', 'std_msgs',
                               'builtin_interfaces', 'rcl_interfaces'}
        if ros_runtime:
            assert relative in ('node.py', 'player.py'), f'{relative} imports {sorted(ros_runtime)}'


def _own_imports(path: Path) -> set[str]:
    """The package's own modules a file imports (absolute imports, at any depth of the file)."""
    tree = ast.parse(path.read_text(encoding='utf-8'))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith('tak_thermo_ros'):
            names.add(node.module)
        elif isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names if alias.name.startswith('tak_thermo_ros'))
    return names


def test_the_maths_imports_no_format_and_no_command_and_formats_no_command():
    """core/ imports only core/ and the leaves (errors, optional); formats/ never imports the commands or passes."""
    leaves = ('tak_thermo_ros.core', 'tak_thermo_ros.errors', 'tak_thermo_ros.optional', 'tak_thermo_ros.progress')
    for path in (PACKAGE / 'core').rglob('*.py'):
        upward = [name for name in _own_imports(path) if not name.startswith(leaves)]
        assert not upward, f'{path.relative_to(PACKAGE)} imports {upward}'
    commands = ('tak_thermo_ros.cli', 'tak_thermo_ros.streaming', 'tak_thermo_ros.noise_run', 'tak_thermo_ros.node',
                'tak_thermo_ros.fleet', 'tak_thermo_ros.report')
    for path in (PACKAGE / 'formats').rglob('*.py'):
        upward = [name for name in _own_imports(path) if name.startswith(commands)]
        assert not upward, f'{path.relative_to(PACKAGE)} imports {upward}'
