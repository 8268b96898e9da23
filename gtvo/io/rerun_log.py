"""A Rerun recording of a run, logged as it goes (``gtvo run ... --rerun FILE.rrd``).

:class:`RerunLogger` is a :class:`gtvo.io.observer.RunObserver`: the run loop hands it every
frame.
``rerun-sdk`` is the optional ``viewer`` extra, imported when a logger is made.

Timelines: ``frame`` (the frame index in the sequence) and ``sensor_time`` (the frame's time: a
date when the sequence's times are Unix times, i.e. after 2001, else a duration from 0).

Entity paths (the world is gtvo's: the first camera, x right, y down, z forward)::

    world                            view coordinates RDF (static)
    world/camera                     Transform3D T_world_cam of each frame
    world/camera/image               Pinhole (static) + the left image (JPEG, or raw with jpeg_quality=None)
    world/camera/image/tracked       Points2D: the keyframe's points where the frame sees them,
                                     coloured by residual (green 0 .. red >= huber_k sigma_I grey levels)
    world/tracked                    Points3D: the same points in the world, same colours
    world/window                     Points3D: the keyframes of the window (track mode: the latest),
                                     labelled with their frame index; world/window/axes: their optical axes
    world/trajectory/estimate        LineStrip3D: every frame's position so far (logged when a keyframe
                                     is made, since the window then moves poses, and at the end)
    world/trajectory/ground_truth    LineStrip3D (static): the ground truth, moved so that its first
                                     pose lies on the estimate of that frame
    world/map/kf_<frame index>       Points3D: each keyframe's points, grey from their intensity,
                                     re-logged while the window optimises them
    plots/tracking/rms               whitened RMS residual of the tracked frame (TrackingResult.rms)
    plots/tracking/iterations        its LM iterations
    plots/tracking/valid_points      its points with a valid residual
    plots/frames_per_second          frames per wall-clock second over the last 10 frames
    plots/rig/right_gain, right_offset   the right camera's brightness relative to the left one,
                                     ``I_R = gain I_L + offset``, from the newest window keyframe,
                                     once the window has one (stereo, window mode)
"""

from __future__ import annotations

import collections
import contextlib
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from gtvo.core.image import to_uint8
from gtvo.core.optional import require_rerun
from gtvo.errors import InputError
from gtvo.core.atomic import atomic_path

if TYPE_CHECKING:
    from gtvo.datasets.sequence import Frame, Sequence
    from gtvo.evaluation.trajectory import Trajectory
    from gtvo.config import OdometryConfig
    from gtvo.odometry import FrameEstimate, OdometryView

#: Times above this (s) are taken as Unix times (2001-09-09 onwards) and logged as dates.
UNIX_TIME_THRESHOLD_S = 1e9
#: Frames over which the frames-per-second plot is averaged.
FPS_WINDOW = 10
#: How long the end of a run waits for a viewer to take the data (s).
CONNECT_FLUSH_TIMEOUT_S = 10.0


