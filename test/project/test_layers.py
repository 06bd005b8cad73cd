"""Three layers: the maths imports no file format, no command and no ROS; formats and the node stay in their rooms."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

from paths import REPO

PACKAGE = REPO / 'tak_thermo_ros'

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
    """`rosbags` appears in formats/bag/ alone; rclpy and ROS message packages in the node's and player's modules alone.

    ros/player.py (``tak_calib play``) publishes a bag into a running node: it needs rclpy and reads
    the bag through formats/; ros/node.py never imports it (test_dependencies holds the node's path).
    """
    for path in PACKAGE.rglob('*.py'):
        roots = _imported_roots(path)
        relative = path.relative_to(PACKAGE).as_posix()
        if 'rosbags' in roots:
            assert relative.startswith('formats/bag/'), f'{relative} imports rosbags'
        ros_runtime = roots & {'rclpy', 'sensor_msgs', 'geometry_msgs', 'diagnostic_msgs', 'std_msgs',
                               'builtin_interfaces', 'rcl_interfaces'}
        if ros_runtime:
            node_or_player = ('ros/node.py', 'ros/main.py', 'ros/player.py')
            assert relative in node_or_player, f'{relative} imports {sorted(ros_runtime)}'


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
    """core/ imports only core/ and the leaves (errors, optional, progress, units); formats/ no command or pass."""
    leaves = ('tak_thermo_ros.core', 'tak_thermo_ros.errors', 'tak_thermo_ros.optional', 'tak_thermo_ros.progress',
              'tak_thermo_ros.units')
    for path in (PACKAGE / 'core').rglob('*.py'):
        upward = [name for name in _own_imports(path) if not name.startswith(leaves)]
        assert not upward, f'{path.relative_to(PACKAGE)} imports {upward}'
    commands = ('tak_thermo_ros.cli', 'tak_thermo_ros.passes', 'tak_thermo_ros.ros', 'tak_thermo_ros.reports')
    for path in (PACKAGE / 'formats').rglob('*.py'):
        upward = [name for name in _own_imports(path) if name.startswith(commands)]
        assert not upward, f'{path.relative_to(PACKAGE)} imports {upward}'


# ----- the house: rooms at the top level, and no import cycle ------------------------------------------

SHARED_MODULES = {'__init__.py', 'errors.py', 'units.py', 'optional.py', 'progress.py'}
ROOMS = {'core', 'formats', 'cli', 'passes', 'ros', 'reports'}


def test_the_top_level_holds_the_rooms_and_the_small_shared_modules_only():
    """The package's top level: its subpackages and at most the four small shared modules."""
    modules = {path.name for path in PACKAGE.glob('*.py')}
    assert modules <= SHARED_MODULES, sorted(modules - SHARED_MODULES)
    rooms = {path.name for path in PACKAGE.iterdir() if path.is_dir() and (path / '__init__.py').exists()}
    assert rooms == ROOMS


def _module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root.parent).with_suffix('').parts)
    if parts[-1] == '__init__':
        parts.pop()
    return '.'.join(parts)


def import_graph(root: Path) -> dict[str, set[str]]:
    """Module -> the package's own modules it imports, at any depth of the file (lazy imports count).

    ``from package import name`` counts as importing ``package.name`` when that is a module
    (else the package itself). A package's ``__init__`` is not an edge of its submodules: Python
    runs it first, but a cycle through an ``__init__`` that imports nothing cannot form.
    """
    modules = {_module_name(path, root): path for path in root.rglob('*.py')}
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        package = name if path.name == '__init__.py' else name.rpartition('.')[0]
        for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ''
                if node.level:
                    anchor = package.split('.')[:len(package.split('.')) - node.level + 1]
                    base = '.'.join(anchor + ([base] if base else []))
                targets = [f'{base}.{alias.name}' if f'{base}.{alias.name}' in modules else base
                           for alias in node.names]
            else:
                continue
            graph[name].update(target for target in targets if target in modules and target != name)
    return graph


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Every strongly connected set of two or more modules (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []
    counter = [0]

    def visit(node: str) -> None:
        index[node] = low[node] = counter[0]
        counter[0] += 1
        stack.append(node)
        on_stack.add(node)
        for target in sorted(graph[node]):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return cycles


def test_no_import_cycle_in_the_package():
    """No two modules of the package import each other, directly or through others (lazy imports count)."""
    assert import_cycles(import_graph(PACKAGE)) == []


def test_the_cycle_test_finds_a_cycle(tmp_path):
    """The cycle test fails on a cycle: a lazy import back, a relative import and a three-module ring are found."""
    root = tmp_path / 'pkg'
    (root / 'sub').mkdir(parents=True)
    (root / '__init__.py').write_text('')
    (root / 'sub' / '__init__.py').write_text('')
    (root / 'a.py').write_text('from pkg.b import thing\n')
    (root / 'b.py').write_text('def thing():\n    from pkg import a\n    return a\n')
    (root / 'sub' / 'c.py').write_text('from . import d\n')
    (root / 'sub' / 'd.py').write_text('import pkg.sub.e\n')
    (root / 'sub' / 'e.py').write_text('from .c import name\n')
    (root / 'leaf.py').write_text('import pkg.a\n')
    assert import_cycles(import_graph(root)) == [['pkg.a', 'pkg.b'], ['pkg.sub.c', 'pkg.sub.d', 'pkg.sub.e']]
