"""Benchmark of the ``compensator`` node against a bare relay node, in the same run.

Both nodes run as their own process with the same layout (a Vector3Stamped and a Temperature
subscription, an Imu publisher, reliable QoS of depth 100); the relay copies the counts into
the Imu without any maths. This process drives them and receives their output.

Figures:

- throughput: closed loop (at most ``WINDOW`` messages in flight, below the QoS depth, so
  nothing is lost), messages per second; and the node's capacity, messages per CPU second
  of the node process (independent of whether this driver or the node is the bottleneck).
  Both nodes run side by side (own domains) and their rounds alternate, so that a change in
  the machine's load hits both; the ratios are medians over the rounds of the ratio within
  a round;
- latency at 1 kHz: counts stamp (system clock at publication) to Imu receipt, p50/p99,
  for both nodes; the *added* latency is the compensator's minus the relay's;
- soak: one million messages through the compensator, resident memory (VmRSS) growth;
- the per-message cost of the node's own work, measured in-process (core + message fill).

Driver input (a version-2 calibration: Imu and degrees C in, both sensors corrected), for each
executor (``events``: rclpy.experimental.EventsExecutor, the node's default; ``single_threaded``):
the compensator and a bare relay (Imu in -> the same Imu out, same subscriptions, same executor
and spin loop) are driven open loop at fixed rates up to 2 kHz (reliable, depth 100); per rate,
messages lost (sent - received) and the node's CPU per message. The sustained rate without loss
is the highest rate at which nothing was lost. ``--driver-only`` runs only this part and
updates ``driver_input`` in ``node.json``.

``--marks --baseline DIR`` measures only the real node's Imu callback (publish stubbed, no DDS),
this version against another's in fresh interpreters taking turns: what honouring an absent
sensor's mark (covariance[0] = -1) costs an ordinary two-sensor message; key ``one_sensor_marks``.

``--rates`` (issue 42): the node as a user starts it (the raw path), the node on the decoded path and
a bare rclpy relay on the default executor, side by side, open loop at 1, 2, 4 and 8 kHz for 10 s
each, counts and driver input, three rounds: messages lost and CPU per message; key ``rates``;
target: at 4 kHz none lost and at most 0.40x the relay's CPU per message.

Usage: ``python bench/bench_node.py [--quick] [--driver-only] [--rates] [--marks --baseline DIR]``; writes
``bench/results/node.json`` (with ``--quick``: ``node_quick.json``, a smoke run, not the figures);
exits 3 (as every ``bench/bench_*.py``) when a target is missed.
"""

from __future__ import annotations

import argparse
import cProfile
import inspect
import io
import json
import os
import pstats
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchlib import bench_domain, stop

REPO = Path(__file__).resolve().parent.parent
RESULTS = REPO / 'bench' / 'results' / 'node.json'
WINDOW = 50
DEPTH = 100
TEMP_EVERY = 100
TARGET_MISSED = 3
NANOSECONDS = 1_000_000_000


def close_all(names, drivers: dict, processes: dict) -> dict[str, int]:
    """Close each name's driver and stop its process (those started); their exit codes by name."""
    codes = {}
    for name in names:
        if name in drivers:
            drivers[name].close()
        if name in processes:
            codes[name] = stop(processes[name])
    return codes


# -- the relay node (run as: bench_node.py relay --ros-args ...) ---------------------------------

def relay_main(input_kind: str = 'counts', depth: int = DEPTH, best_effort: bool = False) -> int:
    """A bare relay on the default executor (``rclpy.spin``): the compensator's topics and QoS, no package, no maths.

    Counts: the Vector3Stamped's header and vector copied into an Imu; driver: the Imu republished as it came.
    Reliable both ways (the closed-loop benchmark), or, ``best_effort``, best-effort input as the node's
    default; ``depth`` of both.
    """
    import rclpy
    from geometry_msgs.msg import Vector3Stamped
    from rclpy.executors import ExternalShutdownException
    from rclpy.node import Node
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu, Temperature

    class Relay(Node):
        def __init__(self) -> None:
            super().__init__('relay')
            qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE)
            inputs = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT
                                ) if best_effort else qos
            driver = input_kind == 'driver'
            self._temp = self.create_subscription(Temperature, 'imu/temperature' if driver else 'tak/temp_code',
                                                  self._on_temperature, inputs)
            self._imu = Imu()
            self._imu.orientation.w = 1.0
            self._imu.orientation_covariance = (-1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            self._imu.angular_velocity_covariance = (-1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            self._imu.linear_acceleration_covariance = (1e-4, 0.0, 0.0, 0.0, 1e-4, 0.0, 0.0, 0.0, 1e-4)
            self._acceleration = self._imu.linear_acceleration
            self._publisher = self.create_publisher(Imu, 'imu/data_compensated' if driver else 'tak/imu/data_raw',
                                                    qos)
            self._publish = self._publisher.publish
            if driver:
                self._input = self.create_subscription(Imu, 'imu/data_raw', self._publish, inputs)
            else:
                self._input = self.create_subscription(Vector3Stamped, 'tak/counts', self._on_counts, inputs)

        def _on_temperature(self, message: Temperature) -> None:
            pass

        def _on_counts(self, message: Vector3Stamped) -> None:
            self._imu.header = message.header
            vector = message.vector
            acceleration = self._acceleration
            acceleration.x, acceleration.y, acceleration.z = vector.x, vector.y, vector.z
            self._publish(self._imu)

    rclpy.init()
    node = Relay()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def driver_relay_main(executor_kind: str) -> int:
    """A bare relay of the driver input: Imu and Temperature subscriptions, the same Imu republished."""
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.node import Node
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu, Temperature

    from tak_thermo_ros.ros.main import make_executor, spin

    class DriverRelay(Node):
        def __init__(self) -> None:
            super().__init__('relay')
            qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DEPTH, reliability=ReliabilityPolicy.RELIABLE)
            self._temp = self.create_subscription(Temperature, 'imu/temperature', self._on_temperature, qos)
            self._publisher = self.create_publisher(Imu, 'imu/data_compensated', qos)
            self._imu = self.create_subscription(Imu, 'imu/data_raw', self._publisher.publish, qos)

        def _on_temperature(self, message: Temperature) -> None:
            pass

    rclpy.init()
    node = DriverRelay()
    executor = make_executor(executor_kind, node.context)
    try:
        spin(node, executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


# -- the driver -------------------------------------------------------------------------------

def rss_kb(pid: int) -> int:
    """Resident set size of a process, kB."""
    for line in Path(f'/proc/{pid}/status').read_text().splitlines():
        if line.startswith('VmRSS:'):
            return int(line.split()[1])
    raise RuntimeError('no VmRSS')


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


class Driver:
    """Publishes counts and temperature codes, receives Imu, in this process."""

    def __init__(self, domain: int, name: str = 'bench_driver') -> None:
        import rclpy
        from geometry_msgs.msg import Vector3Stamped
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import Imu, Temperature
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DEPTH, reliability=ReliabilityPolicy.RELIABLE)
        self.counts_publisher = self.node.create_publisher(Vector3Stamped, 'tak/counts', qos)
        self.temp_publisher = self.node.create_publisher(Temperature, 'tak/temp_code', qos)
        self.subscription = self.node.create_subscription(Imu, 'tak/imu/data_raw', self._on_imu, qos)
        self.counts = Vector3Stamped()
        self.counts.header.frame_id = 'tak_imu'
        self.temperature = Temperature()
        self.received = 0
        self.latencies_ns: list[int] | None = None

    def _on_imu(self, message) -> None:
        self.received += 1
        if self.latencies_ns is not None:
            stamp = message.header.stamp
            self.latencies_ns.append(time.time_ns() - (stamp.sec * NANOSECONDS + stamp.nanosec))

    def spin_until(self, condition, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > deadline:
                raise RuntimeError('timed out')
            self.executor.spin_once(timeout_sec=0.01)

    def matched(self) -> bool:
        return (self.counts_publisher.get_subscription_count() >= 1
                and self.temp_publisher.get_subscription_count() >= 1
                and self.subscription.get_publisher_count() >= 1)

    def publish(self, k: int, stamp_ns: int) -> None:
        if k % TEMP_EVERY == 0:
            self.temperature.header.stamp.sec, self.temperature.header.stamp.nanosec = divmod(stamp_ns, NANOSECONDS)
            self.temperature.temperature = 8200.0 + (k // TEMP_EVERY) % 200
            self.temp_publisher.publish(self.temperature)
        header = self.counts.header
        header.stamp.sec, header.stamp.nanosec = divmod(stamp_ns, NANOSECONDS)
        vector = self.counts.vector
        vector.x, vector.y, vector.z = float(k % 2000 - 1000), 500.0, 2500.0
        self.counts_publisher.publish(self.counts)

    def warm_up(self) -> None:
        """Send until the node answers (its Imu writer matched us too); then drain."""
        self.spin_until(self.matched, 30.0)
        k = 0
        deadline = time.monotonic() + 30.0
        while self.received == 0:
            if time.monotonic() > deadline:
                raise RuntimeError('the node never answered')
            self.publish(0, time.time_ns())
            k += 1
            end = time.monotonic() + 0.2
            while self.received == 0 and time.monotonic() < end:
                self.executor.spin_once(timeout_sec=0.01)
        # Some of the first messages may be dropped (a counts message before the first
        # temperature code reached the node): drain, then count from here.
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.05)
        self.sent = self.received = 0

    def closed_loop(self, count: int, on_progress=None) -> float:
        """Send ``count`` messages, at most WINDOW in flight; messages per second."""
        start_sent, start_received = self.sent, self.received
        spin_once = self.executor.spin_once
        started = time.perf_counter()
        k = 0
        while k < count:
            while k < count and self.sent - self.received < WINDOW:
                self.publish(k, time.time_ns())
                self.sent += 1
                k += 1
            spin_once(timeout_sec=0.1)
            if on_progress is not None and k % 50_000 == 0:
                on_progress(k)
        target = start_received + count
        self.spin_until(lambda: self.received >= target, 30.0)
        elapsed = time.perf_counter() - started
        assert self.sent - start_sent == count and self.received - start_received == count
        return count / elapsed

    def paced(self, count: int, rate_hz: float) -> list[int]:
        """Send ``count`` messages at ``rate_hz``; latencies (ns) of the answers."""
        self.latencies_ns = []
        period_ns = int(NANOSECONDS / rate_hz)
        next_ns = time.monotonic_ns()
        spin_once = self.executor.spin_once
        target = self.received + count
        for k in range(count):
            while True:
                wait = next_ns - time.monotonic_ns()
                if wait <= 0:
                    break
                spin_once(timeout_sec=wait / NANOSECONDS)
            self.publish(k, time.time_ns())
            self.sent += 1
            next_ns += period_ns
        # Open loop: a node that falls more than the QoS depth behind loses messages; wait until
        # everything arrived or nothing more arrives for 2 s, and report the loss.
        last, idle_since = self.received, time.monotonic()
        while self.received < target and time.monotonic() - idle_since < 2.0:
            spin_once(timeout_sec=0.05)
            if self.received != last:
                last, idle_since = self.received, time.monotonic()
        self.lost = target - self.received
        self.received = self.sent = 0
        latencies, self.latencies_ns = self.latencies_ns, None
        return latencies

    def close(self) -> None:
        import rclpy
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def node_env(home: Path, domain: int) -> dict[str, str]:
    """The environment of a node (or driver) process in ROS domain ``domain``, its ROS home ``home``."""
    return {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'ROS_DOMAIN_ID': str(domain),
            'ROS_HOME': str(home), 'ROS_LOG_DIR': str(home / 'log'), 'RCUTILS_COLORIZED_OUTPUT': '0'}


def start(kind: str, params: Path, env: dict[str, str], log: Path) -> subprocess.Popen:
    """The node under test in its own process (and session)."""
    if kind == 'relay':
        command = [sys.executable, str(Path(__file__).resolve()), 'relay', '--ros-args']
    else:
        command = [sys.executable, '-m', 'tak_thermo_ros.ros.main', '--ros-args', '--params-file', str(params),
                   '-p', 'qos:=reliable', '-p', f'qos_depth:={DEPTH}',
                   '-p', 'executor:=single_threaded']  # the relay's rclpy.spin: the same executor
    return subprocess.Popen(command, env=env, stdout=open(log, 'wb'), stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL, start_new_session=True)


def percentile(values: list[int], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(q / 100.0 * (len(ordered) - 1))))] / 1000.0


