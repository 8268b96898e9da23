"""The frame checks of the odometry: is a tracked frame's image consistent with the motion so far?

:class:`FrameChecks` wraps the front end's :class:`gtvo.frontend.frame_checks.FrameChecker` with
what it needs from the run: the step from the last good frame to the tracked pose, measured in
image motion against the motion model's (:func:`gtvo.frontend.frame_checks.measure_step`). A frame
whose image contradicts a motion model that has been right (a duplicated, stale or out-of-order
image) is *suspect*; a frame whose image repeats the previous one's while the rig moves (a frozen
camera or a stuck driver: :func:`gtvo.frontend.frame_checks.image_change`) is *frozen*, decided
before tracking (docs/evaluation.md, "Frame outcomes").
"""

from __future__ import annotations

import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.core.camera import PinholeCamera
from gtvo.datasets.sequence import Frame
from gtvo.frontend.frame_checks import (FrameCheckConfig, FrameChecker, ImageFingerprint, fingerprint, image_change,
                                        measure_step)
from gtvo.odometry.estimates import FrameOutcome, Keyframe, rigid_pose
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
        self._previous: ImageFingerprint | None = None  # the previous frame's left image
        self._repeated = -1  # during a freeze: the frame whose image repeats

    def frozen(self, frame: Frame, left: NDArray[np.float32], kf: Keyframe, T_move: gtsam.Pose3,
               by_wheels: bool) -> str | None:
        """Why the frame with left image ``left`` is *frozen* (its image repeats the previous
        frame's while the rig moves), or None. ``T_move``: where the rig is taken to be, from the
        last good frame: the wheels' pose when ``by_wheels``, else the motion model's prediction.
        Call it for every frame after the first (it keeps the previous frame's image)."""
        current = fingerprint(left)
        previous, self._previous = self._previous, current
        if previous is None or previous.image.shape != current.image.shape or not self._checker.settings.enabled:
            return None
        change = image_change(previous, current)
        if change.motion_px > self._checker.settings.max_still_px:
            return None
        before = self.history.estimates[-1]
        continuing = before.outcome is FrameOutcome.FROZEN
        last = self.history.good(1)[0]
        step = measure_step(self.camera, kf.points, kf.T_world_cam, rigid_pose(last.T_world_cam), T_move, T_move,
                            self._intervals(frame))
        if not self._checker.frozen(change, step, by_wheels, continuing):
            return None
        # the motion model's agreement is stale after a freeze: the first frames after it are not
        # judged by a prediction across the gap (the suspect check re-arms once 3 good frames agree)
        self._checker.not_checked()
        if not continuing:
            self._repeated = before.index
        how = ("byte-identical" if change.identical
               else f"{change.motion_px:.2f} px of image motion beyond the noise of {change.noise:.1f} grey levels")
        moved = "" if continuing else (f"; the {'wheels' if by_wheels else 'motion model'} moved the rig by "
                                       f"{step.step_px:.1f} px per frame")
        return f"camera frozen: the image repeats frame {self._repeated} ({how} against frame {before.index}{moved})"

    def _intervals(self, frame: Frame) -> float:
        """The time since the last good frame in units of the good step before it (frame counts
        when the timestamps do not serve); 0 before there are two good frames."""
        good = self.history.good(2)
        if len(good) < 2:
            return 0.0
        dt, dt_ref = frame.timestamp - good[1].timestamp, good[1].timestamp - good[0].timestamp
        if not (np.isfinite(dt) and np.isfinite(dt_ref) and dt_ref > 0):  # no usable times: frame counts
            dt, dt_ref = frame.index - good[1].index, good[1].index - good[0].index
        return float(dt / dt_ref)

    def suspect(self, frame: Frame, kf: Keyframe, last: gtsam.Pose3, T_pred: gtsam.Pose3,
                T_tracked: gtsam.Pose3) -> str | None:
        """Why the frame tracked at ``T_tracked`` against ``kf`` is suspect, or None. ``last``: the
        last good frame's pose (moved along with a promoted keyframe); ``T_pred``: the prediction."""
        good = self.history.good(2)
        if len(good) < 2:  # no motion model yet
            return None
        step = measure_step(self.camera, kf.points, kf.T_world_cam, last, T_pred, T_tracked, self._intervals(frame))
        previous = self.history.estimates[-1]
        return self._checker.check(step, good[1].index, previous.index if previous.suspect else None)

    def not_checked(self) -> None:
        """A frame that was not checked (its tracking failed): the checks start again."""
        self._checker.not_checked()
