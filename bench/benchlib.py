"""What the benchmark scripts share: how to call ``tak_calib``, and what machine measured it.

Imported by the ``bench_*.py`` scripts, which run with this directory on ``sys.path``.
"""

from __future__ import annotations

import os
import platform
import signal
import subprocess
import sys
from dataclasses import replace
from importlib.metadata import version
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from tak_thermo_ros.core.simulation.scenario import Scenario


def tak_calib_command() -> list[str]:
    """``tak_calib`` of this interpreter's environment (the console script, else ``-m``)."""
    script = Path(sys.executable).parent / 'tak_calib'
    return [str(script)] if script.exists() else [sys.executable, '-m', 'tak_thermo_ros.cli']


REAL_LOG = Path(__file__).resolve().parents[1] / 'data' / 'tofupilot-imu-thermal' / 'imu_raw_data.csv'
"""The repository's real log (a MEMS IMU's thermal cycle, MIT)."""


def run_tak_calib(*args: str) -> str:
    """What ``tak_calib ARGS`` prints (raises on a failure)."""
    return subprocess.run([*tak_calib_command(), *args], capture_output=True, text=True, check=True).stdout


def import_real_log(output: str) -> None:
    """:data:`REAL_LOG` imported as a driver bag at ``output``: both sensors and the temperature."""
    run_tak_calib('import-csv', str(REAL_LOG), '-o', output, '--time-unit', 'us', '--acc-columns', 'imu.acc.x',
                  'imu.acc.y', 'imu.acc.z', '--temp-column', 'imu.temperature', '--gyro-columns', 'imu.gyro.x',
                  'imu.gyro.y', 'imu.gyro.z')


def stop(process: subprocess.Popen) -> int:
    """SIGINT to a node's process group (started with ``start_new_session``), SIGKILL after 10 s; the exit code."""
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGINT)
        try:
            process.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    return process.returncode


def bench_domain(index: int) -> int:
    """A ROS domain for a benchmark's node ``index``: in 101..200, clear of the tests' 1..100.

    The machine may run other jobs' tests beside a benchmark; a node of theirs in the same domain
    (localhost discovery) would join this one's topics and spoil its counts.
    """
    return 101 + (os.getpid() + 37 * index) % 100


def machine() -> dict[str, object]:
    """What the figures were measured on, and how busy it was."""
    model = ''
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                model = line.split(':', 1)[1].strip()
                break
    except OSError:
        pass
    return {'cpus': os.cpu_count(), 'cpu_model': model, 'python': platform.python_version(),
            'numpy': version('numpy'), 'rosbags': version('rosbags'), 'platform': platform.platform(),
            'load_average_1min': os.getloadavg()[0],
            'OPENBLAS_NUM_THREADS': os.environ.get('OPENBLAS_NUM_THREADS', '(unset)')}


def stretched(base: Scenario, hours: float) -> Scenario:
    """``base`` with its plateaus lengthened (or shortened) so that the whole run lasts ``hours``."""
    ramps_s = base.duration_s() - len(base.plateaus_celsius) * base.plateau_hours * 3600.0
    plateau_hours = (hours * 3600.0 - ramps_s) / 3600.0 / len(base.plateaus_celsius)
    if plateau_hours <= 0.0:
        msg = f'--hours {hours:g}: shorter than the ramps of the protocol ({ramps_s / 3600.0:g} h)'
        raise SystemExit(msg)
    return replace(base, plateau_hours=plateau_hours)
