"""The settings of the whole-log refinement, the tree's ``refine`` section: :class:`RefineConfig`
(docs/refinement.md, docs/configuration.md)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from gtvo.config.sections.loops import CHI2_6DOF_99
from gtvo.core.settings import check_settings, setting


@dataclass(frozen=True)
class RefineConfig:
    """The whole-log refinement after the window pass (:mod:`gtvo.refinement`, docs/refinement.md).

    Attributes:
        enabled: after the window pass (and loop closing), optimise one graph over every keyframe:
            each host's points against every keyframe that sees them, stereo terms, affine priors,
            motion prior, the rig offset and the accepted loop edges; non-keyframes are then
            re-placed against the refined keyframes (gtvo run --no-refine turns it off; window mode only).
        solver: ``gtsam`` (GTSAM's Levenberg-Marquardt on the window's smart factors) or
            ``handrolled`` (the window's hand-rolled LM: a dense reduced system, for small logs).
        max_iterations: at most this many LM iterations of the whole-log graph (the relative
            tolerance ends it sooner: measured, 5 left the cost falling and the synthetic turn 1.04x
            its window's keyframe ATE, 20 gave 0.76x; docs/refinement.md).
        relative_tolerance: stop when an iteration lowers the cost by less than this fraction.
        candidates: which keyframes a host may be compared with: ``window`` (those at most
            ``window.size - 1`` keyframes before or after it, the pairs the window could have used;
            a revisit comes in as a loop edge) or ``space`` (also those whose camera centres are
            near, far in time: measured to pull the synthetic turn 2.2x away from the truth,
            docs/refinement.md).
        window_edges: the window's relative pose between consecutive keyframes joins the graph
            as a ``BetweenFactorPose3`` with the tracker's covariance of the pair (an upper bound of
            the window's: the graph keeps the window's local shape where the images barely fix the
            poses; docs/refinement.md).
        max_targets: at most this many keyframes per host (those that see most of its points).
        max_scale_change: a keyframe is a host's target only when the host's points look at most
            this much bigger or smaller there (median ``|log(z_host / z_target)|``): the residual
            pattern is compared unwarped, so a zoomed view biases the residuals (measured: more and
            farther targets pulled KITTI_sequence_1's scale; docs/refinement.md); null: no limit.
        loop_chi2: a loop edge whose whitened squared error after the refinement exceeds this
            (default: the 99 % quantile of chi-square, 6 degrees of freedom) is dropped and the graph
            solved again without it.
        jacobian_cache_mb: MiB of the host factors' Jacobians kept from a cost pass for the
            linearisation that follows (the rest are evaluated again: the same result, more time);
            bounds the graph's memory on long logs (docs/refinement.md, "Cost").
        image_cache_mb: MiB of the keyframes' packed image records (16 bytes a pixel) held at once
            while the graph is solved; the keyframes that left the window keep their grey levels
            alone and are packed again when sampled beyond it (the same result, more time;
            docs/refinement.md, "Cost").
        stacked_factors: GTSAM's LM: the host factors and the motion priors in runs of this many,
            each run one GTSAM factor (the same cost and rows): GTSAM copies the Values for every
            call of a Python factor, a part that grows as the square of the keyframes
            (docs/refinement.md, "Cost"); 1: one factor each, as the window.
    """

    enabled: bool = False
    solver: Literal["gtsam", "handrolled"] = "gtsam"
    max_iterations: int = setting(20, "[1, 1000]")
    relative_tolerance: float = setting(1e-4, "[0, 1]")
    candidates: Literal["window", "space"] = "window"
    window_edges: bool = True
    max_targets: int = setting(6, "[1, 1000]")
    max_scale_change: float | None = setting(0.25, "(0, 10]")
    loop_chi2: float = setting(CHI2_6DOF_99, "(0, 1000000]")
    jacobian_cache_mb: int = setting(512, "[0, 1000000]")
    image_cache_mb: int = setting(512, "[0, 1000000]")
    stacked_factors: int = setting(16, "[1, 1000]")

    def __post_init__(self) -> None:
        check_settings(self)
