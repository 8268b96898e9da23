"""What an observer of a run may read: :class:`OdometryView`, made by the odometry after each frame.

Observers (:class:`gtvo.io.observer.RunObserver`, e.g. the Rerun logger) get data, not the
system (DSO's ``Output3DWrapper`` gets keyframes and the calibration, never ``FullSystem``). The
view's fields are copies taken when it is made; its methods compute copies on demand from the
odometry's state at that moment (the map of every keyframe is too large to copy at every frame).
An observer keeps a view only while it handles that frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from factors.gtsam_factors import DEFAULT_HUBER_K
from gtvo.frontend.tracking import point_residuals
from gtvo.odometry.estimates import Keyframe

if TYPE_CHECKING:
    from factors.params import PhotometricConfig
    from gtvo.odometry.frame_tracking import Track
    from gtvo.odometry.history import FrameHistory
    from gtvo.odometry.keyframer import Keyframer

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class TrackedPoints:
    """The points of the keyframe a frame was tracked against, where the frame sees them.

    Attributes:
        keyframe_index: the keyframe's frame index.
        pixels: (M, 2) the points' pixels in the frame.
        X_world: (M, 3) the points in the world (the keyframe's current pose and depths).
        residual: (M,) the tracker's RMS photometric residual of each point at its solution (grey
            levels; :func:`gtvo.frontend.tracking.point_residuals`).
    """

    keyframe_index: int
    pixels: FloatArray
    X_world: FloatArray
    residual: FloatArray


class OdometryView:
    """A read-only view of the odometry after a frame (module docstring).

    Attributes:
        frame_count: frames processed so far.
        keyframe_count: keyframes made so far.
        window_indices: frame indices of the window's keyframes, oldest first (track mode: the latest keyframe).
        window_poses: (K, 4, 4) their ``T_world_cam``.
        tracked: the frame's tracked points with the tracker's residuals, None when the frame was not
            tracked (the first frame, a re-initialisation) or its tracking failed.
        residual_scale: grey levels at which a residual is an outlier (Huber's ``k`` times the
            photometric noise; the default ``k`` without a robust kernel): the scale of a residual colour map.
        rig_offset: the window's estimate of the right image's offset ``(delta_x, delta_y)`` (px),
            None when the rig is not calibrated.
        right_brightness: the right camera's brightness relative to the left one, ``(a, b)`` with
            ``I_R = exp(a) I_L + b``, from the newest window keyframe (None: no stereo window keyframe).
    """

    def __init__(self, history: "FrameHistory", keyframer: "Keyframer", photometric: "PhotometricConfig",
                 tracked: TrackedPoints | None) -> None:
        self._history = history
        self._keyframer = keyframer
        self.frame_count = len(history.estimates)
        self.keyframe_count = len(keyframer.keyframes)
        window = _window_keyframes(keyframer)
        self.window_indices: tuple[int, ...] = tuple(kf.index for kf in window)
        self.window_poses: FloatArray = (np.stack([kf.T_world_cam.matrix() for kf in window]) if window
                                         else np.zeros((0, 4, 4)))
        self.tracked = tracked
        k = photometric.huber_k if photometric.huber_k is not None else DEFAULT_HUBER_K  # no kernel: the default's scale
        self.residual_scale = float(k * photometric.sigma_intensity)
        rig = keyframer.rig
        self.rig_offset: FloatArray | None = None if rig is None else rig.offset.copy()
        self.right_brightness: tuple[float, float] | None = keyframer.right_brightness()

    @classmethod
    def after(cls, history: "FrameHistory", keyframer: "Keyframer", photometric: "PhotometricConfig",
              track: "Track | None", keyframe: Keyframe | None) -> "OdometryView":
        """The view after the latest frame, tracked as ``track`` against ``keyframe`` (None: not
        tracked); the tracker's residuals at its solution are computed here, only for a view."""
        tracked = None
        if track is not None and track.result.success and keyframe is not None:
            r = point_residuals(track.against, track.target, track.result.T_keyframe_frame, track.result.affine)
            X = keyframer.world_points(keyframe)[r.index]
            tracked = TrackedPoints(keyframe.index, r.pixels, X, r.residual)
        return cls(history, keyframer, photometric, tracked)

    def positions(self) -> FloatArray:
        """(N, 3) every frame's camera position so far (window mode: as the window has moved them)."""
        if not self._history.estimates:
            return np.zeros((0, 3))
        return np.array([e.T_world_cam[:3, 3] for e in self._history.estimates])

    def keyframe_indices(self) -> tuple[int, ...]:
        """Every keyframe's frame index, oldest first."""
        return tuple(kf.index for kf in self._keyframer.keyframes)

    def keyframe_points(self, index: int) -> tuple[FloatArray, FloatArray]:
        """Keyframe ``index``'s points in the world (N, 3) at its current pose and depths, and their
        intensities (N,) (copies)."""
        kf = self._keyframer.keyframe(index)
        if kf is None:
            raise KeyError(f"frame {index} is not a keyframe")
        return self._keyframer.world_points(kf), np.asarray(kf.points.intensity, dtype=np.float64).copy()


def _window_keyframes(keyframer: "Keyframer") -> list[Keyframe]:
    """The keyframes of the window (window mode), else the latest keyframe, oldest first."""
    if not keyframer.keyframes:
        return []
    return keyframer.window_keyframes() or [keyframer.keyframes[-1]]
