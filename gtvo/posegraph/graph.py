"""The :class:`PoseGraph` data type: poses as stacked matrices, edges as stacked arrays."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from gtvo.errors import InputError
from gtvo.posegraph.information import check_blocks

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
