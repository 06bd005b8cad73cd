"""The diagnosis report's figures (matplotlib, Agg backend), one function per figure.

Figures (matplotlib, Agg backend, written into the report directory):

- ``residual_time.png``: temperature code and the residual of each axis against time; the
  noise floor as a band, the stretches where the residual rises above it shaded red.
- ``residual_temperature.png``: the residual against the temperature code, heating (red)
  and cooling (blue) apart: thermal lag and hysteresis draw loops here.
- ``residual_rate.png``: the residual against ``dN_t/dt``: a thermal lag draws a slope.
- ``residual_inputs.png``: the residual of each axis against each axis' input: its own
  (scale nonlinearity draws a parabola) and the others (cross-axis coupling draws a line); not
  drawn for a record with one input per axis (a line says why).
- ``residual_plateaus.png``: the mean residual on each temperature plateau, by the direction
  it was reached from: hysteresis keeps the two apart, lag does not; not drawn for fewer than two
  plateaus (a line says why).
- ``ladder.png``: held-out RMS over the noise floor of the model ladder and of every candidate.
- ``gravity.png``: ``|g| - g`` before and after correction, as in the paper's Figs. 4-5.


The figures are labelled in counts; :mod:`tak_thermo_ros.reports.diagnose` relabels a driver's
in degrees C as it writes them into the page. A driver's |g| *before* is the values as recorded,
as ``validate`` prints it. This module may import the core, never rosbags or rclpy.
"""

from __future__ import annotations

import math
from typing import Sequence

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from tak_thermo_ros.core.diagnose import Diagnosis, binned_means  # noqa: E402
from tak_thermo_ros.core.link.model import AXES  # noqa: E402
from tak_thermo_ros.core.records.record import AlignedSamples  # noqa: E402
from tak_thermo_ros.core.link.validate import validate_gravity  # noqa: E402

HEATING = '#d62728'
COOLING = '#1f77b4'
STEADY = '#7f7f7f'
BEFORE = '#222222'
AFTER = '#2ca02c'
FAIL = '#ff9896'
DPI = 100
MAX_SCATTER = 4000
TIME_BINS = 150


def _direction_colour(direction: int) -> str:
    return HEATING if direction > 0 else COOLING if direction < 0 else STEADY


def _time_axis(time_s: np.ndarray) -> tuple[np.ndarray, str]:
    duration = float(time_s[-1]) if len(time_s) else 0.0
    if duration > 3 * 3600.0:
        return time_s / 3600.0, 'time (h)'
    if duration > 180.0:
        return time_s / 60.0, 'time (min)'
    return time_s, 'time (s)'


def _thin(count: int, limit: int = MAX_SCATTER) -> np.ndarray:
    """Indices of at most ``limit`` evenly spread samples."""
    return np.unique(np.linspace(0, count - 1, min(count, limit)).astype(np.int64))


def failing_spans(time: np.ndarray, residual: np.ndarray, floor: float, bins: int) -> list[tuple[float, float]]:
    """Time spans where the residual's mean or RMS rises clearly above the noise floor.

    A span is one of ``bins`` equal-duration bins where the bin mean exceeds four standard
    errors of noise and half the floor, or the bin's variance exceeds the floor's by four
    standard errors and 25 % (a systematic part a quarter as large as the noise's variance).
    """
    edges = np.linspace(time[0], time[-1] + 1e-9, bins + 1)
    index = np.clip(np.searchsorted(edges, time, side='right') - 1, 0, bins - 1)
    counts = np.bincount(index, minlength=bins).astype(float)
    sums = np.bincount(index, weights=residual, minlength=bins)
    squares = np.bincount(index, weights=residual ** 2, minlength=bins)
    with np.errstate(invalid='ignore', divide='ignore'):
        mean = sums / counts
        ratio = squares / counts / floor ** 2 - 1.0
        shifted = (np.abs(mean) > 4.0 * floor / np.sqrt(counts)) & (np.abs(mean) > 0.5 * floor)
        noisy = (ratio > 4.0 * np.sqrt(2.0 / counts)) & (ratio > 0.25)
    bad = (counts > 1) & (shifted | noisy)
    spans = []
    for start in np.flatnonzero(bad & ~np.concatenate(([False], bad[:-1]))):
        stop = start
        while stop + 1 < bins and bad[stop + 1]:
            stop += 1
        spans.append((float(edges[start]), float(edges[stop + 1])))
    return spans


