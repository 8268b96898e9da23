"""The odometry's side of the IMU: what ``report.json`` says about it and the gravity-aligned frame
the outputs are written in (docs/imu.md, "Outputs").

The IMU itself lives in :class:`gtvo.window.imu.ImuWindow` (``VisualOdometry.imu``): the window
initialises it and estimates the keyframes' velocities and biases.

**The output frame.** The odometry's world is the first camera's frame (every layer of gtvo works
in it). With an initialised IMU the outputs (``trajectory.tum``, ``trajectory_loop_closed.tum``,
``points.ply``) are written in the *gravity-aligned* world instead: the same origin (the first
camera's centre), rotated by the smallest rotation that takes the estimated gravity direction to
``-z``: z points up, x and y span the horizontal plane, the yaw (unobservable) is the first
camera's. :class:`GravityAlignment` is that rotation.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.core.keys import gravity_tilt_key, imu_bias_key
from gtvo.core.map_points import MapPoints
from gtvo.evaluation.trajectory import Trajectory
from gtvo.odometry.result import OdometryResult
from gtvo.window.imu import ImuWindow
from gtvo.window.problem import build_graph

if TYPE_CHECKING:
    from gtvo.odometry.visual_odometry import VisualOdometry

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class GravityAlignment:
    """The rotation ``R_aligned_world`` from the odometry's world to the gravity-aligned one (module doc)."""

    R_aligned_world: FloatArray

    @classmethod
    def of_gravity(cls, gravity_world: FloatArray) -> "GravityAlignment":
        """The smallest rotation taking ``gravity_world``'s direction to ``(0, 0, -1)``."""
        g = np.asarray(gravity_world, dtype=np.float64) / np.linalg.norm(gravity_world)
        down = np.array([0.0, 0.0, -1.0])
        axis = np.cross(g, down)
        s, c = float(np.linalg.norm(axis)), float(g @ down)
        if s < 1e-12:
            R = np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
        else:
            R = gtsam.Rot3.Expmap(axis / s * np.arctan2(s, c)).matrix()
        return cls(R)

    @property
    def T(self) -> FloatArray:
        """The rotation as a 4x4 transform."""
        T = np.eye(4)
        T[:3, :3] = self.R_aligned_world
        return T

    def trajectory(self, traj: Trajectory | None) -> Trajectory | None:
        """``traj``'s poses in the aligned world (None stays None)."""
        return None if traj is None else replace(traj, poses=self.T @ traj.poses)

    def points(self, points: MapPoints) -> MapPoints:
        """The map's points in the aligned world."""
        return replace(points, points=points.points @ self.R_aligned_world.T)


def gravity_alignment(vo: "VisualOdometry") -> GravityAlignment | None:
    """The run's output rotation (module doc), None without an initialised IMU. An IMU not
    initialised by the run's end is tried once more on the final window's keyframes (a static log
    makes one keyframe), where the window is (in a worker too: :meth:`gtvo.odometry.window_port.WindowPort.inspect`)."""
    imu: ImuWindow | None = getattr(vo, "imu", None)
    if imu is None:
        return None
    if not imu.initialised and vo.window is not None:
        state = vo.window.inspect(_initialised_at_end)
        if state is not None:
            imu.take_window_state(state)
    return None if imu.gravity is None else GravityAlignment.of_gravity(imu.gravity)


def _initialised_at_end(window: Any) -> Any:
    """On the window (a :class:`gtvo.window.SlidingWindowOptimizer`): its IMU initialised on its
    keyframes as the run ends, and its state for the front end's copy; None without an IMU."""
    if window.imu is None:
        return None
    window.imu.try_initialise(list(window.keyframes), finishing=True)
    return window.imu.window_state([k.index for k in window.keyframes])


def _final_covariances(window: Any) -> tuple[FloatArray | None, FloatArray | None]:
    """On the window: :func:`imu_covariances` of its IMU (None, None without one)."""
    return (None, None) if window.imu is None else imu_covariances(window.imu, window)


