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

**Frozen frames** (:func:`image_change`, :meth:`FrameChecker.frozen`). A camera driver that keeps
delivering its last image (byte-identical, or with fresh sensor noise) shows no image motion at
all, for as many frames as the fault lasts; the suspect check above stops after
``max_consecutive`` frames and would then accept the repeats at the repeated frame's pose. So a
cheaper test runs first, before tracking, on the image alone: the difference to the previous
frame's image, with the noise of both images subtracted, converted into the RMS image motion
(px) that would cause it (:func:`image_change`). A frame is *frozen* when that motion is at most
``max_still_px`` while the rig is known to move at the latest keyframe's points: the wheels say
it moves by at least twice ``max_still_px`` per frame (with wheel odometry, whose word decides: a
standing robot's wheels stand), or, without wheels, the motion model predicts at least
``min_step_px`` per frame (a crawl could stop within a frame) and either the image is
byte-identical to the previous one (a real sensor's noise never repeats) or the motion model has
been right (the same agreement that arms the suspect check: a vehicle, which cannot stop from
speed to no motion at all within one frame interval). Once frozen, every following frame whose
image is still the same is frozen too, however long the fault lasts. A standing rig (a small
predicted step, or standing wheels) is never frozen: its images are still because it stands.

The constants are about motion, not about one data set: 0.5 frame steps is a speed change of
50 % within one frame interval (a car at 10 Hz braking at 1 g from 50 km/h changes its speed by
7 %), the agreement of 0.15 steps over 3 frames keeps the check off whenever the recent motion was not smooth
enough for a prediction to mean anything. Measured (docs/evaluation.md, "Frame outcomes"): the
clean KITTI snippet's frames deviate by at most 0.04 frame steps, the handheld TUM teddy clip's by
0.19 to 1.1, so a handheld log does not arm the check and a vehicle's does.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.core.camera import PinholeCamera
from gtvo.config.sections.frame_checks import FrameCheckConfig
from gtvo.frontend.image_noise import image_noise_sigma
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


@dataclass(frozen=True)
class ImageChange:
    """How much a frame's image changed from the previous frame's (:func:`image_change`).

    Attributes:
        identical: the two images are byte-identical.
        motion_px: the RMS image motion (px) that would explain the difference beyond the noise
            (0 when the difference is all noise).
        noise: the estimated standard deviation of the difference's noise (grey levels).
    """

    identical: bool
    motion_px: float
    noise: float


#: The least ``ImageFingerprint.texture`` ((grey levels / px)^2) in which image motion can be seen:
#: an RMS gradient of 0.3 grey levels per px beyond the noise (KITTI_sequence_1: 378 as recorded,
#: 0.98 at a twentieth of its exposure, 0.07 at a hundredth; a black or a uniform noisy frame 0).
MIN_TEXTURE = 0.1


@dataclass(frozen=True)
class ImageFingerprint:
    """What :func:`image_change` needs of one image, computed once per frame (:func:`fingerprint`).

    Attributes:
        image: the grey-level image as given (for the byte-identity test).
        small: the image averaged over 2x2 blocks (half the size: four times less work, half the noise).
        noise: :func:`image_noise_sigma` of ``small`` (grey levels).
        texture: the mean squared gradient of ``small`` less its noise's share ((grey levels / px)^2).
    """

    image: NDArray[np.float32]
    small: NDArray[np.float32]
    noise: float
    texture: float


def fingerprint(image: NDArray[np.float32]) -> ImageFingerprint:
    """The :class:`ImageFingerprint` of a grey-level image (at least 6x6 pixels)."""
    img = np.asarray(image, dtype=np.float32)
    h, w = (img.shape[0] // 2) * 2, (img.shape[1] // 2) * 2
    small = cv2.resize(img[:h, :w], (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    noise = image_noise_sigma(small)
    gx = 0.5 * (small[1:-1, 2:] - small[1:-1, :-2])
    gy = 0.5 * (small[2:, 1:-1] - small[:-2, 1:-1])
    texture = float(np.mean(gx * gx + gy * gy)) - noise * noise  # central differences: noise^2 / 2 each
    return ImageFingerprint(img, small, noise, max(texture, 0.0))


def image_change(previous: ImageFingerprint, current: ImageFingerprint) -> ImageChange:
    """How much ``current`` moved against ``previous`` (fingerprints of two images of one size),
    from their difference alone (no tracking).

    For a small image motion ``u`` the difference is ``d = I_k - I_{k-1} = -grad(I) . u + n``, so
    ``E[d^2] = |u|^2 E[|grad I|^2] / 2 + sigma_d^2`` (gradients of no preferred direction) with the
    noise ``sigma_d^2 = sigma_{k-1}^2 + sigma_k^2`` (:func:`image_noise_sigma` of each image):
    ``motion_px = 2 sqrt(max(0, mean(d^2) - sigma_d^2) / (texture / 2))`` on the half-size images
    (2: back to full-size pixels). A motion larger than the image's texture scale saturates it at
    a few pixels, far above anything still; a repeated image, with or without fresh noise, gives
    about 0. Two views without texture (``texture`` below :data:`MIN_TEXTURE`: blank, covered or
    black frames, which tracking finds lost) show no motion either way: ``motion_px`` is infinite
    for them, never still (measured on KITTI: 0 for copies with noise of sigma 1 to 8 grey levels, 0.29 for a
    0.3 px shift, 1.2 for 1 px, 4.7 between two frames 1.2 m apart)."""
    if previous.image.shape != current.image.shape:
        raise ValueError(f"images of different sizes: {previous.image.shape} and {current.image.shape}")
    identical = bool(np.array_equal(previous.image, current.image))
    if min(previous.texture, current.texture) < MIN_TEXTURE:  # a blank or covered view shows no motion
        return ImageChange(identical, float("inf"), float(np.hypot(previous.noise, current.noise)))
    if identical:
        return ImageChange(True, 0.0, 0.0)
    d = (current.small - previous.small)[1:-1, 1:-1]
    noise2 = previous.noise ** 2 + current.noise ** 2
    excess = max(float(np.mean(d * d)) - noise2, 0.0)
    if excess == 0.0:
        return ImageChange(False, 0.0, float(np.sqrt(noise2)))
    motion = 2.0 * np.sqrt(excess / (0.5 * previous.texture)) if previous.texture > 0 else float("inf")
    return ImageChange(False, float(motion), float(np.sqrt(noise2)))


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
        return (s.enabled and 0 < step.intervals <= s.max_intervals and step.step_px >= s.min_step_px
                and self.agreed() and self.consecutive < s.max_consecutive)

    def check(self, step: StepCheck, last_good_index: int, previous_suspect: int | None = None) -> str | None:
        """The reason ``step``'s frame is suspect, or None (the frame is good and joins the history).
        ``previous_suspect``: the frame just before, when it was suspect."""
        if self.armed(step) and step.deviation > self.settings.max_deviation:
            self.consecutive += 1
            return suspect_reason(step, last_good_index, previous_suspect)
        self.consecutive = 0
        self.recent = (self.recent + [step.deviation])[-self.settings.agree_frames:]
        return None

    def agreed(self) -> bool:
        """True when the last ``agree_frames`` good frames each followed the motion model to within
        ``agree_deviation`` frame steps (the model has been right: a vehicle's smooth motion)."""
        s = self.settings
        agreed = self.recent[-s.agree_frames:]
        return len(agreed) == s.agree_frames and max(agreed) <= s.agree_deviation

    def frozen(self, change: ImageChange, step: StepCheck, by_wheels: bool, continuing: bool) -> bool:
        """Whether a frame whose image changed by ``change`` from the previous frame's is *frozen*
        (module docstring): still (``motion_px <= max_still_px``) and either ``continuing`` (the
        previous frame was frozen) or the rig moved by ``step`` (the wheels' step when
        ``by_wheels``, else the motion model's) at least ``min_step_px`` per frame, said by the
        wheels (a step of at least twice ``max_still_px``), by a byte-identical image or by a
        motion model that has been right."""
        s = self.settings
        if not s.enabled or change.motion_px > s.max_still_px:
            return False
        if continuing:
            return True
        # the wheels measure the motion: a step of twice the still bound says it moves; a prediction
        # must be a clear step (min_step_px), a crawl could stop within a frame
        if not (0 < step.intervals and step.step_px >= (2 * s.max_still_px if by_wheels else s.min_step_px)):
            return False
        return by_wheels or change.identical or self.agreed()

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
