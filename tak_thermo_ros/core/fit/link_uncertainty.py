"""A fitted link's own uncertainty, held terms included: what a calibration file states for the watch.

A fit solves some terms and holds others (at 1 or 0: a scale the orientations never reached, a
curvature beyond the chosen order, a coupling the tilts cannot tell from an offset). The file's
values are then off by the fitted terms' errors and by the held terms' true values; and a fitted
term that shares the data with a held one takes up part of it: with the fit's normal matrix ``H``
(free terms ``F``, held ``h``) and ``A = H_FF^-1 H_Fh``, a held term off by ``d`` moves the fitted
ones by ``A d``. With the held terms' spreads ``D`` (their variances), the errors of the file's
terms have the covariance::

    C_FF = cov_F + A D A',   C_Fh = -A D,   C_hh = D

(:class:`~tak_thermo_ros.core.link.uncertainty.LinkUncertainty`). A held term's spread is what
the records say of it where they bound it: freed alone beside the fitted terms, its estimate
``d`` and standard error ``s`` give ``sqrt(d^2 + s^2)`` (what holding it at its value misses);
where they do not (``s`` beyond the default, or no information at all: a scale at 0 g), the
stated default of :class:`HeldSpreads` (a datasheet's figures; ``tak_calib fit --held-spread``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Sequence

import numpy as np

from tak_thermo_ros.core.link.uncertainty import LinkUncertainty
from tak_thermo_ros.errors import FitError

KINDS = ('offset', 'offset_T', 'scale', 'scale_T', 'coupling')
"""The kinds of term a link's uncertainty carries (not the effects' amplitudes, not a pool's turn-on offsets)."""


@dataclass(frozen=True)
class HeldSpreads:
    """A held term's plausible spread where the records do not bound it (SI; per degree C for a drift).

    The defaults are a consumer MEMS datasheet's (initial tolerances of an ICM-42688 or a BMI088 class
    part): an accelerometer's offset 20 mg, its drift 0.2 mg/C, its scale 0.5 % and 0.01 %/C, its
    axes' cross-coupling 1 %; a gyroscope's offset 1 deg/s, its drift 0.015 deg/s/C (54 deg/h/C).
    A temperature term of any power takes its drift times the calibrated half-span (its size at the
    range's edge).
    """

    accel_offset: float = 0.196
    accel_offset_drift: float = 2.0e-3
    accel_scale: float = 5.0e-3
    accel_scale_drift: float = 1.0e-4
    accel_coupling: float = 1.0e-2
    gyro_offset: float = 1.745e-2
    gyro_offset_drift: float = 2.6e-4
    gyro_scale: float = 5.0e-3
    gyro_scale_drift: float = 1.0e-4
    gyro_coupling: float = 1.0e-2

    def __post_init__(self) -> None:
        for item in fields(self):
            value = getattr(self, item.name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                msg = f'held spread {item.name}: expected a number > 0, got {value!r}'
                raise FitError(msg)

    def spread(self, sensor: str, kind: str, temperature_scale: float) -> float:
        """The default spread of a term of ``kind`` (:data:`KINDS`) of a sensor (``accel`` or ``gyro``)."""
        if kind.endswith('_T'):
            return getattr(self, f'{sensor}_{kind[:-2]}_drift') * temperature_scale
        return getattr(self, f'{sensor}_{kind}')


def term_name(name: str) -> str:
    """A fit's column name as the file's term: ``cross_axis.c_yx`` is ``c_yx``; ``x.offset_T2`` stays."""
    return name.split('.', 1)[1] if name.startswith('cross_axis.') else name


def link_uncertainty(names: Sequence[str], kinds: Sequence[str], normal: np.ndarray, gradient: np.ndarray,
                     free: Sequence[int], free_covariance: np.ndarray, variance: np.ndarray,
                     held: Sequence[int], *, sensor: str, temperature_scale: float,
                     spreads: HeldSpreads = HeldSpreads(), carried: Sequence[int] | None = None) -> LinkUncertainty:
    """The covariance of a fit's term errors, held terms included (see the module's description).

    :param names: every column's name (``x.offset``, ``x.scale_T1``, ``c_yx``); ``kinds`` its kind.
    :param normal: ``(W, W)`` the fit's normal matrix ``X' X`` (weighted), every column.
    :param gradient: ``(W,)`` ``X' r``, the residual at the solution against each column (held ones' matter).
    :param free: the fitted columns; ``free_covariance`` their covariance (``(|F|, |F|)``).
    :param variance: ``(W,)`` the residual variance scale of each column's rows (a held term's error from the records).
    :param held: the held columns that count (not the gauge: it defines the frame, it is no error).
    :param carried: the columns the result states (default: every free and held one of :data:`KINDS`).
    """
    free = list(free)
    held = [j for j in held if kinds[j] in KINDS]
    carried = [j for j in (carried if carried is not None else [*free, *held]) if kinds[j] in KINDS]
    normal_ff = normal[np.ix_(free, free)]
    scale = np.sqrt(np.maximum(np.diag(normal_ff), 1e-300))
    inverse = np.linalg.pinv(normal_ff / np.outer(scale, scale), rcond=1e-12) / np.outer(scale, scale)
    gain = inverse @ normal[np.ix_(free, held)] if held else np.zeros((len(free), 0))
    spread, source = [], []
    for k, j in enumerate(held):
        default = spreads.spread(sensor, kinds[j], temperature_scale)
        information = float(normal[j, j] - normal[j, free] @ gain[:, k])  # the Schur complement: j freed alone
        error = math.sqrt(variance[j] / information) if information > 1e-12 * max(normal[j, j], 1e-300) else math.inf
        if error < default:
            spread.append(math.hypot(float(gradient[j]) / information, error))
            source.append('records')
        else:
            spread.append(default)
            source.append('default')
    spread_variance = np.square(spread)
    order = [*free, *held]
    covariance = np.zeros((len(order), len(order)))
    covariance[:len(free), :len(free)] = free_covariance + (gain * spread_variance) @ gain.T
    covariance[:len(free), len(free):] = -gain * spread_variance
    covariance[len(free):, :len(free)] = covariance[:len(free), len(free):].T
    covariance[len(free):, len(free):] = np.diag(spread_variance)
    keep = [order.index(j) for j in carried]
    held_names = tuple(term_name(names[j]) for j in held if j in carried)
    held_from = tuple(source[k] for k, j in enumerate(held) if j in carried)
    beyond = (getattr(spreads, f'{sensor}_offset_drift'),) * 3
    return LinkUncertainty.of(tuple(term_name(names[j]) for j in carried), covariance[np.ix_(keep, keep)],
                              temperature_scale, held_names, held_from, beyond)


def block_normal(factors: Sequence[np.ndarray], theta: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The normal matrix and the residual's gradient of independent fits (one per axis), block-diagonal.

    :param factors: each fit's triangular factor ``R`` of ``[X | y]``.
    :param theta: each fit's full parameter vector (held terms at their values).
    """
    normals, gradients = [], []
    for factor, values in zip(factors, theta):
        design, target = factor[:, :-1], factor[:, -1]
        normals.append(design.T @ design)
        gradients.append(design.T @ (target - design @ values))
    width = sum(len(g) for g in gradients)
    normal = np.zeros((width, width))
    start = 0
    for block in normals:
        normal[start:start + len(block), start:start + len(block)] = block
        start += len(block)
    return normal, np.concatenate(gradients)
