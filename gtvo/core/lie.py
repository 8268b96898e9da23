"""Batched SO(2)/SE(2)/SO(3)/SE(3) maps in GTSAM's conventions (pure numpy, no I/O),
and the pose / quaternion helpers of whole trajectories (``make_poses``, ``invert_poses``,
``rotation_angle``, TUM-order quaternions ``qx qy qz qw``).

Every function works on stacks: rotations ``(m, d, d)``, translations ``(m, d)``, tangents
``(m, 3)`` (SE(2): ``[vx, vy, theta]``) or ``(m, 6)`` (SE(3): ``[omega, v]``, rotation first).
Perturbations are on the RIGHT, ``T.retract(xi) = T * Exp(xi)``, as in GTSAM
(``docs/conventions.md``). Names follow ``docs/posegraph.md``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.errors import InputError

F64 = NDArray[np.float64]
FloatArray = F64

#: A rotation block R read from a file must satisfy max|R^T R - I| <= this and det(R) > 0.
ROTATION_TOLERANCE = 1e-3
#: A quaternion read from a file may deviate this much from unit norm (files print 4-9 digits).
QUATERNION_NORM_TOLERANCE = 1e-3

_SMALL = 1e-4  # below this angle the closed forms switch to their Taylor series


def hat3(w: F64) -> F64:
    """Skew-symmetric matrices ``w^`` of a stack of 3-vectors, ``(m, 3) -> (m, 3, 3)`` (one vector:
    ``(3,) -> (3, 3)``, built directly: the stacking costs 4x on the window's per-pair path)."""
    if w.ndim == 1:
        return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    z = np.zeros(w.shape[:-1])
    return np.stack([np.stack([z, -w[..., 2], w[..., 1]], -1),
                     np.stack([w[..., 2], z, -w[..., 0]], -1),
                     np.stack([-w[..., 1], w[..., 0], z], -1)], -2)


def rot2(theta: F64) -> F64:
    """2x2 rotation matrices of a stack of angles, ``(m,) -> (m, 2, 2)``."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def angle2(R: F64) -> F64:
    """Angles of a stack of 2x2 rotations, in (-pi, pi]."""
    return np.arctan2(R[..., 1, 0], R[..., 0, 0])


def so3_exp(w: F64) -> F64:
    """Rodrigues: ``Exp(w^)`` for a stack of rotation vectors."""
    th2 = np.einsum("...i,...i->...", w, w)
    th = np.sqrt(th2)
    small = th < _SMALL
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th2 / 6.0, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(ths)) / (ths * ths))
    W = hat3(w)
    return np.eye(3) + a[..., None, None] * W + b[..., None, None] * (W @ W)


def so3_log(R: F64) -> F64:
    """Rotation vectors of a stack of rotations (robust near 0 and near pi)."""
    vee = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    s = 0.5 * np.linalg.norm(vee, axis=-1)
    c = np.clip(0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0), -1.0, 1.0)
    th = np.arctan2(s, c)
    small = th < _SMALL
    scale = np.where(small, 0.5 + th * th / 12.0, th / (2.0 * np.where(small, 1.0, np.maximum(s, 1e-300))))
    w = scale[..., None] * vee
    near_pi = (c < 0) & (s < 1e-3)
    if np.any(near_pi):
        Rp = R[near_pi]
        B = 0.5 * (Rp + np.swapaxes(Rp, -1, -2)) + np.eye(3)  # = (1 - cos) a a^T + 2 cos ... ~ 2 a a^T at pi
        k = np.argmax(np.linalg.norm(B, axis=-1), axis=-1)
        axis = B[np.arange(len(Rp)), k]
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        sign = np.sign(np.einsum("ij,ij->i", axis, vee[near_pi]))
        sign[sign == 0] = 1.0
        w[near_pi] = (sign * th[near_pi])[:, None] * axis
    return w


def so3_right_jacobian_inv(w: F64) -> F64:
    """``Jr^-1(w) = I + 1/2 w^ + (1/th^2 - (1 + cos th) / (2 th sin th)) w^ w^``."""
    th2 = np.einsum("...i,...i->...", w, w)
    th = np.sqrt(th2)
    small = th < _SMALL
    ths = np.where(small, 1.0, th)
    c = np.where(small, 1.0 / 12.0 + th2 / 720.0,
                 1.0 / (ths * ths) - (1.0 + np.cos(ths)) / (2.0 * ths * np.sin(ths)))
    W = hat3(w)
    return np.eye(3) + 0.5 * W + c[..., None, None] * (W @ W)


def so3_left_jacobian(w: F64) -> F64:
    """``V(w) = Jl(w)``: maps the translation part of an SE(3) tangent to the translation."""
    th2 = np.einsum("...i,...i->...", w, w)
    th = np.sqrt(th2)
    small = th < _SMALL
    ths = np.where(small, 1.0, th)
    b = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(ths)) / (ths * ths))
    c = np.where(small, 1.0 / 6.0 - th2 / 120.0, (ths - np.sin(ths)) / (ths ** 3))
    W = hat3(w)
    return np.eye(3) + b[..., None, None] * W + c[..., None, None] * (W @ W)


def _q_matrix(w: F64, v: F64) -> F64:
    """Barfoot's ``Q(v, w)``, the off-diagonal block of the SE(3) LEFT Jacobian (tangent [v; w])."""
    th2 = np.einsum("...i,...i->...", w, w)
    th = np.sqrt(th2)
    small = th < 1e-2
    ths = np.where(small, 1.0, th)
    s, c = np.sin(ths), np.cos(ths)
    c1 = np.where(small, 1.0 / 6.0 - th2 / 120.0, (ths - s) / ths ** 3)
    c2 = np.where(small, 1.0 / 24.0 - th2 / 720.0, (ths * ths + 2.0 * c - 2.0) / (2.0 * ths ** 4))
    c3 = np.where(small, 1.0 / 120.0 - th2 / 2520.0, (2.0 * ths - 3.0 * s + ths * c) / (2.0 * ths ** 5))
    W, V = hat3(w), hat3(v)
    WV, VW = W @ V, V @ W
    WVW = WV @ W
    return (0.5 * V + c1[..., None, None] * (WV + VW + WVW)
            + c2[..., None, None] * (W @ WV + VW @ W - 3.0 * WVW)
            + c3[..., None, None] * (WVW @ W + W @ WVW))


def se3_log(R: F64, t: F64) -> F64:
    """``Log(T)`` of a stack of poses, tangent ``[omega, v]`` with ``t = V(omega) v``."""
    w = so3_log(R)
    v = np.linalg.solve(so3_left_jacobian(w), t[..., None])[..., 0]
    return np.concatenate([w, v], -1)


def se3_exp(xi: F64) -> tuple[F64, F64]:
    """``Exp(xi)`` of a stack of tangents ``[omega, v]``: rotations and translations."""
    w, v = xi[..., :3], xi[..., 3:]
    return so3_exp(w), np.einsum("...ij,...j->...i", so3_left_jacobian(w), v)


def se3_right_jacobian_inv(xi: F64) -> F64:
    """Inverse right Jacobian of SE(3) (= ``gtsam.Pose3.LogmapDerivative``), GTSAM order [omega, v].

    ``Jr(xi) = Jl(-xi)``; with ``J = Jr_SO3(omega)`` and ``Q = Q(-v, -omega)``,
    ``Jr = [[J, 0], [Q, J]]`` and ``Jr^-1 = [[J^-1, 0], [-J^-1 Q J^-1, J^-1]]``.
    """
    w, v = xi[..., :3], xi[..., 3:]
    Ji = so3_right_jacobian_inv(w)
    Q = _q_matrix(-w, -v)
    out = np.zeros(xi.shape[:-1] + (6, 6))
    out[..., :3, :3] = Ji
    out[..., 3:, 3:] = Ji
    out[..., 3:, :3] = -Ji @ Q @ Ji
    return out


def se3_adjoint(R: F64, t: F64) -> F64:
    """``Ad_T = [[R, 0], [t^ R, R]]`` in GTSAM order (``gtsam.Pose3.AdjointMap``)."""
    out = np.zeros(R.shape[:-2] + (6, 6))
    out[..., :3, :3] = R
    out[..., 3:, 3:] = R
    out[..., 3:, :3] = hat3(t) @ R
    return out


def se2_log(R: F64, t: F64) -> F64:
    """``Log(T)`` of a stack of SE(2) poses, tangent ``[vx, vy, theta]`` (``gtsam.Pose2.Logmap``).

    ``t = V(theta) v`` with ``V = [[a, -b], [b, a]]``, ``a = sin/theta``, ``b = (1 - cos)/theta``, so
    ``v = [[al, h], [-h, al]] t`` with ``h = theta/2`` and ``al = h cot h``.
    """
    th = angle2(R)
    h = 0.5 * th
    small = np.abs(th) < _SMALL
    hs = np.where(small, 1.0, h)
    al = np.where(small, 1.0 - h * h / 3.0, hs * np.cos(hs) / np.sin(hs))
    vx = al * t[..., 0] + h * t[..., 1]
    vy = -h * t[..., 0] + al * t[..., 1]
    return np.stack([vx, vy, th], -1)


def se2_exp(xi: F64) -> tuple[F64, F64]:
    """``Exp(xi)`` of a stack of SE(2) tangents ``[vx, vy, theta]``."""
    th = xi[..., 2]
    small = np.abs(th) < _SMALL
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th * th / 6.0, np.sin(ths) / ths)
    b = np.where(small, th / 2.0 - th ** 3 / 24.0, (1.0 - np.cos(ths)) / ths)
    tx = a * xi[..., 0] - b * xi[..., 1]
    ty = b * xi[..., 0] + a * xi[..., 1]
    return rot2(th), np.stack([tx, ty], -1)


