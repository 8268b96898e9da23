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
from typing import Any, Callable

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.linalg import LinearOperator, cg, splu

from gtvo.core import lie
from gtvo.posegraph import sesync
from gtvo.posegraph.graph import PoseGraph

F64 = NDArray[np.float64]


def edge_errors(graph: PoseGraph, R: F64, t: F64) -> F64:
    """Unwhitened ``e_ij = Log(Z_ij^-1 X_i^-1 X_j)`` for all edges, ``(m, p)``."""
    return geodesic_parts(graph, R, t)[0]


def gtsam_error(graph: PoseGraph, R: F64, t: F64) -> float:
    """GTSAM's ``graph.error``: ``0.5 sum e^T Omega e`` over the BetweenFactors (no prior)."""
    e = edge_errors(graph, R, t)
    return float(0.5 * np.einsum("ma,mab,mb->", e, graph.information, e))


def sqrt_information(graph: PoseGraph) -> F64:
    """``L_ij`` with ``L^T L = Omega_ij`` (transpose of the lower Cholesky factor)."""
    C = np.linalg.cholesky(0.5 * (graph.information + np.swapaxes(graph.information, 1, 2)))
    return np.swapaxes(C, 1, 2)


def geodesic_parts(graph: PoseGraph, R: F64, t: F64) -> tuple[F64, F64, F64]:
    """``e_ij`` and the relative poses ``X_i^-1 X_j = (Rrel, trel)`` of all edges."""
    i, j = graph.edge_i, graph.edge_j
    RiT = np.swapaxes(R[i], 1, 2)
    RmT = np.swapaxes(graph.meas_rotations, 1, 2)
    Rrel = RiT @ R[j]
    trel = np.einsum("mab,mb->ma", RiT, t[j] - t[i])
    RE = RmT @ Rrel
    tE = np.einsum("mab,mb->ma", RmT, trel - graph.meas_translations)
    e = lie.se2_log(RE, tE) if graph.dim == 2 else lie.se3_log(RE, tE)
    return e, Rrel, trel


def geodesic_jacobians(dim: int, e: F64, Rrel: F64, trel: F64, L: F64) -> tuple[F64, F64]:
    """Whitened ``L A_ij`` and ``L B_ij`` from the parts of :func:`geodesic_parts`."""
    RjiR = np.swapaxes(Rrel, 1, 2)  # X_j^-1 X_i = (Rrel^T, -Rrel^T trel)
    Rji_t = -np.einsum("mab,mb->ma", RjiR, trel)
    if dim == 2:
        Jinv = lie.se2_right_jacobian_inv(e)
        Ad = lie.se2_adjoint(RjiR, Rji_t)
    else:
        Jinv = lie.se3_right_jacobian_inv(e)
        Ad = lie.se3_adjoint(RjiR, Rji_t)
    LB = L @ Jinv
    LA = -LB @ Ad
    return LA, LB


def geodesic_linearize(graph: PoseGraph, R: F64, t: F64, jacobians: bool = True,
                       L: F64 | None = None) -> tuple[F64, F64 | None, F64 | None]:
    """Whitened ``r = L e``, ``A = L A_ij``, ``B = L B_ij`` for all edges (see module docstring)."""
    if L is None:
        L = sqrt_information(graph)
    e, Rrel, trel = geodesic_parts(graph, R, t)
    r = np.einsum("mab,mb->ma", L, e)
    if not jacobians:
        return r, None, None
    LA, LB = geodesic_jacobians(graph.dim, e, Rrel, trel, L)
    return r, LA, LB


def retract(graph_dim: int, R: F64, t: F64, dx: F64) -> tuple[F64, F64]:
    """``X_k <- X_k Exp(dx_k)`` for all nodes (``dx`` of shape ``(n, p)``)."""
    if graph_dim == 2:
        dR, dt = lie.se2_exp(dx)
    else:
        dR, dt = lie.se3_exp(dx)
    return R @ dR, t + np.einsum("mab,mb->ma", R, dt)


