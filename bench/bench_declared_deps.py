"""A colcon build with only package.xml's declared dependencies installed runs both executables.

A fresh venv gets the pip equivalent of every ``exec_depend`` in ``package.xml`` (pinned by
``constraints.txt``) and colcon, nothing else: no dask, no pytest, no hypothesis. The package is
colcon-built into a temporary workspace, and from its install:

- ``compensator`` (the console script ``ros2 run`` executes) with the example driver calibration
  corrects the Imu this script publishes (start to first corrected Imu, as bench_startup.py);
- ``tak_calib --help``; ``simulate`` a short driver run, ``fit`` it, ``apply`` it and
  ``diagnose --report`` it (scipy, rosbags and matplotlib from the declared dependencies);
- ``fit-fleet`` says in one line that it needs the optional ``dask[distributed]``.

What this machine cannot show: ``rosdep install`` itself (no apt ROS here: the rosdep keys are
mapped to their pip packages below), and the launch file (``launch``/``launch_ros`` are no
wheels; test/ros/test_ros2_cli.py runs it with the ros2cli build). Usage:
``python bench/bench_declared_deps.py``; writes ``bench/results/declared_deps.json``; exits 3
when a step fails.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ElementTree
from pathlib import Path

from bench_startup import start_to_output
from benchlib import machine

REPO = Path(__file__).resolve().parent.parent
RESULTS = REPO / 'bench' / 'results' / 'declared_deps.json'
TARGET_MISSED = 3
SOURCES = ('setup.py', 'setup.cfg', 'package.xml', 'resource', 'tak_thermo_ros', 'config', 'launch')
PIP = {
    'rclpy': 'ros-jazzy-rclpy[fastrtps]', 'rcl_interfaces': 'ros-jazzy-common-interfaces',
    'sensor_msgs': 'ros-jazzy-common-interfaces', 'geometry_msgs': 'ros-jazzy-common-interfaces',
    'diagnostic_msgs': 'ros-jazzy-common-interfaces', 'std_msgs': 'ros-jazzy-common-interfaces',
    'python3-numpy': 'numpy', 'python3-yaml': 'pyyaml', 'python3-scipy': 'scipy',
    'python3-matplotlib': 'matplotlib', 'python3-rosbags-pip': 'rosbags',
}
"""rosdep key -> pip package, for the keys a wheel provides."""
NOT_WHEELS = {'launch', 'launch_ros', 'ament_index_python'}
"""Declared for the launch file; launch and launch_ros are no wheels (ament_index_python comes with rclpy)."""


def run(command: list[str], env: dict[str, str], cwd: Path, timeout: float = 900.0) -> dict:
    """Run a command to its end: exit code, seconds, the output's last lines."""
    start = time.perf_counter()
    result = subprocess.run(command, env=env, cwd=cwd, capture_output=True, text=True, timeout=timeout,
                            stdin=subprocess.DEVNULL)
    lines = (result.stdout + result.stderr).strip().splitlines()
    return {'command': ' '.join(Path(c).name if i == 0 else c for i, c in enumerate(command)),
            'exit': result.returncode, 'seconds': round(time.perf_counter() - start, 2), 'last_lines': lines[-3:]}


