"""Start-up of the ``compensator`` node: import time, and process start to the first corrected Imu.

A robot starts the node with its driver already publishing. This script plays the driver
(``sensor_msgs/msg/Imu`` on ``imu/data_raw`` and ``sensor_msgs/msg/Temperature`` on
``imu/temperature`` every 5 ms, reliable) before the node exists, starts the node's console
script (what ``ros2 run tak_thermo_ros compensator`` executes) with the example driver
calibration ``config/compensator_driver.yaml``, and measures from ``Popen`` to the first
corrected Imu received on ``imu/data_compensated``. The same for a bare relay node (the same
subscriptions and publisher, rclpy and messages only, no package import): the difference is
what the package adds. Also, in fresh interpreters: the import time of ``tak_thermo_ros.ros.node``
and of what it needs from ROS alone (``rclpy`` and the message packages).

With ``--baseline DIR`` (a tree holding another version's ``tak_thermo_ros/``, e.g.
``git archive main tak_thermo_ros | tar -x -C DIR``), that version's node (its ``node.main``)
and this one's (its entry point ``node_main.main``) are also started the same way, as
``python -c`` (the console script reads the installed entry points first, the same cost for
both versions but not part of a ``python -c``), in the same rounds, in turn with the others:
the ratio of the medians, and the median of the per-round ratios, say whether this version
starts slower.

Usage: ``python bench/bench_startup.py [--rounds N] [--baseline DIR]``; writes ``bench/results/startup.json``;
exits 3 when a target is missed: the package adds more than ``ADDED_TARGET_S`` to the start-up,
or an offline library (scipy, matplotlib, dask, rosbags, pandas, ...) is loaded by the node.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchlib import bench_domain, machine, stop

REPO = Path(__file__).resolve().parent.parent
RESULTS = REPO / 'bench' / 'results' / 'startup.json'
CONFIG = REPO / 'config' / 'compensator_driver.yaml'
TARGET_MISSED = 3
ADDED_TARGET_S = 1.0
"""At most this much start-up (median, process start to ready) on top of a bare rclpy relay node."""
PERIOD_S = 0.005
NANOSECONDS = 1_000_000_000
OFFLINE = ('scipy', 'matplotlib', 'dask', 'distributed', 'rosbags', 'pandas', 'statsmodels', 'allantools')
ROS_ONLY = 'import rclpy, rcl_interfaces.msg, sensor_msgs.msg, geometry_msgs.msg, diagnostic_msgs.msg'

RELAY = '''
import rclpy
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy, HistoryPolicy
from sensor_msgs.msg import Imu, Temperature

rclpy.init()
node = Node('relay')
out = node.create_publisher(Imu, 'imu/data_compensated',
                            QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
                                       reliability=ReliabilityPolicy.RELIABLE))
node.create_subscription(Temperature, 'imu/temperature', lambda m: None, qos_profile_sensor_data)
node.create_subscription(Imu, 'imu/data_raw', out.publish, qos_profile_sensor_data)
print('ready', flush=True)
try:
    rclpy.spin(node)
except BaseException:
    pass
'''


def import_seconds(statement: str, rounds: int) -> list[float]:
    """Wall time of ``statement`` in ``rounds`` fresh interpreters."""
    code = (f'import time; t = time.perf_counter(); {statement}; '
            f'print(time.perf_counter() - t)')
    return [float(subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True,
                                 cwd=REPO).stdout) for _ in range(rounds)]


def offline_modules_loaded() -> list[str]:
    """Offline-only libraries in ``sys.modules`` after ``import tak_thermo_ros.ros.node``."""
    code = ('import sys, tak_thermo_ros.ros.node; '
            f'print(" ".join(m for m in {OFFLINE!r} if m in sys.modules))')
    return subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True,
                          cwd=REPO).stdout.split()


class Driver:
    """The driver side: Imu and temperature publishers, a subscriber of the corrected Imu."""

    def __init__(self, domain: int) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import Imu, Temperature
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node('bench_startup_driver', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        reliable = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.imu_type, self.temperature_type = Imu, Temperature
        self.imu = self.node.create_publisher(Imu, '/imu/data_raw', reliable)
        self.temperature = self.node.create_publisher(Temperature, '/imu/temperature', reliable)
        self.received: list[float] = []
        self.subscription = self.node.create_subscription(
            Imu, '/imu/data_compensated', lambda _: self.received.append(time.perf_counter()), reliable)

    def run_until_output(self, started: float, timeout: float, log: Path, ready_text: str) -> dict[str, float]:
        """Publish every ``PERIOD_S`` until a corrected Imu arrives; seconds since ``started``.

        Also when the node's log shows ``ready_text`` (its subscriptions and publisher made).
        """
        matched = ready = None
        stamp = 1_700_000_000 * NANOSECONDS
        deadline = time.perf_counter() + timeout
        while not self.received:
            if time.perf_counter() > deadline:
                msg = f'no corrected Imu within {timeout} s'
                raise RuntimeError(msg)
            if matched is None and self.imu.get_subscription_count() >= 1:
                matched = time.perf_counter()
            if ready is None and ready_text in log.read_text(encoding='utf-8', errors='replace'):
                ready = time.perf_counter()
            stamp += int(PERIOD_S * NANOSECONDS)
            temperature = self.temperature_type()
            temperature.header.stamp.sec, temperature.header.stamp.nanosec = divmod(stamp, NANOSECONDS)
            temperature.temperature = 20.0
            self.temperature.publish(temperature)
            imu = self.imu_type()
            imu.header.stamp.sec, imu.header.stamp.nanosec = divmod(stamp + 1, NANOSECONDS)
            imu.linear_acceleration.z = 9.81
            self.imu.publish(imu)
            self.executor.spin_once(timeout_sec=PERIOD_S)
        while ready is None and time.perf_counter() < deadline:
            if ready_text in log.read_text(encoding='utf-8', errors='replace'):
                ready = time.perf_counter()
            time.sleep(0.001)
        return {'ready_s': (ready or float('nan')) - started,
                'subscriptions_matched_s': (matched or self.received[0]) - started,
                'first_corrected_s': self.received[0] - started}

    def close(self) -> None:
        """Tear the driver down."""
        import rclpy
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def start_to_output(command: list[str], env: dict[str, str], log: Path, ready_text: str) -> dict[str, float]:
    """One start: the driver already publishing, the node started, timed to its first output."""
    driver = Driver(int(env['ROS_DOMAIN_ID']))
    try:
        with open(log, 'wb') as output:
            started = time.perf_counter()
            process = subprocess.Popen(command, env=env, stdout=output, stderr=subprocess.STDOUT,
                                       stdin=subprocess.DEVNULL, start_new_session=True)
            try:
                return driver.run_until_output(started, 60.0, log, ready_text)
            finally:
                stop(process)
    finally:
        driver.close()


def summary(values: list[float]) -> dict[str, float]:
    """Median, min and max, rounded to milliseconds."""
    return {'median_s': round(statistics.median(values), 3), 'min_s': round(min(values), 3),
            'max_s': round(max(values), 3)}


def main() -> int:
    """Measure, print, write ``bench/results/startup.json``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--rounds', type=int, default=10, help='starts of each node (default 10)')
    parser.add_argument('--baseline', type=Path, metavar='DIR',
                        help="also start another version's node (DIR holds its tak_thermo_ros/), in the same rounds")
    args = parser.parse_args()
    script = Path(sys.executable).parent / 'compensator'
    node_command = ([str(script)] if script.exists() else [sys.executable, '-m', 'tak_thermo_ros.ros.main'])
    node_command += ['--ros-args', '--params-file', str(CONFIG)]
    relay_command = [sys.executable, '-c', RELAY]

    offline = offline_modules_loaded()
    imports = {'tak_thermo_ros.ros.node': summary(import_seconds('import tak_thermo_ros.ros.node', args.rounds)),
               'rclpy and the message packages': summary(import_seconds(ROS_ONLY, args.rounds))}
    subjects = [('relay', relay_command, 'ready'), ('compensator', node_command, 'correcting ')]
    if args.baseline is not None:
        for name, tree, module in (('this_python_c', REPO, 'node_main'), ('baseline', args.baseline.resolve(), 'node')):
            main_code = (f'import sys; sys.path.insert(0, {str(tree)!r}); '
                         f'from tak_thermo_ros.{module} import main; sys.exit(main())')
            subjects.append((name, [sys.executable, '-c', main_code, '--ros-args', '--params-file', str(CONFIG)],
                             'correcting '))
    starts: dict[str, list[dict[str, float]]] = {name: [] for name, _, _ in subjects}
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix='bench_startup_') as tmp:
        home = Path(tmp) / 'ros_home'
        env = {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'ROS_HOME': str(home),
               'ROS_LOG_DIR': str(home / 'log'), 'ROS_DOMAIN_ID': str(bench_domain(0)),
               'PYTHONUNBUFFERED': '1'}
        for index in range(args.rounds):
            for name, command, ready_text in subjects:
                starts[name].append(start_to_output(command, env, Path(tmp) / f'{name}_{index}.log', ready_text))
    first = {name: summary([s['first_corrected_s'] for s in runs]) for name, runs in starts.items()}
    matched = {name: summary([s['subscriptions_matched_s'] for s in runs]) for name, runs in starts.items()}
    ready = {name: summary([s['ready_s'] for s in runs]) for name, runs in starts.items()}
    added = round(ready['compensator']['median_s'] - ready['relay']['median_s'], 3)
    document = {
        'machine': machine(), 'rounds': args.rounds, 'calibration': 'config/compensator_driver.yaml',
        'command': 'the compensator console script (what ros2 run executes)',
        'import': imports, 'offline_libraries_loaded_by_the_node': offline,
        'start_to_ready': ready, 'start_to_first_corrected_imu': first, 'start_to_subscriptions_matched': matched,
        'added_by_the_package_s': added, 'added_target_s': ADDED_TARGET_S,
        'load_average_1min_before': load_before, 'load_average_1min_after': os.getloadavg()[0],
        'runs': starts,
    }
    if args.baseline is not None:
        document['baseline'] = {
            'directory': str(args.baseline),
            'command': "python -c '...from tak_thermo_ros.ros.node import main...' (this version: node_main)",
            'ready_ratio_of_medians': round(ready['this_python_c']['median_s'] / ready['baseline']['median_s'], 3),
            'ready_ratio_median_per_round': round(statistics.median(
                c['ready_s'] / b['ready_s'] for c, b in zip(starts['this_python_c'], starts['baseline'])), 3),
            'first_corrected_ratio_of_medians': round(
                first['this_python_c']['median_s'] / first['baseline']['median_s'], 3)}
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(document, indent=2) + '\n', encoding='utf-8')
    for name, value in imports.items():
        print(f'import {name:32s} median {value["median_s"]:.3f} s ({value["min_s"]:.3f}..{value["max_s"]:.3f})')
    print(f'offline libraries loaded by the node: {", ".join(offline) or "none"}')
    for name in starts:
        print(f'{name:11s}: start -> ready (log line) {ready[name]["median_s"]:.3f} s, '
              f'-> subscriptions matched {matched[name]["median_s"]:.3f} s, '
              f'-> first corrected Imu {first[name]["median_s"]:.3f} s '
              f'({first[name]["min_s"]:.3f}..{first[name]["max_s"]:.3f}, {args.rounds} starts)')
    print(f'added by the package (start -> ready, medians): {added:.3f} s (target <= {ADDED_TARGET_S} s); '
          f'wrote {RESULTS}')
    if args.baseline is not None:
        base = document['baseline']
        print(f'this version / baseline, start -> ready: {base["ready_ratio_of_medians"]:.3f} (medians), '
              f'{base["ready_ratio_median_per_round"]:.3f} (median of per-round ratios); load average '
              f'{load_before:.1f} -> {os.getloadavg()[0]:.1f}')
    return TARGET_MISSED if offline or added > ADDED_TARGET_S else 0


if __name__ == '__main__':
    sys.exit(main())
