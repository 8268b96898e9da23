"""The ``frame_checks`` section: the thresholds of the suspect-frame check (:mod:`gtvo.frontend.frame_checks`)."""

from __future__ import annotations

from dataclasses import dataclass

from gtvo.core.settings import check_settings, setting


@dataclass(frozen=True)
class FrameCheckConfig:
    """Thresholds of the suspect-frame check (:mod:`gtvo.frontend.frame_checks`).

    Attributes:
        enabled: false turns the checks off (no frame is ever suspect or frozen).
        max_deviation: a frame is suspect when its tracked image is further than this many frame
            steps from the predicted one (0.5: a 50 % speed change within one frame interval).
        agree_deviation: the check is armed only when each of the last ``agree_frames`` good
            frames deviated by at most this many frame steps (0.15).
        agree_frames: how many recent good frames must agree (3).
        min_step_px: the check is armed only when one predicted frame step moves the keyframe's
            points by at least this RMS (3 px): below it, tracking noise is a large fraction of
            the step.
        max_intervals: the check is armed only when the time since the last good frame is at
            most this many frame steps (4.5: up to ``max_consecutive`` excluded frames, e.g. a
            camera frozen for three frames; longer gaps make the prediction too loose).
        max_consecutive: at most this many frames in a row are flagged (3); the next one is
            accepted whatever it shows.
        max_still_px: a frame whose image differs from the previous frame's by no more than this
            RMS image motion (px, :func:`gtvo.frontend.frame_checks.image_change`) while the rig
            moves is *frozen* (0.5: a sixth of the smallest step the check judges, ``min_step_px``).
    """

    enabled: bool = True
    max_deviation: float = setting(0.5, "(0, 100]")
    agree_deviation: float = setting(0.15, "(0, 100]")
    agree_frames: int = setting(3, "[1, 1000]")
    min_step_px: float = setting(3.0, "(0, 10000]")
    max_intervals: float = setting(4.5, "(0, 1000]")
    max_consecutive: int = setting(3, "[1, 1000]")
    max_still_px: float = setting(0.5, "(0, 100]")

    def __post_init__(self) -> None:
        check_settings(self)


