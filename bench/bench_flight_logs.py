"""PX4's and ArduPilot's own thermal calibration against ``tak_calib``, side by side on the same simulated logs.

PX4's procedure (``Tools/process_sensor_caldata.py``): a cold-soaked board powered in a warm
room for 45 min, logged with the thermal-calibration profile (``sensor_accel``,
``sensor_gyro``, ``sensor_baro`` at 10 Hz, each on its own stamps); the sensing elements lag
the die thermometer by 150 s (:mod:`tak_thermo_ros.core.simulation.powered`). The same unit's
warm-up as ArduPilot logs it (``IMU`` messages at 25 Hz, a DataFlash ``.bin``) goes to
ArduPilot's ``Tools/scripts/tempcal_IMU.py``. ``tak_calib`` reads both logs itself:
``diagnose``, ``fit`` (with the effects ``diagnose`` names), ``export --format px4|ardupilot``.
The true static curve, exported the same way, is the yardstick.

Each parameter set is scored on a later in-use log of the unit (2 h, powered warm, the
ambient in slow ramps; written as a ULog and a ``.bin`` and read back), applied as the
firmware applies it (``test/firmware.py``: PX4 with its 1 C update rule and without it,
ArduPilot's ``-P(T-35) + P(CALTEMP-35)``): the constant offset is left to the firmware's
ordinary calibration (the mean error over the log is removed); the score is the RMS over the
log's 60-s windows and the three axes of the mean error, in units of the noise floor of a 60-s
mean (the white noise per sample over sqrt(samples in 60 s)): 1x is noise alone.

Also measured: our DataFlash reader against pymavlink's ``DFReader`` on the in-use ``.bin``
(median of 3), and, when ``--pyulog`` is given, what our ULog reader makes of pyulog's own
test logs (real hardware, BSD).

The peers' scripts run from fetched snapshots, never copied here: ``--px4 DIR`` and
``--ardupilot DIR`` are git directories (``fetch``) holding ``Tools/process_sensor_caldata.py``
and ``Tools/scripts/tempcal_IMU.py``; ``--pyulog DIR`` the pyulog repository (``test/*.ulg``).

Run: ``.venv/bin/python bench/bench_flight_logs.py --px4 PX4_GIT --ardupilot ARDUPILOT_GIT
--pyulog PYULOG_GIT`` (a few minutes); writes ``bench/results/flight_logs.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / 'test'))

from benchlib import machine, tak_calib_command  # noqa: E402
from firmware import ardupilot_correction, px4_applied_offsets  # noqa: E402

from tak_thermo_ros.core.link.model import UnitCalibration  # noqa: E402
from tak_thermo_ros.core.records.record import hold_signal  # noqa: E402
from tak_thermo_ros.core.simulation.powered import PoweredRun, simulate_powered  # noqa: E402
from tak_thermo_ros.formats.ardupilot_params import ardupilot_parameters, read_ardupilot_params  # noqa: E402
from tak_thermo_ros.formats.dataflash import driver_messages, read_dataflash, write_dataflash  # noqa: E402
from tak_thermo_ros.formats.px4_params import px4_parameters, read_px4_params  # noqa: E402
from tak_thermo_ros.formats.ulog import driver_topics, read_ulog, write_ulog  # noqa: E402

WARM_UP = PoweredRun()
"""PX4's procedure: 2 C cold soak, a 25 C room, 8 C of self-heating within 40 s, the board 700 s behind, 45 min."""
WARM_UP_AND_COOL_DOWN = PoweredRun(duration_s=5400.0, ambient_knots=((0.0, 25.0), (2700.0, 25.0), (2760.0, 5.0)))
"""The same warm-up, then the powered board moved to a 5 C room for 45 min: a record that determines a lag."""
SCENARIOS = {'px4_procedure': WARM_UP, 'warm_up_and_cool_down': WARM_UP_AND_COOL_DOWN}
IN_USE = PoweredRun(duration_s=7200.0, start_celsius=20.0, self_heating_celsius=0.0,
                    ambient_knots=((0.0, 20.0), (600.0, 20.0), (3000.0, 30.0), (4200.0, 30.0), (6600.0, 22.0)),
                    seed=5)
"""The unit in use: powered warm (in equilibrium), the ambient ramping 20 -> 30 -> 22 C at 0.25 and 0.2 C/min."""
WINDOW_S = 60.0
ULOG_IDS = {'accel': 2490378, 'gyro': 2490634}


