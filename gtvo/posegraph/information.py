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

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from gtvo.errors import InputError

if TYPE_CHECKING:  # graph.py imports this module
    from gtvo.posegraph.graph import PoseGraph

F64 = NDArray[np.float64]

#: Eigenvalues of a repaired matrix are at least this fraction of its largest eigenvalue.
EIGENVALUE_FLOOR = 1e-6


def blocks(dim: int) -> tuple[slice, slice]:
    """``(translation, rotation)`` index ranges of the information in GTSAM's tangent order
    (2-D ``[x, y, theta]``, 3-D ``[rot, trans]``)."""
    return (slice(0, 2), slice(2, 3)) if dim == 2 else (slice(3, 6), slice(0, 3))


def not_positive_definite(information: F64) -> NDArray[np.bool_]:
    """Per matrix of ``(m, p, p)``: True where its symmetric part has an eigenvalue <= 0."""
    sym = 0.5 * (information + np.swapaxes(information, 1, 2))
    return np.linalg.eigvalsh(sym)[:, 0] <= 0


def edge_name(graph: PoseGraph, e: int) -> str:
    """``"i-j"`` with the file's node ids of edge ``e``."""
    return f"{int(graph.ids[graph.edge_i[e]])}-{int(graph.ids[graph.edge_j[e]])}"


def check_blocks(graph: PoseGraph) -> None:
    """InputError naming the first edge whose translation or rotation block is not positive
    definite (both objectives need them: SE-Sync's weights are built from their inverses)."""
    trans, rot = blocks(graph.dim)
    for name, sl in (("translation", trans), ("rotation", rot)):
        bad = np.flatnonzero(not_positive_definite(graph.information[:, sl, sl]))
        if len(bad):
            raise InputError(f"information matrix of edge {edge_name(graph, int(bad[0]))}: its {name} block is "
                             "not positive definite", graph.source or "pose graph")


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
