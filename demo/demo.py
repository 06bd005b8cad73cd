"""`make demo`: calibrate a simulated unit, then validate on a second run of the same unit.

Runs the real command-line tool, printing each command as a user would type it:
1. simulate the paper's chamber protocol (plateaus 5, 15, 20, 30, 35 C, three hours each);
2. fit the correction link;
3. simulate a second run of the same unit on another temperature profile (another seed);
4. validate on that run: |g| from the three channels, before and after correction;
5. apply the correction to it (sensor_msgs/msg/Imu bag), and draw |g| as in the paper's Figs. 4-5;
6. the same for a ROS 2 driver's unit (sensor_msgs/msg/Imu and a temperature in C): a rate-table
   calibration fits the accelerometer AND the gyroscope, and a static second run shows the
   gyroscope's bias error before and after.
"""

from __future__ import annotations

import json
import math
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / 'demo_out'
TAK_CALIB = str(Path(sys.executable).with_name('tak_calib'))


DRIVER_COMMON = ('# a ROS 2 driver\'s unit: Imu in m/s^2 and rad/s, temperature in C\n'
                 'output: imu\nplateaus_celsius: [5.0, 35.0, 15.0]\nplateau_hours: 0.5\n'
                 'ramp_celsius_per_minute: 1.0\ndwell_s: 30.0\nboard_lag_s: 300.0\n')
TABLE_POSITIONS = [[s if j == i else 0.0 for j in range(3)] for i in range(3) for s in (1.0, -1.0) for _ in range(3)]
TABLE_RATES = [0.0, 1.0, -1.0] * 6
"""A rate table: each axis up and down, at rest and turning at +-1 rad/s about the vertical."""


def run(*args: str) -> None:
    """Print and run one tak_calib command; stop the demo if it fails."""
    print(f'\n$ tak_calib {shlex.join(args)}', flush=True)
    result = subprocess.run([TAK_CALIB, *args], cwd=OUT, check=False)
    if result.returncode != 0:
        sys.exit(result.returncode)


def draw(figures: dict) -> None:
    """|g| before and after along the validation run (the paper's Figs. 4-5)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    import numpy as np

    from tak_thermo_ros.formats.bag import read_record
    from tak_thermo_ros.formats.calibration_file import load_calibration
    from tak_thermo_ros.core.records.record import align
    from tak_thermo_ros.core.link.validate import validate_gravity

    samples = align(read_record(OUT / 'run2', progress=False), use_reference=False)
    result = validate_gravity(load_calibration(OUT / 'params.yaml'), samples.counts, samples.temp_code)
    hours = samples.time_s / 3600.0
    window = 60
    kernel = np.ones(window) / window
    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for axis, magnitude, title in ((axes[0], result.magnitude_before, 'before correction (nominal scale and offset)'),
                                   (axes[1], result.magnitude_after, 'after correction (full link)')):
        axis.plot(hours, magnitude, lw=0.3, color='0.7', label='|g| per sample')
        axis.plot(hours[window - 1:], np.convolve(magnitude, kernel, mode='valid'), lw=1.2, label='1-minute mean')
        axis.axhline(figures['gravity'], color='k', ls='--', lw=0.8, label='local gravity')
        axis.set_ylabel('|g|, m/s$^2$')
        axis.set_title(title)
        axis.legend(loc='upper right', fontsize=8)
    axes[1].set_xlabel('time, h')
    fig.tight_layout()
    fig.savefig(OUT / 'gravity_before_after.png', dpi=110)


def main() -> int:
    """Run the demo."""
    started = time.monotonic()
    shutil.rmtree(OUT, ignore_errors=True)
    OUT.mkdir()
    (OUT / 'second_run.yaml').write_text('# same unit, another temperature profile\n'
                                         'plateaus_celsius: [12.0, 33.0, 8.0, 26.0]\n'
                                         'plateau_hours: 2.0\n')
    run('simulate', 'cal', '--seed', '1')
    run('fit', 'cal', '-o', 'params.yaml')
    run('simulate', 'run2', '--scenario', 'second_run.yaml', '--seed', '2')
    run('validate', 'run2', '--params', 'params.yaml', '--json', 'validation.json')
    run('apply', 'run2', '--params', 'params.yaml', '-o', 'run2_imu')
    figures = json.loads((OUT / 'validation.json').read_text())
    draw(figures)
    (OUT / 'table.yaml').write_text(DRIVER_COMMON + 'positions: ' + json.dumps(TABLE_POSITIONS) + '\n'
                                    'table_rates: ' + json.dumps(TABLE_RATES) + '\n')
    (OUT / 'static.yaml').write_text(DRIVER_COMMON + 'positions: [[0.0, 0.0, 1.0]]\nrecord_references: false\n'
                                     'plateaus_celsius: [30.0, 10.0, 25.0]\n')
    run('simulate', 'driver_cal', '--scenario', 'table.yaml', '--seed', '3')
    run('fit', 'driver_cal', '-o', 'driver_params.yaml')
    run('simulate', 'driver_run2', '--scenario', 'static.yaml', '--seed', '4')
    run('validate', 'driver_run2', '--params', 'driver_params.yaml', '--json', 'driver_validation.json')
    driver = json.loads((OUT / 'driver_validation.json').read_text())['gyro']
    worst_before = max(abs(v['mean']) for v in driver['before'].values())
    worst_after = max(abs(v['mean']) for v in driver['after'].values())
    before, after = figures['before']['rms'], figures['after']['rms']
    mg = 1e3 / figures['gravity']
    deg_h = 180.0 / math.pi * 3600.0
    print(f'\n|g| error on the second run: RMS {before * mg:.3g} -> {after * mg:.3g} mg '
          f'({before / after:.1f}x lower), max {figures["before"]["max"] * mg:.3g} -> '
          f'{figures["after"]["max"] * mg:.3g} mg')
    print(f'driver unit, second run, gyroscope bias (largest axis mean): {worst_before * deg_h:.3g} -> '
          f'{worst_after * deg_h:.3g} deg/h')
    print(f'outputs in {OUT.name}/ (figure: gravity_before_after.png); {time.monotonic() - started:.0f} s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