class SparseSystem:
    """Assembles ``H`` and ``b`` from per-edge whitened blocks, gauge node removed.

    The block pattern (which ``p x p`` blocks of ``H`` are non-zero) is found once from the
    edges; from it the CSC ``indices``/``indptr`` and the CSC slot of every entry of every edge
    block follow in closed form (rows inside a block column are sorted by block row, then by
    the row inside the block). Each assembly is then one batched ``J^T J`` and two
    ``np.bincount`` calls.
    """

    def __init__(self, n: int, p: int, edge_i: NDArray[np.int64], edge_j: NDArray[np.int64], gauge: int = 0):
        self.n, self.p = n, p
        var = np.arange(n) - (np.arange(n) > gauge)  # variable index of each node (gauge: -1)
        var[gauge] = -1
        self.var = var
        nb = n - 1
        self.N = nb * p
        m = len(edge_i)
        vi, vj = var[edge_i], var[edge_j]
        # edge blocks in the order ii, ij, ji, jj: (4, m) block rows / columns
        br = np.stack([vi, vi, vj, vj], 0)
        bc = np.stack([vi, vj, vi, vj], 0)
        valid = (br >= 0) & (bc >= 0)
        bkey = bc[valid].astype(np.int64) * nb + br[valid]
        ukey, binv = np.unique(bkey, return_inverse=True)
        ucol = ukey // nb
        blocks_per_col = np.bincount(ucol, minlength=nb)
        first_in_col = np.concatenate([[0], np.cumsum(blocks_per_col)])[:-1]
        pos_in_col = np.arange(len(ukey)) - first_in_col[ucol]  # l: rank of the block in its block column
        a = np.arange(p)
        col_len = np.repeat(blocks_per_col * p, p)  # entries in each scalar column
        self.indptr = np.concatenate([[0], np.cumsum(col_len)]).astype(np.int64)
        self.nnz = int(self.indptr[-1])
        # slot of entry (r, c) of unique block u: indptr[col_u p + c] + l_u p + r
        ub_slot = (self.indptr[:-1][(ucol[:, None] * p + a[None, :])][:, None, :]
                   + (pos_in_col[:, None, None] * p + a[None, :, None]))  # (nu, p_r, p_c)
        urow = ukey % nb
        self.indices = np.empty(self.nnz, dtype=np.int64)
        self.indices[ub_slot.ravel()] = np.broadcast_to((urow[:, None, None] * p + a[None, :, None]),
                                                        ub_slot.shape).ravel()
        # slot of every entry of every edge's (2p x 2p) J^T J; entries of the gauge node go to a
        # dummy slot nnz that is dropped after the sum
        slot4 = np.full((4, m, p, p), self.nnz, dtype=np.int64)
        slot4[valid] = ub_slot[binv]
        full = np.empty((m, 2 * p, 2 * p), dtype=np.int64)
        full[:, :p, :p], full[:, :p, p:], full[:, p:, :p], full[:, p:, p:] = slot4
        self.slot = full.ravel()
        self.diag_slots = ub_slot[ucol == urow][:, a, a].ravel()
        gi = np.where(vi[:, None] >= 0, vi[:, None] * p + a, self.N)
        gj = np.where(vj[:, None] >= 0, vj[:, None] * p + a, self.N)
        self.grad_idx = np.concatenate([gi, gj], axis=1).ravel()  # per edge: [node i block, node j block]

    def assemble(self, r: F64, A: F64, B: F64,
                 extra: tuple[F64, F64] | None = None) -> tuple[sp.csc_matrix, F64]:
        """``H = J^T J`` (CSC, gauge removed) and ``b = J^T r`` from whitened ``r, A, B``;
        ``extra = (H_ii, H_jj)`` adds per-edge blocks to the node-i and node-j diagonal blocks."""
        p = self.p
        J = np.concatenate([A, B], axis=2)  # (m, k, 2p)
        JT = np.swapaxes(J, 1, 2)
        JtJ = JT @ J
        if extra is not None:
            JtJ[:, :p, :p] += extra[0]
            JtJ[:, p:, p:] += extra[1]
        data = np.bincount(self.slot, weights=JtJ.ravel(), minlength=self.nnz + 1)[:self.nnz]
        H = sp.csc_matrix((data, self.indices, self.indptr), shape=(self.N, self.N))
        g = (JT @ r[:, :, None]).ravel()
        b = np.bincount(self.grad_idx, weights=g, minlength=self.N + 1)[:self.N]
        return H, b

    def factor(self, H: sp.csc_matrix) -> Any:
        """Factor ``H`` (SPD) by sparse LU in symmetric mode (no pivoting, so in effect ``L D L^T``)
        with SuperLU's fill-reducing minimum-degree ordering of ``H + H^T``."""
        return splu(H, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})

    def solve(self, H: sp.csc_matrix, rhs: F64, previous: Any = None, rtol: float = 1e-6,
              max_cg: int = 15) -> tuple[F64, Any]:
        """Solve ``H x = rhs``; returns ``(x, factor)``.

        With ``previous`` (the factor of an earlier, nearby ``H``) it first runs preconditioned
        conjugate gradients with that factor as preconditioner, accepted when the residual
        ``||H x - rhs|| <= rtol ||rhs||`` within ``max_cg`` iterations; otherwise (or without
        ``previous``) ``H`` is factored afresh.
        """
        if previous is not None:
            M = LinearOperator(H.shape, matvec=previous.solve, dtype=np.float64)
            x, info = cg(H, rhs, x0=previous.solve(rhs), rtol=rtol, atol=0.0, maxiter=max_cg, M=M)
            if info == 0:
                return x, previous
        lu = self.factor(H)
        return lu.solve(rhs), lu

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
             lambda0: float = 1e-5, reuse_factor: bool = True, newton: bool = True,
             progress: Callable[[int, float], None] | None = None) -> HandrolledResult:
    """Minimise the chosen objective from ``(R0, t0)`` with Gauss-Newton (``method="gn"``, the
    notes' loop) or Levenberg-Marquardt (``"lm"``: ``H + lambda I`` as GTSAM's default LM, lambda
    divided by 10 after an accepted step and multiplied by 10 after a rejected one).
    ``objective``: ``"geodesic"`` (GTSAM's) or ``"sesync"``.
    Stops when the relative cost decrease is below ``rel_tol`` or the cost below ``abs_tol``.
    Near convergence (the last step lowered the cost by less than 1 %) and with
    ``reuse_factor``, each system is first solved by PCG preconditioned with the previous
    factorisation (:meth:`SparseSystem.solve`), which saves factorisations once ``H`` barely moves.
    For the SE-Sync objective with ``newton``, the same near-convergence test switches from
    ``J^T J`` to the full Hessian (:func:`gtvo.posegraph.sesync.second_order_blocks`): Newton's
    method, where Gauss-Newton converges only linearly on this objective.
    """
    start = time.perf_counter()
    p = graph.tangent_dim
    if objective == "geodesic":
        L = sqrt_information(graph)
        last: dict[str, Any] = {}

        def lin(R: F64, t: F64, jac: bool) -> tuple[F64, F64 | None, F64 | None]:
            # the residual of an accepted trial step is reused for its Jacobians
            if last.get("R") is R and last.get("t") is t:
                r, parts = last["r"], last["parts"]
            else:
                parts = geodesic_parts(graph, R, t)
                r = np.einsum("mab,mb->ma", L, parts[0])
                last.update(R=R, t=t, r=r, parts=parts)
            if not jac:
                return r, None, None
            return (r, *geodesic_jacobians(graph.dim, *parts, L))
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
    lu = None  # factor of the last system; reused as a PCG preconditioner near convergence
    near = False
    for it in range(1, max_iterations + 1):
        extra = None
        if objective == "sesync" and newton and near:
            extra = sesync.second_order_blocks(graph, R, t, w)
        H, b = system.assemble(r, A, B, extra)  # type: ignore[arg-type]
        accepted = False
        while True:
            if method == "gn":
                Hd = H
            else:
                Hd = H.copy()
                Hd.data[system.diag_slots] += lam
            step, lu_new = system.solve(Hd, -b, lu if (near and reuse_factor) else None)
            dx = system.expand(step)
            Rn, tn = retract(graph.dim, R, t, dx)
            rn, _, _ = lin(Rn, tn, False)
            new_cost = 0.5 * float(np.sum(rn * rn))
            if not np.isfinite(new_cost):
                new_cost = np.inf
            if new_cost <= cost or (method == "gn" and extra is None and np.isfinite(new_cost)):
                accepted = True
                lu = lu_new
                lam = max(lam / 10.0, 1e-12)
                break
            if extra is not None and method == "gn":
                # a failed Newton step in plain GN: fall back to the Gauss-Newton Hessian
                extra = None
                H, b = system.assemble(r, A, B)  # type: ignore[arg-type]
                continue
            lam *= 10.0
            if lam > 1e10:
                break
        if not accepted:
            res.converged = True
            break
        decrease = cost - new_cost
        near = decrease <= 1e-2 * cost
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