def _mean_noise(floor: float, samples: int, bins: int) -> float:
    """Two standard errors of a bin mean of white noise at the floor (typical bin size)."""
    return 2.0 * floor / math.sqrt(max(samples / max(bins, 1), 1.0))


def _figure(rows: int, cols: int, width: float, height: float, **kwargs) -> tuple[Figure, np.ndarray]:
    fig, axes = plt.subplots(rows, cols, figsize=(width, height), squeeze=False, **kwargs)
    return fig, axes


def _legend_lines(ax, entries: Sequence[tuple[str, str, str]]) -> None:
    from matplotlib.lines import Line2D
    handles = [Line2D([], [], color=colour, linestyle=style, linewidth=2) for _, colour, style in entries]
    ax.legend(handles, [label for label, _, _ in entries], loc='upper right', fontsize=8, framealpha=0.85)


def figure_residual_time(diagnosis: Diagnosis) -> Figure:
    """Temperature code and residuals against time, failing stretches shaded."""
    views = diagnosis.views
    time, unit = _time_axis(views.time_s)
    floor = diagnosis.white_floor
    fig, axes = _figure(4, 1, 11.0, 9.5, sharex=True, gridspec_kw={'height_ratios': [1.0, 1.4, 1.4, 1.4]})
    top = axes[0, 0]
    for direction in (1, -1, 0):
        mask = views.direction == direction
        pick = np.flatnonzero(mask)[_thin(int(mask.sum()), 3000)] if mask.any() else np.zeros(0, int)
        top.scatter(time[pick], views.temp_code[pick], s=2, color=_direction_colour(direction),
                    label={1: 'heating', -1: 'cooling', 0: 'steady'}[direction], rasterized=True)
    top.set_ylabel('temperature code $N_t$')
    top.legend(loc='upper right', fontsize=8, markerscale=4, ncol=3)
    top.set_title('Residual N - model against time (counts); red: where it rises above the noise floor')
    thin = _thin(len(time))
    for i, name in enumerate(AXES):
        ax = axes[i + 1, 0]
        residual = diagnosis.residual[:, i]
        for start, stop in failing_spans(time, residual, floor[i], TIME_BINS):
            ax.axvspan(start, stop, color=FAIL, alpha=0.35, linewidth=0)
        ax.axhspan(-floor[i], floor[i], color='#c7c7c7', alpha=0.6, linewidth=0)
        ax.scatter(time[thin], residual[thin], s=1.5, color='#9e9e9e', alpha=0.6, rasterized=True)
        centres, means, _ = binned_means(residual, time, TIME_BINS)
        ax.plot(centres, means, color=BEFORE, linewidth=1.6)
        entries = [(f'{diagnosis.ladder[0].label} (binned mean)', BEFORE, '-'), ('noise floor band', '#c7c7c7', '-')]
        if diagnosis.residual_after is not None:
            centres, means, _ = binned_means(diagnosis.residual_after[:, i], time, TIME_BINS)
            ax.plot(centres, means, color=AFTER, linewidth=1.6)
            entries.insert(1, (diagnosis.ladder[-1].label, AFTER, '-'))
        spread = max(float(np.percentile(np.abs(residual), 99.5)), 3.0 * floor[i])
        ax.set_ylim(-1.15 * spread, 1.15 * spread)
        ax.set_ylabel(f'{name} residual (counts)')
        ax.grid(alpha=0.3)
        if i == 0:
            _legend_lines(ax, entries)
    axes[-1, 0].set_xlabel(unit)
    fig.tight_layout()
    return fig


