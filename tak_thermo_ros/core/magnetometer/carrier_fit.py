"""The carrier method's estimate: the Earth field, the Poisson coefficients and the hard iron from a record.

The model and its record are :mod:`tak_thermo_ros.core.magnetometer.carrier`'s (its docstring
tells what can and cannot be identified). :func:`fit_carrier` gives a :class:`CarrierFit`;
:func:`design_condition` how well a planned record determines a model.

**The estimate** is a weighted least squares with the linearised errors-in-variables
("effective variance") weights: each reading's covariance is the magnetometer's variance plus
the turn-angle and attitude variances carried through the model's derivatives, re-evaluated
at the estimate; the parameters' covariance is ``(J^T W J)^-1`` plus the given gauge values'
own uncertainties carried through. Pure numpy and scipy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tak_thermo_ros.core.magnetometer.carrier import (
    AXIS_NAMES,
    NAV_NAMES,
    CarrierModel,
    CarrierRecord,
    CarrierTruth,
    InstrumentErrors,
    _predict,
    _predict_with,
    _turn_matrices,
    attitude_matrix,
    axis_rotation,
    check_record,
    earth_from_parameters,
    earth_parameters,
)

IDENTIFIABLE_RATIO = 1e-6
"""Smallest singular value over the largest (unit-scaled columns) that the fit accepts."""


@dataclass(frozen=True)
class Estimate:
    """One estimated quantity: value and standard uncertainty."""

    name: str
    value: float
    sigma: float
    unit: str


@dataclass(frozen=True)
class CarrierFit:
    """The carrier method's result.

    ``estimates``: the Earth field (north, east, down), the free Poisson coefficients, the hard
    iron and the sensor offset, each with its standard uncertainty; ``covariance`` of those in the
    same order; ``condition`` the condition number of the weighted Jacobian with unit-scaled
    columns; ``singular_values`` of it; ``chi2_per_dof`` the weighted residual (about 1 when the
    stated instrument errors are right); ``parameter_names`` / ``parameters`` the fitted vector.
    """

    model: CarrierModel
    estimates: tuple[Estimate, ...]
    covariance: np.ndarray
    condition: float
    singular_values: np.ndarray
    chi2_per_dof: float
    readings: int
    parameter_names: tuple[str, ...]
    parameters: np.ndarray

    def value(self, name: str) -> float:
        """The value of the estimate called ``name`` (e.g. ``'B_down'``, ``'D_zz'``, ``'p_x'``)."""
        return self.by_name()[name].value

    def by_name(self) -> dict[str, Estimate]:
        """Every estimate by its name."""
        return {estimate.name: estimate for estimate in self.estimates}

    def truth(self) -> CarrierTruth:
        """The estimate as a :class:`CarrierTruth` (held Poisson coefficients zero)."""
        values = self.by_name()
        poisson = np.zeros((3, 3))
        for name in self.model.poisson:
            poisson[AXIS_NAMES.index(name[0]), AXIS_NAMES.index(name[1])] = values[f'D_{name}'].value
        return CarrierTruth(np.array([values[f'B_{n}'].value for n in NAV_NAMES]), poisson,
                            np.array([values[f'p_{a}'].value for a in AXIS_NAMES]),
                            np.array([values[f'o_{a}'].value for a in AXIS_NAMES]))


class _Problem:
    """The parameter vector, the residuals and the effective-variance weights of one record and model."""

    def __init__(self, record: CarrierRecord, model: CarrierModel, errors: InstrumentErrors) -> None:
        self.record = record
        self.model = model
        self.errors = errors
        self.given = {key: value for key, (value, _) in model.gauge.given().items()}
        self.n_earth = len(model.earth_names())
        self.poisson_index = [(AXIS_NAMES.index(name[0]), AXIS_NAMES.index(name[1])) for name in model.poisson]
        self.measured = np.asarray(record.field_uT, dtype=float)
        self.whitening = np.broadcast_to(np.eye(3) / max(errors.sigma(errors.field_uT), 1e-12),
                                         (len(record), 3, 3)).copy()
        self.shift = np.zeros((len(record), 3))
        self.attitude = attitude_matrix(record.roll_rad, record.pitch_rad, record.heading_rad)
        self.turn = _turn_matrices(record.turn_axis, record.turn_angle_rad)

    def unpack(self, theta: np.ndarray, given: dict[str, float] | None = None):
        earth = earth_from_parameters(self.model, theta[:self.n_earth], self.given if given is None else given)
        k = self.n_earth
        induced = np.eye(3)
        for j, (row, col) in enumerate(self.poisson_index):
            induced[row, col] += theta[k + j]
        k += len(self.poisson_index)
        return earth, induced, theta[k:k + 3], theta[k + 3:k + 6]

    def readings(self, theta: np.ndarray, given: dict[str, float] | None = None, *, turn_angle=None,
                 roll=None, pitch=None, heading=None) -> np.ndarray:
        r = self.record
        earth, induced, hard_iron, offset = self.unpack(theta, given)
        if turn_angle is None and roll is None and pitch is None and heading is None:
            return _predict_with(earth, induced, hard_iron, offset, self.attitude, self.turn)
        return _predict(earth, induced, hard_iron, offset, r.turn_axis,
                        r.turn_angle_rad if turn_angle is None else turn_angle, r.roll_rad if roll is None else roll,
                        r.pitch_rad if pitch is None else pitch, r.heading_rad if heading is None else heading)

    def residuals(self, theta: np.ndarray, given: dict[str, float] | None = None) -> np.ndarray:
        raw = self.measured - self.readings(theta, given) - self.shift
        return np.einsum('nij,nj->ni', self.whitening, raw).ravel()

    def reweight(self, theta: np.ndarray) -> None:
        """Each reading's covariance and mean shift: the field noise plus the angle errors carried through the model.

        To first order an angle error ``d`` moves a reading by ``h' d``; to second order by
        ``h'' d^2 / 2`` as well, whose mean ``h'' s^2 / 2`` is added to the prediction and whose
        variance ``h'' h''^T var(d^2) / 4`` to the covariance. The second order matters here: the
        first-order terms all lie across the field, so a reading's magnitude is known to the
        magnetometer's 0.001 uT, 50 times better than its direction, and the fit leans on it.
        """
        e = self.errors
        r = self.record
        covariance = np.broadcast_to(np.eye(3) * e.sigma(e.field_uT) ** 2, (len(r), 3, 3)).copy()
        shift = np.zeros((len(r), 3))
        self.shift = shift
        step = 1e-4
        base = self.readings(theta)
        for name, bound in (('turn_angle', e.turn_rad), ('roll', e.attitude_rad), ('pitch', e.attitude_rad),
                            ('heading', e.attitude_rad)):
            if bound == 0.0:
                continue
            sigma = e.sigma(bound)
            # var(d^2): uniform on +-bound: bound^4 (1/5 - 1/9); normal: 2 sigma^4
            variance_of_square = bound ** 4 * 4.0 / 45.0 if e.distribution == 'uniform' else 2.0 * sigma ** 4
            column = {'turn_angle': r.turn_angle_rad, 'roll': r.roll_rad, 'pitch': r.pitch_rad,
                      'heading': r.heading_rad}[name]
            up = self.readings(theta, **{name: column + step})
            down = self.readings(theta, **{name: column - step})
            first = (up - down) / (2.0 * step)
            second = (up - 2.0 * base + down) / step ** 2
            covariance += sigma ** 2 * np.einsum('ni,nj->nij', first, first)
            covariance += variance_of_square / 4.0 * np.einsum('ni,nj->nij', second, second)
            shift += second * sigma ** 2 / 2.0
        covariance += np.eye(3) * 1e-18  # a floor, should every error be zero
        cholesky = np.linalg.cholesky(covariance)
        self.whitening = np.linalg.inv(cholesky)

    def jacobian(self, theta: np.ndarray, given: dict[str, float] | None = None) -> np.ndarray:
        base = self.residuals(theta, given)
        jac = np.empty((base.size, theta.size))
        for j in range(theta.size):
            step = 1e-6 * max(1.0, abs(theta[j]))
            shifted = theta.copy()
            shifted[j] += step
            jac[:, j] = (self.residuals(shifted, given) - base) / step
        return jac


def _initial(problem: _Problem) -> np.ndarray:
    """A starting point: alternate the linear problems in (D, p, o) given b and in b given (D, p, o)."""
    r = problem.record
    model = problem.model
    attitude = attitude_matrix(r.roll_rad, r.pitch_rad, r.heading_rad)
    turn = np.empty((len(r), 3, 3))
    for axis in (0, 1, 2):
        rows = r.turn_axis == axis
        turn[rows] = axis_rotation(axis, r.turn_angle_rad[rows])
    measured = problem.measured
    earth = np.einsum('nij,njk,nk->i', attitude, turn, measured) / len(r)
    poisson = np.zeros(len(problem.poisson_index))
    hard_iron = np.zeros(3)
    offset = np.zeros(3)
    for _ in range(4):
        # m = R^T ((I + D) u + p) + o, linear in (D entries, p, o) given u = C^T b
        u = np.einsum('nji,j->ni', attitude, earth)
        columns = []
        for row, col in problem.poisson_index:
            unit = np.zeros((len(r), 3))
            unit[:, row] = u[:, col]
            columns.append(np.einsum('nji,nj->ni', turn, unit).ravel())
        for axis in range(3):
            unit = np.zeros((len(r), 3))
            unit[:, axis] = 1.0
            columns.append(np.einsum('nji,nj->ni', turn, unit).ravel())
        for axis in range(3):
            unit = np.zeros((len(r), 3))
            unit[:, axis] = 1.0
            columns.append(unit.ravel())
        target = (measured - np.einsum('nji,nj->ni', turn, u)).ravel()
        solution = np.linalg.lstsq(np.column_stack(columns), target, rcond=None)[0]
        k = len(poisson)
        poisson, hard_iron, offset = solution[:k], solution[k:k + 3], solution[k + 3:]
        induced = np.eye(3)
        for j, (row, col) in enumerate(problem.poisson_index):
            induced[row, col] += poisson[j]
        # given (D, p, o): m - o - R^T p = R^T (I + D) C^T b, linear in b
        design = np.einsum('nji,jk,nlk->nil', turn, induced, attitude).reshape(-1, 3)
        target = (measured - offset - np.einsum('nji,j->ni', turn, hard_iron)).ravel()
        earth = np.linalg.lstsq(design, target, rcond=None)[0]
    earth_values = earth_parameters(model, earth)
    return np.concatenate([earth_values, poisson, hard_iron, offset])


def smoothed_attitude(record: CarrierRecord, attitude_error_rad: float, degree: int = 3) -> CarrierRecord:
    """The record with each stage's roll, pitch and heading replaced by a cubic in time (for the rank check).

    A smoothed angle that moves by less than five times the attitude error within a stage is
    taken as constant (within the stage, and over the whole record when it moves that little
    there too): motion within the instrument's error is not motion.

    A carrier's attitude moves slowly and smoothly within a stage; the attitude errors scatter
    the measured angles around that. Evaluated at the measured angles, the Jacobian would take
    that scatter for real motion and credit the record with information it does not hold (a
    heading that "varies" by +-0.1 deg seems to separate the Earth's field along the tilt axis
    from the hard iron). The identifiability check therefore uses the smoothed attitude.
    """
    smoothed = {name: np.array(getattr(record, name), dtype=float) for name in ('roll_rad', 'pitch_rad', 'heading_rad')}
    for stage in np.unique(record.stage):
        rows = np.nonzero(record.stage == stage)[0]
        time = np.asarray(record.time_s, dtype=float)[rows]
        span = float(np.ptp(time)) or 1.0
        x = (time - time.mean()) / span
        order = min(degree, len(rows) - 1)
        for name, values in smoothed.items():
            fitted = np.polyval(np.polyfit(x, np.unwrap(values[rows]), order), x) if order > 0 else values[rows]
            values[rows] = fitted if float(np.ptp(fitted)) > 5.0 * attitude_error_rad else float(np.mean(fitted))
    for name, values in smoothed.items():  # and an angle that moves that little over the whole record, likewise
        if float(np.ptp(values)) <= 5.0 * attitude_error_rad:
            smoothed[name] = np.full_like(values, float(np.mean(values)))
    return CarrierRecord(record.time_s, record.stage, record.turn_axis, record.turn_angle_rad, smoothed['roll_rad'],
                         smoothed['pitch_rad'], smoothed['heading_rad'], record.field_uT)


def _nullspace_words(names: tuple[str, ...], vector: np.ndarray) -> str:
    weights = np.abs(vector) / np.max(np.abs(vector))
    involved = [names[j] for j in np.argsort(-weights) if weights[j] > 0.2]
    return ', '.join(involved[:6])


def fit_carrier(record: CarrierRecord, model: CarrierModel | None = None,
                errors: InstrumentErrors | None = None, *, reweightings: int = 2) -> CarrierFit:
    """Estimate the Earth field, the Poisson coefficients, the hard iron and the sensor offset.

    :param model: the parametrisation and gauge (default :class:`CarrierModel`: the seed's).
    :param errors: the instrument errors that weight the readings (default the seed's).
    :raises CarrierError: the record is unusable (:func:`check_record`).
    :raises FitError: the record and model cannot determine the parameters (names those that
        move together), or the fit does not converge.
    """
    from scipy.optimize import least_squares

    from tak_thermo_ros.errors import FitError

    model = model or CarrierModel()
    errors = errors or InstrumentErrors()
    check_record(record)
    problem = _Problem(record, model, errors)
    theta = _initial(problem)
    names = model.parameter_names()
    for _ in range(reweightings + 1):
        problem.reweight(theta)
        solution = least_squares(problem.residuals, theta, method='lm', x_scale='jac', xtol=1e-10, ftol=1e-10)
        theta = solution.x
    problem.reweight(theta)
    jac = problem.jacobian(theta)
    smooth = _Problem(smoothed_attitude(record, errors.attitude_rad), model, errors)
    smooth.reweight(theta)
    design_jac = smooth.jacobian(theta)
    column_norms = np.linalg.norm(design_jac, axis=0)
    if np.any(column_norms == 0.0):
        missing = [names[j] for j in np.nonzero(column_norms == 0.0)[0]]
        msg = f'carrier fit: the record does not depend on {", ".join(missing)} at all (no turn or tilt that shows it)'
        raise FitError(msg)
    _, singular, right = np.linalg.svd(design_jac / column_norms, full_matrices=False)
    if singular[-1] < IDENTIFIABLE_RATIO * singular[0]:
        msg = (f'carrier fit: the record cannot separate {_nullspace_words(names, right[-1])} (they move together: '
               f'the record needs a tilt of the carrier that shows them apart, fewer free Poisson coefficients, '
               f'or a declination or |B_earth|)')
        raise FitError(msg)
    condition = float(singular[0] / singular[-1])
    residual = problem.residuals(theta)
    dof = max(residual.size - theta.size, 1)
    information = jac.T @ jac
    covariance_theta = np.linalg.inv(information)
    # The gauge values' own uncertainties: the estimate moves by -(J^T J)^-1 J^T dr/dg per unit of g.
    given_sigmas = model.gauge.given()
    sensitivity = np.zeros((theta.size, len(given_sigmas)))
    output_by_given = np.zeros((3, len(given_sigmas)))
    for j, (key, (value, _)) in enumerate(given_sigmas.items()):
        step = 1e-7 * max(1.0, abs(value))
        shifted = dict(problem.given, **{key: value + step})
        dr = (problem.residuals(theta, shifted) - residual) / step
        sensitivity[:, j] = -covariance_theta @ jac.T @ dr
        output_by_given[:, j] = (earth_from_parameters(model, theta[:problem.n_earth], shifted)
                                 - earth_from_parameters(model, theta[:problem.n_earth], problem.given)) / step
    given_variance = np.diag([sigma ** 2 for _, sigma in given_sigmas.values()])
    # outputs: earth (3), then the other parameters as they are
    n_out = 3 + theta.size - problem.n_earth
    to_output = np.zeros((n_out, theta.size))
    base_earth = earth_from_parameters(model, theta[:problem.n_earth], problem.given)
    for j in range(problem.n_earth):
        step = 1e-7 * max(1.0, abs(theta[j]))
        shifted = theta[:problem.n_earth].copy()
        shifted[j] += step
        to_output[:3, j] = (earth_from_parameters(model, shifted, problem.given) - base_earth) / step
    to_output[3:, problem.n_earth:] = np.eye(theta.size - problem.n_earth)
    by_given = to_output @ sensitivity
    by_given[:3] += output_by_given
    covariance = to_output @ covariance_theta @ to_output.T + by_given @ given_variance @ by_given.T
    values = np.concatenate([base_earth, theta[problem.n_earth:]])
    output_names = (tuple(f'B_{n}' for n in NAV_NAMES) + tuple(f'D_{n}' for n in model.poisson)
                    + tuple(f'p_{a}' for a in AXIS_NAMES) + tuple(f'o_{a}' for a in AXIS_NAMES))
    units = ['uT'] * 3 + [''] * len(model.poisson) + ['uT'] * 6
    sigmas = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    estimates = tuple(Estimate(name, float(v), float(s), unit)
                      for name, v, s, unit in zip(output_names, values, sigmas, units))
    return CarrierFit(model, estimates, covariance, condition, singular, float(residual @ residual / dof), len(record),
                      names, theta)


def design_condition(record: CarrierRecord, truth: CarrierTruth, model: CarrierModel,
                     errors: InstrumentErrors | None = None) -> tuple[float, np.ndarray, tuple[str, ...]]:
    """The condition of a design at a known truth, without noise: (condition, singular values, parameter names).

    The weighted Jacobian at the truth, columns scaled to unit norm; an infinite condition is a
    parameter combination the design cannot determine.
    """
    errors = errors or InstrumentErrors()
    problem = _Problem(record, model, errors)
    theta = np.concatenate([earth_parameters(model, truth.earth_uT),
                            [truth.poisson[AXIS_NAMES.index(n[0]), AXIS_NAMES.index(n[1])] for n in model.poisson],
                            truth.hard_iron_uT, truth.sensor_offset_uT])
    problem.reweight(theta)
    jac = problem.jacobian(theta)
    norms = np.linalg.norm(jac, axis=0)
    norms[norms == 0.0] = 1.0
    singular = np.linalg.svd(jac / norms, compute_uv=False)
    condition = math.inf if singular[-1] < IDENTIFIABLE_RATIO * singular[0] else float(singular[0] / singular[-1])
    return condition, singular, model.parameter_names()
