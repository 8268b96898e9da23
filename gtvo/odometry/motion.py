"""The motion model of the odometry: the guess of each frame's pose before it is tracked.

:class:`MotionModel` predicts ``T_world_cam`` at a frame's time (:meth:`MotionModel.predict`) and
learns from every recorded frame (:meth:`MotionModel.update`). Two models (``motion_model.model``):

* ``constant-velocity``: the last good step, scaled to the time step (no state of its own: it reads
  the last two good frames of the :class:`gtvo.odometry.history.FrameHistory`, whose poses the
  window re-expresses);
* ``kalman``: the constant-acceleration Kalman filter of :mod:`gtvo.motion.model` on the planar
  pose ``(X, Z, theta)``, fed every good frame's pose (a lost frame's pose is the filter's own
  prediction: it only predicts over it; a ``wheel_carried`` frame's pose is the calibrated wheel
  odometry's, a measurement it fuses; suspect and frozen frames are never fed).
"""

from __future__ import annotations

import gtsam

from gtvo.config import MotionModelConfig
from gtvo.motion.model import (ConstantAccelerationFilter, T_world_cam_from_planar_pose,
                               planar_pose_from_T_world_cam)
from gtvo.odometry.estimates import FrameEstimate, FrameOutcome, rigid_pose
from gtvo.odometry.history import FrameHistory


class MotionModel:
    """Predicts a frame's pose from the frames before it.

    Args:
        config: the motion-model settings.
        history: the run's frames (read only).

    Attributes:
        kalman: the constant-acceleration filter (``model: kalman``), else None.
    """

    def __init__(self, config: MotionModelConfig, history: FrameHistory) -> None:
        self.config = config
        self.history = history
        self.kalman: ConstantAccelerationFilter | None = None
        if config.model == "kalman":
            self.kalman = ConstantAccelerationFilter(config.kalman_noise, config.kalman_initial_rate_sigmas)

    def predict(self, timestamp: float) -> gtsam.Pose3:
        """The guess of ``T_world_cam`` at ``timestamp`` (after the last recorded frame's)."""
        good = self.history.good(2)  # suspect and frozen frames are left out: the step spans them
        last = rigid_pose(good[-1].T_world_cam)
        if len(good) < 2:
            return last
        prev = rigid_pose(good[-2].T_world_cam)
        dt_prev = good[-1].timestamp - good[-2].timestamp
        dt = timestamp - good[-1].timestamp
        if self.kalman is not None and self.kalman.initialized:
            X, Z, theta = self.kalman.predict_pose(dt)
            return rigid_pose(T_world_cam_from_planar_pose(X, Z, theta, last.matrix()))
        # constant velocity, scaled to the time step
        xi = gtsam.Pose3.Logmap(prev.between(last)) * (dt / dt_prev if dt_prev > 0 else 1.0)
        return last.compose(gtsam.Pose3.Expmap(xi))

    def update(self, estimate: FrameEstimate) -> None:
        """Learn from ``estimate``, just recorded in the history (suspect and frozen frames are ignored)."""
        if self.kalman is None or estimate.excluded:
            return
        z = planar_pose_from_T_world_cam(estimate.T_world_cam)
        if not self.kalman.initialized:
            self.kalman.initialize(z)
            return
        good = self.history.good(2)
        dt = good[1].timestamp - good[0].timestamp  # over suspect frames, which it never saw
        if estimate.outcome is FrameOutcome.LOST:  # the pose is the filter's own prediction: nothing to fuse
            self.kalman.predict(dt)
        else:
            self.kalman.step(z, dt)