def _split_by_direction(ax, key: np.ndarray, residual: np.ndarray, direction: np.ndarray, bins: int,
                        style: str, alpha: float) -> np.ndarray:
    """Binned means of the residual against ``key``, heating and cooling apart, steady as dots.

    :returns: the sample counts of the drawn bins.
    """
    edges = np.linspace(float(key.min()), float(key.max()) + 1e-9, bins + 1)
    drawn = []
    for value in (1, -1):
        mask = direction == value
        if mask.sum() < 5:
            continue
        centres, means, counts = binned_means(residual[mask], key[mask], bins, edges=edges)
        keep = counts >= 3
        ax.plot(centres[keep], means[keep], style, color=_direction_colour(value), alpha=alpha,
                linewidth=1.8, markersize=3)
        drawn.append(counts[keep])
    mask = direction == 0
    if mask.sum() >= 5:
        centres, means, counts = binned_means(residual[mask], key[mask], bins, edges=edges)
        keep = counts >= 3
        ax.plot(centres[keep], means[keep], 'o', color=STEADY, alpha=alpha, markersize=3.5)
    return np.concatenate(drawn) if drawn else np.zeros(0)


def _residual_rows(diagnosis: Diagnosis) -> list[tuple[str, np.ndarray]]:
    rows = [(diagnosis.ladder[0].label, diagnosis.residual)]
    if diagnosis.residual_after is not None:
        rows.append((diagnosis.ladder[-1].label, diagnosis.residual_after))
    return rows


def figure_residual_temperature(diagnosis: Diagnosis) -> Figure:
    """Residual against the temperature code, heating and cooling apart."""
    views = diagnosis.views
    rows = _residual_rows(diagnosis)
    fig, axes = _figure(len(rows), 3, 12.0, 3.6 * len(rows) + 0.6, sharex=True, sharey='col')
    for r, (label, residual) in enumerate(rows):
        for i, name in enumerate(AXES):
            ax = axes[r, i]
            counts = _split_by_direction(ax, views.temp_code, residual[:, i], views.direction, 40, '-', 1.0)
            typical = float(np.median(counts)) if len(counts) else float(len(residual))
            band = _mean_noise(diagnosis.white_floor[i], int(typical), 1)
            ax.axhspan(-band, band, color='#c7c7c7', alpha=0.6, linewidth=0, zorder=0)
            ax.axhline(0.0, color='k', linewidth=0.6)
            ax.set_title(f'{name}: {label}', fontsize=10)
            ax.grid(alpha=0.3)
            if i == 0:
                ax.set_ylabel('mean residual (counts)')
            if r == len(rows) - 1:
                ax.set_xlabel('temperature code $N_t$')
    _legend_lines(axes[0, 0], [('heating', HEATING, '-'), ('cooling', COOLING, '-'),
                               ('noise of a bin mean (2 sigma)', '#c7c7c7', '-')])
    fig.suptitle('Residual against temperature code (binned means): heating and cooling should coincide', fontsize=11)
    fig.tight_layout()
    return fig