def git_file(repository: str, path: str, out: Path) -> Path:
    """A file of a fetched git snapshot (no work tree), written to ``out``."""
    text = subprocess.run(['git', '--git-dir', repository, 'show', f'HEAD:{path}'], check=True,
                          capture_output=True).stdout
    out.write_bytes(text)
    return out


def tak_calib(*args: str) -> str:
    """Run ``tak_calib``; its standard output (raises on a non-zero exit)."""
    result = subprocess.run([*tak_calib_command(), *args, '--no-progress'] if args[0] != 'export'
                            else [*tak_calib_command(), *args], capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeError(f'tak_calib {" ".join(args)}: {result.stderr.strip()}')
    return result.stdout


def score(corrected: np.ndarray, truth: np.ndarray, stamps_ns: np.ndarray, noise: np.ndarray,
          rate_hz: float) -> dict[str, object]:
    """The bias error in units of the noise floor of a 60-s mean (see the module's description)."""
    error = corrected.astype(float) - truth
    error -= error.mean(axis=0)
    seconds = (stamps_ns - stamps_ns[0]) * 1e-9
    window = np.floor(seconds / WINDOW_S).astype(int)
    full = np.bincount(window) >= 0.9 * WINDOW_S * rate_hz
    means = np.array([error[window == w].mean(axis=0) for w in np.flatnonzero(full)])
    floor = noise / np.sqrt(WINDOW_S * rate_hz)
    per_axis = np.sqrt((means ** 2).mean(axis=0)) / floor
    return {'x_floor': round(float(np.sqrt((per_axis ** 2).mean())), 2),
            'per_axis': [round(float(v), 2) for v in per_axis]}


def px4_scores(params: dict[str, float], in_use, log) -> dict[str, object]:
    """PX4's firmware applied to the in-use ULog (read back), with and without its 1 C update rule."""
    out = {}
    for sensor, letter in (('accel', 'A'), ('gyro', 'G')):
        stamps = log.stamps[sensor]
        temperature = hold_signal(log.temp_stamp_ns, log.temperature, stamps)
        truth = np.tile(in_use.specific_force if sensor == 'accel' else np.zeros(3), (len(stamps), 1))
        for hold in (True, False):
            offset = px4_applied_offsets(params, letter, 0, temperature, log.device_ids[sensor], hold=hold)
            out[f'{sensor}{"" if hold else "_every_sample"}'] = score(
                log.values[sensor] - offset, truth, stamps, in_use.noise[sensor], IN_USE.accel_rate_hz)
    return out


def ardupilot_scores(params: dict[str, float], in_use, log, rate_hz: float) -> dict[str, object]:
    """The in-use ``.bin`` (read back) corrected as ArduPilot's firmware does; CALTEMP its first temperature."""
    out = {}
    for sensor, code in (('accel', 'ACC'), ('gyro', 'GYR')):
        stamps = log.stamps[sensor]
        temperature = hold_signal(log.temp_stamp_ns, log.temperature, stamps)
        truth = np.tile(in_use.specific_force if sensor == 'accel' else np.zeros(3), (len(stamps), 1))
        correction = ardupilot_correction(params, 0, code, temperature, float(temperature[0]))
        out[sensor] = score(log.values[sensor] + correction, truth, stamps, in_use.noise[sensor], rate_hz)
    return out


def truth_unit(run: PoweredRun) -> UnitCalibration:
    """The true static curves with the logs' device IDs (what a perfect fit would export)."""
    truth = run.truth()
    return UnitCalibration(truth.input_kind, truth.accel, truth.gyro,
                           source={'format': 'ulog', 'instance': 0, 'accel_device_id': ULOG_IDS['accel'],
                                   'gyro_device_id': ULOG_IDS['gyro']})


def ours(log: Path, work: Path, name: str) -> tuple[Path, dict[str, object]]:
    """``diagnose`` (against a plain fit), then ``fit`` with what it names; the calibration and what was said."""
    plain = work / f'{name}_plain.yaml'
    tak_calib('fit', str(log), '-o', str(plain))
    report = work / f'{name}_diagnose.json'
    text = tak_calib('diagnose', str(log), '--params', str(plain), '--json', str(report))
    verdicts = {sensor: entry.get('verdict') for sensor, entry in json.loads(report.read_text())['sensors'].items()}
    effects = {sensor: verdict for sensor, verdict in verdicts.items() if verdict not in (None, 'none', 'unexplained')}
    fitted = work / f'{name}.yaml'
    args = ['fit', str(log), '-o', str(fitted)]
    if 'accel' in effects:
        args += ['--effects', effects['accel']]
    if 'gyro' in effects:
        args += ['--gyro-effects', effects['gyro']]
    tak_calib(*args)
    warm_up_line = next((line for line in text.splitlines() if 'warm' in line.lower()), '')
    return fitted, {'verdicts': verdicts, 'effects_fitted': effects, 'warm_up_line': warm_up_line}


def reader_speed(path: Path) -> dict[str, float]:
    """Our DataFlash reader against pymavlink's DFReader on the same file (IMU and PARM), seconds, median of 3."""
    from pymavlink import DFReader

    def ours_once() -> None:
        read_dataflash(path, 0)  # reads the file each time

    def theirs_once() -> None:
        log = DFReader.DFReader_binary(str(path), zero_time_base=False)
        while log.recv_match(type=['IMU', 'PARM']) is not None:
            pass

    times = {}
    for name, run in (('ours_s', ours_once), ('dfreader_s', theirs_once)):
        samples = []
        for _ in range(3):
            start = time.perf_counter()
            run()
            samples.append(time.perf_counter() - start)
        times[name] = round(float(np.median(samples)), 3)
    times['speedup'] = round(times['dfreader_s'] / times['ours_s'], 1)
    return times


def real_ulogs(repository: str, work: Path) -> list[dict[str, object]]:
    """The test logs of pyulog through our reader: what each holds, or its one-line refusal."""
    names = subprocess.run(['git', '--git-dir', repository, 'ls-tree', '--name-only', 'HEAD', 'test/'], check=True,
                           capture_output=True, text=True).stdout.split()
    found = []
    for name in sorted(n for n in names if n.endswith('.ulg')):
        path = work / Path(name).name
        try:
            git_file(repository, name, path)
        except subprocess.CalledProcessError:
            found.append({'log': name, 'read': 'not in the snapshot (a large-file pointer)'})
            continue
        if path.stat().st_size < 1024:
            found.append({'log': name, 'read': f'not in the snapshot ({path.stat().st_size} bytes: a pointer)'})
            continue
        for instance in range(3):
            entry: dict[str, object] = {'log': name, 'instance': instance}
            try:
                log = read_ulog(path, instance)
                entry.update({'accel': log.count('accel'), 'gyro': log.count('gyro'), 'mag': log.count('mag'),
                              'temperature_c': [round(float(log.temperature.min()), 2),
                                                round(float(log.temperature.max()), 2)],
                              'device_ids': log.device_ids})
                result = subprocess.run([*tak_calib_command(), 'fit', str(path), '--instance', str(instance), '-o',
                                         str(work / f'{path.stem}_{instance}.yaml'), '--no-progress', '--force'],
                                        capture_output=True, text=True)
                entry['fit'] = (result.stdout.strip().splitlines()[0] if result.returncode == 0
                                else result.stderr.strip().splitlines()[-1])
            except Exception as err:  # the one line a user would see
                entry['read'] = str(err)
            found.append(entry)
            if 'read' in entry:
                break
    return found


LAG_GRID_S = (30.0, 60.0, 100.0, 150.0, 250.0, 400.0, 800.0)


def lag_profile(run: PoweredRun) -> dict[str, object]:
    """How well the record tells the lag's time constant: the fit's residual with a lag fixed at each tau.

    The gyroscope's residual sum of squares over the white noise's variance, above its smallest
    over the grid (a lag the record determines: a clear dip at 150 s; one it cannot: a few units
    everywhere); and the score the static curve of each of those fits leaves in use.
    """
    from tak_thermo_ros.core.effects.thermal_lag import ThermalLag
    from tak_thermo_ros.core.fit import fit_model
    from tak_thermo_ros.core.records.record import AlignedSamples
    sim = simulate_powered(run)
    stamps = sim.record.sensor_stamps('gyro')
    samples = AlignedSamples(stamp_ns=stamps, counts=sim.record.gyro,
                             temp_code=hold_signal(sim.record.temp_stamp_ns, sim.record.temperature, stamps),
                             reference=np.zeros((len(stamps), 3)), dropped={})
    squares = []
    for tau in LAG_GRID_S:
        result = fit_model(samples, effects=[ThermalLag(tau_s=tau)], bias_order=3, scale_order=0,
                           nominal_scale=(1.0, 1.0, 1.0))
        squares.append([axis.residual_rms ** 2 * result.samples for axis in result.axes])
    squares = np.array(squares) / sim.noise['gyro'] ** 2
    excess = squares - squares.min(axis=0)
    return {'tau_s': list(LAG_GRID_S), 'gyro_rss_over_sigma2_above_min': np.round(excess, 1).tolist()}


def compare(scenario: str, run: PoweredRun, work: Path, px4_script: Path, ardupilot_script: Path, ulog_use,
            bin_use) -> dict[str, object]:
    """One calibration record, as PX4 and as ArduPilot log it, through both peers' scripts and ours; the scores."""
    (in_use_ulog, use_ulog), (in_use_bin, use_bin) = ulog_use, bin_use
    warm_ulog = simulate_powered(run)
    warm_bin = simulate_powered(PoweredRun(**{**run.__dict__, 'accel_rate_hz': 25.0, 'gyro_rate_hz': 25.0,
                                              'gyro_phase_s': 0.0, 'seed': 1}))
    ulog, binary = work / f'{scenario}.ulg', work / f'{scenario}.bin'
    write_ulog(ulog, driver_topics(warm_ulog.record, device_ids=ULOG_IDS), info={'sys_name': 'PX4'})
    write_dataflash(binary, driver_messages(warm_bin.record), parameters={'AHRS_ORIENTATION': 0})
    start = time.perf_counter()
    subprocess.run([sys.executable, str(px4_script), str(ulog)], check=True, capture_output=True, cwd=work)
    px4_time = time.perf_counter() - start
    start = time.perf_counter()
    parm = work / f'{scenario}_tcal.parm'
    subprocess.run([sys.executable, str(ardupilot_script), '--no-graph', '--outfile', str(parm), str(binary)],
                   check=True, capture_output=True, cwd=work)
    ardupilot_time = time.perf_counter() - start
    # the script writes no TC_*_ENABLE: its procedure's step 1 has the user set them to 1
    px4_theirs = {**read_px4_params(Path(f'{ulog}.params').read_text()), 'TC_A_ENABLE': 1, 'TC_G_ENABLE': 1}
    ardupilot_theirs = read_ardupilot_params(parm.read_text())
    start = time.perf_counter()
    ours_ulog, said_ulog = ours(ulog, work, f'{scenario}_ulog')
    ours_bin, said_bin = ours(binary, work, f'{scenario}_bin')
    ours_time = time.perf_counter() - start
    export_lines = {}
    for name, params, suffix in (('px4', ours_ulog, 'params'), ('ardupilot', ours_bin, 'parm')):
        export_lines[name] = tak_calib('export', str(params), '--format', name, '-o',
                                       str(work / f'{scenario}_ours.{suffix}')).splitlines()
    px4_ours = read_px4_params((work / f'{scenario}_ours.params').read_text())
    ardupilot_ours = read_ardupilot_params((work / f'{scenario}_ours.parm').read_text())
    truth = truth_unit(run)
    px4_truth = {name: float(value) for name, (value, _) in px4_parameters(truth, instance=0).values.items()}
    ardupilot_truth = {name: float(value) for name, (value, _) in
                       ardupilot_parameters(truth, instance=0).values.items()}
    return {
        'px4': {name: px4_scores(params, in_use_ulog, use_ulog) for name, params in
                (('process_sensor_caldata', px4_theirs), ('tak_calib', px4_ours), ('true_static_curve', px4_truth))},
        'ardupilot': {name: ardupilot_scores(params, in_use_bin, use_bin, 25.0) for name, params in
                      (('tempcal_IMU', ardupilot_theirs), ('tak_calib', ardupilot_ours),
                       ('true_static_curve', ardupilot_truth))},
        'ours_said': {'ulog': said_ulog, 'bin': said_bin, 'export': export_lines},
        'lag_profile': lag_profile(run),
        'seconds': {'process_sensor_caldata': round(px4_time, 1), 'tempcal_IMU': round(ardupilot_time, 1),
                    'tak_calib_diagnose_fit_fit_both_logs': round(ours_time, 1)}}


ARDUPILOT_EXAMPLE_LOG = 'libraries/AP_Logger/examples/AP_Logger_AllTypes/output.BIN'
"""The one DataFlash log in ArduPilot's repository (GPL-3): AP_Logger's example of every field type."""


def real_dataflash(repository: str, work: Path) -> dict[str, object]:
    """The example log of ArduPilot through our reader and DFReader: the same messages per type; what fit says."""
    from pymavlink import DFReader
    from tak_thermo_ros.formats.dataflash import index_messages
    path = work / 'output.BIN'
    try:
        git_file(repository, ARDUPILOT_EXAMPLE_LOG, path)
    except subprocess.CalledProcessError:
        return {'log': ARDUPILOT_EXAMPLE_LOG, 'read': 'not in the snapshot'}
    types, positions, skipped = index_messages(path, path.read_bytes())
    ours_counts = {types[kind].name: len(rows) for kind, rows in positions.items() if kind != 128}
    theirs: dict[str, int] = {}
    log = DFReader.DFReader_binary(str(path), zero_time_base=False)
    while (message := log.recv_match()) is not None:
        name = message.get_type()
        if name != 'FMT':
            theirs[name] = theirs.get(name, 0) + 1
    result = subprocess.run([*tak_calib_command(), 'fit', str(path), '-o', str(work / 'output.yaml'), '--no-progress'],
                            capture_output=True, text=True)
    return {'log': ARDUPILOT_EXAMPLE_LOG, 'ours': ours_counts, 'dfreader': theirs, 'skipped_bytes': skipped,
            'same': {k: v for k, v in ours_counts.items() if k not in ('FMTU', 'UNIT', 'MULT')} ==
                    {k: v for k, v in theirs.items() if k not in ('FMTU', 'UNIT', 'MULT')},
            'fit': result.stderr.strip().splitlines()[-1] if result.returncode else 'fitted'}


def main() -> int:
    """Run the comparison; write ``bench/results/flight_logs.json``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--px4', required=True, help='git directory of a PX4-Autopilot snapshot')
    parser.add_argument('--ardupilot', required=True, help='git directory of an ardupilot snapshot')
    parser.add_argument('--pyulog', help='git directory of the pyulog repository (its real test logs)')
    parser.add_argument('--out', default=str(HERE / 'results' / 'flight_logs.json'))
    args = parser.parse_args()
    os.environ.setdefault('MPLBACKEND', 'Agg')
    results: dict[str, object] = {'machine': machine(), 'scenarios': {k: repr(v) for k, v in SCENARIOS.items()},
                                  'in_use': repr(IN_USE)}
    with tempfile.TemporaryDirectory() as directory:
        work = Path(directory)
        px4_script = git_file(args.px4, 'Tools/process_sensor_caldata.py', work / 'process_sensor_caldata.py')
        ardupilot_script = git_file(args.ardupilot, 'Tools/scripts/tempcal_IMU.py', work / 'tempcal_IMU.py')
        results['peer_scripts'] = {
            name: subprocess.run(['git', '--git-dir', repository, 'log', '-1', '--format=%H %ci', '--', script],
                                 capture_output=True, text=True).stdout.strip()
            for name, repository, script in (('px4', args.px4, 'Tools/process_sensor_caldata.py'),
                                             ('ardupilot', args.ardupilot, 'Tools/scripts/tempcal_IMU.py'))}
        in_use_ulog = simulate_powered(IN_USE)
        in_use_bin = simulate_powered(PoweredRun(**{**IN_USE.__dict__, 'accel_rate_hz': 25.0, 'gyro_rate_hz': 25.0,
                                                    'gyro_phase_s': 0.0, 'seed': 6}))
        write_ulog(work / 'in_use.ulg', driver_topics(in_use_ulog.record, device_ids=ULOG_IDS))
        write_dataflash(work / 'in_use.bin', driver_messages(in_use_bin.record), parameters={'AHRS_ORIENTATION': 0})
        use_ulog, use_bin = read_ulog(work / 'in_use.ulg', 0), read_dataflash(work / 'in_use.bin', 0)
        results['uncorrected'] = {'px4': px4_scores({}, in_use_ulog, use_ulog),
                                  'ardupilot': ardupilot_scores({}, in_use_bin, use_bin, 25.0)}
        for scenario, run in SCENARIOS.items():
            results[scenario] = compare(scenario, run, work, px4_script, ardupilot_script,
                                        (in_use_ulog, use_ulog), (in_use_bin, use_bin))
        results['dataflash_reader'] = reader_speed(work / 'in_use.bin')
        results['dataflash_reader']['messages'] = len(use_bin.stamps['accel'])
        if args.pyulog:
            results['pyulog_test_logs'] = real_ulogs(args.pyulog, work)
        results['ardupilot_example_log'] = real_dataflash(args.ardupilot, work)
    Path(args.out).write_text(json.dumps(results, indent=2) + '\n')
    for scenario in SCENARIOS:
        for firmware in ('px4', 'ardupilot'):
            print(scenario, firmware, {name: {sensor: value['x_floor'] for sensor, value in scores.items()}
                                       for name, scores in results[scenario][firmware].items()})
    print('dataflash reader', results['dataflash_reader'])
    return 0


if __name__ == '__main__':
    sys.exit(main())
