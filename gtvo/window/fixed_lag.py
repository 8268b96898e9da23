"""The fixed-lag back end: the window kept in ``gtsam.IncrementalFixedLagSmoother`` (iSAM2).

Keyframe sequence numbers are the smoother's timestamps and its lag is ``size - 0.5``, so the
smoother marginalises a keyframe that leaves with its host factor (depths frozen in the marginal),
as docs/window.md ("Fixed-lag backend") describes.
"""

from __future__ import annotations

import time
import gtsam
import numpy as np

from gtvo.core.keys import affine_key, pose_key
from factors.smart import HostPointsFactor
from gtvo.window.covariance import marginals_of_smoother
from gtvo.window.config import WindowKeyframe, WindowResult
from gtvo.window.problem import SolvableWindow, host_factor


class FixedLagBackend:
    """Keeps the window's factors in an iSAM2 fixed-lag smoother across calls (``backend="fixed_lag"``)."""

    name = "fixed_lag"

    @staticmethod
    def solver_name(requested: str) -> str:
        """What runs whatever solver is requested: gtsam's iSAM2 (in the fixed-lag smoother)."""
        return "gtsam_isam2"

    def __init__(self) -> None:
        self._smoother: gtsam.IncrementalFixedLagSmoother | None = None
        self._stamp: dict[int, float] = {}
        self._next_stamp = 0
        self._host_slots: dict[int, tuple[int, HostPointsFactor]] = {}  # kf index -> (factor index, factor)
        self._added: set[tuple[int, ...]] = set()  # the keys of the non-host factors in the smoother

    def remove_oldest(self, window: SolvableWindow) -> WindowKeyframe:
        """Drop the oldest keyframe from the window's list: the smoother marginalises it at the next update."""
        return window.keyframes.pop(0)

    def optimize(self, window: SolvableWindow, targets: list[list[int]], solver: str = "gtsam") -> WindowResult:
        """One update of the fixed-lag smoother, then ``max_iterations - 1`` more (iSAM2 takes one
        Gauss-Newton step per update, relinearising every variable).

        The window's problem (:meth:`gtvo.window.problem.SolvableWindow.problem`) gives the factors:
        each non-host factor joins the smoother once (a new keyframe's affine prior, a new triple's
        motion prior, a caller's factor), the gauge prior at the first update.
        Each call removes the host factors of the keyframes still in the window and adds them again
        with the current targets and depths (a host gains the new keyframe as a target); the host
        factor of a keyframe that has left stays and is marginalised with its pose and affine by
        the smoother (its depths frozen inside the marginal, as :func:`marginalize` does).
        Residuals of remaining hosts' points in the leaving keyframe are dropped (as in the LM path).
        """
        del solver  # the smoother is GTSAM's: the LM solver choice does not apply
        t0 = time.perf_counter()
        cfg = window.config
        if self._smoother is None:
            params = gtsam.ISAM2Params()
            params.setRelinearizeThreshold(0.0)
            params.relinearizeSkip = 1
            self._smoother = gtsam.IncrementalFixedLagSmoother(float(cfg.size) - 0.5, params)
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        stamps: dict[int, float] = {}
        new = [kf for kf in window.keyframes if kf.index not in self._stamp]
        for kf in new:
            self._stamp[kf.index] = float(self._next_stamp)
            self._next_stamp += 1
            for key, val in ((pose_key(kf.index), kf.pose), (affine_key(kf.index), kf.affine)):
                values.insert(key, val)
                stamps[key] = self._stamp[kf.index]
        first = len(self._stamp) == len(new)
        problem = window.problem(targets)  # no rig offset, no wheels: the LM back end's
        factors = problem.factors
        for i in range(factors.size()):  # each non-host factor once (by its keys): a new keyframe's
            keys = tuple(factors.at(i).keys())  # affine prior, a new triple's motion prior
            if i not in problem.gauge_factors and keys not in self._added:
                self._added.add(keys)
                graph.add(factors.at(i))
        if first:  # gauge prior on the oldest keyframe, once (later the marginal fixes the gauge)
            for i in problem.gauge_factors:
                graph.add(factors.at(i))
        in_window = {kf.index for kf in window.keyframes}
        remove = [slot for idx, (slot, _) in self._host_slots.items() if idx in in_window]
        # the window's hosts are removed and added again below; a leaving keyframe's host factor
        # stays in the smoother and is marginalised by this update: either way no slot survives
        self._host_slots = {}
        added: list[tuple[int, HostPointsFactor]] = []
        for h, ts in enumerate(targets):
            if ts:
                f = host_factor(problem, h)
                graph.add(f)
                added.append((window.keyframes[h].index, f))
        n_prior = graph.size() - len(added)
        self._smoother.update(graph, values, stamps, remove)
        ind = list(self._smoother.getISAM2Result().getNewFactorsIndices())
        for (idx, f), slot in zip(added, ind[n_prior:]):
            self._host_slots[idx] = (int(slot), f)
        for _ in range(cfg.max_iterations - 1):
            self._smoother.update()
        est = self._smoother.calculateEstimate()
        pos = {kf.index: h for h, kf in enumerate(window.keyframes)}
        for idx, (_, f) in self._host_slots.items():
            window.keyframes[pos[idx]].inverse_depth = f.commit(est).copy()
        for kf in window.keyframes:
            kf.pose = est.atPose3(pose_key(kf.index))
            kf.affine = np.asarray(est.atVector(affine_key(kf.index)), dtype=float).copy()
        t_cov = time.perf_counter()
        covs = marginals_of_smoother(self._smoother, [kf.index for kf in window.keyframes]) if cfg.covariances else None
        t_cov = time.perf_counter() - t_cov
        n_res = sum(len(window.keyframes[h]) * len(ts) for h, ts in enumerate(targets))
        return WindowResult("fixed_lag", float("nan"), float("nan"), cfg.max_iterations,
                            time.perf_counter() - t0, n_res, covs, t_cov if covs is not None else 0.0)
