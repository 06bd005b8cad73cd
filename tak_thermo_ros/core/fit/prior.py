"""A curve's prior: what a unit's records tell about its curve, and what units of its kind add to a fit.

Both directions go through the one pool fit (:func:`~tak_thermo_ros.core.fit.handheld.fit_handheld`):

- **What a unit's records say** (:class:`Information`): its fit's final system ``[X | y]`` (the
  rests' rows, the turns' rows, each record's turn-on offset as a random effect with its prior
  row) as the quadratic ``-2 log L(theta) = theta' H theta - 2 g' theta + c``, the terms the fit
  holds by construction (the gauge, one orientation's, the orders') put in at their values.
  The turn-on offsets, couplings and effects are integrated out (:meth:`Information.curve`): what
  is left is the unit's information on its **curve terms**, each axis's offset polynomial
  ``x.offset, x.offset_T1 ..`` and scale polynomial ``x.scale, x.scale_T1 ..`` in ``u = (T - ref)
  / n_scale``. Those are the sufficient statistics of a fleet's prior (:mod:`.fleet_prior`): a
  few numbers per unit, however many records. A term the records cannot tell (a narrow span's
  cubic) keeps its little information: nothing is held at 0 here.
- **What a prior adds** (:class:`CurvePrior`): per sensor a Gaussian on the curve terms, as rows
  ``R (theta_P - mean) = 0`` (``R' R`` the prior's precision) beside the records' rows in the same
  solve; the fit then stands in the prior's basis (its ``ref`` and ``n_scale``) at its orders, over
  its temperatures as well as the records'. The posterior's covariance of the curve terms (the
  calibration's :class:`~tak_thermo_ros.core.link.uncertainty.LinkUncertainty`) gives the +- of the
  curve at any temperature: small where the records saw the unit, the prior's spread outside.

A basis change (:func:`basis_change`) carries a polynomial's coefficients from one ``u`` to
another exactly (binomial expansion), and with them the information.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from typing import Mapping, Sequence

import numpy as np

from tak_thermo_ros.core.fit.design import Frame
from tak_thermo_ros.errors import FitError

CURVE_TERM = re.compile(r'^([xyz])\.(offset|scale)(?:_T(\d+))?$')
"""A curve term's name: its axis, its polynomial (offset or scale) and its power (none: 0)."""
NULL_RELATIVE = 1e-12
"""An eigenvalue of a (column-scaled) information below this fraction of the largest carries nothing."""


def curve_term(name: str) -> tuple[str, str, int] | None:
    """``(axis, polynomial, power)`` of a curve term (``x.offset_T2`` -> ``('x', 'offset', 2)``), else ``None``."""
    found = CURVE_TERM.match(name)
    if found is None:
        return None
    return found.group(1), found.group(2), int(found.group(3) or 0)


def term_name(axis: str, polynomial: str, power: int) -> str:
    """The name of a curve term (``('x', 'offset', 2)`` -> ``x.offset_T2``)."""
    return f'{axis}.{polynomial}' + (f'_T{power}' if power else '')


@dataclass(frozen=True)
class Basis:
    """Where a curve's polynomials stand: ``u = (T - ref) / n_scale``, degrees C."""

    ref: float
    n_scale: float

    @classmethod
    def of_frame(cls, frame: Frame) -> Basis:
        """The basis of a fit's frame."""
        return cls(float(frame.ref), float(frame.n_scale))

    def powers(self, temperature: np.ndarray, order: int) -> np.ndarray:
        """``(k, order + 1)``: ``u^0 .. u^order`` at the temperatures."""
        u = (np.asarray(temperature, dtype=float) - self.ref) / self.n_scale
        return u[:, None] ** np.arange(order + 1)[None, :]


def basis_change(source: Basis, target: Basis, order: int) -> np.ndarray:
    """``B`` ``(order + 1, order + 1)``: a polynomial's coefficients in ``target``'s powers from ``source``'s.

    ``sum_k beta_k u_s^k = sum_j gamma_j u_t^j`` with ``gamma = B beta``: ``u_s = a + s u_t``,
    ``a = (ref_t - ref_s) / n_s``, ``s = n_t / n_s``, so ``B[j, k] = C(k, j) a^(k-j) s^j``.
    """
    a = (target.ref - source.ref) / source.n_scale
    s = target.n_scale / source.n_scale
    out = np.zeros((order + 1, order + 1))
    for k in range(order + 1):
        for j in range(k + 1):
            out[j, k] = math.comb(k, j) * a ** (k - j) * s ** j
    return out


def _polynomials(names: Sequence[str]) -> dict[tuple[str, str], list[int]]:
    """The curve terms' positions in ``names`` per polynomial ``(axis, offset|scale)``, by power."""
    found: dict[tuple[str, str], dict[int, int]] = {}
    for index, name in enumerate(names):
        term = curve_term(name)
        if term is not None:
            found.setdefault(term[:2], {})[term[2]] = index
    out = {}
    for key, powers in found.items():
        if sorted(powers) != list(range(len(powers))):
            msg = f'{key[0]}.{key[1]}: the powers {sorted(powers)} are not 0..{len(powers) - 1}'
            raise FitError(msg)
        out[key] = [powers[p] for p in range(len(powers))]
    return out