class Subject:
    """One node under test: its process and the driver talking to it (own domain)."""

    def __init__(self, kind: str, params: Path, env: dict[str, str], workdir: Path) -> None:
        self.kind = kind
        self.process = start(kind, params, env, workdir / f'{kind}.log')
        self.driver = Driver(int(env['ROS_DOMAIN_ID']), f'bench_driver_{kind}')
        self.rates: list[float] = []
        self.capacities: list[float] = []
        self.latencies: list[int] = []
        self.lost = 0
        self.soak: dict | None = None

    def warm_up(self) -> None:
        self.driver.warm_up()
        self.driver.closed_loop(5_000)

    def throughput_round(self, count: int) -> None:
        cpu_before = cpu_s(self.process.pid)
        self.rates.append(self.driver.closed_loop(count))
        self.capacities.append(count / max(cpu_s(self.process.pid) - cpu_before, 1e-9))

    def latency_chunk(self, count: int) -> None:
        self.latencies += self.driver.paced(count, 1000.0)
        self.lost += self.driver.lost

    def run_soak(self, count: int) -> None:
        pid = self.process.pid
        rss_start = rss_kb(pid)
        samples = [(0, rss_start)]
        rate = self.driver.closed_loop(count, lambda k: samples.append((k, rss_kb(pid))))
        samples.append((count, rss_kb(pid)))
        self.soak = {'messages': count, 'rate_msgs_per_s': rate, 'rss_start_kb': rss_start,
                     'rss_end_kb': samples[-1][1], 'rss_growth_kb': samples[-1][1] - rss_start,
                     'rss_max_kb': max(kb for _, kb in samples), 'rss_samples_kb': samples}

    def close(self) -> int:
        try:
            self.driver.close()
        finally:
            code = stop(self.process)
        return code

    def summary(self) -> dict:
        latencies = self.latencies
        result = {
            'throughput_msgs_per_s': statistics.median(self.rates), 'throughput_rounds': self.rates,
            'capacity_msgs_per_cpu_s': statistics.median(self.capacities), 'capacity_rounds': self.capacities,
            'latency_us': {'p50': percentile(latencies, 50), 'p90': percentile(latencies, 90),
                           'p99': percentile(latencies, 99), 'max': max(latencies) / 1000.0,
                           'mean': statistics.fmean(latencies) / 1000.0, 'count': len(latencies),
                           'lost': self.lost},
        }
        if self.soak is not None:
            result['soak'] = self.soak
        return result


