"""What a calibration's own values are uncertain by: the terms of its link with their covariance.

A fitted link is not the truth: every fitted term carries its error (the records' noise through
the fit), and every term the fit held (a scale the orientations never reached, a curvature beyond
the chosen order) is off by whatever the unit's true value is. The watch (:mod:`.watch`) needs
both, at each rest's orientation and temperature, beside the sensor's noise: an error common to
every rest of every run, which a test that took it for noise per rest, or ignored it, would call a
change.

:class:`LinkUncertainty` holds, per sensor, the covariance of the errors of the link's terms
(the file's value less the unit's): the fitted terms through the fit's covariance, the held ones
through a plausible spread (from the records where they bound it, else a stated default), and the
fitted terms' share of the held ones (a term fitted while another was held takes up part of it).
The terms are the fit's own columns, in ``u = (T - temp_code_ref) / temperature_scale``:

- ``x.offset``, ``x.offset_T1`` .. : the offset polynomial ``b(T) = sum_k c_k u^k`` (sensor units);
- ``x.scale``, ``x.scale_T1`` .. : the scale polynomial ``K(T) = sum_k s_k u^k`` (1 at nominal);
- ``c_yx`` ..: a coupling of channel ``y`` to the input along ``x``.

At a rest of input ``f`` (the specific force, or the rate) and temperature ``T`` the corrected
value of axis ``a`` is off by ``-(b_a(T) + K_a(T) f_a + sum_j c_aj f_j)`` errors over ``K_a``:
:meth:`LinkUncertainty.rows` gives that as a row per axis, so that the error's covariance between
two rests is ``J_1 C J_2'``. Numpy only (the node's import path).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tak_thermo_ros.errors import CalibrationError

AXIS_NAMES = ('x', 'y', 'z')
HELD_FROM = ('records', 'default', 'prior')
"""Where a held term's spread comes from: the records bound it, a stated default (a datasheet's), or a fleet's
prior (``fit --prior``)."""


def _term(name: str) -> tuple[int, str, int]:
    """``(axis, kind, power)`` of a term's name; a coupling ``c_yx``: ``(channel, 'coupling', input axis)``."""
    if name.startswith('c_') and len(name) == 4 and name[2] in AXIS_NAMES and name[3] in AXIS_NAMES \
            and name[2] != name[3]:
        return AXIS_NAMES.index(name[2]), 'coupling', AXIS_NAMES.index(name[3])
    axis, _, rest = name.partition('.')
    kind, _, power = rest.partition('_T')
    if axis not in AXIS_NAMES or kind not in ('offset', 'scale') or not (power == '' or power.isdigit()) \
            or power == '0':
        msg = f'uncertainty.terms: unknown term {name!r} (x.offset, x.offset_T1, x.scale, x.scale_T1, c_yx, ...)'
        raise CalibrationError(msg)
    return AXIS_NAMES.index(axis), kind, int(power or 0)


