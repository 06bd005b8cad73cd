"""What a record cannot determine, held and said: the orders a span allows, one orientation's holds, the lines.

:func:`orders_for_span` lowers the polynomials' orders on a narrow temperature span
(:data:`SPAN_PER_ORDER_C`), :func:`order_holds` holds the terms beyond each axis's chosen order,
:func:`one_orientation` the accelerometer's terms rests in one orientation cannot tell, and
:func:`held_lines` says in one line per kind what the fit held.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.fit.handheld.layout import Layout
from tak_thermo_ros.core.fit.handheld.system import BOUNDS, Solved
from tak_thermo_ros.core.link.model import AXES
from tak_thermo_ros.core.values import SENSOR_NAMES, STANDARD_GRAVITY


SPAN_PER_ORDER_C = 2.0
"""Each order of a temperature polynomial needs this much temperature span, degrees C."""


def orders_for_span(span_c: float, bias_order: int, scale_order: int) -> tuple[int, int]:
    """The polynomial orders a temperature span determines: one order per :data:`SPAN_PER_ORDER_C`."""
    allowed = int(math.floor(max(span_c, 0.0) / SPAN_PER_ORDER_C + 1e-9))
    return min(bias_order, allowed), min(scale_order, allowed)


def order_holds(layout: Layout, orders: Sequence[int] | None) -> dict[int, float]:
    """The offset polynomial's terms beyond each axis's order, held at 0."""
    if orders is None:
        return {}
    held = {}
    for axis, order in enumerate(orders):
        start = layout.starts[axis]
        for j in range(start, start + len(layout.columns[axis])):
            name = layout.names[j]
            if layout.kinds[j] == 'offset_T' and int(name.rsplit('_T', 1)[1]) > order:
                held[j] = 0.0
    return held


ONE_ORIENTATION_DEG = 30.0
"""Rests whose up directions all lie within this of their mean are one orientation (near level, on ground
tilted by up to this at any heading): |f| tells the other axes' offsets through the tilts only, and cannot
tell them from the couplings with the gravity axis (``g c_zx u_x u_z`` against ``b_x u_x``: at 15 deg they
differ by 3 %: the fit's bounds would keep a coupling that took up a 10 mg offset)."""


def one_orientation(up: np.ndarray, kept: np.ndarray, layout: Layout) -> tuple[str, dict[int, float]]:
    """When every rest lies in one orientation: the line that says so, and the accelerometer's terms it holds.

    At rest near one orientation ``|f| = g + b . u + g u' S u + ...`` (``u`` the up direction,
    ``S`` the scale errors and the couplings): the tilts of the rests tell the other axes'
    offsets (``b_x u_x``), with their temperature terms where the span allows, and their scales
    (``g s_x u_x^2``); what they cannot tell apart is held and said in one line: the gravity
    axis's scale and its temperature terms (at 1 g they act as its offset, which carries them),
    the couplings between the gravity axis and the others (``g c_zx u_x u_z`` acts as
    ``b_x u_x``) and the other axes' scales' temperature terms. What the rests do not determine
    beyond that is held by the fit's bounds. With up between the axes (no axis within
    :data:`~tak_thermo_ros.core.records.still.FACE_DEG` of it) every offset, scale and coupling is held.
    """
    from tak_thermo_ros.core.records.still import FACE_DEG
    if not len(up):
        return '', {}
    mean = np.average(up, axis=0, weights=np.maximum(kept, 1))
    mean /= np.linalg.norm(mean)
    spread = float(np.degrees(np.arccos(np.clip(np.min(up @ mean), -1.0, 1.0))))
    if spread > ONE_ORIENTATION_DEG:
        return '', {}
    gravity = int(np.argmax(np.abs(mean)))
    where = f'{spread:.1f} deg of one orientation'
    if abs(mean[gravity]) < math.cos(math.radians(FACE_DEG)):
        held = {j: (1.0 if kind == 'scale' else 0.0) for j, kind in enumerate(layout.kinds)
                if kind in ('scale', 'scale_T', 'coupling', 'offset', 'offset_T', 'turn_on')}
        return (f'accelerometer: every rest within {where}, up between the axes: |f| tells no axis\'s offset; '
                f'offsets, scales and misalignment held'), held
    name = AXES[gravity]
    held = {}
    for j, (kind, label) in enumerate(zip(layout.kinds, layout.names)):
        axis = AXES.index(label[0]) if label[1] == '.' else -1
        if kind == 'coupling':
            if name in label[-2:]:
                held[j] = 0.0
        elif axis == gravity and kind in ('scale', 'scale_T'):
            held[j] = 1.0 if kind == 'scale' else 0.0
        elif axis != gravity and kind == 'scale_T':
            held[j] = 0.0
    others = ' '.join(axis for axis in AXES if axis != name)
    line = (f'accelerometer: every rest within {where} ({"+-"[int(mean[gravity] < 0)]}{name} up): the tilts '
            f'determine the offsets on {others} (|f| = g + b . u + ...); the scale of {name} and the couplings '
            f'with {name} held')
    return line, held


def held_lines(sensor: str, solved: Solved, layout: Layout, *, gauge: Sequence[str] = (),
               source: str = 'this record', said: Sequence[int] = ()) -> list[str]:
    """One statement per kind of term the record did not determine (the gauge is said apart)."""
    name = SENSOR_NAMES[sensor]
    # :data:`BOUNDS` in the units a reader expects: 1 %, 10 mrad, 5 mg or 0.29 deg/s.
    offset = {'accel': f'{BOUNDS["offset", "accel"] / STANDARD_GRAVITY * 1e3:.0f} mg',
              'gyro': f'{math.degrees(BOUNDS["offset", "gyro"]):.2f} deg/s'}[sensor]
    scale, scale_t = (f'{100.0 * BOUNDS[kind]:g} %' for kind in ('scale', 'scale_T'))
    words = {'scale': ('scale held at 1 on', f'not determined to {scale}'),
             'scale_T': ("scale's temperature terms held at 0 on", f'not determined to {scale_t}'),
             'offset': ('offset held at 0 on', f'not determined to {offset}'),
             'offset_T': ("offset's temperature terms held at 0 on", f'not determined to {offset}'),
             'coupling': ('couplings held at 0:', f'not determined to {1e3 * BOUNDS["coupling"]:g} mrad'),
             'effect': ('effect terms held at 0:', 'not determined')}
    lines = []
    for kind in ('scale', 'scale_T', 'offset', 'offset_T', 'coupling', 'effect'):
        held = [j for j in solved.held if layout.kinds[j] == kind and layout.names[j].split('.')[-1] not in gauge
                and j not in said]
        if not held:
            continue
        if kind in ('coupling', 'effect'):
            what = ', '.join(layout.names[j].split('.')[-1] for j in held)
        else:
            what = ' '.join(sorted({layout.names[j].split('.')[0] for j in held}))
        lead, why = words[kind]
        lines.append(f'{name}: {lead} {what} ({why} by {source})')
    return lines