def gravity_aligned(result: OdometryResult) -> OdometryResult:
    """``result`` with its outputs in the gravity-aligned world (module doc): the trajectory, the
    loop-closed one and the map's keyframe poses rotated by ``result.gravity_rotation``; ``result``
    itself without an initialised IMU. The keyframes' covariances are in their own frames: unchanged."""
    if result.gravity_rotation is None:
        return result
    alignment = GravityAlignment(result.gravity_rotation)
    poses = {kf.index: kf.T_world_cam for kf in result.keyframes}
    poses.update(result.map_poses or {})
    loops = result.loops
    if loops is not None:
        loops = replace(loops, trajectory=alignment.trajectory(loops.trajectory))  # type: ignore[type-var]
    return replace(result, trajectory=alignment.trajectory(result.trajectory), loops=loops,
                   map_poses={i: alignment.T @ np.asarray(T, dtype=np.float64) for i, T in poses.items()})


def imu_covariances(imu: ImuWindow, window: Any) -> tuple[FloatArray | None, FloatArray | None]:
    """The marginal covariances of the newest keyframe's bias (6x6, ``(b_accel, b_gyro)``) and of
    gravity's tilt (3x3) in the final window's graph (linearised once, ``gtsam.Marginals``); None
    where the window has no such variable or the system is indeterminant."""
    if window is None or not getattr(window, "keyframes", None) or not imu.biases:
        return None, None
    problem = window.problem(rig=window.solved_rig())
    bias, tilt = imu_bias_key(window.keyframes[-1].index), gravity_tilt_key()
    if not problem.variables.exists(bias):
        return None, None
    graph, values, _ = build_graph(problem)
    try:
        marginals = gtsam.Marginals(graph, values)
        return (np.asarray(marginals.marginalCovariance(bias), dtype=np.float64),
                np.asarray(marginals.marginalCovariance(tilt), dtype=np.float64))
    except RuntimeError:  # an indeterminant system: no sigma rather than a wrong one
        return None, None


def imu_report(vo: "VisualOdometry") -> dict[str, Any]:
    """``{"imu": ...}`` when the run had an IMU in the window (``VisualOdometry.imu``): its log,
    the initialisation, gravity and its direction's sigma, the newest keyframe's biases and their
    marginal sigmas (:meth:`gtvo.window.imu.ImuWindow.report`), the output frame; else nothing."""
    imu: ImuWindow | None = getattr(vo, "imu", None)
    if imu is None:
        return {}
    alignment = gravity_alignment(vo)
    figures = imu.report(*(vo.window.inspect(_final_covariances) if vo.window is not None else (None, None)))
    readings = imu.readings
    figures.update({
        "source": getattr(readings, "source", None),
        "rate_hz": float(1.0 / np.median(np.diff(readings.times))),
        "T_cam_imu": np.asarray(readings.T_cam_imu).tolist(),
        "output_frame": ("gravity-aligned: z up, origin and yaw of the first camera" if alignment is not None
                         else "the first camera's (the IMU was not initialised)"),
        "R_aligned_world": None if alignment is None else alignment.R_aligned_world.tolist(),
    })
    return {"imu": figures}


def imu_line(figures: dict[str, Any]) -> str:
    """The console's line about the IMU (``report.json``'s ``imu`` block)."""
    if figures.get("initialised") is None:
        return "imu: not initialised (too short a log for its first second); outputs in the first camera's frame"
    sigma = figures.get("gravity_sigma_deg")
    gyro = figures.get("gyro_bias")
    text = f"imu: initialised {figures['initialised']}, outputs gravity-aligned (z up)"
    if sigma is not None:
        text += f", gravity direction +-{sigma:.3g} deg"
    if gyro is not None:
        text += ", gyro bias [" + ", ".join(f"{x:.4g}" for x in gyro) + "] rad/s"
    return text