def se2_right_jacobian_inv(xi: F64) -> F64:
    """Inverse right Jacobian of SE(2) (= ``gtsam.Pose2.LogmapDerivative``), order [vx, vy, theta].

    ``Jr = [[M, m], [0, 1]]`` with ``M = R(theta)^T V(theta) = V(-theta)`` and
    ``m = R(theta)^T V'(theta) v``; ``Jr^-1 = [[M^-1, -M^-1 m], [0, 1]]``.
    """
    th = xi[..., 2]
    small = np.abs(th) < 1e-3
    ths = np.where(small, 1.0, th)
    s, c = np.sin(ths), np.cos(ths)
    a = np.where(small, 1.0 - th * th / 6.0, s / ths)
    b = np.where(small, th / 2.0 - th ** 3 / 24.0, (1.0 - c) / ths)
    da = np.where(small, -th / 3.0 + th ** 3 / 30.0, (ths * c - s) / (ths * ths))
    db = np.where(small, 0.5 - th * th / 8.0, (ths * s - 1.0 + c) / (ths * ths))
    vx, vy = xi[..., 0], xi[..., 1]
    # V'(theta) v
    dvx = da * vx - db * vy
    dvy = db * vx + da * vy
    cth, sth = np.cos(th), np.sin(th)
    mx = cth * dvx + sth * dvy
    my = -sth * dvx + cth * dvy
    # M = V(-theta) = [[a, b], [-b, a]]; M^-1 = [[a, -b], [b, a]] / (a^2 + b^2)
    det = a * a + b * b
    out = np.zeros(xi.shape[:-1] + (3, 3))
    out[..., 0, 0] = a / det
    out[..., 0, 1] = -b / det
    out[..., 1, 0] = b / det
    out[..., 1, 1] = a / det
    out[..., 0, 2] = -(a * mx - b * my) / det
    out[..., 1, 2] = -(b * mx + a * my) / det
    out[..., 2, 2] = 1.0
    return out


