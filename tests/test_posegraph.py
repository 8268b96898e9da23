"""Pose graphs: Lie maps, analytic Jacobians vs numerical, readers vs the files, solvers vs reference optima."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import gtsam
import numpy as np
import pytest

import gtvo.posegraph as pg
from gtvo.errors import InputError
from gtvo.core import lie
from gtvo.posegraph import gtsam_solver, handrolled, io, sesync
from gtvo.posegraph.graph import PoseGraph

# "GTSAM reference errors" and SE-Sync f* from the data README (pose_graphs/README.md)
GTSAM_REF = {"se_sync/intel.g2o": 22.50211654, "se_sync/CSAIL.g2o": 20.27544167,
             "se_sync/parking-garage.g2o": 0.6341923996, "gtsam/pose2example.txt": 0.5494864475,
             "gtsam/pose3example.txt": 18853.02073, "se_sync/tinyGrid3D.g2o": 9.313909434}
SESYNC_FSTAR = {"se_sync/intel.g2o": 52.35, "se_sync/CSAIL.g2o": 31.70, "se_sync/parking-garage.g2o": 1.263}


def pg_file(shared_data: Path, rel: str) -> Path:
    path = shared_data / "pose_graphs" / rel
    if not path.is_file():
        pytest.skip(f"{path} absent")
    return path


# ---------------------------------------------------------------- Lie maps
@pytest.mark.parametrize("scale", [1e-7, 1e-3, 0.3, 1.5])
def test_se3_maps_match_gtsam(scale: float) -> None:
    rng = np.random.default_rng(1)
    xi = rng.normal(size=(20, 6)) * scale
    R, t = lie.se3_exp(xi)
    for k in range(len(xi)):
        P = gtsam.Pose3.Expmap(xi[k])
        assert np.allclose(R[k], P.rotation().matrix(), atol=1e-12)
        assert np.allclose(t[k], P.translation(), atol=1e-12)
        # Jr^-1 of SE(3) equals GTSAM's Pose3.LogmapDerivative (tol 1e-9)
        assert np.allclose(lie.se3_right_jacobian_inv(xi[k:k + 1])[0], gtsam.Pose3.LogmapDerivative(xi[k]),
                           atol=1e-9)
    inside = np.linalg.norm(xi[:, :3], axis=1) < np.pi  # Log returns angles in [0, pi]
    assert np.allclose(lie.se3_log(R, t)[inside], xi[inside], atol=1e-12)


def _numeric_jr_inv(exp, log, xi: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """d Log(Exp(xi) Exp(d)) / dd at d = 0, central differences."""
    R, t = exp(xi[None])
    p = len(xi)
    J = np.zeros((p, p))
    for k in range(p):
        d = np.zeros(p)
        d[k] = h
        out = []
        for s in (1.0, -1.0):
            Rd, td = exp(s * d[None])
            out.append(log(R @ Rd, t + np.einsum("mab,mb->ma", R, td))[0])
        J[:, k] = (out[0] - out[1]) / (2 * h)
    return J


def test_one_vectors_hat_and_adjoint_are_the_stacks_to_the_bit() -> None:
    """``hat3`` of one vector (built directly) and ``se3_adjoint`` of one pose equal the stacked forms'
    entries byte for byte, and the adjoint is GTSAM's."""
    rng = np.random.default_rng(3)
    xi = rng.normal(size=(20, 6))
    R, t = lie.se3_exp(xi)
    for k in range(20):
        assert lie.hat3(t[k]).tobytes() == lie.hat3(t[k:k + 1])[0].tobytes()
        assert lie.se3_adjoint(R[k], t[k]).tobytes() == lie.se3_adjoint(R[k:k + 1], t[k:k + 1])[0].tobytes()
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R[k], t[k]
        assert np.allclose(lie.se3_adjoint(R[k], t[k]), gtsam.Pose3(T).AdjointMap(), atol=1e-12)


