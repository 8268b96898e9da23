"""The ``keyframes`` section: the thresholds of the rule that makes a tracked frame a keyframe
(:func:`gtvo.frontend.keyframes.needs_keyframe`)."""

from __future__ import annotations

from dataclasses import dataclass

from gtvo.core.settings import check_settings, setting


@dataclass(frozen=True)
class KeyframeConfig:
    """The thresholds of the keyframe rule (:mod:`gtvo.frontend.keyframes`); the defaults are DSO's where DSO has
    one. Any one condition makes a keyframe; 0 for a ``max_*`` makes every tracked frame one.

    Attributes:
        min_visible: fewer than this fraction of the keyframe's points still tracked (valid residuals).
        max_motion: ``|t_keyframe_frame| * median(d)`` (the translation relative to the median scene
            depth, about the parallax angle in radians) above this.
        max_flow: the RMS optical flow that the translation since the keyframe causes at its points
            above this fraction of ``width + height`` (DSO's rule: its translation weight
            0.04 (640 + 480) = 44.8 gives 25 px at VGA).
        max_rotation_deg: the rotation since the keyframe above this (degrees).
        max_brightness: ``|a_frame - a_keyframe|`` (log gain) above this.
    """

    min_visible: float = setting(0.7, "[0, 1]")
    max_motion: float = setting(0.3, "[0, inf]")
    max_flow: float = setting(1.0 / 44.8, "[0, inf]")
    max_rotation_deg: float = setting(8.0, "[0, inf]")
    max_brightness: float = setting(0.3, "[0, inf]")

    def __post_init__(self) -> None:
        check_settings(self)


