"""Real-data analysis: the tofupilot MEMS IMU thermal cycle (issue 5; written up in docs/manual.md, "On a real IMU").

Imports ``data/tofupilot-imu-thermal/imu_raw_data.csv`` as ``tak_calib import-csv`` does
(0.001 m/s^2 and 0.01 C per code), leaves out the start-up minute as ``tak_calib fit
--settle-time 60`` does, fits the base model (offset cubic in the temperature code, scale held
at nominal: one orientation), and asks which physical effect closes the heating/cooling loops:

- residual views: against time, against temperature split by heating and cooling, against
  dT/dt; the noise floor from successive differences;
- ``diagnose`` (the library's verdict, its candidates and its model ladder);
- an independent blocked cross-validation: 10 contiguous time blocks, each held out once,
  the model (time constants and play widths included) fitted by ``fit_model`` on the other
  nine and scored on the held-out block, for base, + thermal_lag, + hysteresis, + both;
  paired per-block differences with their standard errors (the margin of
  ``test/core/diagnose/test_real_imu.py``);
- the start-up minute: kept, with and without a ``warmup`` term;
- a scan of the play width beyond the library's search range (up to the whole range), in
  numpy, to show what a very wide "hysteresis" does on a ramp-only log.

Run: ``.venv/bin/python bench/real_imu.py`` (about 30 s). Prints the figures, writes
``bench/results/real_imu.json`` and ``docs/figures/real_*.png``.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import replace
from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from tak_thermo_ros.formats.calibration_file import write_text_atomic  # noqa: E402
from tak_thermo_ros.formats.csv_log.options import CsvImportOptions  # noqa: E402
from tak_thermo_ros.formats.csv_log.reader import read_csv_log  # noqa: E402
from tak_thermo_ros.core.diagnose import diagnose  # noqa: E402
from tak_thermo_ros.core.effects import seconds_from_ns  # noqa: E402
from tak_thermo_ros.core.fit import fit_calibration, fit_model, residual_counts  # noqa: E402
from tak_thermo_ros.core.records.record import align  # noqa: E402
from tak_thermo_ros.core.values import STANDARD_GRAVITY  # noqa: E402
from tak_thermo_ros.core.link.validate import validate_gravity  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
LOG = ROOT / 'data' / 'tofupilot-imu-thermal' / 'imu_raw_data.csv'
FIGURES = ROOT / 'docs' / 'figures'
RESULTS = ROOT / 'bench' / 'results'
OPTIONS = CsvImportOptions(acc_columns=('imu.acc.x', 'imu.acc.y', 'imu.acc.z'), temp_column='imu.temperature',
                           time_unit='us')
SETTLE_S = 60.0
"""The start-up minute left out (``tak_calib fit --settle-time 60``)."""
BLOCKS = 10
T_975_DOF_9 = 2.262
RATE_WINDOW_S = 30.0
PLAY_WIDTHS_C = (4.0, 8.0, 16.0, 32.0, 46.0, 64.0, 80.0, 96.0)
AXES = 'xyz'
MODELS = {'base': (), 'thermal_lag': ('thermal_lag',), 'thermal_lag_per_axis': ('thermal_lag_per_axis',),
          'hysteresis': ('hysteresis',),
          'thermal_lag+hysteresis': ('thermal_lag', 'hysteresis')}


def mg(counts):
    """Counts (0.001 m/s^2 each) in milli-g."""
    return np.asarray(counts) * OPTIONS.acc_resolution / STANDARD_GRAVITY * 1e3


def temperature_rate(time_s: np.ndarray, temp_code: np.ndarray, window_s: float) -> np.ndarray:
    """dN_t/dt in codes per second, a centred difference over ``window_s``."""
    before = np.searchsorted(time_s, time_s - window_s / 2.0)
    after = np.minimum(np.searchsorted(time_s, time_s + window_s / 2.0), len(time_s) - 1)
    return (temp_code[after] - temp_code[before]) / np.maximum(time_s[after] - time_s[before], 1e-9)


def contiguous_blocks(count: int) -> np.ndarray:
    """Block label 0..BLOCKS-1 of each sample, equal numbers of samples, in time order."""
    return np.minimum((np.arange(count) * BLOCKS) // count, BLOCKS - 1)


def blocked_cv(samples, nominal, effects, *, scored=None) -> dict:
    """Per-block held-out MSE ``(BLOCKS, 3)`` of base + ``effects`` and the fitted effect values per fold."""
    block = contiguous_blocks(len(samples))
    scored = np.ones(len(samples), dtype=bool) if scored is None else scored
    low, high = float(samples.temp_code.min()), float(samples.temp_code.max())
    mse = np.zeros((BLOCKS, 3))
    values = []
    for held in range(BLOCKS):
        result = fit_model(samples, effects=effects, nominal_scale=nominal, train_mask=(block != held) & scored)
        calibration = replace(result.calibration, temp_code_min=low, temp_code_max=high)
        mse[held] = np.mean(residual_counts(calibration, samples)[(block == held) & scored] ** 2, axis=0)
        values.append({effect.name: dict(effect.values) for effect in result.calibration.effects})
    return {'mse': mse, 'heldout_rms': np.sqrt(mse.mean(axis=0)), 'values': values}


def paired(before: dict, after: dict) -> dict:
    """Mean and standard error of the per-block MSE gain ``before - after``, per axis; t; blocks won."""
    gain = before['mse'] - after['mse']
    mean = gain.mean(axis=0)
    stderr = gain.std(axis=0, ddof=1) / math.sqrt(BLOCKS)
    return {'mean': mean, 'stderr': stderr, 't': mean / stderr, 'wins': (gain > 0).sum(axis=0)}


def play_width_scan(samples, nominal) -> dict[float, np.ndarray]:
    """Held-out RMS of base + a play of each full width (numpy; beyond the library's search range)."""
    codes = samples.temp_code
    ref = round((codes.min() + codes.max()) / 2.0)
    scale = max(abs(codes.min() - ref), abs(codes.max() - ref))
    base = np.vander((codes - ref) / scale, 4, increasing=True)
    target = samples.counts - np.asarray(nominal) * samples.reference
    block = contiguous_blocks(len(samples))
    out = {}
    for width_c in PLAY_WIDTHS_C:
        half = width_c / OPTIONS.temp_resolution / 2.0
        signal = np.empty(len(codes))
        position = codes[0]
        for k, code in enumerate(codes.tolist()):
            position = min(max(position, code - half), code + half)
            signal[k] = (code - position) / half
        design = np.column_stack([base, signal])
        errors = []
        for held in range(BLOCKS):
            beta, *_ = np.linalg.lstsq(design[block != held], target[block != held], rcond=None)
            errors.append(target[block == held] - design[block == held] @ beta)
        out[width_c] = np.sqrt(np.mean(np.concatenate(errors) ** 2, axis=0))
    return out


def main() -> None:
    started = time.perf_counter()
    log = read_csv_log(LOG, OPTIONS)
    record = log.record
    nominal = record.nominal_scale
    everything = align(record)
    samples = align(record, settle_time_s=SETTLE_S)
    base = fit_calibration(samples, nominal_scale=nominal)
    residual = residual_counts(base.calibration, samples)
    time_s = (samples.stamp_ns - record.counts_stamp_ns[0]) * 1e-9
    floor = np.std(np.diff(samples.counts, axis=0), axis=0) / math.sqrt(2.0)
    rate = temperature_rate(time_s, samples.temp_code, RATE_WINDOW_S) * 60.0 * OPTIONS.temp_resolution
    correlation = np.array([np.corrcoef(residual[:, i], rate)[0, 1] for i in range(3)])

    diagnosis = diagnose(base.calibration, samples)
    scores = {name: blocked_cv(samples, nominal, effects) for name, effects in MODELS.items()}
    comparisons = {name: paired(scores['base'], scores[name]) for name in MODELS if name != 'base'}
    lag_versus_hysteresis = paired(scores['hysteresis'], scores['thermal_lag'])
    lag_versus_both = paired(scores['thermal_lag'], scores['thermal_lag+hysteresis'])
    shared_versus_per_axis = paired(scores['thermal_lag'], scores['thermal_lag_per_axis'])

    # The start-up minute kept: the lag alone, and the lag plus a warm-up exponential.
    all_time = (everything.stamp_ns - record.counts_stamp_ns[0]) * 1e-9
    startup = {'thermal_lag, first minute kept': blocked_cv(everything, nominal, ('thermal_lag',)),
               'thermal_lag+warmup, first minute kept': blocked_cv(everything, nominal, ('thermal_lag', 'warmup'))}
    settled = all_time >= SETTLE_S
    lag_on_settled = fit_model(everything, effects=('thermal_lag',), nominal_scale=nominal, train_mask=settled)
    first_minute = residual_counts(lag_on_settled.calibration, everything)[~settled]
    first_row_jump = everything.counts[1] - everything.counts[0]

    widths = play_width_scan(samples, nominal)
    lag = fit_model(samples, effects=('thermal_lag',), nominal_scale=nominal)
    lag_residual = residual_counts(lag.calibration, samples)
    lag_values = dict(lag.calibration.effects[0].values)
    gravity_base = validate_gravity(base.calibration, samples.counts, samples.temp_code, gravity=STANDARD_GRAVITY)
    gravity_after_lag = validate_gravity(lag.calibration, samples.counts, samples.temp_code, gravity=STANDARD_GRAVITY,
                                         stamp_s=seconds_from_ns(samples.stamp_ns)).after.rms

    print(f'{log.rows} rows, {log.duration_s:.0f} s at {(log.rows - 1) / log.duration_s:.2f} Hz; fitted '
          f'{len(samples)} samples, the first {SETTLE_S:g} s ({len(everything) - len(samples)} samples) left out')
    print('reference (mean direction x g):', np.round(log.reference, 4), 'm/s^2')
    for i, axis in enumerate(AXES):
        rms = base.axes[i].residual_rms
        print(f'{axis}: base residual RMS {rms:6.2f} counts ({mg(rms):.2f} mg), '
              f'noise floor {floor[i]:.2f} counts, corr(residual, dT/dt) {correlation[i]:+.2f}')
    print(f'diagnose: verdict {diagnosis.verdict}; ladder ' + '; '.join(
        f'{step.label}: {np.round(step.heldout_rms, 2).tolist()}' for step in diagnosis.ladder))
    for candidate in diagnosis.candidates:
        print(f'  {candidate.effect:18s} held-out {np.round(candidate.rms_after, 2).tolist()}, '
              f'explains {candidate.explained:.0%} of the excess')
    for candidate in diagnosis.per_axis_forms:
        print(f'  per-axis form tried: {candidate.effect}: {candidate.evidence}')
    print(f'blocked CV, {BLOCKS} contiguous blocks, held-out RMS in counts (1 count = 0.001 m/s^2 = 0.102 mg):')
    for name, score in {**scores, **startup}.items():
        rms = score['heldout_rms']
        print(f'  {name:38s} x {rms[0]:6.2f}  y {rms[1]:6.2f}  z {rms[2]:6.2f}   (z {rms[2] / 1000:.4f} m/s^2, '
              f'{mg(rms[2]):.2f} mg)')
    for name, c in {**{f'base -> {k}': v for k, v in comparisons.items()},
                    'hysteresis -> thermal_lag': lag_versus_hysteresis,
                    'thermal_lag -> thermal_lag+hysteresis': lag_versus_both,
                    'thermal_lag -> thermal_lag_per_axis': shared_versus_per_axis}.items():
        print(f'  {name:40s} MSE gain per axis {np.round(c["mean"], 1).tolist()} '
              f'+/- {np.round(c["stderr"], 1).tolist()} '
              f'counts^2, t {np.round(c["t"], 2).tolist()}, blocks won {c["wins"].tolist()}')
    taus = [v['thermal_lag']['tau_s'] for v in scores['thermal_lag']['values']]
    plays = [v['hysteresis']['width_codes'] * OPTIONS.temp_resolution for v in scores['hysteresis']['values']]
    print(f'  thermal_lag tau_s per fold {np.round(taus).astype(int).tolist()}; whole log {lag_values}')
    print(f'  hysteresis width per fold (C) {np.round(plays, 1).tolist()}')
    print('  play-width scan (numpy), held-out RMS: ' + '; '.join(
        f'{w:g} C {np.round(r, 1).tolist()}' for w, r in widths.items()))
    print(f'start-up: first row jumps {first_row_jump.tolist()} counts to the second; first-minute residual of the '
          f'lag model fitted after it: RMS {np.round(np.sqrt(np.mean(first_minute ** 2, axis=0)), 1).tolist()} counts')
    print(f'|g| error RMS: nominal {gravity_base.before.rms:.4f}, base {gravity_base.after.rms:.4f}, '
          f'base + thermal_lag {gravity_after_lag:.4f} m/s^2')

    FIGURES.mkdir(parents=True, exist_ok=True)
    _figures(log, samples, base, residual, time_s, rate, floor, scores, lag, lag_residual, everything, all_time,
             lag_on_settled)
    document = {
        'rows': log.rows, 'duration_s': log.duration_s, 'settle_s': SETTLE_S, 'blocks': BLOCKS,
        'reference_m_s2': log.reference.tolist(), 'noise_floor_counts': floor.tolist(),
        'base_residual_rms_counts': [a.residual_rms for a in base.axes],
        'corr_residual_dTdt': correlation.tolist(),
        'diagnose': {'verdict': diagnosis.verdict,
                     'ladder': [step.as_dict() for step in diagnosis.ladder],
                     'candidates': [{'effect': c.effect, 'rms_after': list(c.rms_after), 'explained': c.explained}
                                    for c in diagnosis.candidates],
                     'per_axis_forms': [{'effect': c.effect, 'rms_after': list(c.rms_after), 'evidence': c.evidence}
                                        for c in diagnosis.per_axis_forms]},
        'heldout_rms_counts': {name: s['heldout_rms'].tolist() for name, s in {**scores, **startup}.items()},
        'paired_mse_gain': {name: {k: np.asarray(v).tolist() for k, v in c.items()} for name, c in comparisons.items()},
        'hysteresis_to_lag': {k: np.asarray(v).tolist() for k, v in lag_versus_hysteresis.items()},
        'lag_to_lag_plus_hysteresis': {k: np.asarray(v).tolist() for k, v in lag_versus_both.items()},
        'lag_to_lag_per_axis': {k: np.asarray(v).tolist() for k, v in shared_versus_per_axis.items()},
        'thermal_lag_tau_s_per_fold': taus, 'thermal_lag_whole_log': lag_values,
        'hysteresis_width_c_per_fold': plays,
        'play_width_scan_heldout_rms': {str(w): r.tolist() for w, r in widths.items()},
        'first_minute_residual_rms_counts': np.sqrt(np.mean(first_minute ** 2, axis=0)).tolist(),
        'first_row_jump_counts': first_row_jump.tolist(),
        'gravity_error_rms_m_s2': {'nominal': gravity_base.before.rms, 'base': gravity_base.after.rms,
                                   'base+thermal_lag': gravity_after_lag},
        'seconds': time.perf_counter() - started,
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    write_text_atomic(RESULTS / 'real_imu.json', json.dumps(document, indent=2) + '\n')
    print(f'wrote {RESULTS / "real_imu.json"} and docs/figures/real_*.png in {document["seconds"]:.1f} s')


def _branch_scatter(ax, celsius, values, heating) -> None:
    ax.scatter(celsius[heating], values[heating], s=1, c='tab:red', label='heating')
    ax.scatter(celsius[~heating], values[~heating], s=1, c='tab:blue', label='cooling')
    ax.set_xlabel('die temperature (C)')


def _figures(log, samples, base, residual, time_s, rate, floor, scores, lag, lag_residual, everything, all_time,
             lag_on_settled) -> None:
    to_ms2 = OPTIONS.acc_resolution
    minutes = time_s / 60.0
    celsius = samples.temp_code * OPTIONS.temp_resolution
    heating = rate > 0.0

    # 1. The data and the base fit: N - K0 f against temperature, heating and cooling.
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    target = samples.counts - samples.reference * np.array(log.record.nominal_scale)
    grid = np.linspace(samples.temp_code.min(), samples.temp_code.max(), 300)
    for i, ax in enumerate(axes):
        model = base.calibration.axes[i]
        _branch_scatter(ax, celsius, target[:, i] * to_ms2, heating)
        curve = model.offset + model.offset_drift(grid - base.calibration.temp_code_ref)
        ax.plot(grid * OPTIONS.temp_resolution, curve * to_ms2, 'k', lw=1.5, label='base fit (cubic)')
        ax.set_title(f'{AXES[i]}: measured minus reference')
        ax.set_ylabel('offset (m/s^2)')
    axes[0].legend(markerscale=6, fontsize=8)
    fig.suptitle('Real MEMS IMU, one orientation: base model (offset cubic in temperature, scale held)')
    fig.tight_layout()
    fig.savefig(FIGURES / 'real_base_fit.png', dpi=90)
    plt.close(fig)

    # 2. Diagnosis: residual vs time, vs temperature (heating/cooling), vs dT/dt.
    fig, axes = plt.subplots(3, 3, figsize=(14, 10))
    for i in range(3):
        r = residual[:, i] * to_ms2
        ax = axes[0, i]
        ax.plot(minutes, r, lw=0.4, color='0.3')
        ax.axhspan(-floor[i] * to_ms2, floor[i] * to_ms2, color='tab:green', alpha=0.3, label='noise floor (1 sigma)')
        twin = ax.twinx()
        twin.plot(minutes, celsius, 'tab:orange', lw=0.8)
        twin.set_ylabel('T (C)', color='tab:orange')
        ax.set_xlabel('time (min)')
        ax.set_ylabel(f'{AXES[i]} residual (m/s^2)')
        _branch_scatter(axes[1, i], celsius, r, heating)
        axes[1, i].set_ylabel(f'{AXES[i]} residual (m/s^2)')
        points = axes[2, i].scatter(rate, r, s=1, c=minutes, cmap='viridis')
        axes[2, i].set_xlabel('dT/dt (C/min, 30 s window)')
        axes[2, i].set_ylabel(f'{AXES[i]} residual (m/s^2)')
    axes[0, 0].legend(fontsize=8, loc='lower left')
    axes[1, 0].legend(markerscale=6, fontsize=8)
    fig.colorbar(points, ax=axes[2, 2], label='time (min)')
    fig.suptitle('Base-model residual: loops between heating and cooling that follow dT/dt')
    fig.tight_layout()
    fig.savefig(FIGURES / 'real_diagnosis.png', dpi=80)
    plt.close(fig)

    # 3. Base + thermal_lag: residual vs temperature (heating/cooling) and vs time.
    tau = lag.calibration.effects[0].values['tau_s']
    fig, axes = plt.subplots(2, 3, figsize=(14, 7))
    for i in range(3):
        r = lag_residual[:, i] * to_ms2
        _branch_scatter(axes[0, i], celsius, r, heating)
        axes[0, i].set_ylabel(f'{AXES[i]} residual (m/s^2)')
        axes[1, i].plot(minutes, residual[:, i] * to_ms2, lw=0.4, color='tab:gray', label='base')
        axes[1, i].plot(minutes, r, lw=0.4, color='k', label='base + thermal_lag')
        axes[1, i].set_xlabel('time (min)')
        axes[1, i].set_ylabel(f'{AXES[i]} residual (m/s^2)')
        low, high = axes[1, i].get_ylim()
        axes[0, i].set_ylim(low, high)
    axes[0, 0].legend(markerscale=6, fontsize=8)
    axes[1, 0].legend(fontsize=8)
    fig.suptitle(f'Base + thermal_lag (tau {tau:.0f} s): the loops close; left on z: a step at 17 min (-10 C)')
    fig.tight_layout()
    fig.savefig(FIGURES / 'real_lag_fit.png', dpi=80)
    plt.close(fig)

    # 4. Held-out error, 10 contiguous blocks.
    fig, ax = plt.subplots(figsize=(8, 4.2))
    names = list(scores)
    width = 0.8 / len(names)
    for k, name in enumerate(names):
        ax.bar(np.arange(3) + k * width, scores[name]['heldout_rms'] * to_ms2, width, label=name)
    centre = np.arange(3) + 0.4 - width / 2
    ax.plot(centre, floor * to_ms2, 'k_', markersize=30, mew=2, label='noise floor')
    ax.set_xticks(centre, list(AXES))
    ax.set_ylabel('held-out RMS (m/s^2)')
    secondary = ax.secondary_yaxis('right', functions=(lambda v: v / STANDARD_GRAVITY * 1e3,
                                                       lambda v: v * STANDARD_GRAVITY / 1e3))
    secondary.set_ylabel('mg')
    ax.set_title(f'Held-out error, {BLOCKS} contiguous time blocks (each fitted without it)')
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(FIGURES / 'real_heldout.png', dpi=90)
    plt.close(fig)

    # 5. Start-up: the first three minutes.
    first = all_time < 180.0
    start_residual = residual_counts(lag_on_settled.calibration, everything)
    fig, axes = plt.subplots(1, 2, figsize=(12, 3.8))
    axes[0].plot(all_time[first], everything.counts[first, 2] * to_ms2, '.-', ms=3, lw=0.5)
    axes[1].plot(all_time[first], start_residual[first, 2] * to_ms2, '.', ms=3)
    for ax in axes:
        ax.axvline(SETTLE_S, color='k', ls='--', label='fit uses samples after this')
        ax.set_xlabel('time since the first row (s)')
    axes[0].set_ylabel('z measured (m/s^2)')
    axes[1].set_ylabel('z residual, base + thermal_lag (m/s^2)')
    axes[0].legend(fontsize=8)
    fig.suptitle('Start-up: an outlying first row, then a transient during the steepest cooling (-7 C/min)')
    fig.tight_layout()
    fig.savefig(FIGURES / 'real_startup.png', dpi=90)
    plt.close(fig)


if __name__ == '__main__':
    main()
