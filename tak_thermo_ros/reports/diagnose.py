"""The diagnosis report: PNG figures and one self-contained HTML page.

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

A driver's record (its temperature in degrees C) is said in degrees throughout: labels, captions
and the verdict (:func:`~tak_thermo_ros.units.in_driver_words`); its |g| *before* is the values
as recorded, as ``validate`` prints it.

``report.html`` embeds every figure as base64 PNG: one file to open or mail, no external
resource. This module may import the core, never rosbags or rclpy.
"""

from __future__ import annotations

import base64
import datetime
import html
import io
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from tak_thermo_ros.core.diagnose import (  # noqa: E402
    VERDICT_NONE,
    VERDICT_UNEXPLAINED,
    Diagnosis,
    binned_means,
)
from tak_thermo_ros.core.fit.design import single_input_axes  # noqa: E402
from tak_thermo_ros.core.link.model import AXES  # noqa: E402
from tak_thermo_ros.core.records.record import AlignedSamples  # noqa: E402
from tak_thermo_ros.core.values import STANDARD_GRAVITY  # noqa: E402
from tak_thermo_ros.core.link.validate import validate_gravity  # noqa: E402
from tak_thermo_ros.units import in_driver_words, readable, readable_unit, significant  # noqa: E402

HEATING = '#d62728'
COOLING = '#1f77b4'
STEADY = '#7f7f7f'
BEFORE = '#222222'
AFTER = '#2ca02c'
FAIL = '#ff9896'
DPI = 100
MAX_SCATTER = 4000
TIME_BINS = 150


@dataclass(frozen=True)
class ReportFiles:
    """What :func:`write_report` wrote."""

    html: Path
    figures: tuple[Path, ...]


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


def _allan_table(diagnosis: Diagnosis) -> str:
    """Per rung and axis: the largest ratio of the residual's Allan deviation to the model's, and where."""
    rows = []
    for label, check in diagnosis.allan:
        cells = []
        for i in range(3):
            ratio = check.ratio[:, i]
            if not len(ratio):
                cells.append('<td>-</td>')
                continue
            t = int(np.argmax(ratio / check.bound[:, i]))
            css = 'bad' if ratio[t] > check.bound[t, i] else 'good'
            cells.append(f'<td class="{css}">{ratio[t]:.2f}x at {check.taus[t]:.3g} s '
                         f'(bound {check.bound[t, i]:.2f})</td>')
        rows.append(f'<tr><td>{html.escape(label)}</td>{"".join(cells)}</tr>')
    return ('<table><tr><th>model</th><th>x</th><th>y</th><th>z</th></tr>' + ''.join(rows) + '</table>')


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


def _write_atomic(path: Path, data: bytes) -> None:
    """Write a file atomically.

    (temporary file beside it, then a rename), readable as the umask allows (``mkstemp`` alone would leave it private
    to the owner).
    """
    umask = os.umask(0)
    os.umask(umask)
    handle, temporary = tempfile.mkstemp(prefix=f'.{path.name}.', suffix='.partial', dir=path.parent)
    try:
        with os.fdopen(handle, 'wb') as stream:
            stream.write(data)
            stream.flush()
            os.fsync(stream.fileno())
        os.chmod(temporary, 0o666 & ~umask)
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def _png_bytes(fig: Figure, path: Path) -> bytes:
    """Render a figure to PNG, write it atomically, return the bytes."""
    buffer = io.BytesIO()
    fig.savefig(buffer, dpi=DPI, format='png')
    plt.close(fig)
    data = buffer.getvalue()
    _write_atomic(path, data)
    return data


_CSS = """
body{font-family:-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:0;background:#f4f5f7;color:#222}
main{max-width:1180px;margin:0 auto;padding:18px 24px 40px}
h1{font-size:24px;margin:8px 0 2px}h2{font-size:19px;margin:28px 0 8px;border-bottom:1px solid #ddd;padding-bottom:4px}
.sub{color:#666;font-size:13px}
.verdict{border-radius:8px;padding:14px 18px;margin:16px 0;color:#fff;font-size:15px;line-height:1.45}
.verdict b{font-size:21px;display:block;margin-bottom:4px}
.v-none{background:#2e7d32}.v-effect{background:#e65100}.v-unexplained{background:#b71c1c}
.card{background:#fff;border-radius:8px;padding:12px 16px;margin:10px 0;box-shadow:0 1px 3px rgba(0,0,0,.12)}
table{border-collapse:collapse;font-size:13.5px;margin:6px 0}
td,th{padding:4px 10px;border-bottom:1px solid #e3e3e3;text-align:right}
th{background:#fafafa}td:first-child,th:first-child{text-align:left}
.bad{color:#b71c1c;font-weight:600}.good{color:#2e7d32;font-weight:600}
figure{margin:12px 0;background:#fff;border-radius:8px;padding:8px;box-shadow:0 1px 3px rgba(0,0,0,.12)}
figure img{width:100%;height:auto}figcaption{font-size:13px;color:#444;padding:4px 8px}
.small{font-size:12.5px;color:#555}
"""


