"""`make demo`: calibrate a simulated unit, then validate on a second run of the same unit.

Runs the real command-line tool, printing each command as a user would type it:
1. simulate the paper's chamber protocol (plateaus 5, 15, 20, 30, 35 C, three hours each);
2. fit the correction link;
3. simulate a second run of the same unit on another temperature profile (another seed);
4. validate on that run: |g| from the three channels, before and after correction;
5. apply the correction to it (sensor_msgs/msg/Imu bag), and draw |g| as in the paper's Figs. 4-5.
"""

from __future__ import annotations

import json
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / 'demo_out'
TAK_CALIB = str(Path(sys.executable).with_name('tak_calib'))


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

    from tak_thermo_ros.bagio import read_record
    from tak_thermo_ros.core.calibration_file import load_calibration
    from tak_thermo_ros.core.record import align
    from tak_thermo_ros.core.validate import validate_gravity

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
    before, after = figures['before']['rms'], figures['after']['rms']
    print(f'\n|g| error on the second run: RMS {before:.4f} -> {after:.4f} m/s^2 '
          f'({before / after:.1f}x lower); max {figures["before"]["max"]:.4f} -> {figures["after"]["max"]:.4f} m/s^2')
    print(f'outputs in {OUT} (figure: gravity_before_after.png); {time.monotonic() - started:.0f} s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
