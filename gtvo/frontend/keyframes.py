"""The keyframe rule: when a tracked frame becomes a keyframe (DSO's rules, docs/architecture.md).

A tracked frame becomes a keyframe when

* fewer than ``min_visible`` of the keyframe's points still have valid residuals (the view has
  moved on), or
* the RMS optical flow that the translation since the keyframe causes at its points exceeds
  ``max_flow * (width + height)`` (DSO's rule and constant: 25 px at 640x480), or
* ``|t_keyframe_frame| * median(d) > max_motion`` (translation relative to the median scene
  depth: about the parallax angle in radians), or
* the rotation since the keyframe exceeds ``max_rotation_deg``, or
* the log-gain of the brightness changed by more than ``max_brightness``.
"""

from __future__ import annotations

import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.core.camera import PinholeCamera
from gtvo.config.sections.keyframes import KeyframeConfig
from gtvo.frontend.stereo_depth import KeyframePoints
from gtvo.frontend.tracking import TrackingResult


def needs_keyframe(camera: PinholeCamera, points: KeyframePoints, result: TrackingResult, rule: KeyframeConfig) -> bool:
    """True when a frame tracked against the keyframe hosting ``points`` (``result``) should become a keyframe."""
    n = len(points)
    if result.n_valid < rule.min_visible * n:
        return True
    T = result.T_keyframe_frame
    med_d = float(np.median(points.inverse_depth))
    if float(np.linalg.norm(T.translation())) * med_d > rule.max_motion:
        return True
    if translation_flow_rms(camera, points, T.translation()) > rule.max_flow * (camera.width + camera.height):
        return True
    if np.degrees(np.linalg.norm(gtsam.Rot3.Logmap(T.rotation()))) > rule.max_rotation_deg:
        return True
    return abs(float(result.affine[0])) > rule.max_brightness


def translation_flow_rms(camera: PinholeCamera, points: KeyframePoints, t_keyframe_frame: NDArray) -> float:
    """RMS displacement (px) of a keyframe's points caused by the translation alone.

    A point ``X`` of the keyframe is at ``X - t`` in a frame translated by ``t`` (rotation
    ignored: rotation alone gives no parallax, so it is no reason for a new keyframe).
    """
    X = camera.backproject_inverse_depth(points.pixels, points.inverse_depth)
    uv, ok = camera.project(X - np.asarray(t_keyframe_frame, dtype=float).reshape(1, 3))
    if not np.any(ok):
        return float("inf")
    d = uv[ok] - points.pixels[ok]
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))
