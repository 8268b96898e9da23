"""The visual-odometry driver: frames in, poses out (:class:`VisualOdometry`).

:mod:`gtvo.odometry.visual_odometry` holds the loop (docs/architecture.md, "The odometry loop");
:mod:`gtvo.odometry.estimates` what it says about each frame.
"""

from gtvo.odometry.estimates import FrameEstimate, FrameOutcome, Keyframe, frames_by_outcome, rigid_pose
from gtvo.odometry.visual_odometry import VisualOdometry

__all__ = ["FrameEstimate", "FrameOutcome", "Keyframe", "VisualOdometry", "frames_by_outcome", "rigid_pose"]
