"""When the window is optimised (docs/window.md, "When the window is optimised").

After every new keyframe, unless ``window.optimize_every`` > 1 lets it wait: a keyframe may join
the window without an optimisation while fewer than ``optimize_every`` keyframes wait, when it was
tracked (not re-initialised), comes right after the last keyframe (keyframes at every frame, a car
at 10 Hz: no frame was tracked against a keyframe the window has not refined) and its own stereo
depths suffice to track the next frame against (:meth:`WindowSchedule.depths_suffice`). The LM
back end only; the fixed-lag smoother updates at every keyframe.
"""

from __future__ import annotations

import gtsam
import numpy as np

from factors.params import PhotometricConfig
from gtvo.core.camera import PinholeCamera
from gtvo.frontend import KeyframePoints
from gtvo.window import WindowConfig


class WindowSchedule:
    """Counts the keyframes waiting for the window's optimisation and decides whether the next may wait.

    Args:
        config: the window's settings (``optimize_every``, ``backend``).
        photometric: the residuals' model (its ``pattern``).
        camera: the left camera.

    Attributes:
        waiting: keyframes that joined the window since its last optimisation.
    """

    def __init__(self, config: WindowConfig, photometric: PhotometricConfig, camera: PinholeCamera) -> None:
        self.config = config
        self.photometric = photometric
        self.camera = camera
        self.waiting = 0

    def may_wait(self, tracked: bool, follows_last_keyframe: bool, T_last_keyframe: gtsam.Pose3,
                 T_new: gtsam.Pose3, points: KeyframePoints) -> bool:
        """Whether the keyframe that just joined (the ``waiting``-th) may wait for the next one's
        optimisation (module docstring)."""
        return (tracked and self.config.backend == "lm" and self.waiting < self.config.optimize_every
                and follows_last_keyframe and self.depths_suffice(T_last_keyframe, T_new, points))

    def may_go_unrefined(self, tracked: bool, follows_last_keyframe: bool, T_last_keyframe: gtsam.Pose3,
                         T_new: gtsam.Pose3, points: KeyframePoints) -> bool:
        """Whether the next frames may track against the new keyframe's own stereo depths while
        the window refines them in its worker process (``window.parallel``): :meth:`may_wait`'s
        conditions but the count and the back end (docs/window.md, "The window beside the tracker")."""
        return tracked and follows_last_keyframe and self.depths_suffice(T_last_keyframe, T_new, points)

    def depths_suffice(self, T_last_keyframe: gtsam.Pose3, T_new: gtsam.Pose3, points: KeyframePoints) -> bool:
        """True when the new keyframe's own (unrefined) depths are good enough to track the next
        frame against: their inverse-depth error moves a point by less than the residual pattern's
        radius over one more step like the last one, ``fx |t| sqrt(median V) < max |pattern offset|``
        (``t``: the translation from the last keyframe; 2 px for DSO's pattern). Then the tracker
        still compares the right pixels, and the window may refine the keyframe later."""
        step = float(np.linalg.norm(T_last_keyframe.between(T_new).translation()))
        error_px = float(self.camera.fx) * step * float(np.sqrt(np.median(points.variance)))
        radius = float(np.max(np.linalg.norm(np.asarray(self.photometric.pattern, dtype=float), axis=1)))
        return error_px < radius
