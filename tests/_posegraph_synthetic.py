"""Generated pose graphs for the pose-graph tests and benchmarks (fixed seeds, no files needed).

``chain_with_loops``: an odometry chain (one metre forward per pose, the heading turning by a
random walk) with loop edges that skip one pose, ``(i, i + 2)`` at random ``i``. The measurements
are the true relative poses plus Gaussian noise; the information is diagonal. With translation
precisions ~1e6 times the rotation precisions, GTSAM's LAGO / InitializePose3 give up on many of
these graphs ("indeterminate linear system", docs/posegraph.md).
"""

from __future__ import annotations

import numpy as np

from gtvo.core import lie
from gtvo.posegraph.graph import PoseGraph


def chain_with_loops(n: int, dim: int = 2, loops: int | None = None, sigma_t: float = 1e-3, sigma_r: float = 1.0,
                     noise_t: float | None = None, noise_r: float = 0.5, seed: int = 0) -> PoseGraph:
    """A ``dim``-D chain of ``n`` poses with ``loops`` (default ``n + 1``) loop edges ``(i, i + 2)``.

    The information is ``diag(1/sigma_t^2)`` on the translation and ``diag(1/sigma_r^2)`` on the
    rotation (GTSAM's tangent order); the noise added is ``noise_t`` (default ``sigma_t``) and
    ``noise_r`` (radians, per axis). The poses are the true ones (``has_vertices``).
    """
    rng = np.random.default_rng(seed)
    loops = n + 1 if loops is None else loops
    noise_t = sigma_t if noise_t is None else noise_t
    R = np.empty((n, dim, dim))
    t = np.zeros((n, dim))
    R[0] = np.eye(dim)
    step = np.eye(dim)[0]
    for k in range(1, n):
        turn = lie.rot2(rng.normal(0.0, 0.2)) if dim == 2 else lie.so3_exp(rng.normal(0.0, 0.2, (1, 3)))[0]
        t[k] = t[k - 1] + R[k - 1] @ step
        R[k] = R[k - 1] @ turn
    extra = rng.integers(0, n - 2, loops)
    ei = np.r_[np.arange(n - 1), extra]
    ej = np.r_[np.arange(1, n), extra + 2]
    m = len(ei)
    Rm = np.swapaxes(R[ei], 1, 2) @ R[ej]
    tm = np.einsum("mba,mb->ma", R[ei], t[ej] - t[ei]) + rng.normal(0.0, noise_t, (m, dim))
    if dim == 2:
        Rm = Rm @ lie.rot2(rng.normal(0.0, noise_r, m))
        diag = [1 / sigma_t**2] * 2 + [1 / sigma_r**2]
    else:
        Rm = Rm @ lie.so3_exp(rng.normal(0.0, noise_r, (m, 3)))
        diag = [1 / sigma_r**2] * 3 + [1 / sigma_t**2] * 3
    info = np.broadcast_to(np.diag(diag), (m, len(diag), len(diag))).copy()
    return PoseGraph(dim, np.arange(n), R, t, True, ei, ej, Rm, tm, info, source="chain_with_loops")