def term_change(names: Sequence[str], source: Basis, target: Basis) -> np.ndarray:
    """``(P, P)`` over ``names``: each polynomial's coefficients carried to ``target`` (other terms kept)."""
    out = np.eye(len(names))
    for positions in _polynomials(names).values():
        out[np.ix_(positions, positions)] = basis_change(source, target, len(positions) - 1)
    return out


def _psd_inverse(matrix: np.ndarray) -> np.ndarray:
    """The pseudo-inverse of a symmetric positive semi-definite matrix (columns scaled: terms differ by decades)."""
    size = len(matrix)
    if not size:
        return np.zeros((0, 0))
    scale = np.sqrt(np.maximum(np.diag(matrix), 0.0))
    scale = np.where(scale > 0.0, scale, 1.0)
    scaled = matrix / np.outer(scale, scale)
    values, vectors = np.linalg.eigh(0.5 * (scaled + scaled.T))
    keep = values > NULL_RELATIVE * max(float(values.max()), 1e-300)
    inverse = (vectors[:, keep] / values[keep]) @ vectors[:, keep].T
    return inverse / np.outer(scale, scale)


@dataclass(frozen=True)
class Information:
    """What a unit's records say about its terms: ``-2 log L = theta' H theta - 2 g' theta + c`` (and a constant).

    :param names: the terms, as the fit's layout names them (``x.offset_T1``, ``x.turn_on.r3``, ``cross_axis.c_yx``).
    :param normal: ``(P + 1, P + 1)``: ``[[H, g], [g', c]]``, the normal matrix of the whitened ``[X | y]``.
    :param basis: where the curve terms' polynomials stand.
    :param low: the lowest temperature of the records' rests, C; ``high`` the highest.
    :param rows: the observations behind it (a residual scale's degrees of freedom; 0: not counted).
    :param held: terms the fit held as undetermined (their little information is kept here).
    """

    names: tuple[str, ...]
    normal: np.ndarray
    basis: Basis
    low: float
    high: float
    rows: int = 0
    held: tuple[str, ...] = ()

    @property
    def hessian(self) -> np.ndarray:
        """``H`` ``(P, P)``."""
        return self.normal[:-1, :-1]

    @property
    def gradient(self) -> np.ndarray:
        """``g`` ``(P,)``: ``H theta_hat``."""
        return self.normal[:-1, -1]

    def marginal(self, keep: Sequence[str]) -> Information:
        """The information on ``keep`` alone, every other term integrated out (a flat prior on them).

        The Schur complement of the others' block (its pseudo-inverse: a term nobody tells adds nothing).
        """
        index = [self.names.index(name) for name in keep]
        other = [j for j in range(len(self.names)) if j not in index]
        last = len(self.names)
        kept = [*index, last]
        block = self.normal[np.ix_(kept, kept)]
        if other:
            cross = self.normal[np.ix_(kept, other)]
            block = block - cross @ _psd_inverse(self.normal[np.ix_(other, other)]) @ cross.T
        return replace(self, names=tuple(keep), normal=0.5 * (block + block.T),
                       held=tuple(name for name in self.held if name in keep))

    def curve(self) -> Information:
        """The information on the curve terms alone (turn-on offsets, couplings, effects integrated out)."""
        return self.marginal([name for name in self.names if curve_term(name) is not None])

    def in_basis(self, basis: Basis) -> Information:
        """The same information in another basis (exact: ``theta = B^-1 gamma``)."""
        change = term_change(self.names, self.basis, basis)
        inverse = np.linalg.inv(change)
        carry = np.eye(len(self.names) + 1)
        carry[:-1, :-1] = inverse
        normal = carry.T @ self.normal @ carry
        return replace(self, normal=0.5 * (normal + normal.T), basis=basis)

    def with_level_spread(self, spread: Mapping[str, float]) -> Information:
        """The information when one record's level is the curve's plus a turn-on offset of ``spread`` (per axis).

        A record's level tells the curve's offset only to within its power-up's turn-on offset: a nuisance
        that enters as the axis's ``offset`` term does, with the prior ``N(0, spread^2)``, integrated out.
        """
        out = self
        for axis, sd in spread.items():
            name = f'{axis}.offset'
            if name not in out.names or not sd > 0.0:
                continue
            index = out.names.index(name)
            size = len(out.names)
            normal = np.zeros((size + 2, size + 2))
            kept = [*range(size), size + 1]
            normal[np.ix_(kept, kept)] = out.normal
            row = out.normal[index]  # the level's column is the offset's: its cross terms, its target
            normal[size, kept] = row
            normal[kept, size] = row
            normal[size, size] = out.normal[index, index] + 1.0 / sd ** 2
            augmented = replace(out, names=(*out.names, f'{axis}.level'), normal=normal)
            out = augmented.marginal(out.names)
        return out

    def aligned(self, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray, float]:
        """``H`` ``(Q, Q)``, ``g`` ``(Q,)`` and ``c`` over ``names`` (a term it does not hold: no information)."""
        out = np.zeros((len(names) + 1, len(names) + 1))
        position = {name: i for i, name in enumerate(self.names)}
        here = [i for i, name in enumerate(names) if name in position]
        source = [position[names[i]] for i in here]
        rows = [*here, len(names)]
        out[np.ix_(rows, rows)] = self.normal[np.ix_([*source, len(self.names)], [*source, len(self.names)])]
        return out[:-1, :-1], out[:-1, -1], float(out[-1, -1])

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """The records' own estimate of the terms and its covariance (pseudo-inverse: an untold term has 0 and inf)."""
        inverse = _psd_inverse(self.hessian)
        told = np.diag(self.hessian) > 0.0
        covariance = np.where(np.outer(told, told), inverse, 0.0)
        covariance[np.diag_indices_from(covariance)] = np.where(told, np.diag(inverse), np.inf)
        return inverse @ self.gradient, covariance


