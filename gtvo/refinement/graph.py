"""The whole-log graph's parts that the window does not have: which keyframes a host is compared
with over the whole log (:func:`covisible_targets`), and the loop edges as factors (:func:`loop_factors`).

Everything else (the host factors, priors, motion prior, rig offset, wheels) is the window's own
problem, :class:`gtvo.window.problem.WindowProblem`, given every keyframe and these targets, with
the loop edges added to its graph (:func:`gtvo.refinement.solve.refinement_problem`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from gtvo.core.camera import PinholeCamera
from gtvo.core.keys import pose_key
from gtvo.loops.closure_graph import LoopEdge
from gtvo.window.config import WindowConfig, WindowKeyframe
from gtvo.window.problem import TargetChoice, visible_targets

if TYPE_CHECKING:
    from gtvo.config.sections.refine import RefineConfig

F64 = NDArray[np.float64]

#: Candidates per host: this many times ``max_targets`` of the keyframes whose camera centres are
#: nearest the host's, within :data:`CANDIDATE_DEPTH_FACTOR` times its far points' depth, plus
#: ``max_targets`` neighbours in time on each side; the projection test then picks the targets.
CANDIDATES_PER_TARGET = 4
#: The candidates' radius: this many times the host's 90th-percentile point depth.
CANDIDATE_DEPTH_FACTOR = 2.0


def candidate_targets(keyframes: Sequence[WindowKeyframe], max_targets: int) -> list[list[int]]:
    """Per host (position), the keyframes worth a projection test: the nearest camera centres
    (:data:`CANDIDATES_PER_TARGET` x ``max_targets``) within :data:`CANDIDATE_DEPTH_FACTOR` times
    the host's 90th-percentile point depth, and ``max_targets`` neighbours in time on each side.
    A k-d tree over the centres: O(K log K) in the number of keyframes, not the K^2 of testing every pair."""
    K = len(keyframes)
    if K < 2:
        return [[] for _ in keyframes]
    centres = np.array([np.asarray(kf.pose.translation(), dtype=float) for kf in keyframes])
    tree = cKDTree(centres)
    k = min(K, CANDIDATES_PER_TARGET * max_targets + 1)
    out = []
    for h, kf in enumerate(keyframes):
        d = kf.inverse_depth[kf.inverse_depth > 0]
        radius = CANDIDATE_DEPTH_FACTOR / float(np.quantile(d, 0.1)) if len(d) else np.inf
        dist, idx = tree.query(centres[h], k=k, distance_upper_bound=radius)
        near = {int(i) for i, r in zip(np.atleast_1d(idx), np.atleast_1d(dist)) if np.isfinite(r) and i < K}
        near.update(range(max(0, h - max_targets), min(K, h + max_targets + 1)))
        near.discard(h)
        out.append(sorted(near))
    return out


def window_candidates(n_keyframes: int, span: int, loops: Sequence[tuple[int, int]] = ()) -> list[list[int]]:
    """Per host (position), the keyframes the window could have compared it with: those at most
    ``span`` positions before or after it (a window of ``span + 1`` keyframes). A revisit far in
    time is a candidate only across a verified loop: for each ``(i, j)`` of ``loops`` (positions of
    an accepted loop edge's keyframes) the hosts within ``span`` of ``i`` get those within ``span``
    of ``j`` and the other way round (the photometric loop term, where the overlap allows)."""
    out = [set(range(max(0, h - span), min(n_keyframes, h + span + 1))) for h in range(n_keyframes)]
    for i, j in loops:
        for a, b in ((i, j), (j, i)):
            near_b = range(max(0, b - span), min(n_keyframes, b + span + 1))
            for h in range(max(0, a - span), min(n_keyframes, a + span + 1)):
                out[h].update(near_b)
    return [sorted(c - {h}) for h, c in enumerate(out)]


def scale_change(camera: PinholeCamera, host: WindowKeyframe, target: WindowKeyframe) -> float:
    """How much bigger or smaller the host's points look in the target: the median, over its points
    with a positive inverse depth that are in front of the target, of ``|log(z_host / z_target)|``
    (the magnification of the residual pattern, which the photometric model compares unwarped);
    inf when no point qualifies."""
    ok = host.inverse_depth > 0
    if not np.any(ok):
        return float("inf")
    z_h = 1.0 / host.inverse_depth[ok]
    px = host.pixels[ok]
    X = np.column_stack([(px[:, 0] - camera.cx) / camera.fx * z_h, (px[:, 1] - camera.cy) / camera.fy * z_h, z_h])
    T = target.pose.inverse().compose(host.pose).matrix()  # T_target_host
    z_t = X @ T[2, :3] + T[2, 3]
    front = z_t > 0
    if not np.any(front):
        return float("inf")
    return float(np.median(np.abs(np.log(z_h[front] / z_t[front]))))


def covisible_targets(camera: PinholeCamera, keyframes: Sequence[WindowKeyframe], config: WindowConfig,
                      refine: RefineConfig, loops: Sequence[tuple[int, int]] = ()) -> list[list[int]]:
    """Per host (position in ``keyframes``), its targets over the whole log: among the candidates
    (the refinement's ``candidates``: ``window``, :func:`window_candidates` over the window's span,
    ``config.size - 1``, and across the ``loops``, pairs of positions; ``space``:
    :func:`candidate_targets`) (and, with its ``max_scale_change``, those in which its points look
    at most that much bigger or smaller, :func:`scale_change`), those into which enough of its
    points project (:func:`gtvo.window.problem.visible_targets`, the window's rule), at most its
    ``max_targets`` (those that see most of them)."""
    max_targets, max_scale_change = refine.max_targets, refine.max_scale_change
    tried = (window_candidates(len(keyframes), config.size - 1, loops) if refine.candidates == "window"
             else candidate_targets(keyframes, max_targets))
    if max_scale_change is not None:
        tried = [[t for t in ts if scale_change(camera, keyframes[h], keyframes[t]) <= max_scale_change]
                 for h, ts in enumerate(tried)]
    return visible_targets(camera, keyframes, config, TargetChoice(candidates=tried, max_targets=max_targets))


def loop_factor(edge: LoopEdge) -> gtsam.BetweenFactorPose3:
    """A loop edge between the keyframes of frames ``edge.i`` and ``edge.j`` (frame indices, not
    positions: :attr:`gtvo.loops.closing.LoopClosingResult.measured_edges`) as a
    ``BetweenFactorPose3`` on their pose keys."""
    T = np.asarray(edge.T_i_j, dtype=float)
    info = np.asarray(edge.information, dtype=float)
    measured = gtsam.Pose3(gtsam.Rot3.ClosestTo(T[:3, :3]), T[:3, 3])
    return gtsam.BetweenFactorPose3(pose_key(edge.i), pose_key(edge.j), measured,
                                    gtsam.noiseModel.Gaussian.Information(0.5 * (info + info.T)))


def loop_factors(edges: Sequence[LoopEdge]) -> gtsam.NonlinearFactorGraph:
    """Every loop edge as a factor (:func:`loop_factor`), in order."""
    graph = gtsam.NonlinearFactorGraph()
    for e in edges:
        graph.add(loop_factor(e))
    return graph


def window_edges(keyframes: Sequence[WindowKeyframe], covariances: Sequence[F64 | None]) -> list[LoopEdge]:
    """The window's answer as edges: per pair of consecutive keyframes, their relative pose as the
    window left it, with the tracker's covariance of that pair (``covariances[k]`` for
    ``keyframes[k]`` and ``keyframes[k + 1]``, :func:`gtvo.loops.closing.odometry_covariances`;
    None or not finite: no edge). The tracker's covariance is an upper bound of the window's
    (its joint refinement only adds information), so the edge holds the whole-log graph near the
    window's local shape no harder than the odometry alone would (docs/refinement.md)."""
    out = []
    for a, b, cov in zip(keyframes[:-1], keyframes[1:], covariances):
        if cov is None or not np.all(np.isfinite(cov)):
            continue
        out.append(LoopEdge(a.index, b.index, a.pose.between(b.pose).matrix(), np.linalg.inv(np.asarray(cov, float))))
    return out


def loop_chi2(edges: Sequence[LoopEdge], keyframes: Sequence[WindowKeyframe]) -> F64:
    """Per loop edge, its whitened squared error at the keyframes' poses."""
    values = gtsam.Values()
    for kf in keyframes:
        values.insert(pose_key(kf.index), kf.pose)
    return np.array([2.0 * loop_factor(e).error(values) for e in edges], dtype=float)