def measure(params: Path, workdir: Path, *, throughput_count: int, latency_count: int, rounds: int,
            soak_count: int) -> tuple[dict, dict]:
    """Relay and compensator side by side (own domains), rounds interleaved, then the soak."""
    home = workdir / 'ros_home'
    home.mkdir(exist_ok=True)
    subjects = []
    try:
        for index, kind in enumerate(('relay', 'compensator')):
            env = node_env(home, bench_domain(index))
            subjects.append(Subject(kind, params, env, workdir))
        for subject in subjects:
            subject.warm_up()
        for _ in range(rounds):
            for subject in subjects:
                subject.throughput_round(throughput_count)
        chunks = 4
        for _ in range(chunks):
            for subject in subjects:
                subject.latency_chunk(latency_count // chunks)
        subjects[1].run_soak(soak_count)
    finally:
        codes = [subject.close() for subject in subjects]
    relay, compensator = (subject.summary() for subject in subjects)
    relay['exit_code'], compensator['exit_code'] = codes
    return relay, compensator


def per_message_us(paths, count: int, repeats: int = 3) -> dict[str, float]:
    """Name -> microseconds per message of each ``(name, function)``: the best of ``repeats`` calls of ``count``."""
    timings = {}
    for name, path in paths:
        best = float('inf')
        for _ in range(repeats):
            started = time.perf_counter()
            path()
            best = min(best, time.perf_counter() - started)
        timings[name] = best / count * 1e6
    return timings


def in_process_cost(params: Path, count: int = 200_000) -> dict:
    """Microseconds per message of the node's own work, without DDS: core + message fill."""
    from geometry_msgs.msg import Vector3Stamped
    from sensor_msgs.msg import Imu

    from tak_thermo_ros.formats.calibration_file import load_calibration
    from tak_thermo_ros.core.link.online import OnlineCompensator
    core = OnlineCompensator(load_calibration(params))
    core.process_temperature(8300.0, 0.0)
    message = Vector3Stamped()
    message.vector.x, message.vector.y, message.vector.z = 100.0, -200.0, 2500.0
    imu = Imu()
    acceleration = imu.linear_acceleration
    process = core.process_counts

    def compensator_path() -> None:
        for k in range(count):
            stamp = message.header.stamp
            vector = message.vector
            result = process(stamp.sec, k, vector.x, vector.y, vector.z, 0.5)
            if result.__class__ is tuple:
                imu.header = message.header
                acceleration.x, acceleration.y, acceleration.z = result
            if core.notices:
                core.take_notices()

    def relay_path() -> None:
        for _ in range(count):
            imu.header = message.header
            vector = message.vector
            acceleration.x, acceleration.y, acceleration.z = vector.x, vector.y, vector.z

    timings = per_message_us((('relay_callback_us', relay_path), ('compensator_callback_us', compensator_path)),
                             count)
    timings['added_us'] = timings['compensator_callback_us'] - timings['relay_callback_us']
    profiler = cProfile.Profile()
    profiler.runcall(compensator_path)
    text = io.StringIO()
    pstats.Stats(profiler, stream=text).sort_stats('tottime').print_stats(6)
    timings['profile_top'] = [line.strip() for line in text.getvalue().splitlines()
                              if line.strip() and ('{' in line or '.py' in line)][:6]
    return timings


DRIVER_RATES_HZ = (250.0, 500.0, 1000.0, 1500.0, 2000.0)
DRIVER_SECONDS = 4.0


class ImuDriver:
    """Publishes driver Imu and temperatures (degrees C) at a fixed rate, receives the output."""

    def __init__(self, domain: int, name: str) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.experimental import EventsExecutor
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import Imu, Temperature
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DEPTH, reliability=ReliabilityPolicy.RELIABLE)
        self.imu_publisher = self.node.create_publisher(Imu, 'imu/data_raw', qos)
        self.temp_publisher = self.node.create_publisher(Temperature, 'imu/temperature', qos)
        self.subscription = self.node.create_subscription(Imu, 'imu/data_compensated', self._on_imu, qos)
        self.imu = Imu()
        self.imu.header.frame_id = 'imu_link'
        self.imu.orientation.w = 1.0
        self.temperature = Temperature()
        self.received = 0
        self.last_stamp_ns = 0

    def _on_imu(self, message) -> None:
        self.received += 1

    def publish(self, k: int) -> None:
        stamp_ns = max(time.time_ns(), self.last_stamp_ns + 1)  # strictly increasing: none dropped as backwards
        self.last_stamp_ns = stamp_ns
        sec, nanosec = divmod(stamp_ns, NANOSECONDS)
        if k % TEMP_EVERY == 0:
            self.temperature.header.stamp.sec, self.temperature.header.stamp.nanosec = sec, nanosec
            self.temperature.temperature = 20.0 + (k // TEMP_EVERY) % 10 * 0.5
            self.temp_publisher.publish(self.temperature)
        self.imu.header.stamp.sec, self.imu.header.stamp.nanosec = sec, nanosec
        a, w = self.imu.linear_acceleration, self.imu.angular_velocity
        a.x, a.y, a.z = 0.01 * (k % 100), -0.2, 9.81
        w.x, w.y, w.z = 0.001 * (k % 50), 0.02, -0.03
        self.imu_publisher.publish(self.imu)

    def spin_until(self, condition, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > deadline:
                raise RuntimeError('timed out')
            self.executor.spin_once(timeout_sec=0.01)

    def warm_up(self) -> None:
        """Until the node answers; then drain."""
        self.spin_until(lambda: (self.imu_publisher.get_subscription_count() >= 1
                                 and self.temp_publisher.get_subscription_count() >= 1
                                 and self.subscription.get_publisher_count() >= 1), 30.0)
        deadline = time.monotonic() + 30.0
        k = 0
        while self.received == 0:
            if time.monotonic() > deadline:
                raise RuntimeError('the node never answered')
            self.publish(k * TEMP_EVERY)  # a temperature with each
            k += 1
            end = time.monotonic() + 0.2
            while self.received == 0 and time.monotonic() < end:
                self.executor.spin_once(timeout_sec=0.01)
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.05)

    def paced(self, rate_hz: float, count: int) -> tuple[int, float]:
        """Send ``count`` messages at ``rate_hz`` (open loop); (received, achieved send rate)."""
        self.received = 0
        period_ns = int(NANOSECONDS / rate_hz)
        spin_once = self.executor.spin_once
        started = time.monotonic_ns()
        next_ns = started
        for k in range(count):
            while True:
                wait = next_ns - time.monotonic_ns()
                if wait <= 0:
                    break
                spin_once(timeout_sec=wait / NANOSECONDS)
            self.publish(k)
            next_ns += period_ns
        achieved = count / ((time.monotonic_ns() - started) / NANOSECONDS)
        last, idle_since = self.received, time.monotonic()
        while self.received < count and time.monotonic() - idle_since < 2.0:
            spin_once(timeout_sec=0.05)
            if self.received != last:
                last, idle_since = self.received, time.monotonic()
        return self.received, achieved

    def close(self) -> None:
        import rclpy
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def paced_row(driver: ImuDriver, pid: int, rate: float, count: int) -> dict:
    """``count`` Imu sent at ``rate`` Hz to the node process ``pid``: what it received and the CPU it took."""
    cpu_before = cpu_s(pid)
    received, achieved = driver.paced(rate, count)
    cpu = cpu_s(pid) - cpu_before
    return {'rate_hz': rate, 'sent': count, 'achieved_send_rate_hz': achieved, 'received': received,
            'lost': count - received, 'cpu_us_per_message': cpu / max(received, 1) * 1e6,
            'cpu_fraction': cpu / (count / achieved)}


def measure_driver_input(params: Path, workdir: Path, *, rates: tuple[float, ...], seconds: float,
                         baseline: Path | None = None) -> dict:
    """Relay and compensator (and the baseline's compensator) on each executor, open loop at each rate.

    Per executor the nodes run side by side (own domains), each driven in turn at each rate, so
    that a change in the machine's load hits all of them: messages lost and CPU per message.
    """
    home = workdir / 'ros_home'
    home.mkdir(exist_ok=True)
    kinds = ('relay', 'compensator', *(('baseline',) if baseline is not None else ()))
    results: dict = {}
    for executor_index, executor in enumerate(('events', 'single_threaded')):
        processes, drivers, rows = {}, {}, {kind: [] for kind in kinds}
        try:
            for subject_index, kind in enumerate(kinds):
                env = node_env(home, bench_domain(2 + 3 * executor_index + subject_index))
                node_arguments = ['--ros-args', '--params-file', str(params), '-p', 'qos:=reliable',
                                  '-p', f'qos_depth:={DEPTH}', '-p', f'executor:={executor}']
                if kind == 'relay':
                    command = [sys.executable, str(Path(__file__).resolve()), 'driver_relay', executor, '--ros-args']
                elif kind == 'compensator':
                    command = [sys.executable, '-m', 'tak_thermo_ros.ros.main', *node_arguments]
                else:
                    command = [*baseline_node_command(baseline), *node_arguments]
                log = workdir / f'driver_{executor}_{kind}.log'
                processes[kind] = subprocess.Popen(command, env=env, stdout=open(log, 'wb'), stderr=subprocess.STDOUT,
                                                   stdin=subprocess.DEVNULL, start_new_session=True)
                drivers[kind] = ImuDriver(int(env['ROS_DOMAIN_ID']), f'bench_imu_driver_{kind}')
                drivers[kind].warm_up()
            for rate in rates:
                count = int(rate * seconds)
                for kind in kinds:
                    row = paced_row(drivers[kind], processes[kind].pid, rate, count)
                    rows[kind].append(row)
                    print(f'  driver input, {executor:15s} {kind:11s} {rate:6.0f} Hz '
                          f'(sent at {row["achieved_send_rate_hz"]:6.0f}): {row["lost"]:5d} of {count} lost, '
                          f'{row["cpu_us_per_message"]:6.0f} us CPU per message', flush=True)
        finally:
            codes = close_all(kinds, drivers, processes)
        for kind in kinds:
            without_loss = [row['rate_hz'] for row in rows[kind] if row['lost'] == 0]
            results.setdefault(executor, {})[kind] = {
                'rates': rows[kind], 'exit_code': codes.get(kind),
                'sustained_rate_without_loss_hz': max(without_loss) if without_loss else 0.0,
                'cpu_us_per_message_at_1khz': next((r['cpu_us_per_message'] for r in rows[kind]
                                                    if r['rate_hz'] == 1000.0), None)}
        pair = results[executor]
        pair['added_cpu_us_per_message_at_1khz'] = (
            pair['compensator']['cpu_us_per_message_at_1khz'] - pair['relay']['cpu_us_per_message_at_1khz']
            if pair['relay']['cpu_us_per_message_at_1khz'] is not None else None)
        if baseline is not None:  # at the rates where neither lost anything (loss inflates the CPU per message)
            ratios = [c['cpu_us_per_message'] / b['cpu_us_per_message']
                      for c, b in zip(pair['compensator']['rates'], pair['baseline']['rates'])
                      if c['lost'] == 0 and b['lost'] == 0]
            pair['cpu_ratio_to_baseline_without_loss'] = ratios
            pair['cpu_ratio_to_baseline_median'] = statistics.median(ratios) if ratios else None
    return results


BASELINE_MAIN = 'import sys; sys.path.insert(0, {!r}); from tak_thermo_ros.ros.main import main; sys.exit(main())'
"""The compensator of another version of the package (``--baseline DIR``: a tree holding ``tak_thermo_ros/``)."""


def baseline_node_command(baseline: Path) -> list[str]:
    """The command line running the node of the package under ``baseline`` (its ``ros.main.main``)."""
    return [sys.executable, '-c', BASELINE_MAIN.format(str(baseline.resolve()))]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--quick', action='store_true', help='small counts (a smoke run, not the figures)')
    parser.add_argument('--driver-only', action='store_true',
                        help='only the driver-input part (both executors, rates up to 2 kHz); updates node.json')
    parser.add_argument('--baseline', type=Path, metavar='DIR',
                        help='with --driver-only: also drive the compensator of another version of the package '
                             '(DIR holds its tak_thermo_ros/, e.g. `git archive main | tar -x -C DIR`), in turn '
                             'with this one at each rate')
    parser.add_argument('--watch', action='store_true',
                        help="only the calibration watch's cost: the node with it on against off, in one run "
                             '(callback and process CPU per message); updates node.json')
    parser.add_argument('--pipeline', action='store_true',
                        help="with --baseline: only the Imu callback against the baseline's (issue 35's one "
                             'pipeline); updates node.json')
    parser.add_argument('--marks', action='store_true',
                        help="with --baseline: only the real node's Imu callback, this version against the "
                             "baseline's (the cost of honouring an absent sensor's mark); updates node.json")
    parser.add_argument('--rates', action='store_true',
                        help='only the relay, the decoded node and the raw node at 1, 2, 4 and 8 kHz, counts and '
                             'driver input, in one run (issue 42); updates node.json')
    args = parser.parse_args()
    if args.rates:
        return rates_only(quick=args.quick)
    if args.watch:
        return watch_only(quick=args.quick)
    if args.pipeline:
        if args.baseline is None:
            parser.error('--pipeline needs --baseline DIR')
        return pipeline_only(args.baseline)
    if args.marks:
        if args.baseline is None:
            parser.error('--marks needs --baseline DIR')
        return marks_only(args.baseline)
    if args.driver_only:
        return driver_only(quick=args.quick, baseline=args.baseline)
    throughput_count = 5_000 if args.quick else 10_000
    latency_count = 2_000 if args.quick else 10_000
    soak_count = 20_000 if args.quick else 1_000_000
    rounds = 2 if args.quick else 10

    from tak_thermo_ros.formats.calibration_file import save_calibration
    from tak_thermo_ros.core.simulation.scenario import Scenario

    with tempfile.TemporaryDirectory(prefix='bench_node_') as tmp:
        workdir = Path(tmp)
        params = workdir / 'params.yaml'
        save_calibration(params, Scenario().truth())
        os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_HOME=str(workdir / 'ros_home'),
                          ROS_LOG_DIR=str(workdir / 'ros_home' / 'log'))
        started = time.time()
        relay, compensator = measure(params, workdir, throughput_count=throughput_count,
                                     latency_count=latency_count, rounds=rounds, soak_count=soak_count)
        driver_file = workdir / 'driver_params.yaml'
        driver_params(driver_file)
        driver_input = measure_driver_input(driver_file, workdir,
                                            rates=(500.0, 2000.0) if args.quick else DRIVER_RATES_HZ,
                                            seconds=1.0 if args.quick else DRIVER_SECONDS)
        for name, result in (('relay', relay), ('compensator', compensator)):
            print(f'{name:12s} {result["throughput_msgs_per_s"]:8.0f} msg/s closed loop, '
                  f'{result["capacity_msgs_per_cpu_s"]:8.0f} msg/CPU-s, latency at 1 kHz p50 '
                  f'{result["latency_us"]["p50"]:.0f} us p99 {result["latency_us"]["p99"]:.0f} us '
                  f'({result["latency_us"]["lost"]} lost)', flush=True)
        cost = in_process_cost(params)
        figures = {
            # Median over the rounds of the ratio within a round (the two ran back to back).
            'throughput_ratio': statistics.median(
                c / r for c, r in zip(compensator['throughput_rounds'], relay['throughput_rounds'])),
            'capacity_ratio': statistics.median(
                c / r for c, r in zip(compensator['capacity_rounds'], relay['capacity_rounds'])),
            'added_latency_p50_us': compensator['latency_us']['p50'] - relay['latency_us']['p50'],
            'added_latency_p99_us': compensator['latency_us']['p99'] - relay['latency_us']['p99'],
            'soak_rss_growth_mb': compensator['soak']['rss_growth_kb'] / 1024.0,
            'soak_messages': compensator['soak']['messages'],
            'in_process_added_us_per_message': cost['added_us'],
        }
        document = {'quick': args.quick, 'cpus': os.cpu_count(), 'python': sys.version.split()[0],
                    'wall_s': time.time() - started, 'window': WINDOW, 'depth': DEPTH,
                    'temp_code_every': TEMP_EVERY, 'figures': figures, 'relay': relay,
                    'compensator': compensator, 'in_process': cost, 'driver_input': driver_input,
                    'targets': {'throughput_ratio': '>= 0.9', 'added_latency_p99_us': '<= 50',
                                'soak_rss_growth_mb': '< 10'}}
    results = RESULTS.with_name('node_quick.json') if args.quick else RESULTS
    results.parent.mkdir(parents=True, exist_ok=True)
    results.write_text(json.dumps(document, indent=2) + '\n', encoding='utf-8')
    print(f'throughput ratio {figures["throughput_ratio"]:.3f} (closed loop), capacity ratio '
          f'{figures["capacity_ratio"]:.3f} (messages per node CPU second); target >= 0.9')
    print(f'added latency at 1 kHz: p50 {figures["added_latency_p50_us"]:+.1f} us, p99 '
          f'{figures["added_latency_p99_us"]:+.1f} us (target <= 50 us); node work in-process '
          f'{cost["compensator_callback_us"]:.2f} us vs relay {cost["relay_callback_us"]:.2f} us per message')
    soak = compensator['soak']
    print(f'soak: {soak["messages"]} messages at {soak["rate_msgs_per_s"]:.0f} msg/s, RSS '
          f'{soak["rss_start_kb"] / 1024:.1f} -> {soak["rss_end_kb"] / 1024:.1f} MB '
          f'(growth {figures["soak_rss_growth_mb"]:+.2f} MB, target < 10)')
    print(f'wrote {results}')
    missed = [name for name, held in (
        ('throughput ratio >= 0.9', figures['throughput_ratio'] >= 0.9),
        ('added latency p99 <= 50 us', figures['added_latency_p99_us'] <= 50.0),
        ('soak RSS growth < 10 MB', figures['soak_rss_growth_mb'] < 10.0)) if not held]
    if missed:
        print(f'target missed: {"; ".join(missed)}')
        return TARGET_MISSED
    return 0