def _axes_table(diagnosis: Diagnosis, unit: str = 'counts') -> str:
    """Per axis the residual, the floor and the held-out RMS in the reader's unit (mg, deg/h, uT), 3 figures."""
    def cell(value: float) -> str:
        return f'<td>{readable(value, unit).split()[0]}</td>'
    rows = []
    for name, axis in zip(AXES, diagnosis.axes):
        ratio = axis.heldout_rms / axis.noise_floor
        css = 'bad' if axis.excess_significant else 'good'
        after = ''
        if diagnosis.residual_after is not None:
            index = AXES.index(name)
            after_rms = float(np.sqrt(np.mean(diagnosis.residual_after[:, index] ** 2)))
            held = diagnosis.ladder[-1].heldout_rms[index]
            after = f'{cell(after_rms)}{cell(held)}<td>{held / axis.noise_floor:.2f}x</td>'
        rows.append(f'<tr><td>{name}</td>{cell(axis.rms)}{cell(axis.noise_floor)}'
                    f'{cell(axis.heldout_rms)}<td class="{css}">{ratio:.2f}x</td>{after}</tr>')
    head_after = ''
    if diagnosis.residual_after is not None:
        label = html.escape(diagnosis.ladder[-1].label)
        head_after = f'<th>{label}: RMS</th><th>held-out RMS</th><th>/ floor</th>'
    return (f'<table><tr><th>axis</th><th>RMS ({html.escape(readable_unit(unit)[0])})</th><th>noise floor</th>'
            f'<th>held-out RMS (refit)</th><th>/ floor</th>{head_after}</tr>' + ''.join(rows) + '</table>')


def _triple(values, unit: str) -> str:
    """Three values in the reader's unit, three significant figures each."""
    return ', '.join(readable(v, unit).split()[0] for v in values)


def _candidates_table(diagnosis: Diagnosis, unit: str = 'counts') -> str:
    if not diagnosis.candidates:
        return '<p class="small">No candidate was tried: the current model leaves nothing above the floor.</p>'
    rows = []
    for candidate in diagnosis.candidates:
        css = ' style="background:#fff3e0"' if candidate.effect == diagnosis.verdict else ''
        rms = _triple(candidate.rms_after, unit)
        rows.append(f'<tr{css}><td>{html.escape(candidate.effect)}</td><td>{rms}</td>'
                    f'<td>{round(100 * candidate.explained)}%</td><td>{candidate.significance:.1f}</td>'
                    f'<td style="text-align:left">{html.escape(candidate.evidence)}</td></tr>')
    listed = {candidate.effect for candidate in diagnosis.candidates}
    chosen = set(diagnosis.ladder[-1].effects)
    for form in getattr(diagnosis, 'per_axis_forms', ()):
        if form.effect in listed:
            continue
        rms = _triple(form.rms_after, unit)
        verdict = 'chosen over the shared form' if form.effect in chosen else 'not better than the shared form'
        rows.append(f'<tr><td>{html.escape(form.effect)}</td><td>{rms}</td>'
                    f'<td>{round(100 * form.explained)}%</td><td>{form.significance:.1f}</td>'
                    f'<td style="text-align:left">per-axis form, {verdict} on held-out blocks. '
                    f'{html.escape(form.evidence)}</td></tr>')
    skipped = ''.join(f'<tr><td>{html.escape(name)}</td><td colspan="4" style="text-align:left">not tried: '
                      f'{html.escape(reason)}</td></tr>' for name, reason in diagnosis.skipped.items())
    return (f'<table><tr><th>effect</th><th>held-out RMS x, y, z ({html.escape(readable_unit(unit)[0])})</th>'
            '<th>excess removed</th>'
            '<th>noise sigmas</th><th style="text-align:left">evidence</th></tr>'
            + ''.join(rows) + skipped + '</table>')