@pytest.mark.parametrize("scale", [1e-5, 1e-2, 0.5, 2.0])
def test_right_jacobian_inverses_numerically(scale: float) -> None:
    """SE(2) and SE(3) Jr^-1 against central differences of Log (tol 1e-7)."""
    rng = np.random.default_rng(2)
    for _ in range(5):
        x3 = rng.normal(size=3) * scale
        assert np.allclose(lie.se2_right_jacobian_inv(x3[None])[0], _numeric_jr_inv(lie.se2_exp, lie.se2_log, x3),
                           atol=1e-7)
        x6 = rng.normal(size=6) * scale
        x6[:3] = np.clip(x6[:3], -1.0, 1.0)
        assert np.allclose(lie.se3_right_jacobian_inv(x6[None])[0], _numeric_jr_inv(lie.se3_exp, lie.se3_log, x6),
                           atol=1e-7)


def test_rotation_conversions() -> None:
    rng = np.random.default_rng(3)
    q = rng.normal(size=(50, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    R = lie.quaternions_to_rotations(q)
    for k in range(5):
        assert np.allclose(R[k], gtsam.Rot3(q[k, 3], q[k, 0], q[k, 1], q[k, 2]).matrix(), atol=1e-14)
    assert np.allclose(lie.quaternions_to_rotations(lie.rotations_to_quaternions(R)), R, atol=1e-14)
    rpy = rng.normal(size=3)
    assert np.allclose(lie.rpy_to_rot(rpy), gtsam.Rot3.Ypr(rpy[2], rpy[1], rpy[0]).matrix(), atol=1e-14)
    w = np.array([[np.pi - 1e-7, 0.0, 0.0], [0.0, 1e-9, np.pi], [0.3, -0.2, 0.1]])
    assert np.allclose(lie.so3_exp(lie.so3_log(lie.so3_exp(w))), lie.so3_exp(w), atol=1e-9)


# ---------------------------------------------------------------- analytic A_ij, B_ij
def _pairs_graph(dim: int, rng: np.random.Generator, m: int = 15) -> tuple[PoseGraph, np.ndarray, np.ndarray]:
    """Edges (2k, 2k+1) only, so perturbing all 'i' nodes at once is separable per edge."""
    p = 3 if dim == 2 else 6
    n = 2 * m
    exp = lie.se2_exp if dim == 2 else lie.se3_exp
    R, t = exp(rng.normal(size=(n, p)) * 1.2)
    Rm, tm = exp(rng.normal(size=(m, p)) * 1.2)
    A = rng.normal(size=(m, p, p))
    info = A @ np.swapaxes(A, 1, 2) + np.eye(p)
    g = PoseGraph(dim, np.arange(n), R, t, True, np.arange(0, n, 2), np.arange(1, n, 2), Rm, tm, info)
    return g, R, t


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("objective", ["geodesic", "sesync"])
def test_edge_jacobians_numerically(dim: int, objective: str) -> None:
    """A_ij, B_ij (whitened) against central differences of the whitened residual (tol 1e-6 relative)."""
    rng = np.random.default_rng(4 + dim)
    g, R, t = _pairs_graph(dim, rng)
    p = g.tangent_dim

    def lin(R_: np.ndarray, t_: np.ndarray, jac: bool):
        if objective == "geodesic":
            return handrolled.geodesic_linearize(g, R_, t_, jac)
        return sesync.linearize(g, R_, t_, jac)

    r, A, B = lin(R, t, True)
    h = 1e-6
    for which, J in ((g.edge_i, A), (g.edge_j, B)):
        for k in range(p):
            dx = np.zeros((g.num_poses, p))
            dx[which, k] = h
            rp = lin(*handrolled.retract(dim, R, t, dx), False)[0]
            rm = lin(*handrolled.retract(dim, R, t, -dx), False)[0]
            num = (rp - rm) / (2 * h)
            assert np.allclose(num, J[:, :, k], atol=1e-6 * max(1.0, np.abs(J).max()))


@pytest.mark.parametrize("dim", [2, 3])
def test_sesync_newton_hessian_numerically(dim: int) -> None:
    """J^T J + second_order_blocks equals the finite-difference Hessian of F pulled back through
    R <- R Exp(w^), t <- t + R v (tol 1e-6 relative); J^T J alone does not."""
    rng = np.random.default_rng(8 + dim)
    g, R, t = _pairs_graph(dim, rng, m=1)
    p = g.tangent_dim

    def pullback(x: np.ndarray) -> float:
        x = x.reshape(2, p)
        dR = lie.rot2(x[:, 2]) if dim == 2 else lie.so3_exp(x[:, :3])
        v = x[:, :2] if dim == 2 else x[:, 3:]
        return sesync.objective(g, R @ dR, t + np.einsum("mab,mb->ma", R, v))

    n, h = 2 * p, 1e-4
    E = np.eye(n) * h
    Hn = np.array([[(pullback(E[a] + E[b]) - pullback(E[a] - E[b]) - pullback(E[b] - E[a])
                     + pullback(-E[a] - E[b])) / (4 * h * h) for b in range(n)] for a in range(n)])
    _, A, B = sesync.linearize(g, R, t)
    J = np.concatenate([A[0], B[0]], axis=1)
    Hii, Hjj = sesync.second_order_blocks(g, R, t)
    H = J.T @ J
    assert not np.allclose(H, Hn, atol=1e-3 * np.abs(Hn).max())
    H[:p, :p] += Hii[0]
    H[p:, p:] += Hjj[0]
    assert np.allclose(H, Hn, atol=1e-6 * np.abs(Hn).max())


def test_sparse_assembly_matches_dense(shared_data: Path) -> None:
    """H and b from SparseSystem equal the dense J^T J, J^T r with x_0's rows/columns removed."""
    for rel in ("gtsam/pose3example.txt", "gtsam/pose2example.txt"):
        g = io.read(pg_file(shared_data, rel))
        p = g.tangent_dim
        system = handrolled.SparseSystem(g.num_poses, p, g.edge_i, g.edge_j)
        r, A, B = handrolled.geodesic_linearize(g, g.rotations, g.translations)
        H, b = system.assemble(r, A, B)
        J = np.zeros((g.num_edges * p, g.num_poses * p))
        for e in range(g.num_edges):  # dense reference, a loop is fine here
            J[e * p:(e + 1) * p, g.edge_i[e] * p:(g.edge_i[e] + 1) * p] += A[e]
            J[e * p:(e + 1) * p, g.edge_j[e] * p:(g.edge_j[e] + 1) * p] += B[e]
        scale = np.abs(J.T @ J).max()
        assert np.allclose(H.toarray(), (J.T @ J)[p:, p:], atol=1e-12 * scale)
        assert np.allclose(b, (J.T @ r.ravel())[p:], atol=1e-12 * scale)
        assert np.array_equal(H.data[system.diag_slots], H.diagonal())


def test_geodesic_error_and_sesync_objective_match_gtsam_graphs(shared_data: Path) -> None:
    for rel in ("gtsam/pose3example.txt", "se_sync/intel.g2o"):
        g = io.read(pg_file(shared_data, rel))
        rng = np.random.default_rng(5)
        R, t = handrolled.retract(g.dim, g.rotations, g.translations, 0.1 * rng.normal(size=(g.num_poses, g.tangent_dim)))
        v = gtsam_solver.to_values(g, R, t)
        assert handrolled.gtsam_error(g, R, t) == pytest.approx(gtsam_solver.between_graph(g).error(v), rel=1e-10)
        assert sesync.objective(g, R, t) == pytest.approx(gtsam_solver.sesync_graph(g).error(v), rel=1e-10)
        r, _, _ = sesync.linearize(g, R, t, False)
        assert 0.5 * np.sum(r * r) == pytest.approx(sesync.objective(g, R, t), rel=1e-12)


# ---------------------------------------------------------------- readers
@pytest.mark.slow
def test_g2o_information_matches_readg2o(shared_data: Path) -> None:
    for rel in ("se_sync/parking-garage.g2o", "gtsam/pose3example-offdiagonal.txt", "se_sync/intel.g2o"):
        path = pg_file(shared_data, rel)
        g = io.read(path)
        fg, _ = gtsam.readG2o(str(path), g.dim == 3)
        info = np.array([fg.at(k).noiseModel().R().T @ fg.at(k).noiseModel().R() for k in range(fg.size())])
        assert len(info) == g.num_edges
        assert np.allclose(info, g.information, rtol=1e-12, atol=1e-12 * np.abs(info).max())


@pytest.mark.slow
def test_toro_readers_edge_counts_and_weights(shared_data: Path) -> None:
    w100 = io.read(pg_file(shared_data, "gtsam/w100.graph"))
    assert (w100.dim, w100.num_poses, w100.num_edges) == (2, 100, 300)
    assert w100.skipped == {"EQUIV": 40}
    # TORO order "1 0 1 1 0 0" = Ixx Ixy Iyy Itt Ixt Iyt = identity (g2o order would not be PD)
    assert np.allclose(w100.information, np.eye(3))
    sphere = io.read(pg_file(shared_data, "gtsam/sphere_smallnoise.graph"))
    assert (sphere.dim, sphere.num_poses, sphere.num_edges) == (3, 2200, 8647)
    assert sphere.identity_information == 8647
    ex = io.read(pg_file(shared_data, "gtsam/example.graph"))
    assert ex.skipped == {"BR": 422} and ex.num_edges == 94


def test_toro_information_order(tmp_path: Path) -> None:
    f = tmp_path / "a.graph"
    f.write_text("VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 0 10 1 20 30 2 3\n")
    g = io.read(f)
    assert np.allclose(g.information[0], [[10, 1, 2], [1, 20, 3], [2, 3, 30]])


@pytest.mark.slow
def test_isam_square_root_information(shared_data: Path, tmp_path: Path) -> None:
    s = io.read(pg_file(shared_data, "isam/sphere2500.txt"))
    assert (s.num_poses, s.num_edges) == (2500, 4949)
    # sqrt-information diag(10, 10, 10, 100, 100, 25) over [x y z roll pitch yaw] -> [rot, trans]
    assert np.allclose(s.information[0], np.diag([1e4, 1e4, 625, 100, 100, 100]))
    # same measurements as SE-Sync's g2o copy (rounded quaternions there)
    g = io.read(pg_file(shared_data, "se_sync/sphere2500.g2o"))
    where = {(a, b): e for e, (a, b) in enumerate(zip(s.edge_i.tolist(), s.edge_j.tolist()))}
    idx = np.array([where[(a, b)] for a, b in zip(g.edge_i.tolist(), g.edge_j.tolist())])
    assert len(set(idx.tolist())) == g.num_edges
    assert np.allclose(s.meas_rotations[idx], g.meas_rotations, atol=5e-6)
    assert np.allclose(s.meas_translations[idx], g.meas_translations, atol=1e-12)
    m = io.read(pg_file(shared_data, "isam/manhattanOlson3500.txt"))
    assert (m.num_poses, m.num_edges) == (3500, 5598)
    assert np.allclose(m.information[0], 2000.0 * np.eye(3), rtol=1e-9)
    # initial values compose the odometry
    assert np.allclose(m.rotations[1], m.meas_rotations[0]) and np.allclose(m.translations[1], m.meas_translations[0])
    # a full upper-triangular R: information = R^T R, then reordered to GTSAM's [rot, trans]
    U = np.triu(np.arange(1.0, 37.0).reshape(6, 6)) + 5 * np.eye(6)
    vals = " ".join(str(x) for x in U[np.triu_indices(6)])
    f = tmp_path / "a.txt"
    f.write_text(f"EDGE3 0 1 1 2 3 0.1 0.2 0.3 {vals}\n")
    g3 = io.read(f)
    P = [3, 4, 5, 0, 1, 2]
    assert np.allclose(g3.information[0], (U.T @ U)[np.ix_(P, P)])
    assert np.allclose(g3.meas_rotations[0], gtsam.Rot3.Ypr(0.3, 0.2, 0.1).matrix())
    f2 = tmp_path / "b.txt"
    f2.write_text("EDGE2 0 1 1 0 0.1 2 1 3 4 5 6\n")
    U2 = np.array([[2.0, 1, 3], [0, 4, 5], [0, 0, 6]])
    assert np.allclose(io.read(f2).information[0], U2.T @ U2)


@pytest.mark.slow
def test_w20000_isam_edges(shared_data: Path) -> None:
    g = io.read(pg_file(shared_data, "gtsam/w20000.txt"))
    assert g.num_edges == 26831 and io.detect_format(pg_file(shared_data, "gtsam/w20000.txt")) == "isam"


@pytest.mark.parametrize("text, needle", [
    ("VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0\n", ":2: EDGE_SE2 needs 11"),
    ("VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 1 0 x 1 0 0 1 0 1\n", ":2: EDGE_SE2 has a value that is not a number"),
    ("EDGE_SE2 0 1 1 0 nan 1 0 0 1 0 1\n", ":1: EDGE_SE2 has a non-finite"),
    ("EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nFOO 1 2\n", ":2: unknown g2o tag"),
    ("EDGE_SE2 0 0 1 0 0 1 0 0 1 0 1\n", ":1: edge connects node 0 to itself"),
    ("EDGE_SE2 0 1.5 1 0 0 1 0 0 1 0 1\n", ":1: node ids"),
    ("EDGE_SE2 0 1 1 0 0 1 0 0 1 0 -1\n", "not positive definite"),
    ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 0\nEDGE_SE3:QUAT 0 1 0 0 0 0 0 0 1" + " 1" * 21 + "\n", ":1: quaternion norm"),
    ("# only a comment\n", "no pose-graph lines"),
    ("", "no pose-graph lines"),
    ("EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 2 3 1 0 0 1 0 0 1 0 1\n", "disconnected"),
])
def test_malformed_files_raise_input_error(tmp_path: Path, text: str, needle: str) -> None:
    f = tmp_path / "bad.g2o"
    f.write_text(text)
    with pytest.raises(InputError) as exc:
        g = io.read(f)
        pg.optimize(g, init="odometry")
    assert str(f) in str(exc.value) and needle in str(exc.value)


@pytest.mark.parametrize("solver", ["gtsam", "handrolled"])
@pytest.mark.parametrize("init", ["file", "odometry", "chordal"])
def test_disconnected_graph_is_refused_with_every_init(tmp_path: Path, init: str, solver: str) -> None:
    """Two components (each with vertices, so every init has poses to start from): no init can
    fix the second component's gauge, so each is refused up front, not by a singular solve."""
    f = tmp_path / "two_parts.g2o"
    f.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 5 0 0\nVERTEX_SE2 3 6 0 0\n"
                 "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 2 3 1 0 0 1 0 0 1 0 1\n")
    with pytest.raises(InputError, match="2 disconnected components") as exc:
        pg.optimize(io.read(f), solver=solver, init=init)
    assert str(f) in str(exc.value)


def test_missing_file_and_no_vertices(shared_data: Path, tmp_path: Path) -> None:
    with pytest.raises(InputError, match="pose-graph file not found"):
        io.read(tmp_path / "nope.g2o")
    g = io.read(pg_file(shared_data, "se_sync/CSAIL.g2o"))
    with pytest.raises(InputError, match="VERTEX line for every pose"):
        pg.optimize(g, init="file")


def test_g2o_writer_full_precision_round_trip(shared_data: Path, tmp_path: Path) -> None:
    for rel in ("gtsam/pose3example-offdiagonal.txt", "se_sync/intel.g2o", "gtsam/w100.graph"):
        g = io.read(pg_file(shared_data, rel))
        res = pg.optimize(g, init="odometry", max_iterations=3)
        out = io.write_g2o(tmp_path / "o.g2o", res.graph)
        back = io.read(out)
        assert back.num_edges == g.num_edges and np.array_equal(back.ids, g.ids)
        assert np.allclose(back.information, g.information, rtol=1e-15, atol=0)
        assert np.allclose(back.rotations, res.graph.rotations, atol=1e-15)
        assert np.allclose(back.translations, res.graph.translations, rtol=1e-15, atol=1e-15)
        assert pg.gtsam_error(back) == pytest.approx(res.gtsam_error, rel=1e-9)


def test_odometry_init_reproduces_noise_free_graph() -> None:
    rng = np.random.default_rng(6)
    n = 30
    R, t = lie.se3_exp(rng.normal(size=(n, 6)))
    R[0], t[0] = np.eye(3), 0.0
    i = np.r_[np.arange(n - 1), [0, 5, 20]]
    j = np.r_[np.arange(1, n), [10, 25, 3]]  # one loop edge stored backwards (20 -> 3)
    Rm = np.swapaxes(R[i], 1, 2) @ R[j]
    tm = np.einsum("mba,mb->ma", R[i], t[j] - t[i])
    keep = np.ones(len(i), bool)
    keep[7] = False  # a missing odometry edge: the tree must go around
    g = PoseGraph(3, np.arange(n), np.broadcast_to(np.eye(3), (n, 3, 3)).copy(), np.zeros((n, 3)), False,
                  i[keep], j[keep], Rm[keep], tm[keep], np.broadcast_to(np.eye(6), (keep.sum(), 6, 6)).copy())
    R0, t0 = io.compose_spanning_tree(g)
    assert np.allclose(R0, R, atol=1e-12) and np.allclose(t0, t, atol=1e-10)


# ---------------------------------------------------------------- solvers vs reference optima
@pytest.mark.slow
@pytest.mark.parametrize("rel", sorted(GTSAM_REF))
@pytest.mark.parametrize("solver", ["gtsam", "handrolled"])
def test_reaches_gtsam_reference_error(shared_data: Path, rel: str, solver: str) -> None:
    g = io.read(pg_file(shared_data, rel))
    res = pg.optimize(g, solver=solver, init="chordal")
    assert res.gtsam_error <= GTSAM_REF[rel] * (1 + 1e-6) + 1e-9
    assert res.gtsam_error == pytest.approx(GTSAM_REF[rel], rel=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize("rel", sorted(SESYNC_FSTAR))
@pytest.mark.parametrize("solver", ["gtsam", "handrolled"])
def test_reaches_sesync_fstar(shared_data: Path, rel: str, solver: str) -> None:
    g = io.read(pg_file(shared_data, rel))
    res = pg.optimize(g, solver=solver, init="chordal", objective="sesync")
    assert float(f"{res.sesync_objective:.4g}") == pytest.approx(SESYNC_FSTAR[rel], rel=1e-12)


@pytest.mark.parametrize("solver, method", [("gtsam", "gn"), ("gtsam", "dogleg"), ("handrolled", "gn")])
def test_other_methods_and_inits(shared_data: Path, solver: str, method: str) -> None:
    g = io.read(pg_file(shared_data, "se_sync/CSAIL.g2o"))
    for init in ("odometry", "chordal"):
        res = pg.optimize(g, solver=solver, init=init, method=method)
        assert res.gtsam_error == pytest.approx(GTSAM_REF["se_sync/CSAIL.g2o"], rel=1e-6)
    g3 = io.read(pg_file(shared_data, "gtsam/pose3example.txt"))
    res = pg.optimize(g3, solver=solver, init="file", method=method)
    assert res.gtsam_error == pytest.approx(GTSAM_REF["gtsam/pose3example.txt"], rel=1e-6)


def test_bad_options_raise_input_error(shared_data: Path) -> None:
    g = io.read(pg_file(shared_data, "gtsam/pose2example.txt"))
    for kw in ({"solver": "ceres"}, {"objective": "l1"}, {"init": "random"},
               {"solver": "handrolled", "method": "dogleg"}):
        with pytest.raises(InputError):
            pg.optimize(g, **kw)


# ---------------------------------------------------------------- CLI
def _cli(argv: list[str]) -> int:
    from gtvo.commands import posegraph as cmd

    parser = argparse.ArgumentParser()
    cmd.register(parser.add_subparsers())
    args = parser.parse_args(["posegraph", *argv])
    return args.func(args)


def test_cli_json_out_and_plot(shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = pg_file(shared_data, "gtsam/pose2example.txt")
    out, png = tmp_path / "opt.g2o", tmp_path / "opt.png"
    assert _cli([str(path), "--solver", "handrolled", "--json", "--out", str(out), "--plot", str(png)]) == 0
    info = json.loads(capsys.readouterr().out)
    for k in ("gtsam_error", "sesync_objective", "iterations", "seconds"):
        assert k in info
    assert info["gtsam_error"] == pytest.approx(GTSAM_REF["gtsam/pose2example.txt"], rel=1e-6)
    assert pg.gtsam_error(io.read(out)) == pytest.approx(info["gtsam_error"], rel=1e-9)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert _cli([str(path), "--objective", "sesync"]) == 0
    assert "sesync_objective" in capsys.readouterr().out
