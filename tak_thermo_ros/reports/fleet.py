"""``fleet.html``: the spread of a batch's coefficients and its flagged units, in one file.

Built from the ``fleet.json`` document (:func:`tak_thermo_ros.fleet.fleet_document`). One
strip plot per metric (every unit a dot over a box plot, the median +- k robust sigmas as a
band, flagged units red and named), grouped by axis; the table of units; the flags with
their reasons. Figures are embedded as base64 PNG: no external resource.
"""

from __future__ import annotations

import base64
import datetime
import html
import io
import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from tak_thermo_ros.formats.calibration_file import write_text_atomic  # noqa: E402
from tak_thermo_ros.core.link.model import AXES  # noqa: E402

NORMAL = '#1f77b4'
FLAGGED = '#d62728'
BAND = '#2ca02c'
DPI = 90
COLUMNS = 4


def _metric_group(metric: str) -> str:
    head = metric.split('.', 1)[0]
    return f'axis {head}' if head in AXES else 'effects' if head == 'effects' else 'validation'


def _strip_figure(metrics: list[str], document: dict[str, Any]) -> bytes:
    """One strip plot per metric: the units' values over a box plot, the flag band, flagged units named."""
    rows = [row for row in document['units'] if row['status'] == 'ok']
    k = float(document['flag_sigma'])
    count = len(metrics)
    cols = min(COLUMNS, count)
    lines = math.ceil(count / cols)
    fig, axes = plt.subplots(lines, cols, figsize=(3.2 * cols, 2.6 * lines), squeeze=False)
    jitter = np.random.default_rng(0)
    for ax, metric in zip(axes.flat, metrics):
        spread = document['spread'][metric]
        flagged_units = {row['unit'] for row in rows
                         if any(flag['metric'] == metric for flag in row['flags'])}
        values = [(row['unit'], row['metrics'][metric]) for row in rows if metric in row['metrics']]
        numbers = np.array([value for _, value in values])
        ax.boxplot(numbers, positions=[0.0], widths=0.5, showfliers=False,
                   medianprops={'color': '#444444'}, boxprops={'color': '#999999'},
                   whiskerprops={'color': '#999999'}, capprops={'color': '#999999'})
        if spread['robust_sigma'] > 0.0:
            ax.axhspan(spread['median'] - k * spread['robust_sigma'], spread['median'] + k * spread['robust_sigma'],
                       color=BAND, alpha=0.12, linewidth=0)
        offsets = jitter.uniform(-0.18, 0.18, size=len(values))
        for (unit, value), offset in zip(values, offsets):
            flagged = unit in flagged_units
            ax.plot(offset, value, 'o', color=FLAGGED if flagged else NORMAL, markersize=6 if flagged else 4,
                    alpha=0.9 if flagged else 0.7)
            if flagged:
                ax.annotate(unit, (offset, value), xytext=(6, 0), textcoords='offset points', fontsize=7.5,
                            color=FLAGGED, va='center')
        ax.set_title(metric, fontsize=9)
        ax.set_xticks([])
        ax.set_xlim(-0.6, 0.9)
        ax.tick_params(labelsize=7.5)
        ax.ticklabel_format(axis='y', style='sci', scilimits=(-3, 4), useOffset=False)
    for ax in list(axes.flat)[count:]:
        ax.set_visible(False)
    # Fixed margins: tight_layout measured every tick label and took a third of the report's time.
    width, height = fig.get_size_inches()
    fig.subplots_adjust(left=0.75 / width, right=1.0 - 0.1 / width, bottom=0.15 / height, top=1.0 - 0.45 / height,
                        wspace=0.5, hspace=0.55)
    buffer = io.BytesIO()
    fig.savefig(buffer, dpi=DPI, format='png')
    plt.close(fig)
    return buffer.getvalue()


_CSS = """
body{font-family:-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:0;background:#f4f5f7;color:#222}
main{max-width:1320px;margin:0 auto;padding:18px 24px 40px}
h1{font-size:24px;margin:8px 0 2px}h2{font-size:19px;margin:28px 0 8px;border-bottom:1px solid #ddd;padding-bottom:4px}
.sub{color:#666;font-size:13px}
.card{background:#fff;border-radius:8px;padding:12px 16px;margin:10px 0;box-shadow:0 1px 3px rgba(0,0,0,.12)}
table{border-collapse:collapse;font-size:13px;margin:6px 0}
td,th{padding:4px 9px;border-bottom:1px solid #e3e3e3;text-align:right}
th{background:#fafafa}td:first-child,th:first-child{text-align:left}td.l{text-align:left}
.bad{color:#b71c1c;font-weight:600}.good{color:#2e7d32;font-weight:600}
figure{margin:12px 0;background:#fff;border-radius:8px;padding:8px;box-shadow:0 1px 3px rgba(0,0,0,.12)}
figure img{width:100%;height:auto}figcaption{font-size:13px;color:#444;padding:4px 8px}
"""


