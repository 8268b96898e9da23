"""The settings of loop closing, the ``loops`` section of a run's configuration tree:
:class:`LoopClosureConfig` (whether it runs, and the detector's settings), :class:`LoopDetectorConfig`,
:class:`OrbConfig` and :class:`VerificationConfig` (docs/loop_closure.md, docs/configuration.md).
Each field's default and range are declared once, beside it (:func:`gtvo.core.settings.setting`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from gtvo.core.settings import check_settings, setting

#: The 99 % quantile of chi-square with 6 degrees of freedom: the test of a loop edge (a 6-dof
#: relative pose) against its covariance.
CHI2_6DOF_99 = 16.812


@dataclass(frozen=True)
class OrbConfig:
    """ORB detector settings (``cv2.ORB_create``).

    Attributes:
        n_features: keypoints kept per image.
        scale_factor: pyramid scale between ORB octaves; a keypoint of octave ``o`` is located to
            about ``scale_factor ** o`` pixels, which sets its pixel noise.
        n_levels: ORB pyramid levels.
        fast_threshold: FAST corner threshold (8-bit intensity units).
        edge_threshold: border (pixels) where no keypoint is detected (also ORB's patch size).
    """

    n_features: int = setting(1000, "[10, 100000]")
    scale_factor: float = setting(1.2, "(1, 2]")
    n_levels: int = setting(8, "[1, 16]")
    fast_threshold: int = setting(20, "[1, 255]")
    edge_threshold: int = setting(31, "[3, 255]")

    def __post_init__(self) -> None:
        check_settings(self)

    def create(self) -> Any:
        """A configured ``cv2.ORB`` detector."""
        import cv2  # noqa: PLC0415 (the settings themselves do not need OpenCV)

        return cv2.ORB_create(nfeatures=int(self.n_features), scaleFactor=float(self.scale_factor),
                              nlevels=int(self.n_levels), edgeThreshold=int(self.edge_threshold),
                              patchSize=int(self.edge_threshold), fastThreshold=int(self.fast_threshold))


@dataclass(frozen=True)
class VerificationConfig:
    """Thresholds of :func:`gtvo.loops.match_descriptors` and :func:`gtvo.loops.verify_pnp`.

    Attributes:
        ratio: Lowe ratio test, best / second-best Hamming distance must be below it.
        max_hamming: largest accepted Hamming distance of a match (of 256 bits).
        reprojection_threshold_px: RANSAC and final inlier threshold (pixels).
        ransac_iterations: RANSAC iterations of ``cv2.solvePnPRansac``.
        ransac_confidence: RANSAC confidence.
        min_inliers: a loop needs at least this many PnP inliers.
        min_inlier_ratio: and at least this fraction of the matches as inliers.
        pixel_sigma_px: keypoint noise at octave 0; octave ``o`` has ``pixel_sigma_px * s**o``.
        ransac_seed: seed of OpenCV's global RNG set before each RANSAC (reproducible results).
        min_rotation_sigma_rad, min_translation_sigma_m: a covariance floor
            ``diag(sr^2 I3, st^2 I3)`` added to ``inv(Lambda)`` for the errors the reprojection model
            leaves out (calibration, rolling shutter, keypoint bias); see docs/loop_closure.md.
    """

    ratio: float = setting(0.8, "(0, 1]")
    max_hamming: float = setting(64.0, "[0, 256]")
    reprojection_threshold_px: float = setting(3.0, "(0, 100]")
    ransac_iterations: int = setting(300, "[1, 100000]")
    ransac_confidence: float = setting(0.999, "(0, 1)")
    min_inliers: int = setting(30, "[4, 100000]")
    min_inlier_ratio: float = setting(0.3, "[0, 1]")
    pixel_sigma_px: float = setting(1.0, "(0, 100]")
    ransac_seed: int = setting(0, "[0, 2147483647]")
    min_rotation_sigma_rad: float = setting(0.002, "[0, 3.2]")
    min_translation_sigma_m: float = setting(0.01, "[0, 1000]")

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class LoopDetectorConfig:
    """Settings of :class:`gtvo.loops.LoopDetector` (defaults follow DBoW2 / ORB-SLAM2 where they exist).

    Attributes:
        orb: ORB detector settings.
        verification: matching and PnP thresholds.
        n_words: vocabulary size (flat k-majority vocabulary).
        vocabulary_iterations: k-majority iterations per training.
        min_training_keyframes: the vocabulary is first trained once this many keyframes exist.
        max_training_descriptors: descriptors sampled (uniformly, seeded) for a training.
        temporal_window: the last N keyframes inserted before a query are never candidates.
        reference_neighbours: the reference score is the best score of the query with its
            this-many immediately preceding keyframes.
        min_reference_score: floor on the reference score (avoids dividing by ~0 after a
            sudden view change).
        min_normalised_score: DBoW2's alpha; a candidate needs ``eta`` at least this.
        island_gap: candidates whose insertion ranks differ by at most this form one island.
        max_candidates: islands verified per query (best island score first).
        stereo_max_hamming: Hamming threshold of left-right ORB matching.
        disparity_sigma_px: disparity noise of stereo points (pixels).
        depth_noise_per_m: depth-image noise ``sigma_z = depth_noise_per_m * z^2``.
        seed: random seed of the vocabulary training.
    """

    orb: OrbConfig = field(default_factory=OrbConfig)
    verification: VerificationConfig = field(default_factory=VerificationConfig)
    n_words: int = setting(500, "[1, 1000000]")
    vocabulary_iterations: int = setting(8, "[1, 1000]")
    min_training_keyframes: int = setting(4, "[1, 100000]")
    max_training_descriptors: int = setting(20000, "[1, 10000000]")
    temporal_window: int = setting(10, "[0, 100000]")
    reference_neighbours: int = setting(3, "[1, 1000]")
    min_reference_score: float = setting(0.02, "[0, 1]")
    min_normalised_score: float = setting(0.3, "[0, 100]")
    island_gap: int = setting(2, "[0, 100000]")
    max_candidates: int = setting(3, "[1, 1000]")
    stereo_max_hamming: float = setting(75.0, "[0, 256]")
    disparity_sigma_px: float = setting(0.5, "[0, 100]")
    depth_noise_per_m: float = setting(0.003, "[0, 1]")
    seed: int = setting(0, "[0, 2147483647]")

    def __post_init__(self) -> None:
        check_settings(self)


@dataclass(frozen=True)
class LoopClosureConfig:
    """Loop closing after the odometry (:mod:`gtvo.loops.closing`, docs/loop_closure.md).

    Attributes:
        enabled: after the run, detect loops among the keyframes, optimise the keyframe pose graph
            robustly (GNC), re-estimate every tracked frame against the final keyframes and write
            trajectory_loop_closed.tum as a second output (gtvo run --loop-closure sets it).
        detector: place recognition (ORB bag of words) and the geometric verification of a loop.
    """

    enabled: bool = False
    detector: LoopDetectorConfig = field(default_factory=LoopDetectorConfig)

    def __post_init__(self) -> None:
        check_settings(self)
