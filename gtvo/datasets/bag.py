"""ROS bags (ROS1 ``.bag``, ROS2 folders of ``.db3``/``.mcap``) as a lazy, streamed
:class:`gtvo.datasets.sequence.Sequence`, read with the pure-Python ``rosbags`` (no ROS install).

* Topics: a stereo pair of ``sensor_msgs/Image`` or ``sensor_msgs/CompressedImage`` topics
  (``.../left/...`` and ``.../right/...``, or ``cam0``/``cam1``, ``infra1``/``infra2``), or an
  RGB-D pair (a colour topic and a topic with ``depth`` in its name). With exactly one candidate
  pair no flag is needed; otherwise ``left_topic``/``right_topic`` (``depth_topic`` for RGB-D)
  choose, and the error lists the candidates.
* Frames: left (colour) messages paired with right (depth) messages by header stamp within
  :data:`STEREO_TOLERANCE_S` (:data:`RGBD_TOLERANCE_S`), each right message used once; the
  unpaired messages are counted (:attr:`BagSequence.unpaired`). The frame time is the left
  message's header stamp in seconds.
* Calibration: the ``CameraInfo`` beside each image topic (``<namespace>/camera_info``) or a
  ``--calib`` file (:mod:`gtvo.datasets.bag_calib`).
* Ground truth: a ``PoseStamped``, ``Odometry`` or ``TransformStamped`` topic, taken as poses
  ``T_world_cam`` of the raw left (colour) camera, interpolated at the frame times.
* Streaming: opening reads every image message's header once (no image is decoded or kept but
  the first of each topic); a frame's images are read when asked for, from one stream over the
  bag in log-time order that restarts at the message's log time for a jump back or far ahead.

Layouts and conventions: ``docs/datasets.md`` ("ROS bags").
"""

from __future__ import annotations

import bisect
import sqlite3
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import cv2
import numpy as np
from numpy.typing import NDArray

from gtvo.datasets._common import (FloatArray, associate_unique, interpolate_poses, poses_from_quaternions,
                                   read_trajectory, require_overlap)
from gtvo.datasets.bag_calib import BagCalibration, camera_model_from_msg, read_calib_file, rgbd_calibration, \
    stereo_calibration
from gtvo.errors import InputError
from gtvo.core.image import to_float_gray
from gtvo.datasets.sequence import Sequence

from gtvo.datasets.bag_types import (CAMERA_INFO, COMPRESSED, GROUND_TRUTH_TYPES, GT_MAX_GAP_S, GT_TOLERANCE_S,
                                     MAX_BUFFERED, MAX_READ_AHEAD, RECTIFIED_TOPIC, RGBD_TOLERANCE_S,
                                     STEREO_TOLERANCE_S)
from gtvo.datasets.bag_topics import TopicChoice, TopicSummary, camera_info_topic, choose_topics, topic_summaries


def looks_like_bag(path: Path) -> bool:
    """True for a ROS1 ``.bag`` file, a ROS2 bag folder (``metadata.yaml``), or a ``.db3``/``.mcap``
    file inside one (also when such a file is missing, so that the error says "bag not found")."""
    if path.suffix in (".bag", ".db3", ".mcap") and not path.exists():
        return True
    if path.is_file():
        return path.suffix == ".bag" or (path.suffix in (".db3", ".mcap") and (path.parent / "metadata.yaml").is_file())
    return (path / "metadata.yaml").is_file()


def bag_location(path: Path) -> Path:
    """What ``rosbags`` opens: the ``.bag`` file, or the ROS2 folder (also for a file inside it)."""
    return path.parent if path.is_file() and path.suffix in (".db3", ".mcap") else path


def _reader_errors() -> tuple[type[BaseException], ...]:
    from rosbags.highlevel import AnyReaderError  # noqa: PLC0415
    from rosbags.rosbag1 import ReaderError as Reader1Error  # noqa: PLC0415
    from rosbags.rosbag2 import ReaderError as Reader2Error  # noqa: PLC0415
    from rosbags.serde import SerdeError  # noqa: PLC0415

    return (AnyReaderError, Reader1Error, Reader2Error, SerdeError, sqlite3.Error, struct.error, EOFError,
            OSError, ValueError, KeyError, IndexError, AssertionError)


