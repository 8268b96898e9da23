"""What the odometry says about each frame (:class:`FrameEstimate`, one :class:`FrameOutcome`) and its keyframes."""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any, Iterable

import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.frontend.stereo_depth import KeyframePoints
from gtvo.frontend.tracking import TrackingKeyframe, TrackingResult


class FrameOutcome(enum.Enum):
    """How a frame was handled: one value per frame.

    * ``TRACKED``: tracked against the latest keyframe.
    * ``KEYFRAME``: made a keyframe (the first frame, or a tracked frame the keyframe rule chose, or
      a frame promoted when the next one could not be tracked against the old keyframe).
    * ``REINITIALISED``: tracking failed and the frame became a keyframe at the motion model's
      prediction (counted as a tracking failure).
    * ``LOST``: tracking failed and the frame could not host a keyframe either (too few points
      with a depth); its pose is the prediction (counted as a tracking failure).
    * ``WHEEL_CARRIED``: like ``LOST`` (tracking failed, too few points to re-initialise), but the
      run has wheel odometry: its pose is the last good frame's carried by the calibrated wheel
      motion, not the motion model's prediction (:attr:`FrameEstimate.lost` is True for it too).
    * ``IMU_CARRIED``: like ``WHEEL_CARRIED``, but the run has an IMU in the window: its pose is the
      latest keyframe's carried by the preintegrated IMU readings (:attr:`FrameEstimate.lost` is
      True for it too; docs/imu.md).
    * ``RECOVERED``: failed from every motion-model guess, tracked from the optical-flow guess
      (a recovered frame the keyframe rule makes a keyframe is ``KEYFRAME``, with
      :attr:`FrameEstimate.recovered` True).
    * ``SUSPECT``: tracked, but its image contradicts a motion model that has been right (a
      duplicated, stale or out-of-order image: :mod:`gtvo.frontend.frame_checks`); it keeps the
      predicted pose, does not become a keyframe and is not used for the next prediction.
    * ``FROZEN``: its image repeats the previous frame's while the rig moves (a frozen camera or a
      stuck driver: :mod:`gtvo.frontend.frame_checks`), decided before tracking, for as many frames
      as it lasts; like a suspect frame it keeps the predicted pose (the wheels' with wheel
      odometry), does not become a keyframe and is not used for the next prediction.
    * ``SKIPPED``: the frame's images could not be read (the pipeline's; no estimate is made).
    """

    TRACKED = "tracked"
    KEYFRAME = "keyframe"
    REINITIALISED = "reinitialised"
    LOST = "lost"
    WHEEL_CARRIED = "wheel_carried"
    IMU_CARRIED = "imu_carried"
    RECOVERED = "recovered"
    SUSPECT = "suspect"
    FROZEN = "frozen"
    SKIPPED = "skipped"


