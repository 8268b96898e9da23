"""Marginal covariances of an optimised pose graph (``gtvo posegraph --covariances FILE.npz``).

``gtsam.Marginals`` of the objective's factor graph (docs/posegraph.md) plus the gauge prior on
node 0 that the solvers use (``sigma`` 1e-6), linearised at the graph's poses: at the optimum
whichever solver found it (the marginals are a property of the optimum, not of the solver; after
a run that did not converge, at its last iterate).
Each node's covariance is in GTSAM's tangent order (2-D ``[x, y, theta]``, 3-D
``[rx, ry, rz, tx, ty, tz]``) with the right perturbation ``X = X_hat * Exp(xi)`` (``xi`` in the
node's own frame), relative to node 0 (the gauge).
"""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.errors import InputError
from gtvo.core.atomic import atomic_path
from gtvo.posegraph import information
from gtvo.posegraph.graph import PoseGraph
from gtvo.posegraph.gtsam_solver import _prior, indeterminate_near, key, objective_graph, to_values

F64 = NDArray[np.float64]

TANGENT_ORDER = {2: "x, y, theta (GTSAM Pose2 tangent)",
                 3: "rx, ry, rz, tx, ty, tz (GTSAM Pose3 tangent: rotation [rad] first, then translation)"}
TANGENT_FRAME = ("right perturbation X = X_hat * Exp(xi): xi in the node's own frame; relative to node 0 "
                 "(gauge prior, sigma 1e-6)")


def marginal_covariances(graph: PoseGraph, objective: str = "geodesic") -> F64:
    """(n, d, d) marginal covariance of every node at the graph's poses (d = 3 in 2-D, 6 in 3-D).

    The geodesic objective uses the information matrices as :func:`gtvo.posegraph.optimize` does
    (those that are not positive definite replaced by the nearest positive-definite matrix).
    Raises :class:`InputError` (one line) when GTSAM finds the system indeterminate there.
    """
    if objective == "geodesic":
        graph = information.repaired(graph)[0]
    fg = objective_graph(graph, objective)
    values = to_values(graph, graph.rotations, graph.translations)
    fg.add(_prior(graph, values))
    out = np.empty((graph.num_poses, graph.tangent_dim, graph.tangent_dim))
    try:
        marginals = gtsam.Marginals(fg, values)
        for k in range(graph.num_poses):
            P = np.asarray(marginals.marginalCovariance(key(k)), dtype=float)
            out[k] = 0.5 * (P + P.T)
    except RuntimeError as exc:
        near = indeterminate_near(exc)
        if near is None:
            raise
        raise InputError(f"no covariances: the {objective} system is indeterminate at these poses"
                         f"{' near ' + near if near else ''}", graph.source or None) from None
    return out


def write_marginals(path: str | Path, graph: PoseGraph, covariances: F64, objective: str) -> Path:
    """Write ``node_id`` (n,), ``covariance`` (n, d, d), ``tangent_order``, ``frame``, ``objective``
    as an ``.npz`` (atomically)."""
    arrays = {"node_id": np.asarray(graph.ids, dtype=np.int64), "covariance": np.asarray(covariances, dtype=float),
              "tangent_order": np.str_(TANGENT_ORDER[graph.dim]), "frame": np.str_(TANGENT_FRAME),
              "objective": np.str_(objective)}
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
    return Path(path)
