"""Hard and soft iron: the ellipsoid fit of a rotation record, and its correction.

A magnetometer turned through every orientation in a constant field sees, after its thermal
correction, points on an ellipsoid: ``B = S B_true + h`` (``h`` the hard iron, a constant
field of magnetised parts that turn with the sensor; ``S`` the soft iron, the field those
parts bend). The correction is ``B_corrected = W (B - h)`` with ``W = S^-1`` made symmetric
(the fit cannot see a rotation of ``S``) and of determinant 1 (an isotropic scale of ``S``
cannot be told from another field strength: the corrected radius is the ellipsoid's
geometric mean radius).

The fit and its acceptance checks follow ArduPilot's CompassCalibrator (field radius,
offsets, diagonal and off-diagonal bounds, fit residual, orientation coverage), with the
bounds in tesla. Everything is numpy; the record is in tesla.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tak_thermo_ros.errors import FitError

MIN_SAMPLES = 100
"""Fewest samples an ellipsoid fit takes (nine parameters; ArduPilot keeps 300)."""
RADIUS_RANGE_T = (15e-6, 95e-6)
"""Field radius accepted, tesla (ArduPilot: 150..950 mGauss; the Earth's field is 22..67 uT)."""
MAX_HARD_IRON_T = 180e-6
"""Largest hard-iron magnitude accepted, tesla (ArduPilot's COMPASS_OFFS_MAX, 1800 mGauss)."""
DIAGONAL_RANGE = (0.5, 2.0)
"""Diagonal of ``W`` accepted (ArduPilot 0.2..5 on an unnormalised matrix; ``W`` here has
determinant 1, so the bounds are tighter)."""
MAX_OFF_DIAGONAL = 0.5
"""Largest off-diagonal of ``W`` accepted (ArduPilot 1.0)."""
MAX_RESIDUAL_T = 1.6e-6
"""Largest RMS of ``|W (B - h)| - radius`` accepted, tesla (ArduPilot's fitness, 16 mGauss)."""
MIN_SPREAD = 0.1
"""Smallest spread of the record along its thinnest direction (the square root of the sample
covariance's smallest eigenvalue) over the field's median magnitude: every orientation gives
about 0.58 (``1/sqrt(3)``), a turn about one axis or no turn at all about 0."""
SECTIONS_NEEDED = 16
"""Of the 20 sections of the sphere (the directions of a dodecahedron's vertices), how many
the corrected field must point into (ArduPilot fills a mask of sections likewise)."""

_PHI = (1.0 + math.sqrt(5.0)) / 2.0
_SECTIONS = np.array(
    [(sx, sy, sz) for sx in (-1.0, 1.0) for sy in (-1.0, 1.0) for sz in (-1.0, 1.0)]
    + [(0.0, sy / _PHI, sz * _PHI) for sy in (-1.0, 1.0) for sz in (-1.0, 1.0)]
    + [(sx / _PHI, sy * _PHI, 0.0) for sx in (-1.0, 1.0) for sy in (-1.0, 1.0)]
    + [(sx * _PHI, 0.0, sz / _PHI) for sx in (-1.0, 1.0) for sz in (-1.0, 1.0)])
_SECTIONS /= np.linalg.norm(_SECTIONS, axis=1)[:, None]


def correct_iron(values: np.ndarray, hard_iron: tuple[float, ...], soft_iron: tuple[float, ...]) -> np.ndarray:
    """``W (B - h)`` of ``(k, 3)`` values; the same operations in the same order as :func:`correct_iron_sample`."""
    values = np.asarray(values, dtype=float)
    h0, h1, h2 = hard_iron
    w = soft_iron
    dx = values[:, 0] - h0
    dy = values[:, 1] - h1
    dz = values[:, 2] - h2
    return np.column_stack([w[0] * dx + w[1] * dy + w[2] * dz,
                            w[3] * dx + w[4] * dy + w[5] * dz,
                            w[6] * dx + w[7] * dy + w[8] * dz])


def correct_iron_sample(x: float, y: float, z: float, hard_iron: tuple[float, ...],
                        soft_iron: tuple[float, ...]) -> tuple[float, float, float]:
    """``W (B - h)`` of one sample of plain floats; bit-identical to :func:`correct_iron`."""
    w = soft_iron
    dx = x - hard_iron[0]
    dy = y - hard_iron[1]
    dz = z - hard_iron[2]
    return (w[0] * dx + w[1] * dy + w[2] * dz,
            w[3] * dx + w[4] * dy + w[5] * dz,
            w[6] * dx + w[7] * dy + w[8] * dz)


@dataclass(frozen=True)
class EllipsoidFit:
    """The hard and soft iron fitted to a rotation record, and how well.

    :param hard_iron: ``h``, tesla.
    :param soft_iron: ``W``, row-major, symmetric, determinant 1.
    :param radius: the corrected field's magnitude, tesla.
    :param residual_rms: RMS of ``|W (B - h)| - radius``, tesla.
    :param samples: samples fitted.
    :param sections: of the 20 sections of the sphere, how many the corrected field points into.
    :param spread: the record's thinnest spread over the field's magnitude (see :data:`MIN_SPREAD`).
    """

    hard_iron: tuple[float, float, float]
    soft_iron: tuple[float, ...]
    radius: float
    residual_rms: float
    samples: int
    sections: int
    spread: float


def spread_ratio(values: np.ndarray) -> float:
    """The record's spread along its thinnest direction over the field's median magnitude (see :data:`MIN_SPREAD`)."""
    centred = values - values.mean(axis=0)
    smallest = np.linalg.eigvalsh(centred.T @ centred / max(len(values), 1))[0]
    magnitude = float(np.median(np.linalg.norm(values, axis=1)))
    return float(math.sqrt(max(smallest, 0.0)) / magnitude) if magnitude > 0 else 0.0


def sections_hit(directions: np.ndarray) -> int:
    """How many of the 20 sections of the sphere the ``(k, 3)`` directions point into."""
    nearest = np.argmax(directions @ _SECTIONS.T, axis=1)
    return int(np.unique(nearest).size)


def _quadric(values: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """The quadric ``x^T A x + 2 g^T x + k = 0`` nearest the points: ``(A, g, k)``.

    The smallest right singular vector of the design, whose norm is ``|A|_F^2 + |g|^2 + k^2``
    (the cross terms carry sqrt(2)), so that the fit turns with the record: rotating the
    points rotates ``A`` and ``g`` and nothing else.
    """
    x, y, z = values[:, 0], values[:, 1], values[:, 2]
    root2 = math.sqrt(2.0)
    design = np.column_stack([x * x, y * y, z * z, root2 * x * y, root2 * x * z, root2 * y * z, 2 * x, 2 * y, 2 * z,
                              np.ones(len(values))])
    a, b, c, d, e, f, g, h, i, k = np.linalg.svd(design, full_matrices=False)[2][-1]
    d, e, f = d / root2, e / root2, f / root2
    return np.array([[a, d, e], [d, b, f], [e, f, c]]), np.array([g, h, i]), float(k)


def _symmetric_sqrt(matrix: np.ndarray) -> np.ndarray:
    eigenvalues, vectors = np.linalg.eigh(matrix)
    root = vectors @ np.diag(np.sqrt(eigenvalues)) @ vectors.T
    return (root + root.T) / 2.0


def fit_ellipsoid(values: np.ndarray, *, where: str = 'rotation record') -> EllipsoidFit:
    """Fit ``h`` and ``W`` to a rotation record ``(k, 3)`` in tesla, with the acceptance checks.

    :raises FitError: one line naming the check that failed: too few samples, non-finite
        values, too few orientations (the spread, then the sections), no ellipsoid, radius,
        hard iron, diagonal, off-diagonal or residual out of bounds.
    """
    values = np.asarray(values, dtype=float).reshape(-1, 3)
    spread = check_samples(values, where)
    hard, soft, radius = algebraic_ellipsoid(values, where)
    corrected = (values - hard) @ soft.T
    magnitudes = np.linalg.norm(corrected, axis=1)
    residual = float(np.sqrt(np.mean((magnitudes - radius) ** 2)))
    sections = sections_hit(corrected / magnitudes[:, None])
    fit = EllipsoidFit(hard_iron=tuple(float(v) for v in hard), soft_iron=tuple(float(v) for v in soft.ravel()),
                       radius=float(radius), residual_rms=residual, samples=len(values), sections=sections,
                       spread=spread)
    check_fit(fit, where=where)
    return fit


def check_samples(values: np.ndarray, where: str) -> float:
    """Enough finite samples, turned about more than one axis; the record's spread (:func:`spread_ratio`).

    :raises FitError: too few samples, non-finite values, too few orientations (one line).
    """
    if len(values) < MIN_SAMPLES:
        msg = f'{where}: {len(values)} samples; the ellipsoid fit needs at least {MIN_SAMPLES}'
        raise FitError(msg)
    if not np.all(np.isfinite(values)):
        msg = f'{where}: {int(np.count_nonzero(~np.all(np.isfinite(values), axis=1)))} samples are not finite'
        raise FitError(msg)
    spread = spread_ratio(values)
    if spread < MIN_SPREAD:
        msg = (f'{where}: covers too few orientations: along its thinnest direction the field spreads {spread:.3f} '
               f'of its magnitude (at least {MIN_SPREAD} needed): turn the unit about more than one axis')
        raise FitError(msg)
    return spread


def algebraic_ellipsoid(values: np.ndarray, where: str) -> tuple[np.ndarray, np.ndarray, float]:
    """The ellipsoid nearest the points ``(k, 3)``: ``h`` (3,), ``W`` (3x3, symmetric, determinant 1), radius.

    :raises FitError: the quadric fitted to the points is not an ellipsoid.
    """
    mean = values.mean(axis=0)
    size = float(np.median(np.linalg.norm(values - mean, axis=1)))
    points = (values - mean) / size
    quadratic, linear, k = _quadric(points)
    if np.linalg.eigvalsh(quadratic)[0] * np.linalg.eigvalsh(quadratic)[-1] <= 0:
        msg = f'{where}: the record does not lie on an ellipsoid (the quadric fitted to it is not one)'
        raise FitError(msg)
    centre = -np.linalg.solve(quadratic, linear)
    level = float(centre @ quadratic @ centre - k)
    shape = quadratic / level
    if np.linalg.eigvalsh(shape)[0] <= 0:
        msg = f'{where}: the record does not lie on an ellipsoid (the quadric fitted to it is not one)'
        raise FitError(msg)
    root = _symmetric_sqrt(shape)
    determinant = float(np.linalg.det(root))
    soft = root / determinant ** (1.0 / 3.0)
    soft = (soft + soft.T) / 2.0
    radius = size / determinant ** (1.0 / 3.0)
    return mean + size * centre, soft, float(radius)


def check_fit(fit: EllipsoidFit, *, where: str = 'rotation record') -> None:
    """The acceptance checks of ArduPilot on a fit (bounds in the constants above).

    :raises FitError: one line naming the first check that failed.
    """
    if fit.sections < SECTIONS_NEEDED:
        msg = (f'{where}: covers too few orientations: the corrected field points into {fit.sections} of the 20 '
               f'sections of the sphere (at least {SECTIONS_NEEDED} needed): turn the unit through more orientations')
        raise FitError(msg)
    low, high = RADIUS_RANGE_T
    if not low <= fit.radius <= high:
        msg = (f'{where}: field radius {fit.radius * 1e6:.4g} uT outside {low * 1e6:g}..{high * 1e6:g} uT '
               f'(values in tesla? a field near iron?)')
        raise FitError(msg)
    hard = math.sqrt(sum(v * v for v in fit.hard_iron))
    if hard > MAX_HARD_IRON_T:
        msg = f'{where}: hard iron {hard * 1e6:.4g} uT beyond {MAX_HARD_IRON_T * 1e6:g} uT'
        raise FitError(msg)
    soft = np.array(fit.soft_iron).reshape(3, 3)
    diagonal = np.diag(soft)
    if not np.all((diagonal >= DIAGONAL_RANGE[0]) & (diagonal <= DIAGONAL_RANGE[1])):
        msg = (f'{where}: soft-iron diagonal {", ".join(f"{v:.3g}" for v in diagonal)} outside '
               f'{DIAGONAL_RANGE[0]:g}..{DIAGONAL_RANGE[1]:g}')
        raise FitError(msg)
    off = float(np.max(np.abs(soft - np.diag(diagonal))))
    if off > MAX_OFF_DIAGONAL:
        msg = f'{where}: soft-iron off-diagonal {off:.3g} beyond {MAX_OFF_DIAGONAL:g}'
        raise FitError(msg)
    if fit.residual_rms > MAX_RESIDUAL_T:
        msg = (f'{where}: fit residual RMS {fit.residual_rms * 1e6:.3g} uT beyond {MAX_RESIDUAL_T * 1e6:g} uT '
               f'(the field changed during the turn, or the thermal link does not hold)')
        raise FitError(msg)
