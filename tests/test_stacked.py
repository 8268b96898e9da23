"""Python factors stacked into one GTSAM factor (factors.stacked): the same cost and rows, fewer
calls from GTSAM's optimiser (docs/refinement.md, "Cost")."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
import pytest

from factors.smart import HostPointsFactor
from factors.smoothness import ConstantVelocityFactor
from factors.stacked import StackedFactors, stacked
from gtvo.core.keys import pose_key as X
from gtvo.errors import InputError
from gtvo.refinement import RefineConfig
from gtvo.window import WindowConfig
from tests.test_factors_smart import plane_problem
from tests.test_refinement import keyframes, seq  # noqa: F401 (fixtures)
from tests._window_problem import refine


def _factors():
    cam, poses, imgs, px, d, rng = plane_problem()
    a = HostPointsFactor(X(0), [X(1), X(2)], cam, px, d * 1.02, imgs[0], imgs[1:], 1e-2, huber_k=3.0,
                         depth_prior=False)
    b = HostPointsFactor(X(0), [X(2)], cam, px[::2], d[::2] * 0.98, imgs[0], [imgs[2]], 1e-2, huber_k=None,
                         depth_prior=False)
    c = ConstantVelocityFactor(X(0), X(1), X(2), 0.1, 0.12, 0.5, 2.0)
    v = gtsam.Values()
    for i, T in enumerate(poses):
        v.insert(X(i), T.retract(rng.normal(0, 1e-3, 6)) if i else T)
    return [a, b, c], v


def test_the_stacked_factor_has_the_members_cost_and_rows():
    members, v = _factors()
    one = gtsam.NonlinearFactorGraph()
    for f in members:
        one.add(f)
    expected = one.error(v)
    H_expected = one.linearize(v).hessian()
    members, v = _factors()
    s = StackedFactors(members)
    assert s.keys() == [X(0), X(1), X(2)] and s.noiseModel().dim() == sum(m.noiseModel().dim() for m in members)
    g = gtsam.NonlinearFactorGraph()
    g.add(s)
    assert g.error(v) == pytest.approx(expected, rel=1e-12)
    H, eta = g.linearize(v).hessian()
    assert np.abs(H - H_expected[0]).max() <= 1e-10 * np.abs(H).max()
    assert np.abs(eta - H_expected[1]).max() <= 1e-10 * np.abs(eta).max()


def test_runs_and_refusals():
    members, _ = _factors()
    assert stacked(members, 1) == members
    runs = stacked(members, 2)
    assert isinstance(runs[0], StackedFactors) and runs[1] is members[2]
    with pytest.raises(InputError, match="at least one"):
        StackedFactors([])
    from factors.gtsam_factors import PhotometricFactor  # noqa: PLC0415

    cam, _, imgs, px, _, _ = plane_problem(n=3)
    huber = PhotometricFactor(X(0), X(1), 77, cam, px[0], imgs[0], imgs[1], 1e-2, huber_k=2.0)
    with pytest.raises(InputError, match="robust"):
        StackedFactors([members[2], huber])


def test_the_refinement_with_stacked_factors_reaches_the_same_keyframes(seq, keyframes):  # noqa: F811
    """Stacked runs of 3 (host factors and motion priors): the same start cost, and poses and depths
    within round-off of the unstacked graph's."""
    cam = seq.camera
    cfg = RefineConfig(max_iterations=3, max_scale_change=None)
    a = refine(cam.left, cam.baseline, keyframes, WindowConfig(), cfg)
    b = refine(cam.left, cam.baseline, keyframes, WindowConfig(), dataclasses.replace(cfg, stacked_factors=3))
    assert a.ran and b.ran and a.iterations == b.iterations
    assert b.cost_before == pytest.approx(a.cost_before, rel=1e-12)
    assert b.cost_after == pytest.approx(a.cost_after, rel=1e-8)
    for ka, kb in zip(a.keyframes, b.keyframes):
        assert np.abs(ka.pose.localCoordinates(kb.pose)).max() < 1e-8
        np.testing.assert_allclose(ka.inverse_depth, kb.inverse_depth, rtol=1e-7)