class RerunLogger:
    """Logs a run to a ``.rrd`` file and/or a running viewer (see the module docstring).

    Args:
        save: the ``.rrd`` file to write (atomically: it appears when the run has finished); not
            inside the run's output folder, which :func:`gtvo.pipeline.run` replaces as a set.
        connect: the address of a running viewer (``rerun+http://127.0.0.1:9876/proxy`` is
            the one ``rerun`` opens by default).
        jpeg_quality: JPEG quality of the logged images (1-100), None for raw images.
        application_id: Rerun's application id.

    Use it as a context manager (or call :meth:`close`), so that the ``.rrd`` appears when the
    work succeeded and a run that fails leaves none behind::

        with RerunLogger(save="run.rrd") as log:
            gtvo.run("KITTI_sequence_1", observers=[log])

    Raises:
        DependencyError: rerun-sdk is not installed (``pip install "gtvo[viewer]"``).
        InputError: neither ``save`` nor ``connect``, a bad address, or an unwritable file.
    """

    def __init__(self, save: str | Path | None = None, connect: str | None = None, jpeg_quality: int | None = 90,
                 application_id: str = "gtvo") -> None:
        rr = require_rerun()
        if save is None and connect is None:
            raise InputError("a Rerun logger needs a file to save to or a viewer address to connect to")
        if jpeg_quality is not None and not 1 <= int(jpeg_quality) <= 100:
            raise InputError(f"JPEG quality must be 1..100, got {jpeg_quality}")
        self.rr = rr
        self.jpeg_quality = jpeg_quality
        self.rec = rr.RecordingStream(application_id)
        self.connect = connect
        self.path = None if save is None else Path(save)
        self._files = contextlib.ExitStack()
        self._closed = False
        self._open_sinks(save, connect)
        self._seq: Sequence | None = None
        self._unix_time = False
        self._gt_logged = False
        self._keyframe_count = 0
        self._frame_clock: collections.deque[float] = collections.deque(maxlen=FPS_WINDOW + 1)

    # -- sinks ----------------------------------------------------------------------------------
    def _open_sinks(self, save: str | Path | None, connect: str | None) -> None:
        rr = self.rr
        sinks = []
        if save is not None:
            if Path(save).suffix != ".rrd":
                raise InputError("a Rerun recording is a .rrd file", path=save)
            tmp = self._files.enter_context(atomic_path(save))
            sinks.append(rr.FileSink(str(tmp)))
        if connect is not None:
            if not connect.startswith(("rerun://", "rerun+http://", "rerun+https://")):
                self._discard_file()
                raise InputError(f"Rerun viewer address must start with rerun+http://, rerun+https:// or rerun://, "
                                 f"got {connect!r} (a viewer listens on rerun+http://127.0.0.1:9876/proxy)")
            sinks.append(rr.GrpcSink(connect))
        try:
            self.rec.set_sinks(*sinks)
        except (RuntimeError, ValueError) as exc:
            self._discard_file()
            raise InputError(f"Rerun cannot open {connect or save}: {exc}") from None

    def close(self, success: bool = True) -> None:
        """Send what is left and close the sinks; the ``.rrd`` replaces ``save`` only on ``success``
        (else it is removed). Idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            self.rec.flush(timeout_sec=CONNECT_FLUSH_TIMEOUT_S)
        except RuntimeError as exc:  # a viewer that is not there: the file is still complete
            print(f"warning: Rerun viewer at {self.connect} did not take the data ({exc})", file=sys.stderr)
        self.rec.disconnect()
        if success:
            self._files.close()  # atomic_path: the temporary file becomes ``save``
        else:
            self._discard_file()

    def _discard_file(self) -> None:
        """Remove the temporary ``.rrd`` without replacing ``save`` (atomic_path's failure branch)."""
        failure = RuntimeError("Rerun recording discarded")
        self._files.__exit__(type(failure), failure, None)

    def __enter__(self) -> "RerunLogger":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(success=exc_type is None)

    # -- the observer ---------------------------------------------------------------------------
    def on_start(self, seq: "Sequence", config: "OdometryConfig") -> None:
        """Static data: view coordinates, the camera model; the timeline kind from the first time."""
        rr = self.rr
        self._seq = seq
        self._unix_time = float(seq.timestamps[0]) > UNIX_TIME_THRESHOLD_S
        self.rec.send_recording_name(seq.name)
        self.rec.log("world", rr.ViewCoordinates.RDF, static=True)
        cam = seq.pinhole
        self.rec.log("world/camera/image", rr.Pinhole(image_from_camera=cam.K, resolution=[cam.width, cam.height],
                                                      camera_xyz=rr.ViewCoordinates.RDF), static=True)

    def on_frame(self, frame: "Frame", estimate: "FrameEstimate", view: "OdometryView") -> None:
        """The frame's camera, image, tracked points and plots; on a new keyframe the window,
        the map and the trajectory."""
        self._set_time(frame)
        self._log_camera(frame, estimate)
        self._log_tracked(view)
        self._log_plots(estimate, view)
        if view.keyframe_count != self._keyframe_count:
            self._keyframe_count = view.keyframe_count
            self._log_window(view)
            self._log_trajectory(view)
        if not self._gt_logged and frame.gt_T_world_cam is not None:
            self._log_ground_truth(frame, estimate)

    def on_finish(self, view: "OdometryView", trajectory: "Trajectory", info: dict[str, Any]) -> None:
        """The final trajectory and every keyframe's map points at the last frame (the recording
        is complete when :meth:`close` is called, or the ``with`` block ends)."""
        self._log_trajectory(view)
        self._log_window(view, every_keyframe=True)

    # -- what is logged -------------------------------------------------------------------------
    def _set_time(self, frame: "Frame") -> None:
        self.rec.set_time("frame", sequence=int(frame.index))
        if self._unix_time:
            self.rec.set_time("sensor_time", timestamp=float(frame.timestamp))
        else:
            self.rec.set_time("sensor_time", duration=float(frame.timestamp))

    def _log_camera(self, frame: "Frame", estimate: "FrameEstimate") -> None:
        rr = self.rr
        T = estimate.T_world_cam
        self.rec.log("world/camera", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        image = rr.Image(to_uint8(np.asarray(frame.left), "left image"))
        self.rec.log("world/camera/image", image.compress(jpeg_quality=self.jpeg_quality)
                     if self.jpeg_quality is not None else image)

    def _log_tracked(self, view: "OdometryView") -> None:
        """The tracked points coloured by the residual the tracker computed at its solution."""
        rr = self.rr
        tracked = view.tracked
        if tracked is None:
            self.rec.log("world/camera/image/tracked", rr.Clear(recursive=False))
            self.rec.log("world/tracked", rr.Clear(recursive=False))
            return
        colors = residual_colors(tracked.residual, view.residual_scale)
        self.rec.log("world/camera/image/tracked", rr.Points2D(tracked.pixels, colors=colors, radii=2.0))
        self.rec.log("world/tracked", rr.Points3D(tracked.X_world, colors=colors))

    def _log_plots(self, estimate: "FrameEstimate", view: "OdometryView") -> None:
        rr = self.rr
        if estimate.tracking is not None:
            self.rec.log("plots/tracking/rms", rr.Scalars(float(estimate.tracking.rms)))
            self.rec.log("plots/tracking/iterations", rr.Scalars(float(estimate.tracking.iterations)))
            self.rec.log("plots/tracking/valid_points", rr.Scalars(float(estimate.tracking.n_valid)))
        self._frame_clock.append(time.perf_counter())
        if len(self._frame_clock) > 1:
            span = self._frame_clock[-1] - self._frame_clock[0]
            if span > 0:
                self.rec.log("plots/frames_per_second", rr.Scalars((len(self._frame_clock) - 1) / span))
        if view.right_brightness is not None:
            a, b = view.right_brightness
            self.rec.log("plots/rig/right_gain", rr.Scalars(float(np.exp(a))))
            self.rec.log("plots/rig/right_offset", rr.Scalars(b))
        if view.rig_offset is not None:  # the rig self-calibration's estimate (px), when it runs
            self.rec.log("plots/rig/offset_x_px", rr.Scalars(float(view.rig_offset[0])))
            self.rec.log("plots/rig/offset_y_px", rr.Scalars(float(view.rig_offset[1])))

    def _log_window(self, view: "OdometryView", every_keyframe: bool = False) -> None:
        rr = self.rr
        if not view.window_indices:
            return
        poses = view.window_poses
        self.rec.log("world/window", rr.Points3D(poses[:, :3, 3], labels=[str(i) for i in view.window_indices],
                                                 colors=[255, 160, 0], radii=rr.Radius.ui_points(6.0)))
        axis = 0.5 * step_length(view.positions())
        self.rec.log("world/window/axes", rr.Arrows3D(origins=poses[:, :3, 3], vectors=axis * poses[:, :3, 2],
                                                      colors=[255, 160, 0]))
        for index in (view.keyframe_indices() if every_keyframe else view.window_indices):
            X, intensity = view.keyframe_points(index)
            grey = np.clip(np.rint(intensity), 0, 255).astype(np.uint8)
            self.rec.log(f"world/map/kf_{index:06d}", rr.Points3D(X, colors=np.repeat(grey[:, None], 3, axis=1)))

    def _log_trajectory(self, view: "OdometryView") -> None:
        self.rec.log("world/trajectory/estimate", self.rr.LineStrips3D([view.positions()], colors=[[40, 120, 255]]))

    def _log_ground_truth(self, frame: "Frame", estimate: "FrameEstimate") -> None:
        assert self._seq is not None and self._seq.gt_poses is not None and frame.gt_T_world_cam is not None
        self._gt_logged = True
        align = estimate.T_world_cam @ np.linalg.inv(frame.gt_T_world_cam)
        gt = self._seq.gt_poses
        ok = np.isfinite(gt[:, 0, 0])
        positions = (align @ gt[ok])[:, :3, 3]
        self.rec.log("world/trajectory/ground_truth", self.rr.LineStrips3D([positions], colors=[[0, 200, 80]]),
                     static=True)


# ----------------------------------------------------------------------------------------------
# what the plots are made of (no rerun needed)

def residual_colors(residual: NDArray[np.float64], scale: float) -> NDArray[np.uint8]:
    """RGB (N, 3): green for a zero residual, through yellow, to red at ``|residual| >= scale``."""
    s = np.clip(np.abs(np.asarray(residual, dtype=np.float64)) / scale, 0.0, 1.0)
    rgb = np.stack([np.minimum(2 * s, 1.0), np.minimum(2 * (1 - s), 1.0), np.zeros_like(s)], axis=1)
    return np.rint(255 * rgb).astype(np.uint8)


def step_length(positions: NDArray[np.float64]) -> float:
    """The median distance between consecutive positions of the last 50 (1 when unknown): the
    scale of the drawn axes."""
    if len(positions) < 2:
        return 1.0
    steps = np.linalg.norm(np.diff(positions[-50:], axis=0), axis=1)
    median = float(np.median(steps))
    return median if median > 0 else 1.0
