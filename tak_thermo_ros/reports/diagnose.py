"""The diagnosis report: the PNG figures of :mod:`.diagnose_figures` and one self-contained HTML page.

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
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from tak_thermo_ros.core.diagnose import VERDICT_NONE, VERDICT_UNEXPLAINED, Diagnosis  # noqa: E402
from tak_thermo_ros.core.fit.design import single_input_axes  # noqa: E402
from tak_thermo_ros.core.link.model import AXES  # noqa: E402
from tak_thermo_ros.core.records.record import AlignedSamples  # noqa: E402
from tak_thermo_ros.core.values import STANDARD_GRAVITY  # noqa: E402
from tak_thermo_ros.reports.diagnose_figures import (  # noqa: E402
    DPI,
    figure_allan,
    figure_gravity,
    figure_ladder,
    figure_residual_inputs,
    figure_residual_plateaus,
    figure_residual_rate,
    figure_residual_temperature,
    figure_residual_time,
    gravity_series,
)
from tak_thermo_ros.units import in_driver_words, readable, readable_unit, significant  # noqa: E402


@dataclass(frozen=True)
class ReportFiles:
    """What :func:`write_report` wrote."""

    html: Path
    figures: tuple[Path, ...]


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