TRANSPORT_BURST = 20_000


def measure_transport_loss(params: Path, workdir: Path, *, count: int = TRANSPORT_BURST) -> list[dict]:
    """``count`` driver Imu as fast as this process publishes them into the compensator, per executor and input QoS.

    What the node received, what Fast DDS reported lost (``message_lost``), what is left unaccounted by that (``sent -
    received - message_lost``), and the messages never received by the sequence numbers (``sequence_gap``). One more
    Imu follows the burst once the node has settled, so that a loss at the burst's tail shows too (a gap is seen
    when a later message arrives): ``received + sequence_gap`` is then ``sent`` + 1.
    """
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    rows = []
    home = workdir / 'ros_home'
    home.mkdir(exist_ok=True)
    for index, (executor, qos) in enumerate((('events', 'reliable'), ('events', 'sensor_data'),
                                             ('single_threaded', 'reliable'), ('single_threaded', 'sensor_data'))):
        env = node_env(home, bench_domain(8 + index))
        command = [sys.executable, '-m', 'tak_thermo_ros.ros.main', '--ros-args', '--params-file', str(params),
                   '-p', f'qos:={qos}', '-p', f'qos_depth:={DEPTH}', '-p', f'executor:={executor}']
        log = workdir / f'loss_{executor}_{qos}.log'
        process = subprocess.Popen(command, env=env, stdout=open(log, 'wb'), stderr=subprocess.STDOUT,
                                   stdin=subprocess.DEVNULL, start_new_session=True)
        driver = ImuDriver(int(env['ROS_DOMAIN_ID']), 'bench_loss_driver')
        try:
            from diagnostic_msgs.msg import DiagnosticArray
            statuses: list = []
            driver.node.create_subscription(DiagnosticArray, '/diagnostics', statuses.append, 10)
            if qos == 'sensor_data':  # a best-effort driver, as REP 2003 drivers publish
                best_effort = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DEPTH,
                                         reliability=ReliabilityPolicy.BEST_EFFORT)
                driver.node.destroy_publisher(driver.imu_publisher)
                from sensor_msgs.msg import Imu
                driver.imu_publisher = driver.node.create_publisher(Imu, 'imu/data_raw', best_effort)
            driver.warm_up()

            def latest() -> dict:
                return {pair.key: pair.value for pair in statuses[-1].status[0].values}

            statuses.clear()
            driver.spin_until(lambda: len(statuses) >= 2, 10.0)  # a status after the warm-up
            before = latest()
            started = time.perf_counter()
            for k in range(1, count + 1):
                driver.publish(k)
            rate = count / (time.perf_counter() - started)
            settled(driver, statuses, latest)
            driver.publish(count + 1)  # the tail's losses show when a later message arrives
            settled(driver, statuses, latest)
            after = latest()
            keys = ('received', 'published', 'dropped', 'message_lost')
            values = {key: int(after[key]) - int(before[key]) for key in keys}
            values['sequence_gap'] = (None if after['sequence_gap'] == 'unavailable'
                                      else int(after['sequence_gap']) - int(before['sequence_gap']))
        finally:
            driver.close()
            stop(process)
        received = values['received']
        sent = count + 1  # the burst and the message after it
        row = {'executor': executor, 'qos': qos, 'depth': DEPTH, 'sent': sent, 'send_rate_hz': rate,
               'received_by_node': received, 'published': values['published'], 'dropped': values['dropped'],
               'message_lost_reported': values['message_lost'], 'sequence_gap': values['sequence_gap'],
               'unaccounted': sent - received - values['message_lost'],
               'received_plus_sequence_gap': (received + values['sequence_gap']
                                              if values['sequence_gap'] is not None else None)}
        rows.append(row)
        print(f'  burst of {count} at {rate:.0f} Hz (and one more), {executor:15s} {qos:11s}: node received '
              f'{received}, message_lost {row["message_lost_reported"]}, unaccounted by it {row["unaccounted"]}, '
              f'sequence_gap {row["sequence_gap"]}: received + sequence_gap = {row["received_plus_sequence_gap"]} '
              f'of {sent}', flush=True)
    return rows


def settled(driver: ImuDriver, statuses: list, latest, timeout: float = 30.0) -> None:
    """Spin until two statuses in a row, after a fresh one, show the node's counters unchanged."""
    seen = len(statuses)
    last = None
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        driver.executor.spin_once(timeout_sec=0.05)
        if len(statuses) > seen:
            seen = len(statuses)
            now = latest()
            if last is not None and now['received'] == last['received']:
                return
            last = now


def in_process_driver_cost(params: Path, count: int = 50_000, *, with_sequence: bool = True) -> dict:
    """Microseconds per message of the driver-input callback's own work, without DDS.

    The six values out of an Imu, ``process_values``, the corrected Imu filled (as ``_on_imu``);
    ``driver_callback_us`` with, ``without_sequence_us`` without, what the node's
    ``_with_sequence`` adds before it (the ``(message, info)`` pair the EventsExecutor hands over
    unpacked, the publication sequence number counted).
    """
    from sensor_msgs.msg import Imu

    from tak_thermo_ros.formats.calibration_file import load_unit
    from tak_thermo_ros.core.link.online import OnlineCompensator
    core = OnlineCompensator(load_unit(params))
    core.process_temperature(21.0, 0.0)
    message = Imu()
    message.linear_acceleration.z = 9.81
    message.angular_velocity.x = 0.01
    out = Imu()
    acceleration, rate = out.linear_acceleration, out.angular_velocity
    process = core.process_values
    sequence = core.sequence
    # A version that honours an absent sensor's mark reads the two covariance[0] too, as its node does.
    marks = 'accel_mark' in inspect.signature(process).parameters

    def on_imu(message: Imu, k: int) -> None:
        header = message.header
        stamp = header.stamp
        a = message.linear_acceleration
        w = message.angular_velocity
        if marks:
            result = process(stamp.sec, k, (a.x, a.y, a.z, w.x, w.y, w.z), 0.5,
                             message.linear_acceleration_covariance[0], message.angular_velocity_covariance[0])
        else:
            result = process(stamp.sec, k, (a.x, a.y, a.z, w.x, w.y, w.z), 0.5)
        if result.__class__ is tuple:
            out.header = header
            out.orientation = message.orientation
            out.orientation_covariance = message.orientation_covariance
            acceleration.x, acceleration.y, acceleration.z, rate.x, rate.y, rate.z = result
        if core.notices:
            core.take_notices()

    def with_sequence(pair: tuple, info: dict | None = None) -> None:
        if info is None:
            pair, info = pair
        number = info.get('publication_sequence_number')
        if number is not None:
            sequence('imu', number, 0.5)
        on_imu(pair, number)

    def compensator_path() -> None:
        for k in range(count):
            with_sequence((message, {'publication_sequence_number': k + 1}))

    def without_sequence() -> None:
        for k in range(count):
            on_imu(message, k + 1)

    paths = (('driver_callback_us', compensator_path), ('without_sequence_us', without_sequence))
    timings = per_message_us(paths if with_sequence else paths[1:], count)
    if not with_sequence:
        return {**timings, 'messages': count}
    return {**timings, 'sequence_us': timings['driver_callback_us'] - timings['without_sequence_us'],
            'messages': count}


