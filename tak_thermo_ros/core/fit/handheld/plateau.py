"""The plateau table: the paper's +/- quantities (3)-(5) on each temperature plateau, beside the fitted link.

On a table run (a chamber's plateaus, the unit rested on its six faces on each) the still
intervals are grouped by plateau (:func:`plateau_groups`: successive in time, the temperature
holding) and each plateau where all six faces rested gives one :class:`PlateauRow` per axis
(:func:`plateau_table`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tak_thermo_ros.core.link.model import Calibration
from tak_thermo_ros.core.records.record import AlignedSamples


@dataclass(frozen=True)
class PlateauRow:
    """The paper's +/- quantities (3)-(5) on one plateau and axis, beside the link's values there.

    :param temperature: the plateau's mean temperature, C.
    :param axis: 0, 1, 2.
    :param offset: ``(N+ + N-) / 2`` of the still means with the axis up and down.
    :param scale: ``(N+ - N-) / 2 / g``.
    :param link_offset: the fitted link's offset at that temperature.
    :param link_scale: the fitted link's scale at that temperature.
    :param tilt_deg: the larger of the two faces' tilts from the axis.
    """

    temperature: float
    axis: int
    offset: float
    scale: float
    link_offset: float
    link_scale: float
    tilt_deg: float


PLATEAU_C = 1.0
"""Successive still intervals on a plateau stay within this temperature of its first (the +/- table)."""
PLATEAU_RATE = 0.25 / 60.0
"""A still interval is on a plateau when the temperature moves less than this (C per second, a
quarter of a degree per minute) from it to the interval before it or to the one after it."""


def plateau_groups(temperature: np.ndarray, stamp_s: np.ndarray, interval: np.ndarray) -> list[np.ndarray]:
    """The still intervals of each plateau: successive in time, the temperature holding (:data:`PLATEAU_RATE`).

    Not by temperature alone: sorted by temperature, the rests of the ramps between the chamber's
    plateaus fill the gaps between them (a rest every few tenths of a degree at 1 C/min) and chain
    every plateau into one; the rests of a ramp belong to none.
    """
    count = len(temperature)
    start = np.full(count, np.inf)
    np.minimum.at(start, interval, np.asarray(stamp_s, dtype=float))
    order = np.argsort(start, kind='stable')
    times, temps = start[order], np.asarray(temperature, dtype=float)[order]
    if count > 1:
        # The slower of the two sides: a plateau's first and last rests have one steady side.
        step = np.abs(np.diff(temps)) / np.maximum(np.diff(times), 1e-9)
        rate = np.minimum(np.r_[step[:1], step], np.r_[step, step[-1:]])
    else:
        rate = np.zeros(count)
    groups: list[list[int]] = []
    open_group = False
    for position, index in enumerate(order):
        if rate[position] > PLATEAU_RATE:
            open_group = False
            continue
        if open_group and abs(temps[position] - temperature[groups[-1][0]]) <= PLATEAU_C:
            groups[-1].append(int(index))
        else:
            groups.append([int(index)])
            open_group = True
    return [np.array(group) for group in groups]


FACE_TILT_DEG = 10.0
"""A still interval rests on a face (the +/- table) when its up direction lies within this of an axis."""


def plateau_table(still: AlignedSamples, interval: np.ndarray, up: np.ndarray, calibration: Calibration,
                  gravity: float) -> tuple[PlateauRow, ...]:
    """The paper's eqs. (3)-(5) on each plateau where all six faces rested, beside the fitted link there."""
    from tak_thermo_ros.core.fit.plus_minus import plus_minus
    count = len(up)
    if not count:
        return ()
    kept = np.bincount(interval, minlength=count).astype(float)
    means = np.zeros((count, 3))
    np.add.at(means, interval, still.counts[:, :3])
    means /= kept[:, None]
    temperature = np.bincount(interval, weights=still.temp_code, minlength=count) / kept
    groups = plateau_groups(temperature, still.stamp_s, interval)
    cosine = math.cos(math.radians(FACE_TILT_DEG))
    rows: list[PlateauRow] = []
    for group in groups:
        faces = [(group[up[group, axis] > cosine], group[up[group, axis] < -cosine]) for axis in range(3)]
        if not all(len(plus) and len(minus) for plus, minus in faces):
            continue
        mean_t = float(np.average(temperature[group], weights=kept[group]))
        n = float(np.clip(mean_t, calibration.temp_code_min, calibration.temp_code_max)) - calibration.temp_code_ref
        for axis, (plus, minus) in enumerate(faces):
            code_plus = float(np.average(means[plus, axis], weights=kept[plus]))
            code_minus = float(np.average(means[minus, axis], weights=kept[minus]))
            offset, scale = plus_minus(code_plus, code_minus, gravity)
            link = calibration.axes[axis]
            tilt = float(np.degrees(np.arccos(np.clip(np.min(np.abs(up[np.concatenate([plus, minus]), axis])),
                                                      -1.0, 1.0))))
            rows.append(PlateauRow(temperature=mean_t, axis=axis, offset=float(offset), scale=float(scale),
                                   link_offset=float(link.offset + link.offset_drift(n)),
                                   link_scale=float(link.scale * link.scale_factor(n)), tilt_deg=tilt))
    return tuple(rows)
