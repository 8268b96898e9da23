"""The visual-odometry driver: frames in, poses out (:class:`VisualOdometry`).

:mod:`gtvo.odometry.visual_odometry` holds the loop (docs/architecture.md, "The odometry loop"),
composed of parts that own their state: the frame history (:mod:`~gtvo.odometry.history`), the
motion model (:mod:`~gtvo.odometry.motion`), the frame tracker (:mod:`~gtvo.odometry.frame_tracking`),
the frame checks (:mod:`~gtvo.odometry.checks`) and the keyframer with the window's schedule
(:mod:`~gtvo.odometry.keyframer`, :mod:`~gtvo.odometry.window_schedule`);
:mod:`gtvo.odometry.estimates` is what it says about each frame, :mod:`gtvo.odometry.view` what
observers may read, :mod:`gtvo.odometry.result` the one value it hands to the rest of a run.
"""

from gtvo.odometry.estimates import FrameEstimate, FrameOutcome, Keyframe, frames_by_outcome, rigid_pose
from gtvo.odometry.view import OdometryView, TrackedPoints
from gtvo.odometry.visual_odometry import VisualOdometry

__all__ = ["FrameEstimate", "FrameOutcome", "Keyframe", "OdometryView", "TrackedPoints", "VisualOdometry",
           "frames_by_outcome", "rigid_pose"]
