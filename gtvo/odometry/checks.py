"""The frame checks of the odometry: is a tracked frame's image consistent with the motion so far?

:class:`FrameChecks` wraps the front end's :class:`gtvo.frontend.frame_checks.FrameChecker` with
what it needs from the run: the step from the last good frame to the tracked pose, measured in
image motion against the motion model's (:func:`gtvo.frontend.frame_checks.measure_step`). A frame
whose image contradicts a motion model that has been right (a duplicated, stale or out-of-order
image) is *suspect* (docs/evaluation.md, "Frame outcomes").
"""

from __future__ import annotations

import gtsam
import numpy as np

from gtvo.core.camera import PinholeCamera
from gtvo.datasets.sequence import Frame
from gtvo.frontend.frame_checks import FrameCheckConfig, FrameChecker, measure_step
from gtvo.odometry.estimates import Keyframe
from gtvo.odometry.history import FrameHistory


class FrameChecks:
    """Flags suspect frames (module docstring); owns the checker's state (whether it is armed).

    Args:
        config: the checks' settings.
        camera: the left camera.
        history: the run's frames (read only).
    """

    def __init__(self, config: FrameCheckConfig, camera: PinholeCamera, history: FrameHistory) -> None:
        self.camera = camera
        self.history = history
        self._checker = FrameChecker(config)

    def suspect(self, frame: Frame, kf: Keyframe, last: gtsam.Pose3, T_pred: gtsam.Pose3,
                T_tracked: gtsam.Pose3) -> str | None:
        """Why the frame tracked at ``T_tracked`` against ``kf`` is suspect, or None. ``last``: the
        last good frame's pose (moved along with a promoted keyframe); ``T_pred``: the prediction."""
        good = self.history.good(2)
        if len(good) < 2:  # no motion model yet
            return None
        dt, dt_ref = frame.timestamp - good[1].timestamp, good[1].timestamp - good[0].timestamp
        if not (np.isfinite(dt) and np.isfinite(dt_ref) and dt_ref > 0):  # no usable times: frame counts
            dt, dt_ref = frame.index - good[1].index, good[1].index - good[0].index
        step = measure_step(self.camera, kf.points, kf.T_world_cam, last, T_pred, T_tracked, dt / dt_ref)
        previous = self.history.estimates[-1]
        return self._checker.check(step, good[1].index, previous.index if previous.suspect else None)

    def not_checked(self) -> None:
        """A frame that was not checked (its tracking failed): the checks start again."""
        self._checker.not_checked()
