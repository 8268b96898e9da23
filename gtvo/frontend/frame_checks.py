"""Suspect frames: a tracked frame whose image contradicts a motion model that has been right.

A duplicated frame (the camera driver delivered the same image twice), two frames out of order,
or a stale buffer all track *successfully*: the images are real and sharp, only at the wrong time.
Tracking alone cannot see it. What gives them away is the motion: at frame ``k`` the motion model
predicts the step since the last good frame ``g``; a duplicated image shows no motion at all, a
frame from the future one step too many, and the frame after a swap goes back again.

The comparison is made in the image, at the latest keyframe's points ``X`` (so it is camera- and
rotation-aware, and independent of the scene's scale):

* ``predicted_px``: RMS displacement of the points' projections between the last good pose
  ``T_g`` and the predicted pose ``T_pred`` (the step the motion model expects);
* ``deviation_px``: RMS displacement between ``T_pred`` and the tracked pose ``T_k``;
* ``intervals = dt / dt_ref``: the time step in units of the last good step ``dt_ref`` (2 after
  one excluded frame); ``step_px = predicted_px / intervals`` is the image motion of one frame;
* ``deviation = deviation_px / step_px``: how far, in frame steps, the image is from where the
  model says it should be. A duplicated frame, a swapped pair (both frames, once the first is
  excluded and the second is predicted over two steps) and a frame repeated from further back
  all give about 1 or more; a real vehicle cannot change its speed by half in one frame interval.

A frame is *suspect* when ``deviation > max_deviation`` and the prediction is meaningful: the
step moves the points by at least ``min_step_px`` pixels (a standing or crawling camera is not
checked), the last ``agree_frames`` good frames each followed the model to within
``agree_deviation`` ("the motion model and its neighbours say the rig moved": handheld logs,
whose speed changes from frame to frame, disarm the check by themselves), the time step is at
most ``max_intervals`` frame steps, and fewer than ``max_consecutive`` frames in a row were
suspect (after that the model, not the images, is taken to be wrong: a real collision or stop is
accepted, with the check disarmed until the model agrees again).

The constants are about motion, not about one data set: 0.5 frame steps is a speed change of
50 % within one frame interval (a car at 10 Hz braking at 1 g from 50 km/h changes its speed by
7 %), the agreement of 0.15 steps over 3 frames keeps the check off whenever the recent motion was not smooth
enough for a prediction to mean anything. Measured (docs/evaluation.md, "Frame outcomes"): the
clean KITTI snippet's frames deviate by at most 0.04 frame steps, the handheld TUM teddy clip's by
0.19 to 1.1, so a handheld log does not arm the check and a vehicle's does.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.core.camera import PinholeCamera
from gtvo.config.sections.frame_checks import FrameCheckConfig
from gtvo.frontend.stereo_depth import KeyframePoints


@dataclass(frozen=True)
class StepCheck:
    """The image-motion figures of one tracked frame against its prediction (module docstring)."""

    predicted_px: float
    tracked_px: float
    deviation_px: float
    intervals: float
    #: mean dot product of the tracked and predicted per-point displacements from the last good
    #: frame, over the predicted step's squared RMS: 1 = as predicted, 0 = no motion, < 0 = backwards
    along: float

    @property
    def step_px(self) -> float:
        """Image motion of one frame step (px)."""
        return self.predicted_px / self.intervals if self.intervals > 0 else 0.0

    @property
    def deviation(self) -> float:
        """``deviation_px`` in frame steps (inf when the predicted step is zero)."""
        return self.deviation_px / self.step_px if self.step_px > 0 else float("inf")


def measure_step(camera: PinholeCamera, points: KeyframePoints, T_world_keyframe: gtsam.Pose3,
                 T_last: gtsam.Pose3, T_pred: gtsam.Pose3, T_tracked: gtsam.Pose3, intervals: float) -> StepCheck:
    """:class:`StepCheck` of a frame tracked at ``T_tracked`` (world poses of the left camera),
    measured at the keyframe's points seen in the last good frame's and the predicted image
    (points that leave the view or come close to the camera would dominate the RMS); points
    behind any of the three cameras are left out."""
    X_kf = camera.backproject_inverse_depth(points.pixels, points.inverse_depth)
    T = T_world_keyframe.matrix()
    X = X_kf @ T[:3, :3].T + T[:3, 3]
    uv_g, ok_g = _project(camera, X, T_last)
    uv_p, ok_p = _project(camera, X, T_pred)
    uv_t, ok_t = _project(camera, X, T_tracked)
    ok = ok_g & ok_p & ok_t & _inside(camera, uv_g) & _inside(camera, uv_p)
    if not np.any(ok):
        return StepCheck(0.0, 0.0, 0.0, intervals, 0.0)
    d_pred, d_trk = uv_p[ok] - uv_g[ok], uv_t[ok] - uv_g[ok]
    pred2 = float(np.mean(np.sum(d_pred * d_pred, axis=1)))
    along = float(np.mean(np.sum(d_pred * d_trk, axis=1))) / pred2 if pred2 > 0 else 0.0
    return StepCheck(predicted_px=float(np.sqrt(pred2)), tracked_px=_rms(d_trk), deviation_px=_rms(d_trk - d_pred),
                     intervals=float(intervals), along=along)


@dataclass
class FrameChecker:
    """The check's state over a run: the recent good frames' deviations and the suspect streak.

    Call :meth:`check` for every tracked frame (it returns the reason when the frame is
    suspect) and :meth:`not_checked` for frames that were not tracked (lost, re-initialised):
    they disarm the check until good frames agree with the model again.
    """

    settings: FrameCheckConfig = field(default_factory=FrameCheckConfig)
    recent: list[float] = field(default_factory=list)
    consecutive: int = 0

    def armed(self, step: StepCheck) -> bool:
        """True when ``step``'s prediction is meaningful enough to judge the frame by it."""
        s = self.settings
        agreed = self.recent[-s.agree_frames:]
        return (s.enabled and 0 < step.intervals <= s.max_intervals and step.step_px >= s.min_step_px
                and len(agreed) == s.agree_frames and max(agreed) <= s.agree_deviation
                and self.consecutive < s.max_consecutive)

    def check(self, step: StepCheck, last_good_index: int, previous_suspect: int | None = None) -> str | None:
        """The reason ``step``'s frame is suspect, or None (the frame is good and joins the history).
        ``previous_suspect``: the frame just before, when it was suspect."""
        if self.armed(step) and step.deviation > self.settings.max_deviation:
            self.consecutive += 1
            return suspect_reason(step, last_good_index, previous_suspect)
        self.consecutive = 0
        self.recent = (self.recent + [step.deviation])[-self.settings.agree_frames:]
        return None

    def not_checked(self) -> None:
        """A frame that was not tracked (its pose is a guess): the history starts again."""
        self.consecutive = 0
        self.recent = []