def figure_residual_rate(diagnosis: Diagnosis) -> Figure:
    """Residual against the temperature rate ``dN_t/dt``."""
    views = diagnosis.views
    rate = views.rate * 60.0
    rows = _residual_rows(diagnosis)
    fig, axes = _figure(1, 3, 12.0, 3.8)
    low, high = np.percentile(rate, [0.5, 99.5])
    reach = max(abs(float(low)), abs(float(high)), 1e-9)
    edges = np.linspace(-reach, reach, 32)
    for i, name in enumerate(AXES):
        ax = axes[0, i]
        band = _mean_noise(diagnosis.white_floor[i], len(rate), 4 * (len(edges) - 1))
        ax.axhspan(-band, band, color='#c7c7c7', alpha=0.6, linewidth=0)
        for (label, residual), colour in zip(rows, (BEFORE, AFTER)):
            inside = (rate >= edges[0]) & (rate <= edges[-1])
            centres, means, counts = binned_means(residual[inside, i], rate[inside], 0, edges=edges)
            keep = counts >= 20
            ax.plot(centres[keep], means[keep], 'o-', color=colour, markersize=3, linewidth=1.4, label=label)
        ax.axhline(0.0, color='k', linewidth=0.6)
        ax.set_title(name, fontsize=10)
        ax.set_xlabel('$dN_t/dt$ (codes per minute)')
        ax.grid(alpha=0.3)
        if i == 0:
            ax.set_ylabel('mean residual (counts)')
            ax.legend(fontsize=8, title='grey: noise of a bin mean', title_fontsize=7)
    fig.suptitle('Residual against the temperature rate: a slope means the drift lags the sensor', fontsize=11)
    fig.tight_layout()
    return fig


def figure_residual_inputs(diagnosis: Diagnosis) -> Figure:
    """Residual of each axis (rows) against each axis' input (columns)."""
    views = diagnosis.views
    rows = _residual_rows(diagnosis)
    fig, axes = _figure(3, 3, 11.0, 8.5)
    for i, name in enumerate(AXES):
        for j, source in enumerate(AXES):
            ax = axes[i, j]
            force = views.specific_force[:, j]
            levels, index = np.unique(np.round(force, 6), return_inverse=True)
            if len(levels) > 40:
                edges = np.linspace(force.min(), force.max() + 1e-9, 25)
                index = np.clip(np.searchsorted(edges, force, side='right') - 1, 0, len(edges) - 2)
            counts = np.bincount(index).astype(float)
            filled = counts > 0
            centre = (np.bincount(index, weights=force) / np.maximum(counts, 1))[filled]
            for (label, residual), colour, shift in zip(rows, (BEFORE, AFTER), (-0.08, 0.08)):
                values = residual[:, i]
                mean = (np.bincount(index, weights=values) / np.maximum(counts, 1))[filled]
                error = 2.0 * diagnosis.white_floor[i] / np.sqrt(counts[filled])
                ax.errorbar(centre + shift, mean, yerr=error, fmt='o', color=colour, markersize=3.5,
                            capsize=2, label=label)
            ax.axhline(0.0, color='k', linewidth=0.6)
            ax.grid(alpha=0.3)
            if i == 2:
                ax.set_xlabel(f'input $f_{source}$ (m/s$^2$)')
            if j == 0:
                ax.set_ylabel(f'{name} mean residual (counts)')
            kind = 'own input' if i == j else 'cross-axis'
            ax.set_title(f'{name} vs $f_{source}$ ({kind})', fontsize=9)
    axes[0, 0].legend(fontsize=7)
    fig.suptitle('Residual against the inputs: diagonal = own input (curvature: scale nonlinearity), '
                 'off-diagonal = cross-axis (slope: misalignment)', fontsize=10)
    fig.tight_layout()
    return fig


