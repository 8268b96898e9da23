"""What a run tells its observers: the interface :func:`gtvo.pipeline.run_odometry` calls
once at the start, after every frame and once at the end (e.g.
:class:`gtvo.io.rerun_log.RerunLogger`).

Observers get data, not the system: each frame's :class:`gtvo.odometry.view.OdometryView`, made
by the odometry (window poses and points, the rig offset, the tracker's residuals).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from gtvo.datasets.sequence import Frame, Sequence
    from gtvo.evaluation.trajectory import Trajectory
    from gtvo.config import OdometryConfig
    from gtvo.odometry import FrameEstimate, OdometryView
    from gtvo.odometry.summary import OdometrySummary


class RunObserver(Protocol):
    """Called by the run loop; every method may be a no-op."""

    def on_start(self, seq: "Sequence", config: "OdometryConfig") -> None:
        """Before the first frame: the sequence (camera, ground truth) and the run's settings."""

    def on_frame(self, frame: "Frame", estimate: "FrameEstimate", view: "OdometryView") -> None:
        """After ``vo.process(frame)`` returned ``estimate``; ``view``: ``vo.view()``."""

    def on_finish(self, view: "OdometryView", trajectory: "Trajectory", info: "OdometrySummary") -> None:
        """After the last frame (and ``vo.finish()``), with the trajectory and the odometry's summary
        (:func:`gtvo.odometry.summary.summarize_odometry`)."""
