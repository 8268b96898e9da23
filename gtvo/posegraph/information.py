"""Information matrices that are not positive definite: which edges, and the nearest positive-definite repair.

Some real pose-graph benchmarks (office-scale 3-D graphs built by scan matching) carry 6x6
information matrices with large rotation-translation cross terms beside small diagonal entries,
so that the full matrix is indefinite while its rotation and translation blocks are positive
definite. SE-Sync's objective uses only the isotropic precisions of those two blocks
(:func:`gtvo.posegraph.sesync.weights`), so it is well defined on such a graph; GTSAM's geodesic
objective ``0.5 e^T Omega e`` is not (it would reward some errors), so for it each such matrix
is replaced by the nearest positive-definite one (:func:`nearest_positive_definite`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from gtvo.errors import InputError
from gtvo.posegraph.graph import PoseGraph, blocks, check_blocks, edge_name, not_positive_definite

__all__ = ["EIGENVALUE_FLOOR", "blocks", "check_blocks", "not_positive_definite", "nearest_positive_definite",
           "repaired", "block_diagonal", "refuse_not_positive_definite"]

F64 = NDArray[np.float64]

#: Eigenvalues of a repaired matrix are at least this fraction of its largest eigenvalue.
EIGENVALUE_FLOOR = 1e-6


def nearest_positive_definite(information: F64, floor: float = EIGENVALUE_FLOOR) -> F64:
    """The nearest positive-definite matrices (Frobenius norm) of ``(m, p, p)`` matrices.

    Higham's result for a symmetric matrix: keep the eigenvectors of the symmetric part and
    clip its eigenvalues at zero; here at ``floor`` times the largest eigenvalue, so that the
    result is strictly positive definite (a Cholesky factor exists for the whitening).
    """
    sym = 0.5 * (information + np.swapaxes(information, 1, 2))
    w, V = np.linalg.eigh(sym)
    w = np.maximum(w, floor * np.maximum(w[:, -1:], 0.0))
    out = (V * w[:, None, :]) @ np.swapaxes(V, 1, 2)
    return 0.5 * (out + np.swapaxes(out, 1, 2))


def repaired(graph: PoseGraph) -> tuple[PoseGraph, int]:
    """The graph with every information matrix that is not positive definite replaced by the
    nearest positive-definite one (:func:`nearest_positive_definite`), and how many were."""
    bad = not_positive_definite(graph.information)
    count = int(np.count_nonzero(bad))
    if not count:
        return graph, 0
    info = graph.information.copy()
    info[bad] = nearest_positive_definite(info[bad])
    return graph.with_information(info), count


def block_diagonal(graph: PoseGraph) -> PoseGraph:
    """The graph with its rotation-translation cross terms dropped where a matrix is not positive
    definite (then it is, since its blocks are: :func:`check_blocks`); the same graph when none is.
    The chordal initialisations use this: they ignore correlations anyway (LAGO even reads only
    the diagonal), and the repaired matrices' near-zero eigenvalues make GTSAM's InitializePose3
    give up."""
    bad = not_positive_definite(graph.information)
    if not np.any(bad):
        return graph
    trans, rot = blocks(graph.dim)
    info = graph.information.copy()
    sub = info[bad]
    sub[:, rot, trans] = 0.0
    sub[:, trans, rot] = 0.0
    info[bad] = sub
    return graph.with_information(info)


def refuse_not_positive_definite(graph: PoseGraph) -> None:
    """InputError naming the first edge whose information matrix is not positive definite."""
    bad = np.flatnonzero(not_positive_definite(graph.information))
    if len(bad):
        raise InputError(f"information matrix of edge {edge_name(graph, int(bad[0]))} is not positive definite "
                         f"({len(bad)} of {graph.num_edges} edges)", graph.source or "pose graph")
