"""Rotations of the sensor frame, vectorised: what a turn between two still intervals integrates to.

Rotation matrices ``(..., 3, 3)``; a rotation vector ``phi`` (axis times angle, rad) maps to
``Exp(phi)`` by Rodrigues' formula. A gyroscope's rate ``omega`` (sensor frame, rad/s) over a
step ``dt`` turns the frame by ``Exp(omega dt)`` on the right: ``R(t + dt) = R(t) Exp(omega dt)``,
so ``R`` maps a vector seen in the frame at ``t`` into the frame at the start. The right Jacobian
``J_r(phi)`` carries a small change of ``phi`` to the change of ``Exp(phi)`` on the right:
``Exp(phi + d) = Exp(phi) Exp(J_r(phi) d)`` to first order.
"""

from __future__ import annotations

import numpy as np

SMALL_ANGLE = 1e-6
"""Below this angle (rad) the series of Rodrigues' formula and of ``J_r`` replace the closed forms."""


def hat(vector: np.ndarray) -> np.ndarray:
    """The cross-product matrix ``[v]x`` of ``(..., 3)`` vectors, ``(..., 3, 3)``."""
    vector = np.asarray(vector, dtype=float)
    x, y, z = vector[..., 0], vector[..., 1], vector[..., 2]
    zero = np.zeros_like(x)
    return np.stack([np.stack([zero, -z, y], axis=-1),
                     np.stack([z, zero, -x], axis=-1),
                     np.stack([-y, x, zero], axis=-1)], axis=-2)


def _coefficients(angle: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``sin t / t``, ``(1 - cos t) / t^2`` and ``(t - sin t) / t^3``, by their series near 0."""
    small = angle < SMALL_ANGLE
    safe = np.where(small, 1.0, angle)
    square = angle * angle
    a = np.where(small, 1.0 - square / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - square / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    c = np.where(small, 1.0 / 6.0 - square / 120.0, (safe - np.sin(safe)) / (safe * safe * safe))
    return a, b, c


def exp_map(phi: np.ndarray) -> np.ndarray:
    """``Exp(phi)`` of ``(..., 3)`` rotation vectors, ``(..., 3, 3)`` (Rodrigues)."""
    phi = np.asarray(phi, dtype=float)
    angle = np.linalg.norm(phi, axis=-1)
    a, b, _ = _coefficients(angle)
    cross = hat(phi)
    return np.eye(3) + a[..., None, None] * cross + b[..., None, None] * (cross @ cross)


def log_map(rotation: np.ndarray) -> np.ndarray:
    """The rotation vector ``(..., 3)`` of rotation matrices (angles below pi)."""
    rotation = np.asarray(rotation, dtype=float)
    trace = np.trace(rotation, axis1=-2, axis2=-1)
    angle = np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0))
    skew = np.stack([rotation[..., 2, 1] - rotation[..., 1, 2], rotation[..., 0, 2] - rotation[..., 2, 0],
                     rotation[..., 1, 0] - rotation[..., 0, 1]], axis=-1)
    a, _, _ = _coefficients(angle)
    return skew / (2.0 * a[..., None])


def right_jacobian(phi: np.ndarray) -> np.ndarray:
    """``J_r(phi) = I - (1 - cos t)/t^2 [phi]x + (t - sin t)/t^3 [phi]x^2``, ``(..., 3, 3)``."""
    phi = np.asarray(phi, dtype=float)
    angle = np.linalg.norm(phi, axis=-1)
    _, b, c = _coefficients(angle)
    cross = hat(phi)
    return np.eye(3) - b[..., None, None] * cross + c[..., None, None] * (cross @ cross)


def quaternion_exp(phi: np.ndarray) -> np.ndarray:
    """The unit quaternions ``(..., 4)`` (x, y, z, w) of rotation vectors ``(..., 3)``: ``Exp(phi)``."""
    phi = np.asarray(phi, dtype=float)
    angle = np.linalg.norm(phi, axis=-1)
    small = angle < SMALL_ANGLE
    safe = np.where(small, 1.0, angle)
    half = np.where(small, 0.5 - angle * angle / 48.0, np.sin(0.5 * safe) / safe)
    return np.concatenate([half[..., None] * phi, np.cos(0.5 * angle)[..., None]], axis=-1)


def quaternion_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products ``a b`` of ``(..., 4)`` quaternions (x, y, z, w): the rotation ``R(a) R(b)``."""
    ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz], axis=-1)