def _number(value: Any, digits: int = 4) -> str:
    return '' if value is None else f'{value:.{digits}g}'


def _per_sensor(values: dict[str, Any], show) -> str:
    """``show`` of one link, or of each sensor of a driver calibration (``accel ... / gyro ...``)."""
    if 'accel' in values:
        return ' / '.join(f'{sensor} {show(values[sensor])}' for sensor in ('accel', 'gyro'))
    return show(values)


def _units_table(document: dict[str, Any]) -> str:
    rows = []
    for row in document['units']:
        if row['status'] != 'ok':
            rows.append(f'<tr><td>{html.escape(row["unit"])}</td><td class="bad">failed</td>'
                        f'<td class="l" colspan="9">{html.escape(row["error"] or "")}</td></tr>')
            continue
        coefficients = row['coefficients']
        scales = _per_sensor(coefficients, lambda link: ' '.join(_number(link[axis]['scale'], 6) for axis in AXES))
        offsets = _per_sensor(coefficients, lambda link: ' '.join(_number(link[axis]['offset']) for axis in AXES))
        spans = _per_sensor(coefficients, lambda link: ' '.join(_number(link[axis]['offset_span']) for axis in AXES))
        residual = _per_sensor(row['residual_rms'], lambda rms: ' '.join(_number(rms[axis], 3) for axis in AXES))
        flags = ', '.join(html.escape(flag['metric']) for flag in row['flags'])
        css = 'bad' if row['flags'] else 'good'
        rows.append(f'<tr><td>{html.escape(row["unit"])}</td><td class="good">ok</td><td>{scales}</td>'
                    f'<td>{offsets}</td><td>{spans}</td><td>{residual}</td>'
                    f'<td>{html.escape(str(row["verdict"]))}</td><td>{_number(row["validation_rms"], 3)}</td>'
                    f'<td>{row["seconds"]:.1f}</td><td class="l {css}">{flags or "-"}</td></tr>')
    return ('<table><tr><th>unit</th><th>status</th><th>scale x y z</th><th>offset x y z</th>'
            '<th>offset span x y z</th><th>residual RMS x y z</th><th>verdict</th><th>|g| RMS (m/s^2)</th>'
            '<th>s</th><th>flags</th></tr>' + ''.join(rows) + '</table>')


def _flags_list(document: dict[str, Any]) -> str:
    items = [f'<li><b>{html.escape(row["unit"])}</b>: {html.escape(flag["reason"])}</li>'
             for row in document['units'] for flag in row['flags']]
    return f'<ul>{"".join(items)}</ul>' if items else '<p>No unit lies outside the batch\'s spread.</p>'


def write_fleet_report(document: dict[str, Any], path: str | Path) -> Path:
    """Write ``fleet.html`` for a ``fleet.json`` document; return its path."""
    path = Path(path)
    groups: dict[str, list[str]] = {}
    for metric in document['spread']:
        groups.setdefault(_metric_group(metric), []).append(metric)
    blocks = []
    for group in sorted(groups, key=lambda g: (not g.startswith('axis'), g)):
        encoded = base64.b64encode(_strip_figure(groups[group], document)).decode('ascii')
        blocks.append(f'<figure><img alt="{html.escape(group)}" src="data:image/png;base64,{encoded}">'
                      f'<figcaption>{html.escape(group)}: one dot per calibrated unit over the box of the batch; '
                      f'green band: median &plusmn; {document["flag_sigma"]:g} robust sigmas; red: flagged '
                      f'units.</figcaption></figure>')
    stamp = datetime.datetime.now().strftime('%Y-%m-%d %H:%M')
    failed = [row for row in document['units'] if row['status'] != 'ok']
    failed_text = ''.join(f'<li><b>{html.escape(row["unit"])}</b> ({html.escape(row["bag"])}): '
                          f'{html.escape(row["error"] or "")}</li>' for row in failed)
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>Fleet calibration</title>
<style>{_CSS}</style></head><body><main>
<h1>Fleet calibration: {document['units_total']} units</h1>
<div class="sub">{document['units_ok']} calibrated, {document['units_failed']} failed,
{document['units_flagged']} flagged;
majority verdict {html.escape(str(document['majority_verdict']))}; written {stamp} by tak_calib fit-fleet</div>
<div class="card"><b>Flagged units</b>{_flags_list(document)}
<p class="sub">{html.escape(document['flag_rule'])}.</p></div>
{f'<div class="card"><b>Failed units</b><ul>{failed_text}</ul></div>' if failed else ''}
<h2>Units</h2>
<div class="card">{_units_table(document)}</div>
<h2>Spread of every coefficient across the batch</h2>
{''.join(blocks) if blocks else '<p>No unit was calibrated.</p>'}
</main></body></html>
"""
    write_text_atomic(path, page)
    return path
