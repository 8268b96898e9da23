"""Pose-graph readers (g2o 2-D/3-D, TORO ``.graph``, iSAM text) and a full-precision g2o writer.

All readers return a :class:`~gtvo.posegraph.graph.PoseGraph` with the information matrices in
GTSAM's tangent order (2-D ``[x, y, theta]``, 3-D ``[rot, trans]``). A malformed line raises
:class:`~gtvo.errors.InputError` naming the file and the line number.

* g2o: ``EDGE_SE2 i j dx dy dth`` + upper triangle of the information ``[x y th]``;
  ``EDGE_SE3:QUAT i j x y z qx qy qz qw`` + 21 entries over ``[x y z qx qy qz]`` (translation
  first, reordered here; like ``gtsam.readG2o`` the quaternion block is used as is).
* TORO: ``EDGE2 i j dx dy dth Ixx Ixy Iyy Itt Ixt Iyt`` (TORO's order);
  ``EDGE3 i j x y z roll pitch yaw`` + 21 information entries over ``[x y z roll pitch yaw]``
  (identity when the line has none, as in ``sphere_smallnoise.graph``; counted);
  ``VERTEX2 id x y th``, ``VERTEX3 id x y z roll pitch yaw``. ``EQUIV`` and ``BR`` lines are
  skipped and counted.
* iSAM: ``EDGE2``/``ODOMETRY i j dx dy dth`` + the upper-triangular square-root information
  ``R`` (row-first), ``EDGE3 i j x y z roll pitch yaw`` + 21 entries of ``R`` over
  ``[x y z roll pitch yaw]``; information ``= R^T R``. No vertices: the initial poses compose
  the edges along a spanning tree that prefers the odometry edges ``(i, i+1)``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree

from gtvo.core.atomic import atomic_open
from gtvo.errors import InputError, not_a_file
from gtvo.core import lie
from gtvo.posegraph.graph import PoseGraph

FORMATS = ("auto", "g2o", "toro", "isam")

_SKIP_TAGS = {"EQUIV", "BR", "FIX", "PARAMS_SE2OFFSET", "PARAMS_SE3OFFSET", "LANDMARK", "POINT2", "POINT3"}
_G2O_TAGS = {"VERTEX_SE2", "EDGE_SE2", "VERTEX_SE3:QUAT", "EDGE_SE3:QUAT"}

# 3-D reordering from file order [x y z a b c] to GTSAM's [a b c x y z]
_PERM3 = np.array([3, 4, 5, 0, 1, 2])


def _upper_to_full(vals: np.ndarray, n: int) -> np.ndarray:
    """Symmetric matrices from row-first upper triangles, ``(m, n(n+1)/2) -> (m, n, n)``."""
    iu = np.triu_indices(n)
    out = np.zeros((len(vals), n, n))
    out[:, iu[0], iu[1]] = vals
    out[:, iu[1], iu[0]] = vals
    return out


def _upper_to_tri(vals: np.ndarray, n: int) -> np.ndarray:
    """Upper-triangular matrices from row-first upper triangles."""
    iu = np.triu_indices(n)
    out = np.zeros((len(vals), n, n))
    out[:, iu[0], iu[1]] = vals
    return out


def detect_format(path: str | Path) -> str:
    """``"g2o"``, ``"toro"`` or ``"isam"`` from the file's tags (and the ``.graph`` extension)."""
    path = Path(path)
    tags: set[str] = set()
    with open(path, encoding="utf-8", errors="replace") as f:
        for k, line in enumerate(f):
            parts = line.split(maxsplit=1)
            if parts and not parts[0].startswith("#"):
                tags.add(parts[0])
            if k > 2000:
                break
    if tags & _G2O_TAGS:
        return "g2o"
    if path.suffix == ".graph" or tags & {"VERTEX2", "VERTEX3"}:
        return "toro"
    if tags & {"EDGE2", "EDGE3", "ODOMETRY"}:
        return "isam"
    raise InputError("no pose-graph lines found (expected g2o, TORO or iSAM tags)", path)