def _effect_card(diagnosis: Diagnosis) -> str:
    if diagnosis.verdict in (VERDICT_NONE, VERDICT_UNEXPLAINED):
        if diagnosis.verdict == VERDICT_NONE:
            return ''
        lead = ', '.join(f'{d.name} ({100 * d.largest:.0f}%)' for d in diagnosis.drivers[:4])
        return (f'<div class="card"><b>What the residual follows</b> (share of its variance that a binned mean '
                f'of each quantity explains, worst axis): {html.escape(lead)}.</div>')
    best = next(c for c in diagnosis.candidates if c.effect == diagnosis.verdict)
    params = ', '.join(f'{html.escape(k)} = {v:.4g}' for k, v in best.parameters.items())
    parts = [f'<div class="card"><b>Suspected effect: {html.escape(best.effect)}</b>']
    if best.summary:
        parts.append(f'<p><b>Physics.</b> {html.escape(best.summary)}</p>')
    if best.confirm:
        parts.append(f'<p><b>To confirm it.</b> {html.escape(best.confirm)}</p>')
    parts.append(f'<p><b>Evidence.</b> {html.escape(best.evidence)}</p>')
    if params:
        parts.append(f'<p><b>Fitted on this run.</b> {params}</p>')
    effects = ','.join(diagnosis.ladder[-1].effects)  # a per-axis form in place of its shared form included
    if '[' in effects:  # a held form, thermal_lag[xz]: quoted for the shell
        effects = f"'{effects}'"
    parts.append(f'<p class="small">Refit with it: <code>tak_calib fit BAG -o PARAMS.yaml --effects '
                 f'{html.escape(effects)}</code></p></div>')
    return ''.join(parts)


def _gravity_table(series: list[tuple[str, np.ndarray]], gravity: float) -> str:
    rows = ''.join(f'<tr><td>{html.escape(label)}</td><td>{significant(float(np.sqrt(np.mean(e ** 2))), 4)}</td>'
                   f'<td>{significant(float(np.sqrt(np.mean(e ** 2))) / gravity * 1e3, 3)}</td>'
                   f'<td>{significant(float(np.max(np.abs(e))), 4)}</td></tr>' for label, e in series)
    return ('<table><tr><th>correction</th><th>RMS |g| error (m/s^2)</th><th>RMS (mg)</th>'
            f'<th>max (m/s^2)</th></tr>{rows}</table>')


def _relabel(fig: Figure, unit: str) -> Figure:
    """A driver sensor's figure: residuals in ``unit``, the temperature in degrees C (no word of codes)."""
    for text in fig.findobj(matplotlib.text.Text):
        label = text.get_text()
        changed = in_driver_words(
            label.replace('(counts)', f'({unit})').replace('temperature code $N_t$', 'temperature (C)')
            .replace('$dN_t/dt$ (codes per minute)', '$dT/dt$ (C per minute)')
            .replace('Residual N - model', 'Residual y - model'))
        if changed != label:
            text.set_text(changed)
    return fig


