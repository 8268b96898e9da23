"""What a run tells its observers: the interface :func:`gtvo.pipeline.process_sequence` calls
once at the start, after every frame and once at the end (e.g.
:class:`gtvo.io.rerun_log.RerunLogger`).

An observer only reads: it must not change the odometry it is handed.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from gtvo.datasets.sequence import Frame, Sequence
    from gtvo.evaluation.trajectory import Trajectory
    from gtvo.odometry import FrameEstimate, VisualOdometry
    from gtvo.odometry.summary import OdometrySummary


class RunObserver(Protocol):
    """Called by the run loop; every method may be a no-op."""

    def on_start(self, seq: "Sequence", vo: "VisualOdometry") -> None:
        """Before the first frame: the sequence (camera, ground truth) and the odometry."""

    def on_frame(self, frame: "Frame", estimate: "FrameEstimate", vo: "VisualOdometry") -> None:
        """After ``vo.process(frame)`` returned ``estimate`` (``vo`` holds the keyframes and window)."""

    def on_finish(self, vo: "VisualOdometry", trajectory: "Trajectory", info: "OdometrySummary") -> None:
        """After the last frame, with the trajectory and the odometry's summary
        (:func:`gtvo.odometry.summary.summarize_odometry`)."""