IN_PROCESS_ROUNDS = 15


def taking_turns(baseline: Path, rounds: int, call, environment: dict[str, str] | None = None) -> dict[str, list[dict]]:
    """Run a function of this module in fresh interpreters, this version and the baseline's taking turns.

    :param call: ``name -> 'function(arguments)'`` (``name`` is ``'this'`` or ``'baseline'``), the
        expression evaluated in ``bench_node`` imported with that version of the package first on
        ``sys.path``; it gives a JSON-serialisable result.
    :returns: ``{'this': [...], 'baseline': [...]}``, one result per round each.
    """
    runs: dict[str, list[dict]] = {'this': [], 'baseline': []}
    for _ in range(rounds):
        for name, tree in (('this', REPO), ('baseline', baseline.resolve())):
            code = (f'import sys, json; sys.path.insert(0, {str(tree)!r}); '
                    f'sys.path.insert(1, {str(Path(__file__).parent)!r}); '
                    f'import bench_node; print(json.dumps(bench_node.{call(name)}))')
            result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True,
                                    env=environment)
            runs[name].append(json.loads(result.stdout.strip().splitlines()[-1]))
    return runs


def in_process_against_baseline(params: Path, baseline: Path, rounds: int = IN_PROCESS_ROUNDS) -> dict:
    """The callback's own work in this version and in the baseline's, fresh interpreters taking turns.

    Both without the sequence-number wrapper (the baseline's EventsExecutor path had none), then
    this version's whole path; the ratio is the median of the per-round ratios.
    """
    runs = taking_turns(baseline, rounds, lambda name: f'in_process_driver_cost(bench_node.Path({str(params)!r}), '
                                                       f'20_000, with_sequence={name == "this"})')
    ratios = [t['without_sequence_us'] / b['without_sequence_us'] for t, b in zip(runs['this'], runs['baseline'])]
    return {'rounds': rounds, 'runs': runs,
            'this_without_sequence_us_best': min(r['without_sequence_us'] for r in runs['this']),
            'baseline_us_best': min(r['without_sequence_us'] for r in runs['baseline']),
            'this_with_sequence_us_best': min(r['driver_callback_us'] for r in runs['this']),
            'this_without_sequence_us_median': statistics.median(r['without_sequence_us'] for r in runs['this']),
            'baseline_us_median': statistics.median(r['without_sequence_us'] for r in runs['baseline']),
            'this_with_sequence_us_median': statistics.median(r['driver_callback_us'] for r in runs['this']),
            'ratio_without_sequence_median': statistics.median(ratios),
            'ratio_with_sequence_median': statistics.median(
                t['driver_callback_us'] / b['without_sequence_us'] for t, b in zip(runs['this'], runs['baseline']))}


CALLBACK_ROUNDS = 21


def node_callback_cost(params: Path, count: int = 5_000, repeats: int = 30) -> dict:
    """Microseconds per message of the real node's Imu callback (``CompensatorNode._on_imu``), without DDS.

    rclpy is initialised on a benchmark domain, the node built from ``params`` (any version of the
    package that is first on ``sys.path``), its Imu publish replaced by a no-op (the middleware's
    share is the same for every version), and the callback called directly with a two-sensor Imu
    whose stamp goes on by 1 us: the best of ``repeats`` short runs of ``count`` (on a shared
    machine the best of many short runs is the one least disturbed). Where the version
    honours the marks of an absent sensor (``core.link.online_rules.OneSensor``), also the callback on
    messages that carry one sensor each, alternately the accelerometer and the gyroscope.
    """
    import rclpy
    from sensor_msgs.msg import Imu, Temperature

    from tak_thermo_ros.ros.node import CompensatorNode
    try:
        from tak_thermo_ros.core.link.online_rules import OneSensor  # noqa: F401 - this version's one-sensor path
        marks = True
    except ImportError:
        try:  # a baseline from before the input rules had a module of their own
            from tak_thermo_ros.core.link.online import OneSensor  # noqa: F401, F811
            marks = True
        except ImportError:
            marks = False
    context = rclpy.context.Context()
    rclpy.init(args=['--ros-args', '--params-file', str(params), '-p', 'temp_timeout:=1000.0'], context=context,
               domain_id=bench_domain(7))
    node = CompensatorNode(context=context)
    node._publish_imu = lambda message: None  # noqa: SLF001 - the callback alone, not the middleware
    temperature = Temperature()
    temperature.temperature = 21.0
    node._on_temperature(temperature)  # noqa: SLF001
    on_imu = node._on_imu  # noqa: SLF001

    def messages(one_sensor: bool) -> list:
        out = []
        for sensor in range(2):
            message = Imu()
            message.linear_acceleration.z = 9.81
            message.angular_velocity.x = 0.01
            if one_sensor:
                covariance = message.angular_velocity_covariance if sensor == 0 else \
                    message.linear_acceleration_covariance
                covariance[0] = -1.0
            out.append(message)
        return out

    second = [1_700_000_000]

    def run(pair: list) -> None:
        second[0] += 1
        for message in pair:
            message.header.stamp.sec = second[0]
        for k in range(count):
            message = pair[k & 1]
            message.header.stamp.nanosec = k * 1000
            on_imu(message)

    timings = per_message_us((('two_sensor_us', lambda: run(messages(False))),), count, repeats)
    if marks:
        timings.update(per_message_us((('one_sensor_us', lambda: run(messages(True))),), count, repeats))
    status = node._core.status(0.0)  # noqa: SLF001
    timings['published'] = int(status.value('published'))
    timings['received'] = int(status.value('received'))
    node.destroy_node()
    rclpy.shutdown(context=context)
    return {**timings, 'messages': count, 'marks': marks}