@dataclass(frozen=True)
class LinkUncertainty:
    """The covariance of a link's term errors (see the module's description).

    :param terms: the terms' names.
    :param upper: the upper triangle of their errors' covariance, row by row (``n (n + 1) / 2``
        numbers, sensor units; :attr:`covariance` is the matrix).
    :param temperature_scale: the terms' temperature powers are of ``(T - temp_code_ref) / temperature_scale``.
    :param held: the terms the fit held (their variance is their plausible spread's square).
    :param held_from: per held term, :data:`HELD_FROM`: its spread from the records, or a default.
    :param beyond: per axis the spread of the offset's slope beyond the calibrated range (sensor units
        per degree C; the correction holds the curve at its edge there, the unit's goes on): a
        default (``HeldSpreads``), beside the curve's own slope at the edge; empty: not stated.
    :param source: what the covariance comes from: ``records``, or ``records and prior`` (a fleet's prior).
    :param prior: what that prior was (``''``: none).
    :param records_share: per term the share of its precision from the unit's own records (empty: all).
    :param records_min: with a prior, the lowest temperature the unit's own records saw, C; ``records_max``
        the highest (outside them the curve is what the prior told; ``None``: the calibrated range is theirs).
    """

    terms: tuple[str, ...]
    upper: tuple[float, ...]
    temperature_scale: float
    held: tuple[str, ...] = ()
    held_from: tuple[str, ...] = ()
    beyond: tuple[float, ...] = ()
    source: str = 'records'
    prior: str = ''
    records_share: tuple[float, ...] = ()
    records_min: float | None = None
    records_max: float | None = None

    def __post_init__(self) -> None:
        count = len(self.terms)
        if len(set(self.terms)) != count:
            msg = 'uncertainty.terms: a term given twice'
            raise CalibrationError(msg)
        parsed = tuple(_term(name) for name in self.terms)
        if len(self.upper) != count * (count + 1) // 2 or not all(math.isfinite(v) for v in self.upper):
            msg = (f'uncertainty.covariance: expected {count * (count + 1) // 2} finite numbers (the upper triangle '
                   f'of {count} terms), got {len(self.upper)}')
            raise CalibrationError(msg)
        if not (math.isfinite(self.temperature_scale) and self.temperature_scale > 0.0):
            msg = f'uncertainty.temperature_scale: expected a number > 0, got {self.temperature_scale!r}'
            raise CalibrationError(msg)
        if len(self.held_from) != len(self.held) or any(name not in self.terms for name in self.held) \
                or any(where not in HELD_FROM for where in self.held_from):
            msg = (f'uncertainty.held: expected terms of uncertainty.terms, with held_from one of '
                   f'{", ".join(HELD_FROM)} each')
            raise CalibrationError(msg)
        if self.beyond and (len(self.beyond) != 3 or not all(math.isfinite(v) and v >= 0.0 for v in self.beyond)):
            msg = 'uncertainty.beyond: expected three finite numbers >= 0 (x y z)'
            raise CalibrationError(msg)
        if self.records_share and (len(self.records_share) != count or not all(
                math.isfinite(v) and 0.0 <= v <= 1.0 for v in self.records_share)):
            msg = f'uncertainty.records_share: expected {count} numbers within 0..1 (one per term)'
            raise CalibrationError(msg)
        seen = (self.records_min, self.records_max)
        if (seen[0] is None) != (seen[1] is None) or (seen[0] is not None and not (
                math.isfinite(seen[0]) and math.isfinite(seen[1]) and seen[0] <= seen[1])):  # type: ignore[arg-type]
            msg = 'uncertainty.records_min: expected records_min and records_max, finite, records_min <= records_max'
            raise CalibrationError(msg)
        covariance = np.zeros((count, count))
        covariance[np.triu_indices(count)] = self.upper
        covariance = covariance + np.triu(covariance, 1).T
        if np.any(np.diag(covariance) < 0.0):
            msg = 'uncertainty.covariance: a negative variance'
            raise CalibrationError(msg)
        object.__setattr__(self, 'upper', tuple(float(v) for v in self.upper))
        object.__setattr__(self, '_parsed', parsed)
        object.__setattr__(self, '_matrix', covariance)

    @classmethod
    def of(cls, terms: tuple[str, ...], covariance: np.ndarray, temperature_scale: float,
           held: tuple[str, ...] = (), held_from: tuple[str, ...] = (), beyond: tuple[float, ...] = ()
           ) -> LinkUncertainty:
        """From a covariance matrix (symmetrised)."""
        matrix = np.asarray(covariance, dtype=float)
        matrix = 0.5 * (matrix + matrix.T)
        return cls(tuple(terms), tuple(matrix[np.triu_indices(len(terms))].tolist()), float(temperature_scale),
                   tuple(held), tuple(held_from), tuple(float(v) for v in beyond))

    @property
    def covariance(self) -> np.ndarray:
        """``(n, n)`` the errors' covariance."""
        return self._matrix  # type: ignore[attr-defined]

    def rows(self, temperature: float, inputs: np.ndarray, reference: float, scales: np.ndarray) -> np.ndarray:
        """``(3, n)``: how each axis's corrected value moves with the terms' errors at one rest.

        :param temperature: the rest's temperature (the caller clamps it to the calibrated range).
        :param inputs: ``(3,)`` the input at the rest (specific force m/s^2, or rate rad/s).
        :param reference: the calibration's ``temp_code_ref``.
        :param scales: ``(3,)`` each axis's scale there (the corrected value is divided by it).
        """
        u = (temperature - reference) / self.temperature_scale
        out = np.zeros((3, len(self.terms)))
        for column, (axis, kind, power) in enumerate(self._parsed):  # type: ignore[attr-defined]
            if kind == 'coupling':
                out[axis, column] = -inputs[power]
            elif kind == 'scale':
                out[axis, column] = -inputs[axis] * u ** power
            else:
                out[axis, column] = -u ** power
        return out / np.asarray(scales, dtype=float)[:, None]

    def offset_covariance_between(self, axis: int, n_first, n_second):
        """The covariance of an axis's offset curve's errors at ``n_first`` and ``n_second`` (``n = T - T_ref``)."""
        columns = [j for j, (a, kind, _) in enumerate(self._parsed) if a == axis and kind == 'offset']  # type: ignore
        powers = np.array([self._parsed[j][2] for j in columns])  # type: ignore[attr-defined]
        matrix = self.covariance[np.ix_(columns, columns)]
        first = (np.asarray(n_first, dtype=float) / self.temperature_scale)[..., None] ** powers
        second = (np.asarray(n_second, dtype=float) / self.temperature_scale)[..., None] ** powers
        return np.einsum('...p,pq,...q->...', first, matrix, second)

    def offset_change_variance(self, axis: int, n_from, n_to):
        """The variance of an axis's offset curve's error change from ``n_from`` to ``n_to`` (constants cancel)."""
        return (self.offset_variance(axis, n_from) + self.offset_variance(axis, n_to)
                - 2.0 * self.offset_covariance_between(axis, n_from, n_to))

    def offset_variance(self, axis: int, n):
        """The variance of an axis's offset curve's error at ``n = T - T_ref`` (scalar or array)."""
        return self.offset_covariance_between(axis, n, n)

    def standard_error(self, name: str) -> float:
        """One term's standard error (``nan``: not among the terms)."""
        if name not in self.terms:
            return math.nan
        index = self.terms.index(name)
        return float(math.sqrt(max(self.covariance[index, index], 0.0)))

    def to_mapping(self) -> dict[str, object]:
        """The file's ``uncertainty`` section (``covariance``: the upper triangle, row by row)."""
        mapping: dict[str, object] = {'terms': list(self.terms), 'temperature_scale': float(self.temperature_scale),
                                      'covariance': list(self.upper)}
        if self.held:
            mapping['held'] = list(self.held)
            mapping['held_from'] = list(self.held_from)
        if self.beyond:
            mapping['beyond'] = list(self.beyond)
        if self.source != 'records' or self.prior:
            mapping['source'] = self.source
        if self.prior:  # no empty string among a node's parameters
            mapping['prior'] = self.prior
        if self.records_min is not None:
            mapping['records_min'] = float(self.records_min)
            mapping['records_max'] = float(self.records_max)  # type: ignore[arg-type]
        if self.records_share:
            mapping['records_share'] = list(self.records_share)
        return mapping