def figure_residual_plateaus(diagnosis: Diagnosis) -> Figure:
    """Mean residual per temperature plateau, marked by the direction it was reached from."""
    views = diagnosis.views
    rows = _residual_rows(diagnosis)
    fig, axes = _figure(1, 3, 12.0, 3.8)
    plateaus = views.plateaus
    for i, name in enumerate(AXES):
        ax = axes[0, i]
        for (label, residual), marker, fill in zip(rows, ('o', 's'), (True, False)):
            for plateau in plateaus:
                # The second half of each plateau: a lag has settled there, hysteresis has not.
                middle = (plateau.start + plateau.stop) // 2
                part = residual[middle:plateau.stop, i]
                colour = _direction_colour(plateau.approach)
                ax.errorbar(plateau.temp_code, float(np.mean(part)),
                            yerr=2.0 * diagnosis.white_floor[i] / math.sqrt(len(part)), fmt=marker,
                            color=colour, markerfacecolor=colour if fill else 'white', markersize=6, capsize=2)
        ax.axhline(0.0, color='k', linewidth=0.6)
        ax.set_title(name, fontsize=10)
        ax.set_xlabel('plateau temperature code $N_t$')
        ax.grid(alpha=0.3)
        if i == 0:
            ax.set_ylabel('mean residual, settled half (counts)')
    from matplotlib.lines import Line2D
    handles = [Line2D([], [], marker='o', linestyle='', color=colour) for colour in (HEATING, COOLING, STEADY)]
    names = ['reached by heating', 'reached by cooling', 'start']
    if len(rows) > 1:
        handles += [Line2D([], [], marker='o', linestyle='', color='k'),
                    Line2D([], [], marker='s', linestyle='', color='k', markerfacecolor='white')]
        names += [rows[0][0], rows[1][0]]
    axes[0, 0].legend(handles, names, fontsize=7)
    if not plateaus:
        for ax in axes[0]:
            ax.text(0.5, 0.5, 'no temperature plateau in this run', transform=ax.transAxes, ha='center')
    fig.suptitle('Mean residual per temperature plateau: reached by heating vs by cooling', fontsize=11)
    fig.tight_layout()
    return fig