def quaternion_matrix(q: np.ndarray) -> np.ndarray:
    """The rotation matrices ``(..., 3, 3)`` of quaternions ``(..., 4)`` (x, y, z, w), normalised first."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([np.stack([1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w)], axis=-1),
                     np.stack([2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w)], axis=-1),
                     np.stack([2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)], axis=-1)],
                    axis=-2)


def cumulative_quaternion(quaternions: np.ndarray) -> np.ndarray:
    """``q_0 q_1 ... q_j`` of ``(n, 4)`` quaternions, by a parallel prefix (log2 n vectorised steps)."""
    out = np.array(quaternions, dtype=float, copy=True)
    shift = 1
    while shift < len(out):
        out[shift:] = quaternion_product(out[:-shift], out[shift:])
        shift *= 2
    return out


def tangent_basis(direction: np.ndarray) -> np.ndarray:
    """Two unit vectors ``(..., 3, 2)`` perpendicular to unit ``direction`` ``(..., 3)`` and to each other."""
    direction = np.asarray(direction, dtype=float)
    helper = np.zeros_like(direction)
    smallest = np.argmin(np.abs(direction), axis=-1)
    np.put_along_axis(helper, smallest[..., None], 1.0, axis=-1)
    first = np.cross(direction, helper)
    first /= np.linalg.norm(first, axis=-1, keepdims=True)
    second = np.cross(direction, first)
    return np.stack([first, second], axis=-1)


def rotation_between(start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """The shortest rotation ``(3, 3)`` that carries unit vector ``start`` onto unit vector ``end``."""
    start = np.asarray(start, dtype=float)
    end = np.asarray(end, dtype=float)
    axis = np.cross(start, end)
    sine = float(np.linalg.norm(axis))
    cosine = float(np.clip(start @ end, -1.0, 1.0))
    if sine < 1e-12:
        if cosine > 0.0:
            return np.eye(3)
        perpendicular = tangent_basis(start)[:, 0]
        return exp_map(np.pi * perpendicular)
    return exp_map(axis / sine * np.arctan2(sine, cosine))


def integrate_segments(rate: np.ndarray, stamp_s: np.ndarray, segment: np.ndarray, count: int, *,
                       jacobian: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """The rotation each segment's rates integrate to, and how it moves with each sample's rate.

    Between consecutive samples of one segment the rate is taken as the mean of the two (the
    trapezoid rule): ``R = prod_j Exp(omega_j dt_j)``. With ``jacobian``, ``C`` ``(n, 3, 3)``
    per sample such that a change ``d omega_s`` of the sample rates turns the segment's end by
    ``R Exp(R^T sum_s C_s d omega_s)`` to first order (a change seen in the segment's start frame).

    :param rate: ``(n, 3)`` rates, rad/s, time order.
    :param stamp_s: ``(n,)`` their stamps, seconds.
    :param segment: ``(n,)`` the segment of each sample, ``0 .. count - 1``, non-decreasing.
    :returns: ``(count, 3, 3)`` rotations (identity for a segment of fewer than two samples) and ``C``.
    """
    rate = np.asarray(rate, dtype=float)
    segment = np.asarray(segment)
    step_of = np.flatnonzero(segment[1:] == segment[:-1])  # step j joins samples step_of[j], +1
    rotations = np.broadcast_to(np.eye(3), (count, 3, 3)).copy()
    jacobians = np.zeros((len(rate), 3, 3)) if jacobian else None
    if not len(step_of):
        return rotations, jacobians
    dt = (np.asarray(stamp_s, dtype=float)[step_of + 1] - np.asarray(stamp_s, dtype=float)[step_of])
    phi = 0.5 * (rate[step_of] + rate[step_of + 1]) * dt[:, None]
    running = cumulative_quaternion(quaternion_exp(phi))  # quaternions: cheaper products than 3x3 matrices
    owner = segment[step_of]
    first = np.flatnonzero(np.diff(owner, prepend=-1) != 0)
    last = np.append(first[1:], len(owner)) - 1
    before = np.zeros((len(first), 4))
    before[:, 3] = 1.0
    inner = first > 0
    before[inner] = running[first[inner] - 1] * np.array([-1.0, -1.0, -1.0, 1.0])  # the inverse: the conjugate
    group = np.repeat(np.arange(len(first)), last - first + 1)
    relative = quaternion_matrix(quaternion_product(before[group], running))
    rotations[owner[first]] = relative[last]
    if jacobians is not None:
        half = 0.5 * (relative @ right_jacobian(phi)) * dt[:, None, None]
        jacobians[step_of] += half  # each step once: the indices do not repeat
        jacobians[step_of + 1] += half
    return rotations, jacobians