def callback_against_baseline(params: Path, baseline: Path, rounds: int = CALLBACK_ROUNDS) -> dict:
    """:func:`node_callback_cost` of this version and the baseline's, fresh interpreters taking turns.

    The ratio is the median of the per-round ratios (a change in the machine's load hits both).
    """
    environment = {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    with tempfile.TemporaryDirectory(prefix='bench_node_callback_') as home:
        environment.update(ROS_HOME=home, ROS_LOG_DIR=str(Path(home) / 'log'))
        runs = taking_turns(baseline, rounds, lambda name: f'node_callback_cost(bench_node.Path({str(params)!r}))',
                            environment)
    ratios = [t['two_sensor_us'] / b['two_sensor_us'] for t, b in zip(runs['this'], runs['baseline'])]
    return {'rounds': rounds, 'runs': runs,
            'this_two_sensor_us_best': min(r['two_sensor_us'] for r in runs['this']),
            'baseline_two_sensor_us_best': min(r['two_sensor_us'] for r in runs['baseline']),
            'this_two_sensor_us_median': statistics.median(r['two_sensor_us'] for r in runs['this']),
            'baseline_two_sensor_us_median': statistics.median(r['two_sensor_us'] for r in runs['baseline']),
            'this_one_sensor_us_median': statistics.median(r['one_sensor_us'] for r in runs['this']),
            'ratio_median': statistics.median(ratios), 'ratios': ratios}


def _callback_run(baseline: Path, rounds: int, key: str) -> dict:
    """The callback's cost against the baseline's, merged into ``node.json`` under ``key``."""
    with tempfile.TemporaryDirectory(prefix=f'bench_node_{key}_') as tmp:
        params = Path(tmp) / 'driver_params.yaml'
        driver_params(params)
        load = os.getloadavg()[0]
        started = time.time()
        result = callback_against_baseline(params, baseline, rounds)
    result.update(baseline=str(baseline), wall_s=time.time() - started, load_average_1min_before=load,
                  load_average_1min_after=os.getloadavg()[0])
    document = json.loads(RESULTS.read_text(encoding='utf-8')) if RESULTS.exists() else {}
    document[key] = result
    RESULTS.write_text(json.dumps(document, indent=2) + '\n', encoding='utf-8')
    return result


def marks_only(baseline: Path, rounds: int = CALLBACK_ROUNDS) -> int:
    """The callback's cost against the baseline's (``--marks``); merged into ``node.json`` as ``one_sensor_marks``."""
    result = _callback_run(baseline, rounds, 'one_sensor_marks')
    print(f'two-sensor Imu callback: {result["this_two_sensor_us_median"]:.2f} us (best '
          f'{result["this_two_sensor_us_best"]:.2f}) against {result["baseline_two_sensor_us_median"]:.2f} us '
          f'(best {result["baseline_two_sensor_us_best"]:.2f}) before, medians of {rounds} rounds; '
          f'ratio {result["ratio_median"]:.3f} (median of the per-round ratios)')
    print(f'one-sensor Imu callback: {result["this_one_sensor_us_median"]:.2f} us (median)')
    print(f'wrote {RESULTS}')
    return 0


WATCH_ROUNDS = 15
WATCH_RATES_HZ = (500.0, 1000.0, 2000.0)
WATCH_SECONDS = 4.0


def watch_params(path: Path) -> None:
    """The simulator's driver unit with its noise models: a calibration the watch runs on."""
    from dataclasses import replace
    from tak_thermo_ros.formats.calibration_file import save_unit
    from tak_thermo_ros.core.simulation.scenario import Scenario
    scenario = Scenario(output='imu')
    unit = scenario.driver_truth()
    save_unit(path, replace(unit, accel=replace(unit.accel, noise=scenario.noise_truth('accel')),
                            gyro=replace(unit.gyro, noise=scenario.noise_truth('gyro'))))


def watch_callback_cost(params: Path, count: int = 5_000, rounds: int = WATCH_ROUNDS, repeats: int = 5) -> dict:
    """Microseconds per message of the real node's Imu callback with the watch on and off, rounds interleaved.

    Two nodes in this process (their own contexts): ``watch: true`` and ``watch: false`` on the same
    calibration, publish stubbed (the middleware's share is the same), each called directly with a
    two-sensor Imu at 1 kHz stamps (the watch closes a window every 500 messages); per round the
    best of ``repeats`` runs of ``count`` each, alternately; the ratio is the median of the
    per-round ratios. The watch's judgement runs in the diagnostics timer, not here: its cost per
    rest is measured apart (``judge_ms_per_rest``, a minute-long rest judged after 31 others).
    """
    import rclpy
    from sensor_msgs.msg import Imu, Temperature

    from tak_thermo_ros.ros.node import CompensatorNode
    nodes, contexts = {}, []
    for index, watch in enumerate(('true', 'false')):
        context = rclpy.context.Context()
        rclpy.init(args=['--ros-args', '--params-file', str(params), '-p', 'temp_timeout:=1000.0',
                         '-p', f'watch:={watch}'], context=context, domain_id=bench_domain(12 + index))
        node = CompensatorNode(context=context)
        node._publish_imu = lambda message: None  # noqa: SLF001 - the callback alone, not the middleware
        temperature = Temperature()
        temperature.temperature = 21.0
        node._on_temperature(temperature)  # noqa: SLF001
        nodes[watch == 'true'] = node
        contexts.append(context)
    assert nodes[True]._core.watch is not None and nodes[False]._core.watch is None  # noqa: SLF001
    message = Imu()
    message.linear_acceleration.z = 9.81
    message.angular_velocity.x = 0.01
    seconds = {True: 1_700_000_000, False: 1_700_000_000}

    def run(watch: bool) -> None:
        on_imu = nodes[watch]._on_imu  # noqa: SLF001
        start = seconds[watch]
        seconds[watch] += count // 1000 + 1  # the next run goes on a second later: no stamp dropped
        stamp = message.header.stamp
        for k in range(count):
            stamp.sec, stamp.nanosec = start + k // 1000, (k % 1000) * 1_000_000
            message.linear_acceleration.x = 1e-3 * (k % 7)  # a little noise: windows judged still, rests found
            on_imu(message)

    on, off, ratios = [], [], []
    for round_index in range(rounds):
        timings = {}
        for watch in ((True, False) if round_index % 2 else (False, True)):  # either goes first in turn
            timings[watch] = per_message_us(((str(watch), lambda: run(watch)),), count, repeats)[str(watch)]
        on.append(timings[True])
        off.append(timings[False])
        ratios.append(timings[True] / timings[False])
    core = nodes[True]._core  # noqa: SLF001
    watch = core.watch
    assert core.dropped_total() == 0 and nodes[False]._core.dropped_total() == 0  # noqa: SLF001
    windows = watch.finder.windows
    judge_ms = judge_cost(watch)
    for node, context in zip(nodes.values(), contexts):
        node.destroy_node()
        rclpy.shutdown(context=context)
    return {'rounds': rounds, 'messages': count, 'watch_on_us': on, 'watch_off_us': off, 'ratios': ratios,
            'watch_on_us_median': statistics.median(on), 'watch_off_us_median': statistics.median(off),
            'ratio_median': statistics.median(ratios), 'windows_closed': windows, 'judge_ms_per_rest': judge_ms}


def judge_cost(watch, rests: int = 32) -> float:
    """Milliseconds to judge one rest once ``rests`` are held (the most a judgement looks at), in the timer."""
    from dataclasses import replace as copy
    from tak_thermo_ros.core.link.rests import Rest
    start = 1_700_000_000 * NANOSECONDS
    template = Rest(index=1, start_ns=start, end_ns=start + 60 * NANOSECONDS, samples=60_000, duration_s=60.0,
                    mean=(0.0, 0.0, 9.81, 0.0, 0.0, 0.0), temperature=21.0, closed_ns=start + 61 * NANOSECONDS)
    from tak_thermo_ros.core.link.watch import CalibrationWatch
    judge = CalibrationWatch(watch.unit)  # a watch of its own: the node's is left as it is
    for index in range(1, rests):
        shift = index * 120 * NANOSECONDS
        judge.pending.append(copy(template, index=index, start_ns=template.start_ns + shift,
                                  end_ns=template.end_ns + shift, closed_ns=template.closed_ns + shift,
                                  temperature=21.0 + 0.1 * index))
    judge.judge()
    shift = rests * 120 * NANOSECONDS
    judge.pending.append(copy(template, index=rests, start_ns=template.start_ns + shift,
                              end_ns=template.end_ns + shift, closed_ns=template.closed_ns + shift))
    started = time.perf_counter()
    judge.judge()
    return (time.perf_counter() - started) * 1e3


def measure_watch_cpu(params: Path, workdir: Path, *, rates: tuple[float, ...], seconds: float,
                      rounds: int = 3) -> dict:
    """The node's CPU per message (the process: middleware, executor, callback) with the watch on and off.

    Two compensators on the same calibration (``watch: true``, ``watch: false``), EventsExecutor,
    side by side in their own domains, driven open loop in turn at each rate, ``rounds`` times:
    a change in the machine's load hits both. The ratio is the median over the rates and rounds
    where neither lost a message.
    """
    home = workdir / 'ros_home'
    home.mkdir(exist_ok=True)
    kinds = {'watch_on': 'true', 'watch_off': 'false'}
    processes, drivers = {}, {}
    rows: dict[str, list] = {kind: [] for kind in kinds}
    try:
        for index, (kind, value) in enumerate(kinds.items()):
            env = node_env(home, bench_domain(20 + index))
            command = [sys.executable, '-m', 'tak_thermo_ros.ros.main', '--ros-args', '--params-file', str(params),
                       '-p', 'qos:=reliable', '-p', f'qos_depth:={DEPTH}', '-p', f'watch:={value}']
            processes[kind] = subprocess.Popen(command, env=env, stdout=open(workdir / f'{kind}.log', 'wb'),
                                               stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                               start_new_session=True)
            drivers[kind] = ImuDriver(int(env['ROS_DOMAIN_ID']), f'bench_watch_{kind}')
            drivers[kind].warm_up()
        for _ in range(rounds):
            for rate in rates:
                count = int(rate * seconds)
                for kind in kinds:
                    row = paced_row(drivers[kind], processes[kind].pid, rate, count)
                    rows[kind].append(row)
                    print(f'  watch CPU, {kind:9s} {rate:6.0f} Hz: {row["lost"]:5d} of {count} lost, '
                          f'{row["cpu_us_per_message"]:6.1f} us CPU per message', flush=True)
    finally:
        for kind in kinds:
            if kind in drivers:
                drivers[kind].close()
            if kind in processes:
                stop(processes[kind])
    ratios = [on['cpu_us_per_message'] / off['cpu_us_per_message']
              for on, off in zip(rows['watch_on'], rows['watch_off']) if on['lost'] == 0 and off['lost'] == 0]
    return {'rates': rows, 'ratios_without_loss': ratios,
            'ratio_median': statistics.median(ratios) if ratios else None}


def watch_only(*, quick: bool) -> int:
    """``--watch``: the node with the watch on against off, in one run; merged into ``node.json`` as ``watch``."""
    with tempfile.TemporaryDirectory(prefix='bench_node_watch_') as tmp:
        workdir = Path(tmp)
        params = workdir / 'watch_params.yaml'
        watch_params(params)
        os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_HOME=str(workdir / 'ros_home'),
                          ROS_LOG_DIR=str(workdir / 'ros_home' / 'log'))
        load = os.getloadavg()[0]
        started = time.time()
        result = {'callback': watch_callback_cost(params, rounds=3 if quick else WATCH_ROUNDS),
                  'process': measure_watch_cpu(params, workdir, rates=(1000.0,) if quick else WATCH_RATES_HZ,
                                               seconds=1.0 if quick else WATCH_SECONDS, rounds=1 if quick else 3)}
    result.update(wall_s=time.time() - started, load_average_1min_before=load,
                  load_average_1min_after=os.getloadavg()[0],
                  target="the node process's CPU per message, watch on / watch off <= 1.10")
    results = RESULTS.with_name('node_quick.json') if quick else RESULTS
    document = json.loads(results.read_text(encoding='utf-8')) if results.exists() else {}
    document['watch'] = result
    results.write_text(json.dumps(document, indent=2) + '\n', encoding='utf-8')
    callback, process = result['callback'], result['process']
    print(f'Imu callback: watch on {callback["watch_on_us_median"]:.2f} us, off {callback["watch_off_us_median"]:.2f} '
          f'us per message (medians of {callback["rounds"]} rounds); ratio {callback["ratio_median"]:.3f}')
    print(f'judging a rest (in the timer, 32 rests held): {callback["judge_ms_per_rest"]:.1f} ms')
    if process['ratio_median'] is not None:
        print(f'node process CPU per message, watch on / off: {process["ratio_median"]:.3f} (median over '
              f'{len(process["ratios_without_loss"])} rate-rounds without loss)')
    print(f'wrote {results}')
    # The target is the node's CPU per message (the process's: what a robot pays); the callback's own
    # share is reported beside it (a Python callback of a few us, where the watch's append shows most).
    if process['ratio_median'] is None or process['ratio_median'] > 1.10:
        print('target missed: the watch costs more than 10 % of the node\'s CPU per message')
        return TARGET_MISSED
    return 0