def write_report(diagnosis: Diagnosis, samples: AlignedSamples, directory: str | Path, *,
                 source: str = '', gravity: float = STANDARD_GRAVITY, sensor: str = 'accel',
                 unit: str = 'counts') -> ReportFiles:
    """Write the figures and ``report.html`` into ``directory`` (created if needed).

    :param diagnosis: what :func:`tak_thermo_ros.core.diagnose.diagnose` found on ``samples``.
    :param samples: the same aligned run.
    :param source: the bag's name, shown in the title.
    :param gravity: local gravity for the |g| figure, m/s^2.
    :param sensor: ``'accel'`` or ``'gyro'`` (no |g| figure for a gyroscope).
    :param unit: the unit of the residuals: ``counts``, or a driver's ``m/s^2`` / ``rad/s``.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    driver = unit != 'counts'
    words = in_driver_words if driver else (lambda text: text)
    series = gravity_series(diagnosis, samples, gravity, as_recorded=driver) if sensor == 'accel' else []
    after = diagnosis.residual_after is not None
    steady = bool(np.any(diagnosis.views.direction == 0))
    figures = [
        ('residual_time.png', figure_residual_time(diagnosis),
         'The residual against time. Grey band: &plusmn; the noise floor; red: stretches where the residual '
         'rises clearly above it; black: binned mean of the current model'
         + (', green: with the suspected effect.' if after else '.')),
        ('residual_temperature.png', figure_residual_temperature(diagnosis),
         'Against the temperature code, heating (red) and cooling (blue) apart'
         + (', grey dots on plateaus' if steady else '') + '. '
         'A loop that closes on plateaus is a thermal lag; one that stays open is hysteresis; '
         'a common bend is a temperature shape the polynomial cannot follow.'),
        ('residual_rate.png', figure_residual_rate(diagnosis),
         'Against the rate of the temperature code. A straight slope through zero: the drifting part '
         'lags the temperature sensor.'),
    ]
    # A panel of one point shows nothing: said in a line instead of drawn.
    skipped = []
    if len(diagnosis.views.plateaus) >= 2:
        figures.append(('residual_plateaus.png', figure_residual_plateaus(diagnosis),
                        'Mean residual over the settled half of each plateau, by the direction it was reached '
                        'from. Hysteresis keeps heating and cooling apart even there; a lag has settled.'))
    else:
        skipped.append(f'{len(diagnosis.views.plateaus) or "No"} temperature plateau'
                       f'{"" if len(diagnosis.views.plateaus) == 1 else "s"} in this run: the residual per plateau, '
                       f'reached by heating against by cooling, takes two or more.')
    if not all(single_input_axes(samples)):
        figures.append(('residual_inputs.png', figure_residual_inputs(diagnosis),
                        'Against the inputs. A curve on the diagonal: scale nonlinearity; a slope off the '
                        'diagonal: cross-axis coupling.'))
    else:
        skipped.append('One input per axis in this run (one orientation): the residual against the inputs '
                       '(scale nonlinearity, cross-axis coupling) takes several.')
    figures += [
        ('ladder.png', figure_ladder(diagnosis),
         'Left: the model ladder, held-out RMS over the noise floor as each effect is added. '
         'Right: every candidate effect added to the current model, scored on held-out time blocks.'),
    ]
    if diagnosis.allan:
        figures.append(('allan.png', figure_allan(diagnosis),
                        'Overlapping Allan deviation of the residual, per axis: the calibration as given, then '
                        'the model refitted with each effect of the ladder. Dashed: what the noise model predicts '
                        '(the measured white floor plus its bias instability and random walk); grey: up to the '
                        'bound that noise explains (chi-square on the equivalent degrees of freedom).'))
    if sensor == 'accel':
        figures.append(('gravity.png', figure_gravity(diagnosis, series, gravity),
                        f'|g| from the three channels minus local gravity: {series[0][0]} (as validate\'s '
                        f'before), with the current model'
                        + (', and with the suspected effect added.' if diagnosis.calibration_after is not None
                           else '.')))
    paths = []
    blocks = {}
    for name, fig, caption in figures:
        path = directory / name
        data = _png_bytes(fig if unit == 'counts' else _relabel(fig, unit), path)
        paths.append(path)
        encoded = base64.b64encode(data).decode('ascii')
        blocks[name] = (f'<figure><img alt="{name}" src="data:image/png;base64,{encoded}">'
                        f'<figcaption>{words(caption)}</figcaption></figure>')
    notes = ''.join(f'<p class="small">{html.escape(words(text))}</p>' for text in skipped)
    kind = ('v-none' if diagnosis.verdict == VERDICT_NONE else
            'v-unexplained' if diagnosis.verdict == VERDICT_UNEXPLAINED else 'v-effect')
    headline = {VERDICT_NONE: 'Verdict: none (the residual is at the noise floor)',
                VERDICT_UNEXPLAINED: 'Verdict: unexplained structure'}.get(
        diagnosis.verdict, f'Verdict: {diagnosis.verdict}')
    stamp = datetime.datetime.now().strftime('%Y-%m-%d %H:%M')
    duration = float(diagnosis.views.time_s[-1]) / 3600.0 if len(diagnosis.views.time_s) else 0.0
    title = f'Model diagnosis{": " + source if source else ""}'
    ladder_rows = ''.join(
        f'<tr><td>{html.escape(step.label)}</td>' + ''.join(
            f'<td>{readable(v, unit).split()[0]} ({v / f:.2f}x)</td>'
            for v, f in zip(step.heldout_rms, diagnosis.noise_floor)) + '</tr>'
        for step in diagnosis.ladder)
    stride_text = ('on all samples' if diagnosis.cv_stride == 1 else
                   f'on every {diagnosis.cv_stride}th sample')
    allan_section = (f"<h2>Against the noise model</h2>\n{blocks['allan.png']}\n"
                     f'<div class="card"><b>Largest Allan deviation ratio, residual / noise model</b> '
                     f'(source: {html.escape(str(diagnosis.allan[0][1].source))}'
                     + (f'; cross-validated on {diagnosis.averaging_time_s:.3g} s means, whitened by the noise '
                        f'model, against {diagnosis.yardstick_replicates} simulated copies of the run'
                        if diagnosis.averaging_time_s else '')
                     + f'){_allan_table(diagnosis)}</div>') if diagnosis.allan else ''
    gravity_section = (f"<h2>|g| before and after</h2>\n{blocks['gravity.png']}\n"
                       f'<div class="card">{_gravity_table(series, gravity)}</div>') if sensor == 'accel' else ''
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>{_CSS}</style></head><body><main>
<h1>{html.escape(title)}</h1>
<div class="sub">{len(diagnosis.views.time_s)} samples, {duration:.2f} h;
model: {html.escape(diagnosis.ladder[0].label)};
written {stamp} by tak_calib diagnose</div>
<div class="verdict {kind}"><b>{html.escape(headline)}</b>{html.escape(words(diagnosis.message))}</div>
<div class="card"><b>Residual against the noise floor</b> ({html.escape(readable_unit(unit)[0])}; the floor is estimated
from successive differences of the residual and includes the code rounding)
{_axes_table(diagnosis, unit)}</div>
{words(_effect_card(diagnosis))}
<h2>Where the model fails</h2>
{blocks['residual_time.png']}
{blocks['residual_temperature.png']}
{blocks['residual_rate.png']}
{blocks.get('residual_plateaus.png', '')}
{blocks.get('residual_inputs.png', '')}
{notes}
<h2>Which effect explains it</h2>
{blocks['ladder.png']}
<div class="card"><b>Model ladder</b>: held-out RMS per axis, {html.escape(readable_unit(unit)[0])} (over the floor)
<table><tr><th>model</th><th>x</th><th>y</th><th>z</th></tr>{ladder_rows}</table>
<b>Candidates</b>, best first
{words(_candidates_table(diagnosis, unit))}
<p class="small">Blocked cross-validation: {diagnosis.blocks} contiguous time blocks dealt round-robin into
{diagnosis.folds} folds; each model is fitted without one fold and scored on it (stateful effects run over the
whole series), {stride_text}. An effect joins the ladder when it removes at least half of the
held-out excess variance over the floor that the rung below leaves, by far more than noise could; the
ladder's first effect is named when the ladder removes at least three quarters of the excess.</p></div>
{allan_section}
{gravity_section}
</main></body></html>
"""
    html_path = directory / 'report.html'
    _write_atomic(html_path, page.encode('utf-8'))
    return ReportFiles(html=html_path, figures=tuple(paths))


