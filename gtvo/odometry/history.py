"""Every frame's estimate so far (:class:`FrameHistory`), and what the odometry's parts ask of it.

The history is the record the driver appends to once per frame. The motion model reads its last
good frames, the keyframer re-expresses its poses when the window moves a keyframe, the frame
checks read the step before. A *good* frame is one that is neither suspect nor frozen: those keep the
predicted pose and are left out of everything that learns from the past.
"""

from __future__ import annotations

import dataclasses
from typing import Mapping

import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.odometry.estimates import FrameEstimate, FrameOutcome, Keyframe


class FrameHistory:
    """The estimates of the frames processed so far, in order (:attr:`estimates`)."""

    def __init__(self) -> None:
        self.estimates: list[FrameEstimate] = []

    def append(self, estimate: FrameEstimate) -> None:
        """Record the next frame's estimate."""
        self.estimates.append(estimate)

    def good(self, n: int) -> list[FrameEstimate]:
        """The last ``n`` (or fewer) estimates that are not suspect or frozen, oldest first."""
        out: list[FrameEstimate] = []
        for e in reversed(self.estimates):
            if not e.excluded:
                out.append(e)
                if len(out) == n:
                    break
        return out[::-1]

    def last_rms(self) -> float | None:
        """The tracking RMS of the last frame tracked successfully and not suspect, None before one."""
        for e in reversed(self.estimates):
            if e.tracking is not None and e.tracking.success and not e.excluded:
                return e.tracking.rms
        return None

    def affine_guess(self, keyframe_index: int) -> NDArray[np.float64]:
        """The last good frame's affine brightness if it was tracked against keyframe
        ``keyframe_index``, else ``(0, 0)``: the tracker's starting brightness."""
        last = self.good(1)[0]
        if last.keyframe_index == keyframe_index and last.tracking is not None and last.tracking.success:
            return last.tracking.affine.copy()
        return np.zeros(2)

    def latest_other_than(self, index: int) -> int | None:
        """The frame index of the latest estimate that is not frame ``index`` (None: none)."""
        for e in reversed(self.estimates):
            if e.index != index:
                return e.index
        return None

    def mark_last_good_as_keyframe(self) -> None:
        """Record that the last good frame (the keyframe candidate) was promoted to a keyframe."""
        i = next(i for i in range(len(self.estimates) - 1, -1, -1) if not self.estimates[i].excluded)
        self.estimates[i] = dataclasses.replace(self.estimates[i], outcome=FrameOutcome.KEYFRAME)

    def rescale_tracked(self, scales: Mapping[int, float], keyframes: Mapping[int, Keyframe]) -> None:
        """Scale the translation relative to its keyframe of every frame tracked against a keyframe
        of ``scales`` (``{keyframe index: s}``; keyframes themselves, in ``keyframes``, are left
        alone): the keyframe's depths changed scale, and a tracked translation is only known in
        the scale of the depths it was tracked with (:mod:`gtvo.window.depth_change`)."""
        for i, e in enumerate(self.estimates):
            s = scales.get(e.keyframe_index)
            if s is None or e.T_keyframe_frame is None or e.index in keyframes:
                continue
            T = e.T_keyframe_frame
            self.estimates[i] = dataclasses.replace(
                e, T_keyframe_frame=gtsam.Pose3(T.rotation(), s * np.asarray(T.translation())))

    def re_express(self, keyframes: Mapping[int, Keyframe], since: int) -> None:
        """Re-express the poses of the frames from frame ``since`` on against their keyframes'
        current poses (``keyframes``: ``{frame index: Keyframe}``): a keyframe's pose is its
        own, any other frame's ``T_world_keyframe * T_keyframe_frame``. Older frames did not move
        (a frame's keyframe is never newer than the frame)."""
        for i in range(len(self.estimates) - 1, -1, -1):
            e = self.estimates[i]
            if e.index < since:
                break
            if e.index in keyframes:
                T = keyframes[e.index].T_world_cam
            elif e.T_keyframe_frame is not None and e.keyframe_index in keyframes:
                T = keyframes[e.keyframe_index].T_world_cam.compose(e.T_keyframe_frame)
            else:
                continue
            self.estimates[i] = dataclasses.replace(e, T_world_cam=T.matrix())