def pipeline_only(baseline: Path, rounds: int = CALLBACK_ROUNDS) -> int:
    """``--pipeline --baseline DIR``: the Imu callback of this version against another's (one pipeline, issue 35)."""
    result = _callback_run(baseline, rounds, 'one_pipeline')
    print(f'two-sensor Imu callback: {result["this_two_sensor_us_median"]:.2f} us against '
          f'{result["baseline_two_sensor_us_median"]:.2f} us before (medians of {rounds} rounds); ratio '
          f'{result["ratio_median"]:.3f}; one-sensor: {result["this_one_sensor_us_median"]:.2f} us')
    print(f'wrote {RESULTS}')
    return 0


def driver_params(path: Path) -> None:
    """The simulator's default driver unit as a version-2 calibration file."""
    from tak_thermo_ros.formats.calibration_file import save_unit
    from tak_thermo_ros.core.simulation.scenario import Scenario
    save_unit(path, Scenario(output='imu').driver_truth())


def driver_only(*, quick: bool, baseline: Path | None = None) -> int:
    """Run the driver-input part and merge it into the results file."""
    import platform
    with tempfile.TemporaryDirectory(prefix='bench_node_driver_') as tmp:
        workdir = Path(tmp)
        params = workdir / 'driver_params.yaml'
        driver_params(params)
        started = time.time()
        load = os.getloadavg()[0]
        driver_input = measure_driver_input(params, workdir, rates=(500.0, 2000.0) if quick else DRIVER_RATES_HZ,
                                            seconds=1.0 if quick else DRIVER_SECONDS, baseline=baseline)
        driver_input['transport_loss'] = measure_transport_loss(params, workdir,
                                                                count=2_000 if quick else TRANSPORT_BURST)
        driver_input['in_process'] = in_process_driver_cost(params)
        if baseline is not None:
            driver_input['in_process_against_baseline'] = in_process_against_baseline(params, baseline)
    driver_input['wall_s'] = time.time() - started
    driver_input['load_average_1min_before'] = load
    driver_input['load_average_1min_after'] = os.getloadavg()[0]
    driver_input['baseline'] = str(baseline) if baseline is not None else None
    driver_input['machine'] = {'cpus': os.cpu_count(), 'python': platform.python_version()}
    results = RESULTS.with_name('node_quick.json') if quick else RESULTS
    document = json.loads(results.read_text(encoding='utf-8')) if results.exists() else {}
    document['driver_input'] = driver_input
    results.parent.mkdir(parents=True, exist_ok=True)
    results.write_text(json.dumps(document, indent=2) + '\n', encoding='utf-8')
    for executor in ('events', 'single_threaded'):
        pair = driver_input[executor]
        if baseline is not None:
            ratios = ', '.join(f'{r:.2f}' for r in pair['cpu_ratio_to_baseline_without_loss'])
            print(f'{executor:15s} compensator / baseline CPU per message (rates without loss): {ratios or "none"}')
        for kind in [k for k in ('relay', 'compensator', 'baseline') if k in pair]:
            cpu = ', '.join(f'{row["rate_hz"]:.0f} Hz {row["cpu_us_per_message"]:.0f} us'
                            for row in pair[kind]['rates'])
            print(f'{executor:15s} {kind:11s}: no loss up to {pair[kind]["sustained_rate_without_loss_hz"]:.0f} Hz; '
                  f'CPU per message {cpu}')
    print(f'wrote {results}')
    return 0


# -- the node at 1, 2, 4 and 8 kHz (issue 42): the relay, the decoded node and the raw node in one run --------------

RATES_KHZ = (1.0, 2.0, 4.0, 8.0)
RATE_SECONDS = 10.0
"""Seconds per rate: 40,000 messages at 4 kHz."""
RATE_ROUNDS = 3
TICK_S = 0.001
"""The bench driver publishes every millisecond what is due (4 messages a tick at 4 kHz), as a driver reading its
sensor's FIFO does."""
RATE_SUBJECTS = ('relay', 'decoded', 'raw')
RATE_INPUTS = ('counts', 'driver')
RATE_TEMP_EVERY = 100
RATIO_TARGET = 0.40