def write_sensor_index(pages: dict[str, tuple[ReportFiles, Diagnosis]], directory: str | Path, *,
                       source: str = '') -> Path:
    """``report.html`` of a driver bag: each sensor's verdict, and its own report embedded.

    :param pages: sensor -> (its report files, written into ``directory/<sensor>``, its diagnosis).
    """
    directory = Path(directory)
    names = {'accel': 'Accelerometer', 'gyro': 'Gyroscope', 'mag': 'Magnetometer'}
    sections = []
    for sensor, (files, diagnosis) in pages.items():
        kind = ('v-none' if diagnosis.verdict == VERDICT_NONE else
                'v-unexplained' if diagnosis.verdict == VERDICT_UNEXPLAINED else 'v-effect')
        relative = files.html.relative_to(directory).as_posix()
        sections.append(
            f'<h2>{names.get(sensor, sensor)}</h2>'
            f'<div class="verdict {kind}"><b>Verdict: {html.escape(diagnosis.verdict)}</b>'
            f'{html.escape(diagnosis.message)}</div>'
            f'<p><a href="{html.escape(relative)}">{html.escape(relative)}</a> (the whole report of this sensor)</p>'
            f'<iframe src="{html.escape(relative)}" style="width:100%;height:900px;border:1px solid #ccc"></iframe>')
    title = f'Model diagnosis{": " + source if source else ""}'
    page = (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>'
            f'<style>{_CSS}</style></head><body><main><h1>{html.escape(title)}</h1>'
            f'<div class="sub">a driver bag: the accelerometer and the gyroscope, each diagnosed on its own</div>'
            + ''.join(sections) + '</main></body></html>\n')
    path = directory / 'report.html'
    _write_atomic(path, page.encode('utf-8'))
    return path
