"""The notes' Gauss-Newton / Levenberg-Marquardt for SE(2) and SE(3) pose graphs (numpy + scipy).

Edge error (GTSAM's BetweenFactor, right perturbation): ``e_ij = Log(Z_ij^-1 X_i^-1 X_j)``,
cost ``0.5 sum e_ij^T Omega_ij e_ij``. With ``E_ij = Z_ij^-1 X_i^-1 X_j``:

* ``B_ij = de/dxi_j = Jr^-1(e_ij)``
* ``A_ij = de/dxi_i = -Jr^-1(e_ij) Ad(X_j^-1 X_i)``

(:func:`geodesic_linearize`). Whitened with ``L_ij`` (``L^T L = Omega``), the blocks
``H_ii += A^T A``, ``H_ij += A^T B``, ``H_jj += B^T B``, ``b_i += A^T e``, ``b_j += B^T e`` are
assembled for all edges at once into a ``scipy.sparse`` matrix whose pattern is computed once
(:class:`SparseSystem`). The gauge is fixed by removing the rows and columns of ``x_0``
(notes 4.3). ``(H + lambda I) dx = -b`` is solved by a sparse LU in symmetric mode with a
fill-reducing ordering (``scipy.sparse.linalg.splu``, ``MMD_AT_PLUS_A``) and
applied as ``X_k <- X_k Exp(dx_k)``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.linalg import splu

from gtvo.posegraph import lie, sesync
from gtvo.posegraph.graph import PoseGraph

F64 = NDArray[np.float64]
Linearizer = Callable[[F64, F64, bool], tuple[F64, F64 | None, F64 | None]]


def edge_errors(graph: PoseGraph, R: F64, t: F64) -> F64:
    """Unwhitened ``e_ij = Log(Z_ij^-1 X_i^-1 X_j)`` for all edges, ``(m, p)``."""
    i, j = graph.edge_i, graph.edge_j
    RiT = np.swapaxes(R[i], 1, 2)
    RmT = np.swapaxes(graph.meas_rotations, 1, 2)
    Rrel = RiT @ R[j]
    trel = np.einsum("mab,mb->ma", RiT, t[j] - t[i])
    RE = RmT @ Rrel
    tE = np.einsum("mab,mb->ma", RmT, trel - graph.meas_translations)
    return lie.se2_log(RE, tE) if graph.dim == 2 else lie.se3_log(RE, tE)


def gtsam_error(graph: PoseGraph, R: F64, t: F64) -> float:
    """GTSAM's ``graph.error``: ``0.5 sum e^T Omega e`` over the BetweenFactors (no prior)."""
    e = edge_errors(graph, R, t)
    return float(0.5 * np.einsum("ma,mab,mb->", e, graph.information, e))


def sqrt_information(graph: PoseGraph) -> F64:
    """``L_ij`` with ``L^T L = Omega_ij`` (transpose of the lower Cholesky factor)."""
    C = np.linalg.cholesky(0.5 * (graph.information + np.swapaxes(graph.information, 1, 2)))
    return np.swapaxes(C, 1, 2)


def geodesic_linearize(graph: PoseGraph, R: F64, t: F64, jacobians: bool = True,
                       L: F64 | None = None) -> tuple[F64, F64 | None, F64 | None]:
    """Whitened ``r = L e``, ``A = L A_ij``, ``B = L B_ij`` for all edges (see module docstring)."""
    if L is None:
        L = sqrt_information(graph)
    i, j = graph.edge_i, graph.edge_j
    RiT = np.swapaxes(R[i], 1, 2)
    RmT = np.swapaxes(graph.meas_rotations, 1, 2)
    Rrel = RiT @ R[j]
    trel = np.einsum("mab,mb->ma", RiT, t[j] - t[i])
    RE = RmT @ Rrel
    tE = np.einsum("mab,mb->ma", RmT, trel - graph.meas_translations)
    if graph.dim == 2:
        e = lie.se2_log(RE, tE)
    else:
        e = lie.se3_log(RE, tE)
    r = np.einsum("mab,mb->ma", L, e)
    if not jacobians:
        return r, None, None
    # X_j^-1 X_i = (Rrel^T, -Rrel^T trel)
    RjiR = np.swapaxes(Rrel, 1, 2)
    Rji_t = -np.einsum("mab,mb->ma", RjiR, trel)
    if graph.dim == 2:
        Jinv = lie.se2_right_jacobian_inv(e)
        Ad = lie.se2_adjoint(RjiR, Rji_t)
    else:
        Jinv = lie.se3_right_jacobian_inv(e)
        Ad = lie.se3_adjoint(RjiR, Rji_t)
    LB = L @ Jinv
    LA = -LB @ Ad
    return r, LA, LB