def main() -> int:
    """Build the venv and the workspace, run the executables, write the results."""
    declared = [e.text.strip() for e in ElementTree.parse(REPO / 'package.xml').getroot()
                if e.tag == 'exec_depend']
    unmapped = [key for key in declared if key not in PIP and key not in NOT_WHEELS]
    if unmapped:
        print(f'no pip package known for {", ".join(unmapped)}')
        return TARGET_MISSED
    packages = sorted({PIP[key] for key in declared if key in PIP})
    steps: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix='declared_deps_') as tmp:
        root = Path(tmp)
        venv, workspace = root / 'venv', root / 'ws'
        env = {key: value for key, value in os.environ.items() if key not in ('VIRTUAL_ENV', 'PYTHONPATH')}
        env.update(ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_HOME=str(root / 'ros_home'),
                   ROS_LOG_DIR=str(root / 'ros_home' / 'log'), ROS_DOMAIN_ID=str(30 + os.getpid() % 30),
                   COLCON_HOME=str(root / 'colcon_home'), PYTHONUNBUFFERED='1', MPLBACKEND='Agg')
        steps['venv'] = run([sys.executable, '-m', 'venv', str(venv)], env, root)
        python = venv / 'bin' / 'python'
        steps['pip install'] = run([str(python), '-m', 'pip', 'install', '--quiet', '-c', str(REPO / 'constraints.txt'),
                                    *packages, 'colcon-common-extensions'], env, root)
        frozen = subprocess.run([str(python), '-m', 'pip', 'freeze'], capture_output=True, text=True).stdout
        installed = sorted(line.split('==')[0].lower() for line in frozen.splitlines() if '==' in line)
        source = workspace / 'src' / 'tak_thermo_ros'
        source.mkdir(parents=True)
        for name in SOURCES:
            subprocess.run(['cp', '-r', str(REPO / name), str(source / name)], check=True)
        steps['colcon build'] = run([str(venv / 'bin' / 'colcon'), 'build'], env, workspace)
        prefix = workspace / 'install' / 'tak_thermo_ros'
        site = prefix / 'lib' / f'python{sys.version_info.major}.{sys.version_info.minor}' / 'site-packages'
        run_env = {**env, 'AMENT_PREFIX_PATH': str(prefix), 'PYTHONPATH': str(site),
                   'PATH': f'{venv / "bin"}{os.pathsep}{env["PATH"]}'}
        bin_dir = prefix / 'lib' / 'tak_thermo_ros'
        compensator = [str(bin_dir / 'compensator'), '--ros-args', '--params-file',
                       str(REPO / 'config' / 'compensator_driver.yaml')]
        try:
            start = start_to_output(compensator, run_env, root / 'compensator.log', 'correcting ')
            steps['compensator'] = {'exit': 0, 'first_corrected_s': round(start['first_corrected_s'], 3)}
        except RuntimeError as error:
            steps['compensator'] = {'exit': 1, 'error': str(error),
                                    'log': (root / 'compensator.log').read_text()[-500:]}
        tak_calib = str(bin_dir / 'tak_calib')
        bag, params = root / 'run', root / 'params.yaml'
        scenario = root / 'scenario.yaml'
        scenario.write_text('output: imu\nsample_rate_hz: 2.0\nplateaus_celsius: [10.0, 30.0]\n'
                            'plateau_hours: 0.2\ndwell_s: 60.0\nboard_lag_s: 60.0\n', encoding='utf-8')
        for name, argv in (('tak_calib --help', ['--help']),
                           ('tak_calib simulate', ['simulate', str(bag), '--scenario', str(scenario)]),
                           ('tak_calib fit', ['fit', str(bag), '-o', str(params)]),
                           ('tak_calib apply', ['apply', str(bag), '--params', str(params), '-o', str(root / 'out')]),
                           ('tak_calib diagnose --report', ['diagnose', str(bag), '--params', str(params),
                                                            '--report', str(root / 'report')])):
            steps[name] = run([tak_calib, *argv], run_env, root)
        fleet = run([tak_calib, 'fit-fleet', str(bag), '-o', str(root / 'fleet')], run_env, root)
        fleet['expected_exit'] = 2
        steps['tak_calib fit-fleet (no dask)'] = fleet
    failed = [name for name, step in steps.items() if step['exit'] != step.get('expected_exit', 0)]
    fleet_line = steps['tak_calib fit-fleet (no dask)']['last_lines'][-1:]
    document = {'machine': machine(), 'declared_exec_depends': declared, 'pip_packages': packages,
                'installed': installed, 'not_installed': [m for m in ('dask', 'distributed', 'pytest', 'hypothesis')
                                                          if m not in installed],
                'steps': steps, 'failed': failed, 'fit_fleet_says': fleet_line}
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(document, indent=2) + '\n', encoding='utf-8')
    for name, step in steps.items():
        detail = step.get('first_corrected_s', step.get('seconds', ''))
        print(f'{name:32s} exit {step["exit"]}  {detail}  {" | ".join(step.get("last_lines", [])[-1:])[:110]}')
    print(f'installed: {len(installed)} distributions; not installed: {", ".join(document["not_installed"])}')
    print(f'failed: {", ".join(failed) or "none"}; wrote {RESULTS}')
    return TARGET_MISSED if failed else 0


if __name__ == '__main__':
    sys.exit(main())
