"""When the window is optimised (docs/window.md, "When the window is optimised").

After every new keyframe, unless ``window.optimize_every`` > 1 lets it wait: a keyframe may join
the window without an optimisation while fewer than ``optimize_every`` keyframes wait, when it was
tracked (not re-initialised), comes right after the last keyframe (keyframes at every frame, a car
at 10 Hz: no frame was tracked against a keyframe the window has not refined) and its own stereo
depths suffice to track the next frame against (:meth:`WindowSchedule.depths_suffice`). The LM
back end only; the fixed-lag smoother updates at every keyframe.

**Where the window runs** (``window.parallel: auto``, docs/window.md, "The window beside the
tracker"). A window in a worker process pays only where its optimisation overlaps the front end's
next frames: keyframes at every frame whose own stereo depths the next frames may track against
(:meth:`WindowSchedule.may_go_unrefined`). Where a keyframe's window must be waited for at once
(frames between keyframes, steps too long for the stereo depths) the worker only adds its hand-over
(0.83-0.89x the sequential frames/s). The schedule counts the keyframes that could have gone
unrefined while the window runs in this process, and at the :data:`AUTO_DECISION_KEYFRAME`-th
keyframe moves it to the worker when at least :data:`AUTO_MIN_OVERLAP` of them could
(:meth:`WindowSchedule.moves_to_worker`): a count over the sequence, so two runs decide alike
whatever the load; a short run (fewer keyframes) never pays a worker's start. The LM back end
only (the fixed-lag smoother's state does not move between processes).
"""

from __future__ import annotations

import gtsam
import numpy as np

from factors.params import PhotometricConfig
from gtvo.core.camera import PinholeCamera
from gtvo.frontend import KeyframePoints
from gtvo.window import WindowConfig

#: ``window.parallel: auto`` decides at this keyframe (counted from 1): after two windows of the
#: default size, when the start (the rig offset's first test, the first marginalisations) is over and
#: the count of keyframes that could overlap says enough about the log.
AUTO_DECISION_KEYFRAME = 15
#: ... for the worker when at least this fraction of the keyframes after the first could have gone
#: unrefined (KITTI at 10 Hz: all of them; frames between keyframes, TUM and EuRoC: none).
AUTO_MIN_OVERLAP = 0.75


class WindowSchedule:
    """Counts the keyframes waiting for the window's optimisation and decides whether the next may wait.

    Args:
        config: the window's settings (``optimize_every``, ``backend``).
        photometric: the residuals' model (its ``pattern``).
        camera: the left camera.

    Attributes:
        waiting: keyframes that joined the window since its last optimisation.
        keyframes: keyframes that joined the window so far.
        overlapping: of those, the ones whose next frames could track against their own stereo
            depths (:meth:`may_go_unrefined`): with a worker, their windows overlap the front end.
    """

    def __init__(self, config: WindowConfig, photometric: PhotometricConfig, camera: PinholeCamera) -> None:
        self.config = config
        self.photometric = photometric
        self.camera = camera
        self.waiting = 0
        self.keyframes = 0
        self.overlapping = 0

    def note_keyframe(self, could_go_unrefined: bool) -> None:
        """Count a keyframe that joined the window (and whether :meth:`may_go_unrefined` said yes)."""
        self.keyframes += 1
        self.overlapping += int(could_go_unrefined)

    def moves_to_worker(self) -> bool:
        """True exactly once, at the :data:`AUTO_DECISION_KEYFRAME`-th keyframe of a run with
        ``window.parallel: auto``, when at least :data:`AUTO_MIN_OVERLAP` of the keyframes after the
        first could have gone unrefined (module docstring): the window continues in a worker. The
        LM back end only: the fixed-lag smoother's iSAM2 state cannot move to another process (with
        it ``auto`` stays in this one; ``window.parallel: true`` starts it in the worker)."""
        if self.config.parallel != "auto" or self.config.backend != "lm" or self.keyframes != AUTO_DECISION_KEYFRAME:
            return False
        return self.overlapping >= AUTO_MIN_OVERLAP * (self.keyframes - 1)

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
