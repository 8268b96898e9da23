"""The :class:`PoseGraph` data type: poses as stacked matrices, edges as stacked arrays."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from gtvo.errors import InputError

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


@dataclass
class PoseGraph:
    """A 2-D or 3-D pose graph.

    Nodes are numbered ``0..n-1`` (``ids[k]`` is node ``k``'s id in the file). Poses are
    ``T_world_node`` as ``rotations (n, d, d)`` and ``translations (n, d)``; they are the file's
    vertices when ``has_vertices`` and identity otherwise. Edge ``e`` measures
    ``Z_e = X_{edge_i[e]}^-1 X_{edge_j[e]}`` (``meas_rotations``, ``meas_translations``) with
    ``information[e]`` in GTSAM's tangent order (2-D ``[x, y, theta]``; 3-D ``[rot, trans]``).
    ``skipped`` counts lines of kinds the graph does not use (``EQUIV``, ``BR``...);
    ``identity_information`` counts edges whose line gave no information matrix (identity used).
    """

    dim: int
    ids: I64
    rotations: F64
    translations: F64
    has_vertices: bool
    edge_i: I64
    edge_j: I64
    meas_rotations: F64
    meas_translations: F64
    information: F64
    source: str = ""
    skipped: dict[str, int] = field(default_factory=dict)
    identity_information: int = 0

    @property
    def num_poses(self) -> int:
        """Number of nodes."""
        return int(len(self.ids))

    @property
    def num_edges(self) -> int:
        """Number of edges."""
        return int(len(self.edge_i))

    @property
    def tangent_dim(self) -> int:
        """3 in 2-D, 6 in 3-D."""
        return 3 if self.dim == 2 else 6

    def with_poses(self, rotations: F64, translations: F64) -> "PoseGraph":
        """A copy with other node poses (same edges), marked as having vertices."""
        return PoseGraph(self.dim, self.ids, np.asarray(rotations, float), np.asarray(translations, float), True,
                         self.edge_i, self.edge_j, self.meas_rotations, self.meas_translations, self.information,
                         self.source, dict(self.skipped), self.identity_information)

    def with_information(self, information: F64) -> "PoseGraph":
        """A copy with other information matrices (same poses and measurements)."""
        return PoseGraph(self.dim, self.ids, self.rotations, self.translations, self.has_vertices, self.edge_i,
                         self.edge_j, self.meas_rotations, self.meas_translations, np.asarray(information, float),
                         self.source, dict(self.skipped), self.identity_information)

    def validate(self) -> None:
        """Raise :class:`InputError` for an empty graph, NaN, a self-loop, or an information matrix
        whose translation or rotation block is not positive definite. A full matrix that is not
        positive definite (cross terms) is allowed here: see :mod:`gtvo.posegraph.information`."""
        where = self.source or "pose graph"
        if self.num_edges == 0:
            raise InputError("pose graph has no edges", where)
        for name in ("rotations", "translations", "meas_rotations", "meas_translations", "information"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise InputError(f"non-finite values in {name}", where)
        if np.any(self.edge_i == self.edge_j):
            e = int(np.flatnonzero(self.edge_i == self.edge_j)[0])
            raise InputError(f"edge {e} connects node {int(self.ids[self.edge_i[e]])} to itself", where)
        check_blocks(self)


def blocks(dim: int) -> tuple[slice, slice]:
    """``(translation, rotation)`` index ranges of an information matrix in GTSAM's tangent order
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