class RateDriver:
    """The driver of one subject: pre-serialised input messages published every tick, the answers counted as bytes.

    Publishing serialised bytes (``publish(bytes)``) and counting the answers with a raw subscription
    keeps this process's share of the 2 cores small; stamps go on by the period from run to run.
    """

    def __init__(self, domain: int, input_kind: str, name: str) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import Vector3Stamped
        from rclpy.context import Context
        from rclpy.experimental import EventsExecutor
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import Imu, Temperature
        self.driver = input_kind == 'driver'
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DEPTH, reliability=ReliabilityPolicy.RELIABLE)
        answers = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100 * DEPTH, reliability=ReliabilityPolicy.RELIABLE)
        self.input_publisher = self.node.create_publisher(Imu if self.driver else Vector3Stamped,
                                                          'imu/data_raw' if self.driver else 'tak/counts', qos)
        self.temp_publisher = self.node.create_publisher(Temperature, 'imu/temperature' if self.driver
                                                         else 'tak/temp_code', qos)
        self.subscription = self.node.create_subscription(
            Imu, 'imu/data_compensated' if self.driver else 'tak/imu/data_raw', self._on_answer, answers, raw=True)
        self.statuses: list = []
        self.diagnostics = self.node.create_subscription(DiagnosticArray, '/diagnostics', self.statuses.append, 10)
        self.answered = 0
        self.stamp_ns = 1_700_000_000 * NANOSECONDS

    def _on_answer(self, raw: bytes) -> None:
        self.answered += 1

    def messages(self, count: int, period_ns: int) -> tuple[list[bytes], list[bytes]]:
        """``count`` input messages stamped a period apart, and a temperature for every RATE_TEMP_EVERY of them."""
        import numpy as np

        from tak_thermo_ros.formats.cdr.encoder import encode_messages
        stamps = self.stamp_ns + period_ns * np.arange(1, count + 1, dtype=np.int64)
        self.stamp_ns = int(stamps[-1])
        k = np.arange(count)
        if self.driver:
            accel = np.column_stack([0.01 * (k % 100), np.full(count, -0.2), np.full(count, 9.81)])
            gyro = np.column_stack([0.001 * (k % 50), np.full(count, 0.02), np.full(count, -0.03)])
            inputs = encode_messages('sensor_msgs/msg/Imu', stamps, {
                'orientation': np.array([0.0, 0.0, 0.0, 1.0]), 'orientation_covariance': np.zeros(9),
                'angular_velocity': gyro, 'angular_velocity_covariance': np.zeros(9),
                'linear_acceleration': accel, 'linear_acceleration_covariance': np.zeros(9)}, {'frame_id': 'imu_link'})
            temperature = 20.0 + (k[::RATE_TEMP_EVERY] // RATE_TEMP_EVERY) % 10 * 0.5
        else:
            counts = np.column_stack([k % 2000 - 1000.0, np.full(count, 500.0), np.full(count, 2500.0)])
            inputs = encode_messages('geometry_msgs/msg/Vector3Stamped', stamps, {'vector': counts},
                                     {'frame_id': 'tak_imu'})
            temperature = 8200.0 + (k[::RATE_TEMP_EVERY] // RATE_TEMP_EVERY) % 200
        temperatures = encode_messages('sensor_msgs/msg/Temperature', stamps[::RATE_TEMP_EVERY],
                                       {'temperature': temperature, 'variance': 0.0}, {'frame_id': 'imu_link'})
        return inputs, temperatures

    spin_until = ImuDriver.spin_until

    def warm_up(self) -> None:
        """Until the subject answers, then 1 s at 1 kHz, drained."""
        self.spin_until(lambda: (self.input_publisher.get_subscription_count() >= 1
                                 and self.temp_publisher.get_subscription_count() >= 1
                                 and self.subscription.get_publisher_count() >= 1), 30.0)
        deadline = time.monotonic() + 30.0
        while self.answered == 0:
            if time.monotonic() > deadline:
                raise RuntimeError('the subject never answered')
            inputs, temperatures = self.messages(1, 1_000_000)
            self.temp_publisher.publish(temperatures[0])
            self.executor.spin_once(timeout_sec=0.05)
            self.input_publisher.publish(inputs[0])
            end = time.monotonic() + 0.2
            while self.answered == 0 and time.monotonic() < end:
                self.executor.spin_once(timeout_sec=0.01)
        self.paced(1000.0, 1000)

    def paced(self, rate_hz: float, count: int) -> tuple[int, float]:
        """``count`` messages at ``rate_hz``, what is due published every tick (open loop); (answered, send rate)."""
        inputs, temperatures = self.messages(count, round(NANOSECONDS / rate_hz))
        publish, publish_temperature = self.input_publisher.publish, self.temp_publisher.publish
        spin_once = self.executor.spin_once
        self.answered = 0
        started = time.monotonic()
        sent = 0
        while sent < count:
            due = min(count, int((time.monotonic() - started) * rate_hz) + 1)
            while sent < due:
                if sent % RATE_TEMP_EVERY == 0:
                    publish_temperature(temperatures[sent // RATE_TEMP_EVERY])
                publish(inputs[sent])
                sent += 1
            next_tick = started + (int((time.monotonic() - started) / TICK_S) + 1) * TICK_S
            while True:  # answers until the next tick
                wait = next_tick - time.monotonic()
                if wait <= 0:
                    break
                spin_once(timeout_sec=wait)
        achieved = count / (time.monotonic() - started)
        last, idle_since = self.answered, time.monotonic()
        while self.answered < count and time.monotonic() - idle_since < 2.0:
            spin_once(timeout_sec=0.05)
            if self.answered != last:
                last, idle_since = self.answered, time.monotonic()
        return self.answered, achieved

    def settle(self) -> None:
        """Spin until a compensator's /diagnostics status newer than the last message (the relay has none)."""
        if not self.statuses:
            return
        seen = len(self.statuses)
        deadline = time.monotonic() + 3.0
        while len(self.statuses) < seen + 2 and time.monotonic() < deadline:  # the second one is surely after it
            self.executor.spin_once(timeout_sec=0.05)

    def node_counters(self) -> dict[str, int] | None:
        """The compensator's own counters from its latest /diagnostics (None for the relay)."""
        for array_message in reversed(self.statuses):
            for status in array_message.status:
                if status.name.endswith('temperature compensation'):
                    values = {pair.key: pair.value for pair in status.values}
                    return {key: int(values[key]) for key in ('received', 'published', 'dropped', 'sequence_gap')
                            if values.get(key, 'unavailable') != 'unavailable'}
        return None

    def close(self) -> None:
        import rclpy
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def rate_subject_command(subject: str, input_kind: str, params: Path) -> list[str]:
    """How each subject is started: the relay (rclpy.spin), and the compensator as a user starts it.

    The node: its console script (what ``ros2 run`` executes) with the calibration file and no other
    parameter, so every default holds (best-effort input, depth 1000, the events executor, ``message_path:
    raw``); the decoded node adds ``-p message_path:=decoded`` alone.
    """
    if subject == 'relay':
        from tak_thermo_ros.ros.parameters import _tunables
        depth = _tunables()['qos_depth'][0]  # the node's default, for the relay too
        return [sys.executable, str(Path(__file__).resolve()), 'relay', input_kind, str(depth), 'best_effort',
                '--ros-args']
    script = Path(sys.executable).parent / 'compensator'
    command = [str(script)] if script.exists() else [sys.executable, '-m', 'tak_thermo_ros.ros.main']
    command += ['--ros-args', '--params-file', str(params)]
    return command + (['-p', 'message_path:=decoded'] if subject == 'decoded' else [])


def measure_rates(params: dict[str, Path], workdir: Path, *, rates_khz: tuple[float, ...], seconds: float,
                  rounds: int) -> dict:
    """Each input, the three subjects side by side (own domains), taking turns at each rate, ``rounds`` times.

    Per subject, rate and round: messages sent, answered and lost (sent - answered), and the subject's
    CPU (user + system of its process over the run) per message answered and per message sent; the
    compensators' own counters (received, dropped, sequence gaps) from their /diagnostics. The order
    of the subjects turns at each rate, so that none always runs first.
    """
    home = workdir / 'ros_home'
    home.mkdir(exist_ok=True)
    results: dict = {}
    for input_index, input_kind in enumerate(RATE_INPUTS):
        processes, drivers = {}, {}
        rows: dict[str, list] = {subject: [] for subject in RATE_SUBJECTS}
        try:
            for index, subject in enumerate(RATE_SUBJECTS):
                env = node_env(home, bench_domain(30 + 3 * input_index + index))
                processes[subject] = subprocess.Popen(
                    rate_subject_command(subject, input_kind, params[input_kind]), env=env,
                    stdout=open(workdir / f'rates_{input_kind}_{subject}.log', 'wb'), stderr=subprocess.STDOUT,
                    stdin=subprocess.DEVNULL, start_new_session=True)
                drivers[subject] = RateDriver(int(env['ROS_DOMAIN_ID']), input_kind, f'bench_rates_{subject}')
            for subject in RATE_SUBJECTS:
                drivers[subject].warm_up()
                drivers[subject].settle()
            turn = 0
            for round_index in range(rounds):
                for khz in rates_khz:
                    count = int(khz * 1000 * seconds)
                    order = RATE_SUBJECTS[turn % 3:] + RATE_SUBJECTS[:turn % 3]
                    turn += 1
                    for subject in order:
                        driver, pid = drivers[subject], processes[subject].pid
                        before = driver.node_counters()
                        cpu_before = cpu_s(pid)
                        answered, achieved = driver.paced(khz * 1000.0, count)
                        cpu = cpu_s(pid) - cpu_before
                        driver.settle()
                        after = driver.node_counters()
                        row = {'round': round_index, 'rate_hz': khz * 1000.0, 'sent': count, 'answered': answered,
                               'lost': count - answered, 'achieved_send_rate_hz': achieved,
                               'cpu_s': cpu, 'cpu_us_per_message': cpu / max(answered, 1) * 1e6,
                               'cpu_us_per_message_sent': cpu / count * 1e6,
                               'load_average_1min': os.getloadavg()[0]}
                        if before is not None and after is not None:
                            row['node'] = {key: after[key] - before.get(key, 0) for key in after}
                        rows[subject].append(row)
                        print(f'  {input_kind:7s} {subject:8s} {khz:3.0f} kHz round {round_index + 1} (sent at '
                              f'{achieved:5.0f} Hz): {row["lost"]:6d} of {count} lost, '
                              f'{row["cpu_us_per_message"]:6.1f} us CPU per message '
                              f'({row["cpu_us_per_message_sent"]:6.1f} per sent), load '
                              f'{row["load_average_1min"]:.1f}', flush=True)
        finally:
            codes = close_all(RATE_SUBJECTS, drivers, processes)
        results[input_kind] = {'rows': rows, 'exit_codes': codes, 'summary': rate_summary(rows, rates_khz)}
    return results


def rate_summary(rows: dict[str, list], rates_khz: tuple[float, ...]) -> dict:
    """Per rate: each subject's median CPU per message and its worst loss over the rounds; the ratios to the relay.

    A ratio is the median over the rounds of the ratio within a round (the subjects ran back to back).
    """
    summary = {}
    for khz in rates_khz:
        at = {subject: [row for row in rows[subject] if row['rate_hz'] == khz * 1000.0] for subject in RATE_SUBJECTS}
        entry: dict = {}
        for subject, runs in at.items():
            entry[subject] = {'cpu_us_per_message': statistics.median(r['cpu_us_per_message'] for r in runs),
                              'cpu_us_per_message_sent': statistics.median(r['cpu_us_per_message_sent'] for r in runs),
                              'lost_max': max(r['lost'] for r in runs), 'lost': [r['lost'] for r in runs]}
        for subject in ('decoded', 'raw'):
            for key in ('cpu_us_per_message', 'cpu_us_per_message_sent'):
                entry[subject][f'ratio_to_relay_{key.removeprefix("cpu_us_")}'] = statistics.median(
                    node[key] / relay[key] for node, relay in zip(at[subject], at['relay']))
        summary[f'{khz:g} kHz'] = entry
    return summary


def rates_only(*, quick: bool) -> int:
    """``--rates``: the relay, the decoded node and the raw node at 1, 2, 4 and 8 kHz; ``rates`` in ``node.json``."""
    import platform
    with tempfile.TemporaryDirectory(prefix='bench_node_rates_') as tmp:
        workdir = Path(tmp)
        params = {'counts': workdir / 'counts.yaml', 'driver': workdir / 'driver.yaml'}
        from tak_thermo_ros.formats.calibration_file import save_calibration
        from tak_thermo_ros.core.simulation.scenario import Scenario
        save_calibration(params['counts'], Scenario().truth())
        watch_params(params['driver'])  # with its noise models: the watch runs, as it does from `tak_calib fit`
        load = os.getloadavg()
        started = time.time()
        rates = measure_rates(params, workdir, rates_khz=RATES_KHZ, seconds=1.0 if quick else RATE_SECONDS,
                              rounds=1 if quick else RATE_ROUNDS)
    rates.update(wall_s=time.time() - started, load_average_before=load, load_average_after=os.getloadavg(),
                 niceness=os.nice(0), seconds_per_rate=1.0 if quick else RATE_SECONDS,
                 rounds=1 if quick else RATE_ROUNDS, temperature_every=RATE_TEMP_EVERY, tick_s=TICK_S,
                 machine={'cpus': os.cpu_count(), 'python': platform.python_version()},
                 target=f'at 4 kHz the raw node (as a user starts it) loses none and costs <= {RATIO_TARGET} x the '
                        'relay\'s CPU per message')
    results = RESULTS.with_name('node_quick.json') if quick else RESULTS
    document = json.loads(results.read_text(encoding='utf-8')) if results.exists() else {}
    document['rates'] = rates
    results.parent.mkdir(parents=True, exist_ok=True)
    results.write_text(json.dumps(document, indent=2) + '\n', encoding='utf-8')
    missed = []
    for input_kind in RATE_INPUTS:
        print(f'{input_kind} input: CPU per message answered (per message sent), median of the rounds; the most '
              f'lost in a round; the ratio to the relay (median of the rounds\' ratios)')
        for rate, entry in rates[input_kind]['summary'].items():
            cells = [f'{subject} {entry[subject]["cpu_us_per_message"]:5.0f} us '
                     f'({entry[subject]["cpu_us_per_message_sent"]:4.0f}), lost {entry[subject]["lost_max"]:5d}'
                     for subject in RATE_SUBJECTS]
            print(f'  {rate:6s}: {"; ".join(cells)}; raw/relay {entry["raw"]["ratio_to_relay_per_message"]:.2f} '
                  f'({entry["raw"]["ratio_to_relay_per_message_sent"]:.2f})')
        at_4 = rates[input_kind]['summary']['4 kHz']['raw']
        if at_4['lost_max'] > 0 or at_4['ratio_to_relay_per_message'] > RATIO_TARGET:
            missed.append(f'{input_kind} at 4 kHz: lost {at_4["lost"]}, ratio {at_4["ratio_to_relay_per_message"]:.2f}')
    print(f'load average before {load[0]:.1f}, after {rates["load_average_after"][0]:.1f}; wrote {results}')
    if missed:
        print(f'target missed: {"; ".join(missed)}')
        return TARGET_MISSED
    return 0


if __name__ == '__main__':
    if len(sys.argv) > 1 and sys.argv[1] == 'relay':  # relay [counts|driver DEPTH best_effort|reliable]
        given = sys.argv[2:5] if len(sys.argv) > 4 and sys.argv[2] != '--ros-args' else None
        sys.exit(relay_main(given[0], int(given[1]), given[2] == 'best_effort') if given else relay_main())
    if len(sys.argv) > 2 and sys.argv[1] == 'driver_relay':
        sys.exit(driver_relay_main(sys.argv[2]))
    sys.exit(main())