@dataclass(frozen=True)
class FrameEstimate:
    """What the VO says about one frame.

    Attributes:
        index, timestamp: the frame's.
        T_world_cam: the left camera's pose (4x4). In window mode it is rewritten whenever the
            window moves the frame's keyframe (``T_world_keyframe * T_keyframe_frame``).
        outcome: how the frame was handled (:class:`FrameOutcome`); :attr:`is_keyframe`,
            :attr:`reinitialised` and :attr:`lost` are read from it.
        tracking: the tracker's result (None for keyframes made without tracking: the first
            frame and re-initialisations).
        seconds: wall time spent on the frame.
        keyframe_index: the frame index of the keyframe it was tracked against (its own index
            when it was made a keyframe without tracking).
        T_keyframe_frame: a frame that is not a keyframe: its pose relative to ``keyframe_index``
            (tracked, or predicted when it is lost or suspect), from which ``T_world_cam`` is
            re-expressed.
        reason: why the frame was lost, re-initialised, recovered or suspect ("" otherwise).
        from_flow_guess: tracked from the optical-flow guess (:attr:`recovered`).
    """

    index: int
    timestamp: float
    T_world_cam: NDArray[np.float64]
    outcome: FrameOutcome
    tracking: TrackingResult | None
    seconds: float
    keyframe_index: int = -1
    T_keyframe_frame: gtsam.Pose3 | None = None
    reason: str = ""
    from_flow_guess: bool = False

    @property
    def recovered(self) -> bool:
        """True when the frame was tracked from the optical-flow guess (``RECOVERED``, or a
        ``KEYFRAME`` made from such a frame)."""
        return self.outcome is FrameOutcome.RECOVERED or self.from_flow_guess

    @property
    def suspect(self) -> bool:
        """True when the frame's image contradicted the motion model (``SUSPECT``): its pose is
        the prediction, relative to ``keyframe_index`` like a lost frame's."""
        return self.outcome is FrameOutcome.SUSPECT

    @property
    def excluded(self) -> bool:
        """True when the frame's image is not used beyond its own flag (``SUSPECT``, ``FROZEN``):
        the motion model does not learn from it and the next prediction spans it."""
        return self.outcome in (FrameOutcome.SUSPECT, FrameOutcome.FROZEN)

    @property
    def is_keyframe(self) -> bool:
        """True when the frame became a keyframe (``KEYFRAME`` or ``REINITIALISED``)."""
        return self.outcome in (FrameOutcome.KEYFRAME, FrameOutcome.REINITIALISED)

    @property
    def reinitialised(self) -> bool:
        """True when tracking failed and the frame was re-initialised as a keyframe."""
        return self.outcome is FrameOutcome.REINITIALISED

    @property
    def lost(self) -> bool:
        """True when tracking failed and the frame could not be re-initialised either (too few
        points with a depth: a blank, covered or textureless view). Its pose is the motion
        model's prediction (relative to ``keyframe_index``, re-expressed when the window moves
        that keyframe), ``tracking`` holds the failed attempt, and no keyframe is made from it:
        the next frames are tracked against the latest keyframe (which may be the frame before
        it, promoted when it failed) again. Also True for a ``WHEEL_CARRIED`` frame (its pose the
        wheels' instead of the prediction) and an ``IMU_CARRIED`` one (the IMU's)."""
        return self.outcome in (FrameOutcome.LOST, FrameOutcome.WHEEL_CARRIED, FrameOutcome.IMU_CARRIED)


@dataclass
class Keyframe:
    """A keyframe: its pose, its points (hosted in it) and its tracking pyramid.

    Each keyframe is its own brightness reference: the affine brightness ``(a, b)`` a tracked
    frame gets is relative to its keyframe, so brightness errors do not chain from keyframe
    to keyframe.
    """

    index: int
    T_world_cam: gtsam.Pose3
    points: KeyframePoints
    #: the tracker's data (pyramid samples of the points) and the left image (grey levels, the
    #: optical-flow fallback's reference) while this is the latest keyframe, the only one frames
    #: are tracked against; both are dropped when the next keyframe is made, so a long run keeps
    #: only each keyframe's pose and points
    tracker: TrackingKeyframe | None
    image: NDArray[np.float32] | None = None


#: The outcomes ``report.json`` lists frame by frame (with the reason); the others are counted.
FLAGGED_OUTCOMES = ("frozen", "suspect", "lost", "reinitialised", "wheel_carried", "imu_carried", "recovered", "skipped")


def frames_by_outcome(estimates: list[FrameEstimate], skipped: Iterable[tuple[int, str]] = ()) -> dict[str, Any]:
    """The frames of a run by outcome, for ``report.json``: ``tracked`` and ``keyframe`` as counts,
    every flagged frame (:data:`FLAGGED_OUTCOMES`) as ``{"index", "reason"}``. ``recovered``
    lists every frame whose pose was tracked from the optical-flow guess, keyframes among them
    (not a suspect frame, whose tracked pose was not used); ``skipped``:
    ``(index, reason)`` of the frames whose images could not be read (the pipeline's)."""
    out: dict[str, Any] = {
        "tracked": sum(1 for e in estimates if e.outcome is FrameOutcome.TRACKED),
        "keyframe": sum(1 for e in estimates if e.outcome is FrameOutcome.KEYFRAME),
    }
    for name in FLAGGED_OUTCOMES[:-2]:
        out[name] = [{"index": e.index, "reason": e.reason} for e in estimates if e.outcome.value == name]
    out["recovered"] = [{"index": e.index, "reason": e.reason} for e in estimates if e.recovered and not e.suspect]
    out["skipped"] = [{"index": int(i), "reason": r} for i, r in skipped]
    return out


#: Outcomes whose pose the run trusts (tracked, or a keyframe made from a tracked frame or the first
#: frame); the others are predictions (re-initialised, lost, suspect, frozen).
TRUSTED_OUTCOMES = (FrameOutcome.TRACKED, FrameOutcome.KEYFRAME, FrameOutcome.RECOVERED)