def read(path: str | Path, fmt: str = "auto") -> PoseGraph:
    """Read a pose graph (``fmt``: ``auto``, ``g2o``, ``toro`` or ``isam``)."""
    path = Path(path)
    if not path.is_file():
        raise not_a_file(path, "pose-graph file")
    if fmt not in FORMATS:
        raise InputError(f"unknown pose-graph format {fmt!r} (choose from {', '.join(FORMATS)})")
    if fmt == "auto":
        fmt = detect_format(path)
    return _Parser(path, fmt).parse()


class _Parser:
    """Line-by-line parser that collects vertices and edges, then builds the arrays once."""

    def __init__(self, path: Path, fmt: str):
        self.path, self.fmt = path, fmt
        self.dim: int | None = None
        self.vertices: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.vertex_raw: list[tuple[int, list[float]]] = []
        self.edge_ids: list[tuple[int, int]] = []
        self.edge_lines: list[int] = []
        self.edge_meas: list[list[float]] = []
        self.edge_info: list[list[float]] = []
        self.edge_has_info: list[bool] = []
        self.skipped: dict[str, int] = {}
        self.lineno = 0

    def fail(self, msg: str) -> InputError:
        return InputError(msg, self.path, self.lineno)

    def set_dim(self, d: int) -> None:
        if self.dim is None:
            self.dim = d
        elif self.dim != d:
            raise self.fail(f"mixes {self.dim}-D and {d}-D lines")

    def numbers(self, parts: list[str], count: int | tuple[int, ...]) -> list[float]:
        counts = (count,) if isinstance(count, int) else count
        if len(parts) - 1 not in counts:
            raise self.fail(f"{parts[0]} needs {' or '.join(map(str, counts))} numbers, got {len(parts) - 1}")
        try:
            vals = [float(x) for x in parts[1:]]
        except ValueError:
            raise self.fail(f"{parts[0]} has a value that is not a number") from None
        if not np.all(np.isfinite(vals)):
            raise self.fail(f"{parts[0]} has a non-finite value")
        return vals

    def node_ids(self, vals: list[float], n: int) -> list[int]:
        ids = vals[:n]
        if any(v != int(v) or v < 0 for v in ids):
            raise self.fail("node ids must be non-negative integers")
        return [int(v) for v in ids]

    def parse(self) -> PoseGraph:
        handlers: dict[str, Callable[[list[str]], None]] = {
            "g2o": self.g2o_line, "toro": self.toro_line, "isam": self.isam_line}
        handle = handlers[self.fmt]
        try:
            f = open(self.path, encoding="utf-8")
        except OSError as exc:
            raise InputError(f"cannot open ({exc.strerror})", self.path) from None
        with f:
            try:
                for self.lineno, line in enumerate(f, start=1):
                    parts = line.split()
                    if not parts or parts[0].startswith("#"):
                        continue
                    if parts[0] in _SKIP_TAGS:
                        self.skipped[parts[0]] = self.skipped.get(parts[0], 0) + 1
                        continue
                    handle(parts)
            except UnicodeDecodeError:
                raise self.fail("is not a text file") from None
        self.lineno = None  # type: ignore[assignment]
        return self.build()

    # --- per-format line handlers -------------------------------------------------------
    def g2o_line(self, parts: list[str]) -> None:
        tag = parts[0]
        if tag == "VERTEX_SE2":
            self.vertex_se2(parts)
        elif tag == "EDGE_SE2":
            v = self.numbers(parts, 11)
            self.set_dim(2)
            self.add_edge(v, v[2:5], v[5:11], True)
        elif tag == "VERTEX_SE3:QUAT":
            v = self.numbers(parts, 8)
            self.set_dim(3)
            q = np.array(v[4:8])
            self.check_quat(q)
            self.add_vertex(self.node_ids(v, 1)[0], lie.quaternions_to_rotations(q[None])[0], np.array(v[1:4]))
        elif tag == "EDGE_SE3:QUAT":
            v = self.numbers(parts, 30)
            self.set_dim(3)
            self.check_quat(np.array(v[5:9]))
            self.add_edge(v, v[2:9], v[9:30], True)
        else:
            raise self.fail(f"unknown g2o tag {tag!r}")

    def toro_line(self, parts: list[str]) -> None:
        tag = parts[0]
        if tag == "VERTEX2":
            self.vertex_se2(parts)
        elif tag == "EDGE2":
            v = self.numbers(parts, (5, 11))
            self.set_dim(2)
            self.add_edge(v, v[2:5], v[5:11], len(v) == 11)
        elif tag == "VERTEX3":
            v = self.numbers(parts, 7)
            self.set_dim(3)
            self.add_vertex(self.node_ids(v, 1)[0], lie.rpy_to_rot(np.array(v[4:7])), np.array(v[1:4]))
        elif tag == "EDGE3":
            v = self.numbers(parts, (8, 29))
            self.set_dim(3)
            self.add_edge(v, v[2:8], v[8:29], len(v) == 29)
        else:
            raise self.fail(f"unknown TORO tag {tag!r}")

    def isam_line(self, parts: list[str]) -> None:
        tag = parts[0]
        if tag in ("EDGE2", "ODOMETRY"):
            v = self.numbers(parts, 11)
            self.set_dim(2)
            self.add_edge(v, v[2:5], v[5:11], True)
        elif tag == "EDGE3":
            v = self.numbers(parts, 29)
            self.set_dim(3)
            self.add_edge(v, v[2:8], v[8:29], True)
        else:
            raise self.fail(f"unknown iSAM tag {tag!r}")

    def check_quat(self, q: np.ndarray) -> None:
        n = float(np.linalg.norm(q))
        if not 0.5 < n < 2.0:
            raise self.fail(f"quaternion norm {n:.3g} is not close to 1")

    def vertex_se2(self, parts: list[str]) -> None:
        """``TAG id x y theta``: g2o's ``VERTEX_SE2`` and TORO's ``VERTEX2`` read the same."""
        v = self.numbers(parts, 4)
        self.set_dim(2)
        self.add_vertex(self.node_ids(v, 1)[0], lie.rot2(np.array(v[3])), np.array(v[1:3]))

    def add_vertex(self, i: int, R: np.ndarray, t: np.ndarray) -> None:
        if i in self.vertices:
            raise self.fail(f"vertex {i} defined twice")
        self.vertices[i] = (R, t)

    def add_edge(self, v: list[float], meas: list[float], info: list[float], has_info: bool) -> None:
        i, j = self.node_ids(v, 2)
        if i == j:
            raise self.fail(f"edge connects node {i} to itself")
        self.edge_ids.append((i, j))
        self.edge_lines.append(self.lineno)
        self.edge_meas.append(meas)
        self.edge_info.append(info if has_info else [])
        self.edge_has_info.append(has_info)

    # --- assembly -----------------------------------------------------------------------
    def check_edge_vertices(self, ij: np.ndarray) -> None:
        """In a file with vertex lines, every edge must join two of them (a pose of its own would
        be made up at the identity otherwise): InputError at the first edge that does not."""
        if not self.vertices:
            return
        known = np.array(sorted(self.vertices), dtype=np.int64)
        missing = ~np.isin(ij, known)
        if np.any(missing):
            e = int(np.flatnonzero(missing.any(axis=1))[0])
            node = int(ij[e][missing[e]][0])
            raise InputError(f"edge {ij[e, 0]}-{ij[e, 1]} refers to node {node}, which has no vertex line",
                             self.path, self.edge_lines[e])

    def build(self) -> PoseGraph:
        if not self.edge_ids:
            raise InputError("pose graph has no edges", self.path)
        d = int(self.dim)  # type: ignore[arg-type]
        p = 3 if d == 2 else 6
        ij = np.array(self.edge_ids, dtype=np.int64)
        self.check_edge_vertices(ij)
        meas = np.array(self.edge_meas, dtype=float)
        has = np.array(self.edge_has_info, dtype=bool)
        m = len(ij)
        raw = np.zeros((m, p * (p + 1) // 2))
        if np.any(has):
            raw[has] = np.array([x for x, h in zip(self.edge_info, self.edge_has_info) if h], dtype=float)
        info = np.broadcast_to(np.eye(p), (m, p, p)).copy()
        if d == 2:
            Rm = lie.rot2(meas[:, 2])
            tm = meas[:, :2]
            if self.fmt == "g2o":
                info[has] = _upper_to_full(raw[has], 3)
            elif self.fmt == "toro":  # xx xy yy tt xt yt
                g = raw[has][:, [0, 1, 4, 2, 5, 3]]
                info[has] = _upper_to_full(g, 3)
            else:
                U = _upper_to_tri(raw, 3)
                info = np.swapaxes(U, 1, 2) @ U
        else:
            if self.fmt == "g2o":
                Rm = lie.quaternions_to_rotations(meas[:, 3:7])
                full = _upper_to_full(raw[has], 6)
            else:
                Rm = lie.rpy_to_rot(meas[:, 3:6])
                if self.fmt == "toro":
                    full = _upper_to_full(raw[has], 6)
                else:
                    U = _upper_to_tri(raw[has], 6)
                    full = np.swapaxes(U, 1, 2) @ U
            tm = meas[:, :3]
            info[has] = full[:, _PERM3][:, :, _PERM3]
        ids = np.union1d(np.array(sorted(self.vertices), dtype=np.int64), ij.ravel())
        index = {int(k): n for n, k in enumerate(ids)}
        ei = np.array([index[int(a)] for a in ij[:, 0]], dtype=np.int64)
        ej = np.array([index[int(b)] for b in ij[:, 1]], dtype=np.int64)
        n = len(ids)
        R = np.broadcast_to(np.eye(d), (n, d, d)).copy()
        t = np.zeros((n, d))
        has_vertices = len(self.vertices) == n
        for k, (Rv, tv) in self.vertices.items():
            R[index[k]] = Rv
            t[index[k]] = tv
        graph = PoseGraph(d, ids, R, t, has_vertices, ei, ej, Rm, tm, info, str(self.path), self.skipped,
                          int(np.count_nonzero(~has)))
        graph.validate()
        if self.fmt == "isam":
            graph = graph.with_poses(*compose_spanning_tree(graph))
        return graph


def check_connected(graph: PoseGraph) -> None:
    """Raise :class:`InputError` when the graph's edges leave it in more than one component: each
    component would have a gauge of its own, which nothing fixes (the normal equations are
    singular), whatever the initial poses."""
    n = graph.num_poses
    ncomp, _ = connected_components(coo_matrix((np.ones(graph.num_edges), (graph.edge_i, graph.edge_j)),
                                               shape=(n, n)), directed=False)
    if ncomp != 1:
        raise InputError(f"pose graph has {ncomp} disconnected components", graph.source or None)


def spanning_tree(graph: PoseGraph) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """BFS order from node 0 over a spanning tree that prefers odometry edges ``(i, i+1)``.

    Returns ``(order, parent, edge)``: ``parent[k]`` is ``k``'s tree parent and ``edge[k]`` the
    index of the graph edge that links them (``-1`` for the root). Raises InputError when the
    graph is not connected (a pose graph with two components has no single gauge).
    """
    n = graph.num_poses
    check_connected(graph)
    ids = graph.ids
    sequential = np.abs(ids[graph.edge_i] - ids[graph.edge_j]) == 1
    weight = np.where(sequential, 1.0, 2.0) + 1e-9 * np.arange(graph.num_edges) / max(graph.num_edges, 1)
    a, b = np.minimum(graph.edge_i, graph.edge_j), np.maximum(graph.edge_i, graph.edge_j)
    # keep the lightest edge of each node pair, remember which edge it was
    order_e = np.lexsort((weight, b, a))
    first = np.ones(len(order_e), bool)
    first[1:] = (a[order_e][1:] != a[order_e][:-1]) | (b[order_e][1:] != b[order_e][:-1])
    keep = order_e[first]
    W = coo_matrix((weight[keep], (a[keep], b[keep])), shape=(n, n)).tocsr()
    T = minimum_spanning_tree(W)
    T = T + T.T
    order, pred = breadth_first_order(T, 0, directed=False, return_predecessors=True)
    lookup = {(int(x), int(y)): int(e) for x, y, e in zip(a[keep], b[keep], keep)}
    edge = np.full(n, -1, dtype=np.int64)
    for k in order[1:]:
        u = int(pred[k])
        edge[k] = lookup[(min(u, int(k)), max(u, int(k)))]
    return order, pred, edge


def compose_spanning_tree(graph: PoseGraph) -> tuple[np.ndarray, np.ndarray]:
    """Poses from composing the edges along :func:`spanning_tree` from node 0 at the identity."""
    d = graph.dim
    order, pred, edge = spanning_tree(graph)
    R = np.broadcast_to(np.eye(d), (graph.num_poses, d, d)).copy()
    t = np.zeros((graph.num_poses, d))
    Rm, tm = graph.meas_rotations, graph.meas_translations
    for k in order[1:]:
        u, e = pred[k], edge[k]
        if graph.edge_i[e] == u:  # X_k = X_u Z
            R[k] = R[u] @ Rm[e]
            t[k] = t[u] + R[u] @ tm[e]
        else:  # X_u = X_k Z  ->  X_k = X_u Z^-1
            R[k] = R[u] @ Rm[e].T
            t[k] = t[u] - R[k] @ tm[e]
    return R, t


def write_g2o(path: str | Path, graph: PoseGraph) -> Path:
    """Write ``graph`` (its poses as vertices) as g2o at full double precision (``%.17g``), atomically."""
    d = graph.dim
    ids = graph.ids
    lines: list[str] = []
    g = "%.17g"
    if d == 2:
        th = lie.angle2(graph.rotations)
        for k in range(graph.num_poses):
            lines.append("VERTEX_SE2 %d %s %s %s" % (ids[k], g % graph.translations[k, 0],
                                                     g % graph.translations[k, 1], g % th[k]))
        mth = lie.angle2(graph.meas_rotations)
        iu = np.triu_indices(3)
        up = graph.information[:, iu[0], iu[1]]
        for e in range(graph.num_edges):
            vals = [*graph.meas_translations[e], mth[e], *up[e]]
            lines.append("EDGE_SE2 %d %d " % (ids[graph.edge_i[e]], ids[graph.edge_j[e]])
                         + " ".join(g % x for x in vals))
    else:
        q = lie.rotations_to_quaternions(graph.rotations)
        for k in range(graph.num_poses):
            lines.append("VERTEX_SE3:QUAT %d " % ids[k]
                         + " ".join(g % x for x in [*graph.translations[k], *q[k]]))
        mq = lie.rotations_to_quaternions(graph.meas_rotations)
        inv = np.argsort(_PERM3)
        info_file = graph.information[:, inv][:, :, inv]
        iu = np.triu_indices(6)
        up = info_file[:, iu[0], iu[1]]
        for e in range(graph.num_edges):
            vals = [*graph.meas_translations[e], *mq[e], *up[e]]
            lines.append("EDGE_SE3:QUAT %d %d " % (ids[graph.edge_i[e]], ids[graph.edge_j[e]])
                         + " ".join(g % x for x in vals))
    with atomic_open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    return Path(path)