def se2_adjoint(R: F64, t: F64) -> F64:
    """``Ad_T = [[R, [t_y, -t_x]^T], [0, 1]]`` in GTSAM's Pose2 order (``gtsam.Pose2.AdjointMap``)."""
    out = np.zeros(R.shape[:-2] + (3, 3))
    out[..., :2, :2] = R
    out[..., 0, 2] = t[..., 1]
    out[..., 1, 2] = -t[..., 0]
    out[..., 2, 2] = 1.0
    return out


def rpy_to_rot(rpy: F64) -> F64:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` of a stack ``[roll, pitch, yaw]`` (``gtsam.Rot3.Ypr(y, p, r)``)."""
    r, p, y = rpy[..., 0], rpy[..., 1], rpy[..., 2]
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.stack([
        np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
        np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
        np.stack([-sp, cp * sr, cp * cr], -1)], -2)


# ---------------------------------------------------------------------------------------------
# SE(3) / quaternion helpers (vectorised over a leading axis)
# ---------------------------------------------------------------------------------------------

def make_poses(rotations: ArrayLike, translations: ArrayLike) -> FloatArray:
    """Stack (N, 3, 3) rotations and (N, 3) translations into (N, 4, 4) homogeneous poses."""
    R = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    t = np.asarray(translations, dtype=np.float64).reshape(-1, 3)
    if len(R) != len(t):
        raise InputError(f"{len(R)} rotations but {len(t)} translations")
    T = np.zeros((len(R), 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = t
    T[:, 3, 3] = 1.0
    return T


def pose_from_xyz_quaternion(xyz_quaternion: ArrayLike) -> FloatArray:
    """``[x, y, z, qx, qy, qz, qw]`` (a translation and a unit quaternion, ROS order) as a 4x4 transform."""
    v = np.asarray(xyz_quaternion, dtype=np.float64).reshape(7)
    return make_poses(quaternions_to_rotations(v[3:]), v[:3])[0]


def invert_poses(poses: ArrayLike) -> FloatArray:
    """Inverse ``[R^T, -R^T t]`` of (..., 4, 4) rigid poses (the rotation is not re-orthonormalised)."""
    T = np.asarray(poses, dtype=np.float64)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def rotation_angle(rotations: ArrayLike) -> FloatArray:
    """Angle in radians, in [0, pi], of (..., 3, 3) rotation matrices.

    Uses ``atan2(|vee(R - R^T)| / 2, (trace(R) - 1) / 2)``, which stays accurate for small and
    for near-pi angles (``arccos`` of the trace alone loses half the digits near 0).
    """
    R = np.asarray(rotations, dtype=np.float64)
    s = 0.5 * np.sqrt((R[..., 2, 1] - R[..., 1, 2]) ** 2 + (R[..., 0, 2] - R[..., 2, 0]) ** 2
                      + (R[..., 1, 0] - R[..., 0, 1]) ** 2)
    c = 0.5 * (R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2] - 1.0)
    return np.arctan2(s, c)


def quaternions_to_rotations(quaternions_xyzw: ArrayLike) -> FloatArray:
    """(N, 4) quaternions in TUM order ``qx qy qz qw`` -> (N, 3, 3) rotation matrices.

    Each quaternion is normalised first; ``q`` and ``-q`` give the same rotation. The caller
    checks for zero or non-finite quaternions (readers do, naming the line).
    """
    q = np.asarray(quaternions_xyzw, dtype=np.float64).reshape(-1, 4)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    x, y, z, w = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    R = np.empty((len(q), 3, 3))
    R[:, 0, 0] = 1 - 2 * (y * y + z * z)
    R[:, 0, 1] = 2 * (x * y - z * w)
    R[:, 0, 2] = 2 * (x * z + y * w)
    R[:, 1, 0] = 2 * (x * y + z * w)
    R[:, 1, 1] = 1 - 2 * (x * x + z * z)
    R[:, 1, 2] = 2 * (y * z - x * w)
    R[:, 2, 0] = 2 * (x * z - y * w)
    R[:, 2, 1] = 2 * (y * z + x * w)
    R[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def rotations_to_quaternions(rotations: ArrayLike) -> FloatArray:
    """(N, 3, 3) rotation matrices -> (N, 4) unit quaternions ``qx qy qz qw`` with ``qw >= 0``.

    Shepperd's method: per matrix, the branch with the largest of ``trace, R00, R11, R22``
    avoids dividing by a small number, so it is accurate for every angle including pi.
    """
    R = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    n = len(R)
    tr = R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2]
    diag = np.stack([R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], axis=1)
    branch = np.argmax(np.column_stack([tr, diag]), axis=1)  # 0: trace, 1..3: diagonal i-1
    q = np.empty((n, 4))
    m = branch == 0
    if np.any(m):
        s = 2.0 * np.sqrt(1.0 + tr[m])  # s = 4 qw
        q[m, 3] = 0.25 * s
        q[m, 0] = (R[m, 2, 1] - R[m, 1, 2]) / s
        q[m, 1] = (R[m, 0, 2] - R[m, 2, 0]) / s
        q[m, 2] = (R[m, 1, 0] - R[m, 0, 1]) / s
    for i in range(3):  # three branches, not a loop over poses
        m = branch == i + 1
        if not np.any(m):
            continue
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(np.maximum(1.0 + R[m, i, i] - R[m, j, j] - R[m, k, k], 0.0))  # s = 4 q_i
        q[m, i] = 0.25 * s
        q[m, 3] = (R[m, k, j] - R[m, j, k]) / s
        q[m, j] = (R[m, j, i] + R[m, i, j]) / s
        q[m, k] = (R[m, k, i] + R[m, i, k]) / s
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 3] < 0] *= -1.0
    return q


def rotation_defects(rotations: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(max |R^T R - I|, det R)`` of (..., 3, 3) blocks: a block read from a file is taken as a
    rotation when the first is at most :data:`ROTATION_TOLERANCE` and the second positive."""
    R = np.asarray(rotations, dtype=np.float64)
    ortho = np.max(np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)), axis=(-2, -1))
    return ortho, np.linalg.det(R)


def rotation_block_error(rotation: ArrayLike) -> str | None:
    """None when one 3x3 block is a rotation (:func:`rotation_defects`), else why it is not
    (``"is not a rotation (max |R^T R - I| = ..., det ...)"``), for a message naming the block."""
    ortho, det = rotation_defects(rotation)
    return None if ortho <= ROTATION_TOLERANCE and det > 0 else not_a_rotation(float(ortho), float(det))


def not_a_rotation(ortho: float, det: float) -> str:
    """The message for a block that is not a rotation (its defects as :func:`rotation_defects` gives them)."""
    return f"is not a rotation (max |R^T R - I| = {ortho:.3g}, det {det:.6g})"