def figure_ladder(diagnosis: Diagnosis) -> Figure:
    """Held-out RMS / floor of the model ladder and of every candidate effect."""
    floor = diagnosis.noise_floor
    fig, axes = _figure(1, 2, 12.0, 4.2, gridspec_kw={'width_ratios': [1.0, 1.3]})
    ax = axes[0, 0]
    steps = diagnosis.ladder
    positions = np.arange(len(steps))
    for i, (name, marker) in enumerate(zip(AXES, ('o', 's', '^'))):
        ratio = [step.heldout_rms[i] / floor[i] for step in steps]
        ax.plot(positions, ratio, marker=marker, linewidth=1.8, markersize=7, label=name)
    ax.axhline(1.0, color='k', linestyle='--', linewidth=1.0, label='noise floor')
    ax.set_xticks(positions, [step.label if k == 0 else '+ ' + step.effects[-1] for k, step in enumerate(steps)])
    ax.set_ylabel('held-out RMS / noise floor')
    ax.set_title('Model ladder (blocked cross-validation)', fontsize=10)
    ax.set_ylim(bottom=0.0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax = axes[0, 1]
    candidates = diagnosis.candidates
    if candidates:
        names = [c.effect for c in candidates][::-1]
        values = [max(np.max(np.array(c.rms_after) / floor), 0.0) for c in candidates][::-1]
        base = float(np.max(np.array(steps[0].heldout_rms) / floor))
        colours = [AFTER if name == diagnosis.verdict else '#aec7e8' for name in names]
        ax.barh(names, values, color=colours)
        ax.axvline(base, color=BEFORE, linewidth=1.5, label=f'{steps[0].label}: {base:.2f}')
        ax.axvline(1.0, color='k', linestyle='--', linewidth=1.0, label='noise floor')
        limit = 1.6 * max(base, 1.0)
        for y, (value, candidate) in enumerate(zip(values, candidates[::-1])):
            ax.text(min(value, limit), y, f'  {value:.2f}  ({round(100 * candidate.explained)}% of excess)',
                    va='center', fontsize=8)
        ax.set_xlim(0.0, limit * 1.45)
        ax.legend(fontsize=8, loc='upper right')
    else:
        ax.text(0.5, 0.5, 'no candidate tried: the residual is at the noise floor', transform=ax.transAxes,
                ha='center', fontsize=10)
        ax.set_yticks([])
    ax.set_xlabel('worst axis: held-out RMS / noise floor')
    ax.set_title(f'Each candidate effect added to {steps[0].label}', fontsize=10)
    fig.tight_layout()
    return fig


def figure_allan(diagnosis: Diagnosis) -> Figure:
    """The residual's Allan deviation before and after each effect of the ladder, against the noise model."""
    fig, axes = _figure(1, 3, 13.0, 4.2)
    colours = (BEFORE, AFTER, '#ff7f0e', '#9467bd', '#8c564b')
    for i, name in enumerate(AXES):
        ax = axes[0, i]
        first = diagnosis.allan[0][1]
        ax.fill_between(first.taus, first.model_adev[:, i], first.model_adev[:, i] * first.bound[:, i],
                        color='#c7c7c7', alpha=0.6, linewidth=0, label='within the bound')
        ax.plot(first.taus, first.model_adev[:, i], color='k', linestyle='--', linewidth=1.4,
                label=f'noise model ({first.source})')
        for k, (label, check) in enumerate(diagnosis.allan):
            ax.plot(check.taus, check.residual_adev[:, i], color=colours[k % len(colours)], marker='o',
                    markersize=3, linewidth=1.6, label=label if k == 0 else '+ ' + label.split(' + ')[-1])
        ax.set_xscale('log')
        ax.set_yscale('log')
        ax.set_xlabel('averaging time tau (s)')
        ax.set_ylabel(f'{name}: Allan deviation (counts)')
        ax.grid(alpha=0.3, which='both')
        if i == 0:
            ax.legend(fontsize=7)
    fig.suptitle('Allan deviation of the residual before and after each effect, against the noise model', fontsize=11)
    fig.tight_layout()
    return fig


def gravity_series(diagnosis: Diagnosis, samples: AlignedSamples, gravity: float, *,
                   as_recorded: bool = False) -> list[tuple[str, np.ndarray]]:
    """``|g| - g`` in m/s^2 (:func:`validate_gravity`, as ``validate`` computes it).

    *Before* (a driver's values as recorded with ``as_recorded``, else the codes through the
    file's nominal scale and offset: ``validate``'s before), the current model, and the model
    with the ladder's effects.
    """
    stamps = samples.stamp_s
    current = validate_gravity(diagnosis.calibration, samples.counts, samples.temp_code, gravity=gravity,
                               stamp_s=stamps, aux=samples.aux, raw_before=as_recorded)
    before = 'as recorded (no correction)' if as_recorded else 'nominal scale and offset only'
    series = [(before, current.magnitude_before - gravity),
              (diagnosis.ladder[0].label, current.magnitude_after - gravity)]
    if diagnosis.calibration_after is not None:
        after = validate_gravity(diagnosis.calibration_after, samples.counts, samples.temp_code, gravity=gravity,
                                 stamp_s=stamps, aux=samples.aux)
        series.append((diagnosis.ladder[-1].label, after.magnitude_after - gravity))
    return series


def figure_gravity(diagnosis: Diagnosis, series: list[tuple[str, np.ndarray]], gravity: float) -> Figure:
    """|g| error before and after correction against time, in mg (the paper's Figs. 4-5)."""
    time, unit = _time_axis(diagnosis.views.time_s)
    fig, axes = _figure(len(series), 1, 11.0, 2.3 * len(series) + 0.8, sharex=True)
    thin = _thin(len(time), 6000)
    colours = ('#8c564b', BEFORE, AFTER)
    for r, ((label, error), colour) in enumerate(zip(series, colours)):
        ax = axes[r, 0]
        mg = error / gravity * 1e3
        ax.scatter(time[thin], mg[thin], s=1.5, color=colour, alpha=0.5, rasterized=True)
        rms = float(np.sqrt(np.mean(mg ** 2)))
        for level in (-rms, rms):
            ax.axhline(level, color=colour, linestyle='--', linewidth=1.0)
        ax.axhline(0.0, color='k', linewidth=0.6)
        ax.set_title(f'{label}: RMS {rms:.3f} mg, max {float(np.max(np.abs(mg))):.3f} mg', fontsize=10)
        ax.set_ylabel('|g| - g (mg)')
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel(unit)
    fig.suptitle('|g| from the three channels minus local gravity (the paper\'s Figs. 4-5)', fontsize=11)
    fig.tight_layout()
    return fig