@dataclass(frozen=True)
class SensorPrior:
    """A Gaussian on a sensor's curve terms: what a fit of one unit takes from its kind.

    :param names: the curve terms (``x.offset``, ``x.offset_T1``, ...).
    :param mean: ``(P,)`` in the prior's basis; ``covariance`` ``(P, P)``.
    :param label: what it is, for the file and the lines (``prior.yaml: 40 units, group 2 of 3``).
    """

    names: tuple[str, ...]
    mean: np.ndarray
    covariance: np.ndarray
    label: str = ''

    def rows(self, layout_names: Sequence[str]) -> np.ndarray:
        """``(P, W + 1)``: the whitened rows ``R (theta_P - mean)`` in a fit's columns ``layout_names``.

        :raises FitError: a prior term the fit has no column for.
        """
        missing = [name for name in self.names if name not in layout_names]
        if missing:
            msg = f'the prior holds {", ".join(missing)}, which the fit does not (its orders differ from the prior\'s)'
            raise FitError(msg)
        values, vectors = np.linalg.eigh(0.5 * (self.covariance + self.covariance.T))
        root = vectors.T / np.sqrt(np.maximum(values, 1e-300))[:, None]  # root' root = covariance^-1
        out = np.zeros((len(self.names), len(layout_names) + 1))
        out[:, [list(layout_names).index(name) for name in self.names]] = root
        out[:, -1] = root @ self.mean
        return out

    def information(self) -> Information:
        """The prior as an :class:`Information` over its names (to add to or take from a fit's)."""
        precision = np.linalg.inv(self.covariance)
        normal = np.zeros((len(self.names) + 1, len(self.names) + 1))
        normal[:-1, :-1] = precision
        normal[:-1, -1] = normal[-1, :-1] = precision @ self.mean
        normal[-1, -1] = float(self.mean @ precision @ self.mean)
        return Information(self.names, normal, Basis(0.0, 1.0), math.nan, math.nan)


@dataclass(frozen=True)
class CurvePrior:
    """What a fit of one unit takes from its kind: the basis, the orders, the temperatures, per sensor a Gaussian.

    :param basis: where the prior's polynomials stand (the fit then stands there too); ``None``: the
        records' own (a prior that only fixes the orders: a fleet's first pass).
    :param bias_order: the offset polynomials' order; ``scale_order`` the scale polynomials'.
    :param low: the lowest temperature the prior covers, C (the calibrated range reaches it); ``high`` likewise.
    :param sensors: per sensor (``accel``, ``gyro``) its :class:`SensorPrior`; a sensor without one is
        fitted from its records alone at these orders.
    """

    basis: Basis | None
    bias_order: int
    scale_order: int
    low: float = math.nan
    high: float = math.nan
    sensors: Mapping[str, SensorPrior] = field(default_factory=dict)

    def frame(self, low: float, high: float, temp_code_ref: float | None = None) -> Frame:
        """The fit's frame over the records' ``low..high`` and the prior's temperatures, in the prior's basis."""
        if self.basis is None:
            return Frame.of_range(low, high, temp_code_ref)
        if math.isfinite(self.low):
            low, high = min(low, self.low), max(high, self.high)
        return Frame(ref=self.basis.ref, low=low, high=high, n_scale=self.basis.n_scale)

    def rows(self, sensor: str, layout_names: Sequence[str]) -> np.ndarray:
        """A sensor's prior rows in a fit's columns (none without a prior on it)."""
        prior = self.sensors.get(sensor)
        if prior is None:
            return np.zeros((0, len(layout_names) + 1))
        return prior.rows(layout_names)