def retract(graph_dim: int, R: F64, t: F64, dx: F64) -> tuple[F64, F64]:
    """``X_k <- X_k Exp(dx_k)`` for all nodes (``dx`` of shape ``(n, p)``)."""
    if graph_dim == 2:
        dR, dt = lie.se2_exp(dx)
    else:
        dR, dt = lie.se3_exp(dx)
    return R @ dR, t + np.einsum("mab,mb->ma", R, dt)


class SparseSystem:
    """Assembles ``H`` (upper and lower) and ``b`` from per-edge whitened blocks, gauge node removed.

    The pattern (CSC ``indices``/``indptr`` and the map from every block entry to its CSC slot)
    is computed once; each assembly is two ``np.bincount`` calls.
    """

    def __init__(self, n: int, p: int, edge_i: NDArray[np.int64], edge_j: NDArray[np.int64], gauge: int = 0):
        self.n, self.p = n, p
        var = np.arange(n) - (np.arange(n) > gauge)  # variable index of each node (gauge: dropped)
        var[gauge] = -1
        self.var = var
        self.N = (n - 1) * p
        m = len(edge_i)
        vi, vj = var[edge_i], var[edge_j]
        a = np.arange(p)
        # blocks in the order ii, ij, ji, jj; each (m, p, p) row-major
        rb = np.stack([vi, vi, vj, vj], 0)  # (4, m)
        cb = np.stack([vi, vj, vi, vj], 0)
        rows = rb[:, :, None, None] * p + a[None, None, :, None]
        cols = cb[:, :, None, None] * p + a[None, None, None, :]
        rows = np.broadcast_to(rows, (4, m, p, p)).ravel()
        cols = np.broadcast_to(cols, (4, m, p, p)).ravel()
        valid = np.broadcast_to(((rb >= 0) & (cb >= 0))[:, :, None, None], (4, m, p, p)).ravel()
        self.valid = valid
        key = cols[valid].astype(np.int64) * self.N + rows[valid]
        uniq, inv = np.unique(key, return_inverse=True)
        self.slot = inv
        self.nnz = len(uniq)
        self.indices = (uniq % self.N).astype(np.int32)
        colcount = np.bincount((uniq // self.N).astype(np.int64), minlength=self.N)
        self.indptr = np.concatenate([[0], np.cumsum(colcount)]).astype(np.int32)
        diag_mask = self.indices == np.repeat(np.arange(self.N), colcount)
        self.diag_slots = np.flatnonzero(diag_mask)
        # gradient: b entries of node i and node j for each edge
        gi = np.broadcast_to(vi[:, None] * p + a, (m, p))
        gj = np.broadcast_to(vj[:, None] * p + a, (m, p))
        self.grad_idx = np.concatenate([gi.ravel(), gj.ravel()])
        self.grad_valid = self.grad_idx >= 0

    def assemble(self, r: F64, A: F64, B: F64) -> tuple[sp.csc_matrix, F64]:
        """``H = J^T J`` (CSC, gauge removed) and ``b = J^T r`` from whitened ``r, A, B``."""
        AtA = np.einsum("mka,mkb->mab", A, A)
        AtB = np.einsum("mka,mkb->mab", A, B)
        BtB = np.einsum("mka,mkb->mab", B, B)
        vals = np.stack([AtA, AtB, np.swapaxes(AtB, 1, 2), BtB], 0).ravel()[self.valid]
        data = np.bincount(self.slot, weights=vals, minlength=self.nnz)
        H = sp.csc_matrix((data, self.indices, self.indptr), shape=(self.N, self.N))
        ga = np.einsum("mka,mk->ma", A, r).ravel()
        gb = np.einsum("mka,mk->ma", B, r).ravel()
        g = np.concatenate([ga, gb])
        b = np.bincount(self.grad_idx[self.grad_valid], weights=g[self.grad_valid], minlength=self.N)
        return H, b

    def solve(self, H: sp.csc_matrix, rhs: F64) -> F64:
        """Solve ``H x = rhs`` (``H`` SPD) by sparse LU in symmetric mode (no pivoting, so in effect
        ``L D L^T``) with SuperLU's fill-reducing minimum-degree ordering of ``H + H^T``."""
        lu = splu(H, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        return lu.solve(rhs)

    def expand(self, dx: F64) -> F64:
        """Per-node steps ``(n, p)`` from the reduced step (zero at the gauge node)."""
        out = np.zeros((self.n, self.p))
        keep = self.var >= 0
        out[keep] = dx.reshape(-1, self.p)
        return out


@dataclass
class HandrolledResult:
    """Poses at the end, the cost history (``0.5 ||r||^2``), iterations and seconds."""

    rotations: F64
    translations: F64
    costs: list[float] = field(default_factory=list)
    iterations: int = 0
    seconds: float = 0.0
    converged: bool = False


def optimize(graph: PoseGraph, R0: F64, t0: F64, objective: str = "geodesic", method: str = "lm",
             max_iterations: int = 100, rel_tol: float = 1e-10, abs_tol: float = 1e-12,
             lambda0: float = 1e-5, progress: Callable[[int, float], None] | None = None) -> HandrolledResult:
    """Minimise the chosen objective from ``(R0, t0)`` with Gauss-Newton (``method="gn"``, the
    notes' loop) or Levenberg-Marquardt (``"lm"``: ``H + lambda I`` as GTSAM's default LM, lambda
    divided by 10 after an accepted step and multiplied by 10 after a rejected one). ``objective``: ``"geodesic"`` (GTSAM's) or ``"sesync"``.
    Stops when the relative cost decrease is below ``rel_tol`` or the cost below ``abs_tol``.
    """
    start = time.perf_counter()
    p = graph.tangent_dim
    if objective == "geodesic":
        L = sqrt_information(graph)

        def lin(R: F64, t: F64, jac: bool) -> tuple[F64, F64 | None, F64 | None]:
            return geodesic_linearize(graph, R, t, jac, L)
    elif objective == "sesync":
        w = sesync.weights(graph)

        def lin(R: F64, t: F64, jac: bool) -> tuple[F64, F64 | None, F64 | None]:
            return sesync.linearize(graph, R, t, jac, w)
    else:
        raise ValueError(f"unknown objective {objective!r}")
    system = SparseSystem(graph.num_poses, p, graph.edge_i, graph.edge_j)
    R, t = np.array(R0, float), np.array(t0, float)
    r, A, B = lin(R, t, True)
    cost = 0.5 * float(np.sum(r * r))
    res = HandrolledResult(R, t, [cost])
    lam = lambda0
    it = 0
    for it in range(1, max_iterations + 1):
        H, b = system.assemble(r, A, B)  # type: ignore[arg-type]
        accepted = False
        while True:
            if method == "gn":
                Hd = H
            else:
                Hd = H.copy()
                Hd.data[system.diag_slots] += lam
            dx = system.expand(system.solve(Hd, -b))
            Rn, tn = retract(graph.dim, R, t, dx)
            rn, _, _ = lin(Rn, tn, False)
            new_cost = 0.5 * float(np.sum(rn * rn))
            if method == "gn" or new_cost <= cost:
                accepted = True
                lam = max(lam / 10.0, 1e-12)
                break
            lam *= 10.0
            if lam > 1e10:
                break
        if not accepted:
            res.converged = True
            break
        decrease = cost - new_cost
        R, t, cost = Rn, tn, new_cost
        res.costs.append(cost)
        if progress is not None:
            progress(it, cost)
        if cost < abs_tol or abs(decrease) <= rel_tol * max(cost, 1e-300):
            res.converged = True
            break
        r, A, B = lin(R, t, True)
    res.rotations, res.translations = R, t
    res.iterations = it
    res.seconds = time.perf_counter() - start
    return res
