"""SE-Sync's objective: chordal rotation distance with isotropic weights (pure math, no I/O).

``F = sum_ij kappa_ij ||R_j - R_i R~_ij||_F^2 + tau_ij ||t_j - t_i - R_i t~_ij||^2``

with the weights SE-Sync's g2o reader derives from the information matrix ``I`` (data README):
2-D ``tau = 2 / trace(inv(I_tt))``, ``kappa = I_thth``; 3-D ``tau = 3 / trace(inv(I_tt))``,
``kappa = 3 / (2 trace(inv(I_RR)))``. ``I_tt`` / ``I_RR`` are the translation / rotation
blocks (GTSAM order: 2-D ``[x, y, theta]``, 3-D ``[rot, trans]``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from gtvo.posegraph.graph import PoseGraph
from gtvo.core.lie import hat3

F64 = NDArray[np.float64]


def weights(graph: PoseGraph) -> tuple[F64, F64]:
    """SE-Sync's ``(kappa, tau)`` per edge from the information matrices."""
    info = graph.information
    if graph.dim == 2:
        tau = 2.0 / np.trace(np.linalg.inv(info[:, :2, :2]), axis1=1, axis2=2)
        kappa = info[:, 2, 2].copy()
    else:
        tau = 3.0 / np.trace(np.linalg.inv(info[:, 3:, 3:]), axis1=1, axis2=2)
        kappa = 3.0 / (2.0 * np.trace(np.linalg.inv(info[:, :3, :3]), axis1=1, axis2=2))
    return kappa, tau


def residuals(graph: PoseGraph, R: F64, t: F64) -> tuple[F64, F64]:
    """Unweighted residuals: ``R_j - R_i R~`` ``(m, d, d)`` and ``t_j - t_i - R_i t~`` ``(m, d)``."""
    i, j = graph.edge_i, graph.edge_j
    Ri = R[i]
    dR = R[j] - Ri @ graph.meas_rotations
    dt = t[j] - t[i] - np.einsum("mab,mb->ma", Ri, graph.meas_translations)
    return dR, dt


def objective(graph: PoseGraph, R: F64, t: F64) -> float:
    """SE-Sync's ``F`` at poses ``(R, t)``."""
    kappa, tau = weights(graph)
    dR, dt = residuals(graph, R, t)
    return float(np.sum(kappa * np.sum(dR * dR, axis=(1, 2))) + np.sum(tau * np.sum(dt * dt, axis=1)))


def linearize(graph: PoseGraph, R: F64, t: F64, jacobians: bool = True,
              w: tuple[F64, F64] | None = None) -> tuple[F64, F64 | None, F64 | None]:
    """Whitened residuals ``r`` with ``0.5 ||r||^2 = F`` and their Jacobians ``A``, ``B``.

    ``r = [sqrt(2 kappa) vec(R_i R~ - R_j); sqrt(2 tau) (t_i + R_i t~ - t_j)]`` (row-major vec).
    With right perturbations ``R <- R Exp(w^)``, ``t <- t + R v`` (GTSAM's tangent order):
    ``d(R_i R~) = R_i w^ R~``, ``d(R_i t~) = -R_i t~^ w``, ``dt_i = R_i v_i``; so in 3-D
    ``A_rot[:, k] = vec(R_i G_k R~)``, ``B_rot[:, k] = -vec(R_j G_k)``, ``A_t = [-R_i t~^, R_i]``,
    ``B_t = [0, -R_j]`` (``G_k`` the so(3) generators). In 2-D (order ``[vx, vy, theta]``, one
    generator ``G``) ``A_rot[:, 2] = vec(R_i G R~)``, ``B_rot[:, 2] = -vec(R_j G)``,
    ``A_t = [R_i, R_i G t~]``, ``B_t = [-R_j, 0]``.
    """
    kappa, tau = weights(graph) if w is None else w
    i, j = graph.edge_i, graph.edge_j
    d = graph.dim
    m = graph.num_edges
    Ri, Rj = R[i], R[j]
    Rm, tm = graph.meas_rotations, graph.meas_translations
    sk = np.sqrt(2.0 * kappa)
    st = np.sqrt(2.0 * tau)
    RiRm = Ri @ Rm
    r_rot = (RiRm - Rj).reshape(m, d * d) * sk[:, None]
    r_t = (t[i] + np.einsum("mab,mb->ma", Ri, tm) - t[j]) * st[:, None]
    r = np.concatenate([r_rot, r_t], axis=1)
    if not jacobians:
        return r, None, None
    p = 3 if d == 2 else 6
    A = np.zeros((m, d * d + d, p))
    B = np.zeros((m, d * d + d, p))
    if d == 2:
        G = np.array([[0.0, -1.0], [1.0, 0.0]])
        A[:, :4, 2] = (Ri @ G @ Rm).reshape(m, 4)
        B[:, :4, 2] = -(Rj @ G).reshape(m, 4)
        A[:, 4:, :2] = Ri
        A[:, 4:, 2] = (Ri @ G @ tm[:, :, None])[:, :, 0]
        B[:, 4:, :2] = -Rj
    else:
        Gs = hat3(np.eye(3))  # so(3) generators G_k
        for k in range(3):
            A[:, :9, k] = (Ri @ Gs[k] @ Rm).reshape(m, 9)
            B[:, :9, k] = -(Rj @ Gs[k]).reshape(m, 9)
        A[:, 9:, :3] = -Ri @ hat3(tm)
        A[:, 9:, 3:] = Ri
        B[:, 9:, 3:] = -Rj
    A[:, : d * d] *= sk[:, None, None]
    B[:, : d * d] *= sk[:, None, None]
    A[:, d * d:] *= st[:, None, None]
    B[:, d * d:] *= st[:, None, None]
    return r, A, B