def trusted_fraction(estimates: list[FrameEstimate]) -> float | None:
    """The fraction of the trajectory's frames whose pose the run trusts (:data:`TRUSTED_OUTCOMES`);
    None without frames."""
    if not estimates:
        return None
    return sum(1 for e in estimates if e.outcome in TRUSTED_OUTCOMES) / len(estimates)


def undetermined_frames(estimates: list[FrameEstimate], max_relative_rms: float) -> list[int]:
    """The frames whose tracking failed (re-initialised or lost) where the images did not determine
    the pose: the tracker's best attempt left more than ``max_relative_rms`` of the residual of an
    unrelated image (:attr:`gtvo.frontend.tracking.TrackingResult.relative_rms`)."""
    return [e.index for e in estimates if (e.reinitialised or e.lost) and e.tracking is not None
            and e.tracking.relative_rms > max_relative_rms]


#: A log is "too dark or too flat to trust" when the images did not determine the pose of at least
#: this fraction of its frames.
UNDETERMINED_LOG_FRACTION = 0.05


def trust_warning(frames: int, undetermined: list[int], trusted: float | None) -> str | None:
    """The console's word on frames the images did not determine (None when there are none)."""
    if not undetermined or trusted is None:
        return None
    what = ("the log is too dark or too flat to trust: " if len(undetermined) >= UNDETERMINED_LOG_FRACTION * frames
            else "")
    shown = ", ".join(str(i) for i in undetermined[:10]) + (", ..." if len(undetermined) > 10 else "")
    return (f"{what}the images did not determine the pose of {len(undetermined)} of {frames} frames ({shown}: "
            f"flagged as failed, their poses predicted); {trusted:.0%} of the trajectory is trustworthy")


def frozen_ranges(estimates: list[FrameEstimate]) -> list[tuple[int, int]]:
    """The runs of consecutive ``FROZEN`` frames, as ``(first, last)`` frame indices."""
    ranges: list[tuple[int, int]] = []
    previous: FrameEstimate | None = None
    for e in estimates:
        if e.outcome is FrameOutcome.FROZEN:
            if previous is not None and previous.outcome is FrameOutcome.FROZEN:
                ranges[-1] = (ranges[-1][0], e.index)
            else:
                ranges.append((e.index, e.index))
        previous = e
    return ranges


def frozen_warning(estimates: list[FrameEstimate], wheels: bool = False) -> str | None:
    """The console's one line on a frozen camera (None when no frame was frozen): the frame
    ranges, what placed them (the motion model, or the wheels when ``wheels``), how the run went on
    after each and how much of the trajectory is trustworthy."""
    ranges = frozen_ranges(estimates)
    if not ranges:
        return None
    by_index = {e.index: e for e in estimates}
    source = "the wheels'" if wheels else "the motion model's"
    parts = []
    for first, last in ranges:
        span = f"{first}-{last}" if last > first else f"{first}"
        after = next((e for e in estimates if e.index > last), None)
        before = by_index.get(first - 1)
        what = f"frames {span}" if last > first else f"frame {span}"
        repeated = "" if before is None else f" {'repeat' if last > first else 'repeats'} frame {before.index}'s image"
        if after is None:
            then = "the log ends frozen"
        elif after.reinitialised:
            then = f"frame {after.index} re-initialised at {source} pose"
        elif after.lost:
            then = f"frame {after.index} lost, placed at {source} pose"
        elif after.excluded:
            then = f"frame {after.index} suspect, placed at {source} pose"
        else:
            then = f"frame {after.index} tracked again from {source} pose"
        parts.append(f"{what}{repeated} ({then})")
    trusted = trusted_fraction(estimates)
    return (f"the camera froze while the rig moved: {'; '.join(parts)}; flagged as frozen, their poses are "
            f"{source} guesses, not measurements; {trusted:.0%} of the trajectory is trustworthy")


class TooFewPoints(Exception):
    """Control flow: a frame cannot host a keyframe (too few points with a depth)."""


def rigid_pose(T: NDArray[np.float64]) -> gtsam.Pose3:
    """A ``Pose3`` from a 4x4 matrix, its rotation projected onto SO(3).

    ``gtsam.Pose3(matrix)`` keeps a slightly non-orthonormal rotation as it is, and chaining
    ``between``/``compose`` over hundreds of frames amplifies the error (measured: x3 per frame);
    projecting each pose read back from a matrix keeps every pose rigid.
    """
    return gtsam.Pose3(gtsam.Rot3.ClosestTo(np.asarray(T[:3, :3], dtype=np.float64)), np.asarray(T[:3, 3], dtype=np.float64))