def suspect_reason(step: StepCheck, last_good_index: int, previous_suspect: int | None = None) -> str:
    """One line saying how a suspect frame's image motion contradicts the prediction
    (``previous_suspect``: the frame before it, when it was suspect too)."""
    figures = (f"{step.tracked_px:.1f} px of image motion since frame {last_good_index} against "
               f"{step.predicted_px:.1f} px predicted, {step.deviation:.2f} frame steps off")
    if step.tracked_px < 0.25 * step.step_px:
        return f"no image motion while the rig moved ({figures})"
    if previous_suspect is not None and step.along < 1:
        return f"motion reversed after suspect frame {previous_suspect} ({figures})"
    if step.along < 0:
        return f"motion reversed ({figures})"
    if step.along < 1:
        return f"image behind the motion model ({figures})"
    return f"image ahead of the motion model ({figures})"


def _project(camera: PinholeCamera, X_world: NDArray[np.float64], T_world_cam: gtsam.Pose3
             ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    T = T_world_cam.matrix()
    Xc = (X_world - T[:3, 3]) @ T[:3, :3]  # R^T (X - t)
    ok = Xc[:, 2] > 1e-6
    z = np.where(ok, Xc[:, 2], 1.0)
    uv = np.stack([camera.fx * Xc[:, 0] / z + camera.cx, camera.fy * Xc[:, 1] / z + camera.cy], axis=1)
    return uv, ok


def _inside(camera: PinholeCamera, uv: NDArray[np.float64]) -> NDArray[np.bool_]:
    return (uv[:, 0] >= 0) & (uv[:, 0] <= camera.width - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= camera.height - 1)


def _rms(d: NDArray[np.float64]) -> float:
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1)))) if len(d) else 0.0