def second_order_blocks(graph: PoseGraph, R: F64, t: F64, w: tuple[F64, F64] | None = None) -> tuple[F64, F64]:
    """The residual-curvature part ``sum_k r_k d2 r_k`` of the Hessian of ``F = 0.5 ||r||^2``.

    Pulled back through ``R <- R Exp(w^)``, ``t <- t + R v`` (which agrees with GTSAM's
    retraction to the first order, so the Hessian agrees at critical points). Only the
    rotation-rotation sub-blocks of node ``i`` and node ``j`` are non-zero. With the weighted
    residuals ``W = s_r (R_i R~ - R_j)`` (``s_r = sqrt(2 kappa)``) and
    ``u = s_t (t_i + R_i t~ - t_j)`` (``s_t = sqrt(2 tau)``) and ``Exp(w^) = I + w^ + w^w^/2 + ...``,
    ``w^ w^ = w w^T - |w|^2 I``:

    * 3-D: ``H_ii += s_r [sym(R~ W^T R_i) - tr(W^T R_i R~) I] + s_t [sym(R_i^T u t~^T) - (u^T R_i t~) I]``,
      ``H_jj += -s_r [sym(W^T R_j) - tr(W^T R_j) I]``;
    * 2-D (``w^ w^ = -theta^2 I``): ``H_ii[th, th] += -s_r tr(W^T R_i R~) - s_t u^T R_i t~``,
      ``H_jj[th, th] += s_r tr(W^T R_j)``.

    Adding them to ``J^T J`` gives Newton's method; near the optimum it converges quadratically
    where Gauss-Newton on this objective converges only linearly. Returns ``(H_ii, H_jj)``, ``(m, p, p)``.
    """
    kappa, tau = weights(graph) if w is None else w
    i, j = graph.edge_i, graph.edge_j
    d = graph.dim
    m = graph.num_edges
    Ri, Rj = R[i], R[j]
    Rm, tm = graph.meas_rotations, graph.meas_translations
    sr, st = np.sqrt(2.0 * kappa), np.sqrt(2.0 * tau)
    W = sr[:, None, None] * (Ri @ Rm - Rj)
    u = st[:, None] * (t[i] + np.einsum("mab,mb->ma", Ri, tm) - t[j])
    WT = np.swapaxes(W, 1, 2)
    tr_i = np.trace(WT @ Ri @ Rm, axis1=1, axis2=2)
    tr_j = np.trace(WT @ Rj, axis1=1, axis2=2)
    uRt = np.einsum("ma,mab,mb->m", u, Ri, tm)
    p = 3 if d == 2 else 6
    Hii = np.zeros((m, p, p))
    Hjj = np.zeros((m, p, p))
    if d == 2:
        Hii[:, 2, 2] = -sr * tr_i - st * uRt
        Hjj[:, 2, 2] = sr * tr_j
        return Hii, Hjj
    eye = np.eye(3)
    Mi = Rm @ WT @ Ri
    Mt = np.einsum("mba,mb,mc->mac", Ri, u, tm)  # R_i^T u t~^T
    Mj = WT @ Rj
    Hii[:, :3, :3] = (sr[:, None, None] * (0.5 * (Mi + np.swapaxes(Mi, 1, 2)) - tr_i[:, None, None] * eye)
                      + st[:, None, None] * (0.5 * (Mt + np.swapaxes(Mt, 1, 2)) - uRt[:, None, None] * eye))
    Hjj[:, :3, :3] = -sr[:, None, None] * (0.5 * (Mj + np.swapaxes(Mj, 1, 2)) - tr_j[:, None, None] * eye)
    return Hii, Hjj