def open_reader(path: Path) -> Any:
    """An open ``rosbags.highlevel.AnyReader`` on ``path``; any failure is one InputError naming it."""
    from rosbags.highlevel import AnyReader  # noqa: PLC0415
    from rosbags.typesys import Stores, get_typestore  # noqa: PLC0415

    where = bag_location(path)
    if not where.exists():
        raise InputError("bag not found", path=where)
    try:
        reader = AnyReader([where], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except _reader_errors() as exc:
        raise InputError(f"cannot read bag (truncated or corrupt?): {_first_line(exc)}", path=where) from None
    return reader


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{exc.__class__.__name__}: {text[0]}" if text else exc.__class__.__name__


def header_stamp_ns(raw: bytes | memoryview, ros2: bool) -> int:
    """The ``header.stamp`` (ns) of a serialised message that starts with a ``std_msgs/Header``
    (ROS1: ``uint32 seq`` then ``sec, nsec``; ROS2 CDR: 4 encapsulation bytes then ``sec, nanosec``)."""
    if ros2:
        fmt = "<iI" if raw[1] == 1 else ">iI"
    else:
        fmt = "<II"
    sec, nsec = struct.unpack_from(fmt, raw, 4)
    return int(sec) * 1_000_000_000 + int(nsec)


def ns_to_seconds(ns: NDArray[np.int64] | int) -> FloatArray:
    """Seconds as ``sec + nsec / 1e9`` (the float nearest the decimal stamp ``sec.nsec``)."""
    ns = np.asarray(ns, dtype=np.int64)
    return (ns // 1_000_000_000).astype(np.float64) + (ns % 1_000_000_000) / 1e9


@dataclass
class _TopicStamps:
    header_ns: list[int] = field(default_factory=list)
    log_ns: list[int] = field(default_factory=list)


def _scan(reader: Any, image_topics: list[str], gt_topic: str | None, where: Path
          ) -> tuple[dict[str, _TopicStamps], list[tuple[int, FloatArray]]]:
    """One pass: header and log stamps of every message of ``image_topics``, and the ground-truth
    samples ``(stamp ns, T_world_cam)`` of ``gt_topic``."""
    stamps = {t: _TopicStamps() for t in image_topics}
    gt: list[tuple[int, FloatArray]] = []
    wanted = set(image_topics) | ({gt_topic} if gt_topic else set())
    connections = [c for c in reader.connections if c.topic in wanted]
    try:
        for conn, log_ns, raw in reader.messages(connections=connections):
            if conn.topic in stamps:
                entry = stamps[conn.topic]
                entry.header_ns.append(header_stamp_ns(raw, reader.is2))
                entry.log_ns.append(int(log_ns))
            else:
                gt.append(_pose_sample(reader.deserialize(raw, conn.msgtype), conn.msgtype))
    except _reader_errors() as exc:
        raise InputError(f"cannot read bag (truncated or corrupt?): {_first_line(exc)}", path=where) from None
    return stamps, gt


def _pose_sample(msg: Any, msgtype: str) -> tuple[int, FloatArray]:
    """``(header stamp ns, [tx ty tz qx qy qz qw])`` of a ground-truth message."""
    if msgtype.endswith("TransformStamped"):
        p, q = msg.transform.translation, msg.transform.rotation
    else:
        pose = msg.pose.pose if msgtype.endswith("Odometry") else msg.pose
        p, q = pose.position, pose.orientation
    stamp = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
    return stamp, np.array([p.x, p.y, p.z, q.x, q.y, q.z, q.w], dtype=np.float64)


# --------------------------------------------------------------------------------------------
# streaming messages

class BagStream:
    """Serves message ``k`` of a topic (in log-time order) from one stream over the bag.

    Asked in increasing order (a run), it reads the bag once; messages of other wanted topics met
    on the way are kept (at most :data:`MAX_BUFFERED`) until asked for. A message behind the
    stream, or more than :data:`MAX_READ_AHEAD` messages ahead, restarts the stream at its log time.
    """

    def __init__(self, path: Path, log_ns: dict[str, list[int]], wanted: dict[str, set[int]]):
        self.path = path
        self.log_ns = log_ns
        self.wanted = wanted
        self._reader: Any = None
        self._messages: Iterator[tuple[Any, int, bytes]] | None = None
        self._next: dict[str, int] = {}
        self._buffer: dict[tuple[str, int], bytes] = {}

    @property
    def reader(self) -> Any:
        """The open ``AnyReader`` (opened on first use)."""
        if self._reader is None:
            self._reader = open_reader(self.path)
        return self._reader

    def get(self, topic: str, k: int) -> bytes:
        """The raw (serialised) message ``k`` of ``topic``."""
        key = (topic, k)
        if key in self._buffer:
            return self._buffer.pop(key)
        position = self._next.get(topic, -1)
        if self._messages is None or position > k or k - position > MAX_READ_AHEAD:
            self._restart(self.log_ns[topic][k])
        try:
            for conn, _log, raw in self._messages:  # type: ignore[union-attr]
                j = self._next[conn.topic]
                self._next[conn.topic] = j + 1
                if conn.topic == topic and j == k:
                    return raw
                if j in self.wanted[conn.topic]:
                    self._keep((conn.topic, j), raw)
        except _reader_errors() as exc:
            raise InputError(f"cannot read bag (truncated or corrupt?): {_first_line(exc)}", path=self.path) from None
        self._messages = None
        raise InputError(f"message {k} of {topic} not found in the bag", path=self.path)

    def _restart(self, start_ns: int) -> None:
        topics = set(self.log_ns)
        connections = [c for c in self.reader.connections if c.topic in topics]
        self._next = {t: bisect.bisect_left(times, start_ns) for t, times in self.log_ns.items()}
        self._buffer.clear()
        self._messages = iter(self.reader.messages(connections=connections, start=start_ns))

    def _keep(self, key: tuple[str, int], raw: bytes) -> None:
        self._buffer[key] = bytes(raw)
        while len(self._buffer) > MAX_BUFFERED:
            self._buffer.pop(next(iter(self._buffer)))


# --------------------------------------------------------------------------------------------
# decoding images

def decode_image(msg: Any, msgtype: str) -> NDArray:
    """The pixels of a ``sensor_msgs/Image`` (mono8, mono16, rgb8, bgr8, rgba8, bgra8, 8UC1,
    16UC1, 32FC1) or ``CompressedImage`` (png, jpeg) as stored: gray (H, W), BGR (H, W, 3),
    uint16 or float32. InputError (message only; the caller names the file) for anything else."""
    if msgtype == COMPRESSED:
        fmt = str(msg.format).lower()
        if "compresseddepth" in fmt or not any(k in fmt for k in ("png", "jpeg", "jpg")):
            raise InputError(f"unknown compressed image format {msg.format!r} (png or jpeg)")
        image = cv2.imdecode(np.frombuffer(bytes(msg.data), dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        if image is None or image.size == 0:
            raise InputError(f"cannot decode the {msg.format!r} compressed image (corrupt data)")
        return image
    encoding = str(msg.encoding).lower()
    layouts = {"mono8": (np.uint8, 1), "8uc1": (np.uint8, 1), "mono16": (np.uint16, 1), "16uc1": (np.uint16, 1),
               "32fc1": (np.float32, 1), "rgb8": (np.uint8, 3), "bgr8": (np.uint8, 3), "rgba8": (np.uint8, 4),
               "bgra8": (np.uint8, 4)}
    if encoding not in layouts:
        raise InputError(f"unknown image encoding {msg.encoding!r} (mono8, mono16, rgb8, bgr8, 16UC1, 32FC1)")
    dtype, channels = layouts[encoding]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    item = np.dtype(dtype).itemsize
    if h < 1 or w < 1 or step < w * channels * item or data.size < h * step:
        raise InputError(f"{encoding} image {w}x{h} with step {step} needs {h * step} bytes, has {data.size}")
    rows = data[: h * step].reshape(h, step)[:, : w * channels * item]
    order = ">" if int(msg.is_bigendian) else "<"
    image = np.ascontiguousarray(rows).view(np.dtype(dtype).newbyteorder(order) if item > 1 else dtype)
    image = image.reshape(h, w, channels).astype(dtype) if channels > 1 else image.reshape(h, w).astype(dtype)
    if encoding.startswith("rgb"):
        image = image[..., [2, 1, 0]]
    return image


def depth_metres(image: NDArray, encoding: str) -> NDArray[np.float32]:
    """A depth image as metres, 0 where unknown: 16-bit values are millimetres, float values metres."""
    if image.ndim != 2 or image.dtype not in (np.uint16, np.float32):
        raise InputError(f"depth image must be 16UC1 (mm) or 32FC1 (m), got {encoding} "
                         f"({image.dtype}, shape {image.shape})")
    if image.dtype == np.uint16:
        return image.astype(np.float32) / np.float32(1000.0)
    out = image.astype(np.float32, copy=True)
    out[~np.isfinite(out)] = 0.0
    return out


class BagImageLoader:
    """Loads frame ``i`` of one topic: ``stream.get(topic, ordinals[i])``, decoded, converted to
    float gray (or metres for ``depth``) and warped when the calibration rectifies."""

    def __init__(self, stream: BagStream, topic: str, msgtype: str, ordinals: list[int], names: list[str],
                 depth: bool = False, warp: Any = None):
        self.stream, self.topic, self.msgtype = stream, topic, msgtype
        self.ordinals, self.names, self.depth, self.warp = ordinals, names, depth, warp

    def __call__(self, i: int) -> NDArray[np.float32]:
        where = self.names[i]
        try:
            msg = self.stream.reader.deserialize(self.stream.get(self.topic, self.ordinals[i]), self.msgtype)
            image = decode_image(msg, self.msgtype)
            encoding = getattr(msg, "encoding", getattr(msg, "format", "?"))
            if self.depth:
                return depth_metres(image, str(encoding))
            gray = to_float_gray(image, name=f"{self.topic} image")
        except InputError as exc:
            raise InputError(str(exc), path=where) from None
        except _reader_errors() as exc:
            raise InputError(f"cannot decode message: {_first_line(exc)}", path=where) from None
        return gray if self.warp is None else self.warp(gray)


# --------------------------------------------------------------------------------------------
# the sequence

@dataclass
class BagSequence(Sequence):
    """A :class:`Sequence` read from a bag, with what pairing left out and what it used.

    Attributes:
        unpaired: messages of each image topic that found no partner (whole bag).
        topics: the :class:`TopicChoice` used.
        calibration_source: where the calibration came from.
    """

    unpaired: dict[str, int] = field(default_factory=dict)
    topics: TopicChoice | None = None
    calibration_source: str = ""


def _pair(first: _TopicStamps, second: _TopicStamps, tolerance: float, choice: TopicChoice, where: Path
          ) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.int64]]:
    """Ordinals of paired (first, second) messages, ordered by the first's stamp, and its stamps."""
    a = np.asarray(first.header_ns, dtype=np.int64)
    b = np.asarray(second.header_ns, dtype=np.int64)
    if a.size == 0 or b.size == 0:
        raise InputError(f"no messages on {choice.first if a.size == 0 else choice.second}", path=where)
    for topic, stamps in ((choice.first, a), (choice.second, b)):
        distinct = np.unique(stamps).size
        if 2 * distinct < stamps.size:
            raise InputError(f"{topic}: {stamps.size} messages carry only {distinct} distinct header stamps "
                             f"(a driver that does not stamp its images?)", path=where)
    origin = int(min(a.min(), b.min()))
    order_a, order_b = np.argsort(a, kind="stable"), np.argsort(b, kind="stable")
    ta, tb = (a[order_a] - origin) * 1e-9, (b[order_b] - origin) * 1e-9
    ia, ib = associate_unique(tb, ta, tolerance)
    if ia.size == 0:
        raise InputError(f"the stamps of {choice.first} ({ns_to_seconds(a.min()):.6f}..{ns_to_seconds(a.max()):.6f} s) "
                         f"and {choice.second} ({ns_to_seconds(b.min()):.6f}..{ns_to_seconds(b.max()):.6f} s) never "
                         f"pair within {tolerance * 1e3:g} ms", path=where)
    return order_a[ia], order_b[ib], a[order_a[ia]]


def _calibration(topics: list[TopicSummary], choice: TopicChoice, calib: Path | None, size: tuple[int, int],
                 where: Path) -> BagCalibration:
    """From ``calib`` when given, else from the first CameraInfo beside each image topic."""
    if calib is not None:
        return read_calib_file(calib, choice.kind, size)
    image_topics = [choice.first] if choice.kind == "rgbd" else [choice.first, choice.second]
    models = []
    for topic in image_topics:
        info = camera_info_topic(topic, topics)
        if info is None:
            raise InputError(f"no sensor_msgs/CameraInfo topic beside {topic} (its namespace's camera_info): "
                             f"pass --calib FILE", path=where)
        reader = open_reader(where)
        try:
            conn = [c for c in reader.connections if c.topic == info]
            _, _, raw = next(iter(reader.messages(connections=conn)))
            msg = reader.deserialize(raw, CAMERA_INFO)
        except StopIteration:
            raise InputError(f"{info} has no message", path=where) from None
        except _reader_errors() as exc:
            raise InputError(f"cannot read {info}: {_first_line(exc)}", path=where) from None
        finally:
            reader.close()
        models.append(camera_model_from_msg(msg, f"{where}: {info}"))
    rectified = all(RECTIFIED_TOPIC.search(t) for t in image_topics)
    if choice.kind == "rgbd":
        return rgbd_calibration(models[0], rectified, size)
    return stereo_calibration(models[0], models[1], rectified, size)


def _ground_truth(samples: list[tuple[int, FloatArray]], gt_topic: str | None, gt_file: Path | None,
                  times: FloatArray, calibration: BagCalibration, where: Path) -> FloatArray | None:
    """Ground truth at ``times`` (NaN rows where none), carried to the rectified left camera; from
    ``gt_file`` when given, else from the topic's ``samples``; None without either."""
    if gt_file is not None:
        gt_times, poses = read_trajectory(gt_file)
        label: Path | str = gt_file
    elif gt_topic is not None:
        if not samples:
            raise InputError(f"ground-truth topic {gt_topic} has no message", path=where)
        samples = sorted(samples, key=lambda s: s[0])
        ns = np.array([s[0] for s in samples], dtype=np.int64)
        if np.any(np.diff(ns) <= 0):
            raise InputError(f"ground-truth topic {gt_topic} has repeated header stamps", path=where)
        table = np.array([s[1] for s in samples])
        label = f"{where}: {gt_topic}"
        gt_times = ns_to_seconds(ns)
        poses = poses_from_quaternions(table[:, :3], table[:, 3:], Path(label), list(range(1, len(samples) + 1)))
    else:
        return None
    out = interpolate_poses(gt_times, poses, times, GT_TOLERANCE_S, GT_MAX_GAP_S) @ calibration.T_raw_rect
    require_overlap(out, Path(str(label)), times, gt_times)
    return out


def read_bag(path: Path, max_frames: int | None = None, calib: Path | None = None, left_topic: str | None = None,
             right_topic: str | None = None, depth_topic: str | None = None, ground_truth_topic: str | None = None,
             ground_truth: Path | None = None, stamp_tolerance: float | None = None) -> BagSequence:
    """Open a ROS1 ``.bag`` or a ROS2 bag folder as a lazy, streamed stereo or RGB-D sequence.

    Args:
        path: the ``.bag`` file, the ROS2 folder, or its ``.db3``/``.mcap`` file.
        max_frames: keep only the first paired frames.
        calib: a calibration file instead of the bag's CameraInfo (:func:`read_calib_file`).
        left_topic, right_topic, depth_topic: the image topics (module docstring).
        ground_truth_topic: a PoseStamped / Odometry / TransformStamped topic of ``T_world_cam``.
        ground_truth: a TUM or ASL trajectory file instead of a topic.
        stamp_tolerance: pairing tolerance (s); default :data:`STEREO_TOLERANCE_S` / :data:`RGBD_TOLERANCE_S`.
    """
    where = bag_location(path)
    reader = open_reader(where)
    try:
        topics = topic_summaries(reader)
        choice = choose_topics(topics, left_topic, right_topic, depth_topic, where)
        if ground_truth_topic is not None:
            _check_gt_topic(ground_truth_topic, topics, where)
        stamps, samples = _scan(reader, [choice.first, choice.second], ground_truth_topic, where)
        msgtypes = {t.name: t.msgtype for t in topics}
    finally:
        reader.close()
    tolerance = stamp_tolerance if stamp_tolerance is not None else (
        STEREO_TOLERANCE_S if choice.kind == "stereo" else RGBD_TOLERANCE_S)
    first, second, stamp_ns = _pair(stamps[choice.first], stamps[choice.second], tolerance, choice, where)
    unpaired = {choice.first: len(stamps[choice.first].header_ns) - first.size,
                choice.second: len(stamps[choice.second].header_ns) - second.size}
    if max_frames is not None:
        first, second, stamp_ns = first[:max_frames], second[:max_frames], stamp_ns[:max_frames]
    times = ns_to_seconds(stamp_ns)
    log_ns = {t: stamps[t].log_ns for t in (choice.first, choice.second)}
    stream = BagStream(where, log_ns, {choice.first: set(first.tolist()), choice.second: set(second.tolist())})
    names = [f"{where}:{choice.first}@{t:.9f}" for t in times]
    probe = BagImageLoader(stream, choice.first, msgtypes[choice.first], first.tolist(), names)
    height, width = probe(0).shape[:2]
    calibration = _calibration(topics, choice, calib, (width, height), where)
    gt_poses = _ground_truth(samples, ground_truth_topic, ground_truth, times, calibration, where)
    second_names = [f"{where}:{choice.second}@{ns_to_seconds(stamps[choice.second].header_ns[k]):.9f}"
                    for k in second]
    load_left = BagImageLoader(stream, choice.first, msgtypes[choice.first], first.tolist(), names,
                               warp=calibration.warp_left)
    load_second = BagImageLoader(stream, choice.second, msgtypes[choice.second], second.tolist(), second_names,
                                 depth=choice.kind == "rgbd", warp=calibration.warp_right)
    load_second(0)  # an unknown encoding fails here, naming the bag and topic
    stereo = choice.kind == "stereo"
    return BagSequence(name=(where.stem if where.is_file() else where.resolve().name), kind=choice.kind,
                       camera=calibration.camera, timestamps=times, load_left=load_left,
                       load_right=load_second if stereo else None, load_depth=None if stereo else load_second,
                       gt_poses=gt_poses, source=where, frame_names=names, unpaired=unpaired, topics=choice,
                       calibration_source=calibration.source)


def _check_gt_topic(topic: str, topics: list[TopicSummary], where: Path) -> None:
    types = {t.name: t.msgtype for t in topics}
    if topic not in types:
        candidates = [t.name for t in topics if t.msgtype in GROUND_TRUTH_TYPES]
        raise InputError(f"--ground-truth-topic {topic}: no such topic in the bag; pose topics: "
                         f"{', '.join(candidates) or 'none'}", path=where)
    if types[topic] not in GROUND_TRUTH_TYPES:
        raise InputError(f"--ground-truth-topic {topic} is {types[topic]}, not PoseStamped, Odometry or "
                         f"TransformStamped", path=where)
