"""The ``tracking`` section: the settings of the coarse-to-fine frame tracker (:mod:`gtvo.frontend.tracking`)."""

from __future__ import annotations

from dataclasses import dataclass

from gtvo.core.settings import check_settings, setting


@dataclass(frozen=True)
class TrackingConfig:
    """Settings of the coarse-to-fine tracker (shared by both solvers; its photometric model,
    pattern, noise, Huber threshold and clipped range, is the :class:`factors.params.PhotometricConfig`
    its :class:`TrackingKeyframe` is given).

    Attributes:
        levels: pyramid levels used (level 0 = full resolution).
        max_iterations: LM iterations per level.
        estimate_affine: include the frame's affine brightness (a, b) in the state.
        step_tolerance: stop when the step is below this (pose in rad and m, log gain, offset b
            in units of 100 grey levels): 1e-5 rad moves a KITTI pixel by 0.007 px.
        max_rejections: consecutive rejected steps (lambda 0.2 .. 0.2 * 2^(n-1)) after which a
            level counts as converged (the model no longer predicts the cost at that scale).
        cost_tolerance: stop when an accepted step lowers the cost, or the Gauss-Newton model
            promises to lower it, by less than this fraction (GTSAM: relative error tolerance).
        min_valid_points: fewer points with a valid residual at level 0 is a failure.
        min_valid_fraction: a smaller fraction of the keyframe's points valid is a failure.
        max_rms: a whitened RMS residual per valid pixel above this at level 0 is a failure
            (the pose explains the images no better than noise of ``max_rms * sqrt(2) sigma_I``).
        max_outlier_fraction: more valid points than this fraction down-weighted by Huber at
            level 0 is a failure.
        max_abs_log_gain: a brightness gain ``|a| = |log(gain)|`` above this is a failure (a
            solver that explains an unrelated image by fading the keyframe out).
        max_rotation_sigma_deg: a rotation standard deviation (largest axis, from
            :attr:`TrackingResult.covariance`) above this is a failure: the images do not determine
            the rotation (few points, texture along one direction); the converged pose can then be
            tens of degrees off at a low residual.
        max_relative_rms: a :attr:`TrackingResult.relative_rms` above this is a failure: the pose
            leaves more than ``max_relative_rms ** 2`` of the mean-square residual an unrelated image
            would leave, so the images do not determine it (a dark or flat log, whose whole contrast is
            below ``sigma_intensity``: every pose passes ``max_rms`` there).
        lost_point_norm: a point whose pattern leaves the frame (or goes behind it) costs
            ``rho(lost_point_norm)`` (spread over its pattern pixels), like a strong outlier;
            without it a solver lowers the cost by pushing points out of the image (seen on
            KITTI's coarsest level: a 2.5 deg pitch error that dropped 40 of 334 points).
        coarse_decay: level ``l`` uses every ``ceil(coarse_decay^l)``-th point (at least
            ``min_coarse_points``): a coarse image has fewer pixels to constrain the pose and the
            points crowd there; the finest level always uses all points.
        min_coarse_points: lower bound of the points used on a coarse level.
    """

    levels: int = setting(4, "[1, 10]")
    max_iterations: int = setting(12, "[1, 1000]")
    estimate_affine: bool = True
    step_tolerance: float = setting(1e-5, "[0, 1]")
    cost_tolerance: float = setting(1e-3, "[0, 1]")
    max_rejections: int = setting(2, "[0, 100]")
    min_valid_points: int = setting(30, "[0, 100000]")
    min_valid_fraction: float = setting(0.1, "[0, 1]")
    max_rms: float = setting(2.0, "(0, inf]")
    max_outlier_fraction: float = setting(0.6, "[0, 1]")
    max_abs_log_gain: float = setting(1.0, "(0, inf]")
    max_rotation_sigma_deg: float = setting(1.0, "(0, inf]")
    max_relative_rms: float = setting(0.5, "(0, inf]")
    lost_point_norm: float = setting(6.0, "[0, 100]")
    coarse_decay: float = setting(2.0, "[1, 10]")
    min_coarse_points: int = setting(300, "[1, 100000]")

    def __post_init__(self) -> None:
        check_settings(self)


