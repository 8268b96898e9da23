"""Writing ROS1 / ROS2 bags with ``rosbags``' writers: images, CameraInfo, poses, wheel odometry and
``/tf_static`` from numpy arrays (:class:`BagWriter`), and a whole stereo sequence with its ground
truth and wheel odometry (:func:`write_sequence_bag`: ``gtvo synthetic --bag``; the bag reader's tests).

>>> with BagWriter(tmp / "log.bag") as bag:                      # doctest: +SKIP
...     bag.image("/cam/left/image_raw", stamp_ns, gray_uint8, "mono8")
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from gtvo.core.camera import StereoCamera
from gtvo.core.lie import rot2, rotations_to_quaternions, se2_log
from gtvo.datasets.sequence import Sequence
from gtvo.datasets.wheel import WheelOdometry
from gtvo.errors import InputError


def stamp_from_text(text: str) -> int:
    """Nanoseconds of a decimal stamp ``"1341847980.722988"`` (exact, no float on the way)."""
    sec, _, frac = text.strip().partition(".")
    return int(sec) * 1_000_000_000 + int((frac + "000000000")[:9])


#: The message type of ``/tf_static``.
TF_MESSAGE = "tf2_msgs/msg/TFMessage"


class BagWriter:
    """A ROS1 ``.bag`` (path ending ``.bag``) or a ROS2 folder (sqlite3, or mcap with ``mcap=True``)."""

    def __init__(self, path: Path, mcap: bool = False):
        from rosbags.typesys import Stores, get_typestore  # noqa: PLC0415

        self.path = Path(path)
        self.ros2 = self.path.suffix != ".bag"
        if self.ros2:
            from rosbags.rosbag2 import StoragePlugin, Writer  # noqa: PLC0415

            plugin = StoragePlugin.MCAP if mcap else StoragePlugin.SQLITE3
            self.writer = Writer(self.path, version=9, storage_plugin=plugin)
            self.typestore = get_typestore(Stores.ROS2_HUMBLE)
        else:
            from rosbags.rosbag1 import Writer  # noqa: PLC0415

            self.writer = Writer(self.path)
            self.typestore = get_typestore(Stores.ROS1_NOETIC)
        self.connections: dict[str, Any] = {}
        if TF_MESSAGE not in self.typestore.types:  # not among rosbags' stored types: defined here
            from rosbags.typesys import get_types_from_msg  # noqa: PLC0415

            self.typestore.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF_MESSAGE))

    def __enter__(self) -> "BagWriter":
        self.writer.open()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.writer.close()

    # -- message construction ------------------------------------------------------------
    def _make(self, msgtype: str, **values: Any) -> Any:
        cls = self.typestore.types[msgtype]
        names = {f.name for f in dataclasses.fields(cls)}
        fixed = {}
        for key, value in values.items():
            for name in (key, key.upper(), key.lower()):
                if name in names:
                    fixed[name] = value
                    break
        return cls(**fixed)

    def header(self, stamp_ns: int, frame_id: str = "cam") -> Any:
        time = self._make("builtin_interfaces/msg/Time", sec=stamp_ns // 1_000_000_000,
                          nanosec=stamp_ns % 1_000_000_000)
        return self._make("std_msgs/msg/Header", seq=0, stamp=time, frame_id=frame_id)

    def write(self, topic: str, msgtype: str, log_ns: int, msg: Any) -> None:
        """Serialise and write ``msg`` on ``topic`` at log time ``log_ns``."""
        if topic not in self.connections:
            self.connections[topic] = self.writer.add_connection(topic, msgtype, typestore=self.typestore)
        data = (self.typestore.serialize_cdr(msg, msgtype) if self.ros2
                else self.typestore.serialize_ros1(msg, msgtype))
        self.writer.write(self.connections[topic], int(log_ns), data)

    # -- messages ------------------------------------------------------------------------
    def image(self, topic: str, stamp_ns: int, pixels: np.ndarray, encoding: str, log_ns: int | None = None,
              frame_id: str = "cam") -> None:
        """A ``sensor_msgs/Image`` of ``pixels`` (stored as given, little-endian) named ``encoding``."""
        arr = np.ascontiguousarray(pixels)
        h, w = arr.shape[:2]
        msg = self._make("sensor_msgs/msg/Image", header=self.header(stamp_ns, frame_id), height=h, width=w, encoding=encoding,
                         is_bigendian=0, step=arr.nbytes // h, data=arr.view(np.uint8).reshape(-1))
        self.write(topic, "sensor_msgs/msg/Image", stamp_ns if log_ns is None else log_ns, msg)

    def compressed(self, topic: str, stamp_ns: int, pixels: np.ndarray, fmt: str = "png") -> None:
        """A ``sensor_msgs/CompressedImage`` of ``pixels`` (gray or BGR) encoded as ``fmt``."""
        ok, buf = cv2.imencode(".png" if fmt == "png" else ".jpg", pixels)
        assert ok
        msg = self._make("sensor_msgs/msg/CompressedImage", header=self.header(stamp_ns), format=fmt,
                         data=np.asarray(buf, dtype=np.uint8).reshape(-1))
        self.write(topic, "sensor_msgs/msg/CompressedImage", stamp_ns, msg)

    def camera_info(self, topic: str, stamp_ns: int, width: int, height: int, K: np.ndarray,
                    P: np.ndarray, D: np.ndarray | None = None, R: np.ndarray | None = None) -> None:
        """A ``sensor_msgs/CameraInfo`` (plumb_bob)."""
        roi = self._make("sensor_msgs/msg/RegionOfInterest", x_offset=0, y_offset=0, height=0, width=0,
                         do_rectify=False)
        msg = self._make("sensor_msgs/msg/CameraInfo", header=self.header(stamp_ns), height=height, width=width,
                         distortion_model="plumb_bob",
                         d=np.asarray(D if D is not None else np.zeros(5), dtype=np.float64),
                         k=np.asarray(K, dtype=np.float64).reshape(-1),
                         r=np.asarray(R if R is not None else np.eye(3), dtype=np.float64).reshape(-1),
                         p=np.asarray(P, dtype=np.float64).reshape(-1), binning_x=0, binning_y=0, roi=roi)
        self.write(topic, "sensor_msgs/msg/CameraInfo", stamp_ns, msg)

    def _vector(self, x: float, y: float, z: float, msgtype: str = "geometry_msgs/msg/Vector3") -> Any:
        return self._make(msgtype, x=float(x), y=float(y), z=float(z))

    def _quaternion(self, R: np.ndarray) -> Any:
        qx, qy, qz, qw = (float(v) for v in rotations_to_quaternions(R)[0])
        return self._make("geometry_msgs/msg/Quaternion", x=qx, y=qy, z=qz, w=qw)

    def _transform(self, stamp_ns: int, parent: str, child: str, T: np.ndarray) -> Any:
        tf = self._make("geometry_msgs/msg/Transform", translation=self._vector(*T[:3, 3]),
                        rotation=self._quaternion(T[:3, :3]))
        return self._make("geometry_msgs/msg/TransformStamped", header=self.header(stamp_ns, parent),
                          child_frame_id=child, transform=tf)

    def pose(self, topic: str, stamp_ns: int, T: np.ndarray, msgtype: str = "geometry_msgs/msg/PoseStamped") -> None:
        """A pose ``T`` (4x4) as PoseStamped, Odometry or TransformStamped."""
        if msgtype.endswith("TransformStamped"):
            msg = self._transform(stamp_ns, "world", "cam", T)
        else:
            pose = self._make("geometry_msgs/msg/Pose", position=self._vector(*T[:3, 3], "geometry_msgs/msg/Point"),
                              orientation=self._quaternion(T[:3, :3]))
            if msgtype.endswith("Odometry"):
                msg = self._odometry_msg(stamp_ns, pose, np.zeros(3), "world", "cam")
            else:
                msg = self._make(msgtype, header=self.header(stamp_ns, "world"), pose=pose)
        self.write(topic, msgtype, stamp_ns, msg)

    def _odometry_msg(self, stamp_ns: int, pose: Any, twist: np.ndarray, frame: str, child: str) -> Any:
        cov = np.zeros(36)
        vx, vy, wz = (float(v) for v in twist)
        moving = self._make("geometry_msgs/msg/Twist", linear=self._vector(vx, vy, 0.0), angular=self._vector(0, 0, wz))
        return self._make("nav_msgs/msg/Odometry", header=self.header(stamp_ns, frame), child_frame_id=child,
                          pose=self._make("geometry_msgs/msg/PoseWithCovariance", pose=pose, covariance=cov),
                          twist=self._make("geometry_msgs/msg/TwistWithCovariance", twist=moving, covariance=cov))

    def odometry(self, topic: str, stamp_ns: int, planar_pose: np.ndarray, twist: np.ndarray,
                 frame: str = "odom", child: str = "base_link") -> None:
        """A ``nav_msgs/Odometry`` of a planar base pose ``(x, y, theta)`` and body twist ``(vx, vy, wz)``."""
        x, y, theta = (float(v) for v in planar_pose)
        c, s = np.cos(theta), np.sin(theta)
        R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        pose = self._make("geometry_msgs/msg/Pose", position=self._vector(x, y, 0.0, "geometry_msgs/msg/Point"),
                          orientation=self._quaternion(R))
        self.write(topic, "nav_msgs/msg/Odometry", stamp_ns, self._odometry_msg(stamp_ns, pose, twist, frame, child))

    def joint_state(self, topic: str, stamp_ns: int, names: list[str], positions: np.ndarray) -> None:
        """A ``sensor_msgs/JointState`` of joint ``positions`` (rad), no velocities or efforts."""
        msg = self._make("sensor_msgs/msg/JointState", header=self.header(stamp_ns, ""), name=list(names),
                         position=np.asarray(positions, dtype=np.float64), velocity=np.zeros(0), effort=np.zeros(0))
        self.write(topic, "sensor_msgs/msg/JointState", stamp_ns, msg)

    def imu(self, topic: str, stamp_ns: int, gyro: np.ndarray, accel: np.ndarray, frame_id: str = "imu") -> None:
        """A ``sensor_msgs/Imu`` of an angular rate (rad/s) and a specific force (m/s^2); no orientation
        (its covariance's first entry -1, REP 145), zero covariances."""
        cov = np.zeros(9)
        orientation_cov = cov.copy()
        orientation_cov[0] = -1.0
        msg = self._make("sensor_msgs/msg/Imu", header=self.header(stamp_ns, frame_id),
                         orientation=self._make("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0),
                         orientation_covariance=orientation_cov, angular_velocity=self._vector(*gyro),
                         angular_velocity_covariance=cov, linear_acceleration=self._vector(*accel),
                         linear_acceleration_covariance=cov)
        self.write(topic, "sensor_msgs/msg/Imu", stamp_ns, msg)

    def tf_static(self, stamp_ns: int, transforms: list[tuple[str, str, np.ndarray]]) -> None:
        """A ``/tf_static`` message of ``(parent, child, T_parent_child)`` transforms."""
        msg = self._make(TF_MESSAGE,
                         transforms=[self._transform(stamp_ns, a, b, T) for a, b, T in transforms])
        self.write("/tf_static", TF_MESSAGE, stamp_ns, msg)


#: Topics and frames of :func:`write_sequence_bag`.
SEQUENCE_TOPICS = {"left": "/cam/left/image_rect", "right": "/cam/right/image_rect", "ground_truth": "/ground_truth",
                   "odometry": "/odom", "joints": "/joint_states", "imu": "/imu"}
WHEEL_JOINTS = ("left_wheel_joint", "right_wheel_joint")


def write_sequence_bag(seq: Sequence, path: str | Path, wheel_radius: float = 0.1, mcap: bool = False,
                       progress: bool = False) -> Path:
    """Write a stereo sequence as a ROS1 ``.bag`` (``path`` ending ``.bag``) or a ROS2 folder.

    Topics (:data:`SEQUENCE_TOPICS`): rectified mono8 images and their CameraInfo under
    ``/cam/{left,right}/``, the ground truth ``T_world_cam`` as PoseStamped on ``/ground_truth``
    (``--ground-truth-topic /ground_truth``), and with wheel odometry: ``/odom``
    (``nav_msgs/Odometry``: the planar pose the robot integrates, and its twist), ``/joint_states``
    (``sensor_msgs/JointState``: :data:`WHEEL_JOINTS` at arc / ``wheel_radius``) and ``/tf_static``
    (``base_link`` to the left camera's frame ``cam_left``); with an IMU: ``/imu``
    (``sensor_msgs/Imu`` in the frame ``imu``) and ``/tf_static`` from ``imu`` to ``cam_left``.
    """
    path = Path(path)
    if seq.kind != "stereo" or not isinstance(seq.camera, StereoCamera):
        raise InputError(f"sequence {seq.name} is not stereo; the bag writer writes a stereo pair")
    if path.exists():
        raise InputError("exists: a bag is not overwritten (remove it first)", path)
    cam = seq.camera
    P = np.hstack([cam.left.K, np.zeros((3, 1))])
    stamps = [int(round(t * 1e9)) + 1_000_000_000 for t in seq.timestamps]  # a ROS time > 0
    frames = range(len(seq))
    if progress:
        from tqdm import tqdm  # noqa: PLC0415
        frames = tqdm(frames, desc=f"writing {path}", unit="frame")
    with BagWriter(path, mcap=mcap) as bag:
        for side, tx in (("left", 0.0), ("right", -cam.left.fx * cam.baseline)):
            P[0, 3] = tx
            bag.camera_info(f"/cam/{side}/camera_info", stamps[0], cam.left.width, cam.left.height, cam.left.K, P)
        if seq.wheel_odometry is not None:
            _write_wheels(bag, seq.wheel_odometry, stamps[0], wheel_radius)
        if seq.imu is not None:
            bag.tf_static(stamps[0], [("imu", "cam_left", np.linalg.inv(seq.imu.T_cam_imu))])
            for t, w, a in zip(seq.imu.times, seq.imu.gyro, seq.imu.accel):
                bag.imu(SEQUENCE_TOPICS["imu"], int(round(t * 1e9)) + 1_000_000_000, w, a)
        for i in frames:
            for side, image in (("left", seq.left(i)), ("right", seq.right(i))):
                bag.image(SEQUENCE_TOPICS[side], stamps[i], np.clip(np.rint(image), 0, 255).astype(np.uint8),
                          "mono8", frame_id=f"cam_{side}")
            if seq.gt_poses is not None and np.all(np.isfinite(seq.gt_poses[i])):
                bag.pose(SEQUENCE_TOPICS["ground_truth"], stamps[i], seq.gt_poses[i])
    return path


def _write_wheels(bag: BagWriter, odo: WheelOdometry, first_ns: int, wheel_radius: float) -> None:
    """``/odom``, ``/joint_states`` and ``/tf_static`` of the wheel odometry (:func:`write_sequence_bag`)."""
    poses, arcs = odo.as_kind("pose").values, odo.as_kind("arcs").values
    steps = odo.as_kind("pose").steps()
    xi = se2_log(rot2(steps[:, 2]), steps[:, :2])  # the twist held over a step that makes the step
    twists = np.vstack([xi / np.diff(odo.times)[:, None], np.zeros((1, 3))])
    if odo.base_to_camera is not None:
        bag.tf_static(first_ns, [("base_link", "cam_left", odo.base_to_camera)])
    for k, t in enumerate(odo.times):
        ns = int(round(t * 1e9)) + 1_000_000_000
        bag.odometry(SEQUENCE_TOPICS["odometry"], ns, poses[k], twists[k])
        bag.joint_state(SEQUENCE_TOPICS["joints"], ns, list(WHEEL_JOINTS), arcs[k] / wheel_radius)
