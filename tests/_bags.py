"""Writing small ROS1 / ROS2 bags with ``rosbags``' writers for the bag reader's tests (and the
memory benchmark): images, CameraInfo and pose messages from numpy arrays.

>>> with BagWriter(tmp / "log.bag") as bag:                      # doctest: +SKIP
...     bag.image("/cam/left/image_raw", stamp_ns, gray_uint8)
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import cv2
import numpy as np


def stamp_from_text(text: str) -> int:
    """Nanoseconds of a decimal stamp ``"1341847980.722988"`` (exact, no float on the way)."""
    sec, _, frac = text.strip().partition(".")
    return int(sec) * 1_000_000_000 + int((frac + "000000000")[:9])


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
    def image(self, topic: str, stamp_ns: int, pixels: np.ndarray, encoding: str, log_ns: int | None = None) -> None:
        """A ``sensor_msgs/Image`` of ``pixels`` (stored as given, little-endian) named ``encoding``."""
        arr = np.ascontiguousarray(pixels)
        h, w = arr.shape[:2]
        msg = self._make("sensor_msgs/msg/Image", header=self.header(stamp_ns), height=h, width=w, encoding=encoding,
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

    def pose(self, topic: str, stamp_ns: int, T: np.ndarray, msgtype: str = "geometry_msgs/msg/PoseStamped") -> None:
        """A pose ``T`` (4x4) as PoseStamped, Odometry or TransformStamped."""
        from scipy.spatial.transform import Rotation  # noqa: PLC0415

        qx, qy, qz, qw = Rotation.from_matrix(T[:3, :3]).as_quat()
        x, y, z = (float(v) for v in T[:3, 3])
        quat = self._make("geometry_msgs/msg/Quaternion", x=qx, y=qy, z=qz, w=qw)
        if msgtype.endswith("TransformStamped"):
            tf = self._make("geometry_msgs/msg/Transform", translation=self._make("geometry_msgs/msg/Vector3", x=x, y=y,
                                                                                  z=z), rotation=quat)
            msg = self._make(msgtype, header=self.header(stamp_ns, "world"), child_frame_id="cam", transform=tf)
        else:
            pose = self._make("geometry_msgs/msg/Pose", position=self._make("geometry_msgs/msg/Point", x=x, y=y, z=z),
                              orientation=quat)
            if msgtype.endswith("Odometry"):
                cov = np.zeros(36)
                pose = self._make("geometry_msgs/msg/PoseWithCovariance", pose=pose, covariance=cov)
                twist = self._make("geometry_msgs/msg/TwistWithCovariance", twist=self._make(
                    "geometry_msgs/msg/Twist", linear=self._make("geometry_msgs/msg/Vector3", x=0.0, y=0.0, z=0.0),
                    angular=self._make("geometry_msgs/msg/Vector3", x=0.0, y=0.0, z=0.0)), covariance=cov)
                msg = self._make(msgtype, header=self.header(stamp_ns, "world"), child_frame_id="cam", pose=pose,
                                 twist=twist)
            else:
                msg = self._make(msgtype, header=self.header(stamp_ns, "world"), pose=pose)
        self.write(topic, msgtype, stamp_ns, msg)
