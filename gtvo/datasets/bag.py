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

import struct
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gtvo.datasets._common import (FloatArray, associate_unique, interpolate_poses, poses_from_quaternions,
                                   read_trajectory, require_overlap)
from gtvo.datasets.bag_calib import BagCalibration, camera_model_from_msg, read_calib_file, rgbd_calibration, \
    stereo_calibration
from gtvo.errors import InputError
from gtvo.datasets.sequence import Sequence

from gtvo.datasets.bag_types import (CAMERA_INFO, GROUND_TRUTH_TYPES, GT_MAX_GAP_S, GT_TOLERANCE_S, RECTIFIED_TOPIC,
                                     RGBD_TOLERANCE_S, STEREO_TOLERANCE_S)
from gtvo.datasets.bag_stream import BagImageLoader, BagStream, first_line, open_reader, reader_errors, bag_location
from gtvo.datasets.bag_topics import TopicChoice, TopicSummary, camera_info_topic, choose_topics, topic_summaries
from gtvo.datasets.bag_imu import bag_imu
from gtvo.datasets.bag_wheel import bag_wheel_odometry
from gtvo.datasets.imu_files import ImuReadOptions
from gtvo.datasets.wheel_files import WheelReadOptions


def looks_like_bag(path: Path) -> bool:
    """True for a ROS1 ``.bag`` file, a ROS2 bag folder (``metadata.yaml``), or a ``.db3``/``.mcap``
    file inside one (also when such a file is missing, so that the error says "bag not found")."""
    if path.suffix in (".bag", ".db3", ".mcap") and not path.exists():
        return True
    if path.is_file():
        return path.suffix == ".bag" or (path.suffix in (".db3", ".mcap") and (path.parent / "metadata.yaml").is_file())
    return (path / "metadata.yaml").is_file()


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
    except reader_errors() as exc:
        raise InputError(f"cannot read bag (truncated or corrupt?): {first_line(exc)}", path=where) from None
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

    def unpaired_warning(self) -> str | None:
        """One line when image messages found no partner (a camera dropped images, or stamps
        further apart than the pairing tolerance): the frames they would have made are left out.
        None when every message was paired."""
        counts = {topic: n for topic, n in self.unpaired.items() if n}
        if not counts:
            return None
        topics = list(self.unpaired)
        parts = [f"{n} {topic} message{'s' if n > 1 else ''} without a "
                 f"{next((t for t in topics if t != topic), 'partner')} partner" for topic, n in counts.items()]
        return (f"{self.source}: {', '.join(parts)}: those frames are left out (a camera dropped images, or "
                f"--stamp-tolerance is too tight; unpaired_messages in report.json)")


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
        except reader_errors() as exc:
            raise InputError(f"cannot read {info}: {first_line(exc)}", path=where) from None
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
             ground_truth: Path | None = None, stamp_tolerance: float | None = None, wheel_topic: str | None = None,
             wheel_options: WheelReadOptions | None = None, imu_options: ImuReadOptions | None = None) -> BagSequence:
    """Open a ROS1 ``.bag`` or a ROS2 bag folder as a lazy, streamed stereo or RGB-D sequence.

    Args:
        path: the ``.bag`` file, the ROS2 folder, or its ``.db3``/``.mcap`` file.
        max_frames: keep only the first paired frames.
        calib: a calibration file instead of the bag's CameraInfo (:func:`read_calib_file`).
        left_topic, right_topic, depth_topic: the image topics (module docstring).
        ground_truth_topic: a PoseStamped / Odometry / TransformStamped topic of ``T_world_cam``.
        ground_truth: a TUM or ASL trajectory file instead of a topic.
        stamp_tolerance: pairing tolerance (s); default :data:`STEREO_TOLERANCE_S` / :data:`RGBD_TOLERANCE_S`.
        wheel_topic: the wheel odometry topic (``"none"``: none), default ``wheel_options.topic`` or
            the one candidate (:mod:`gtvo.datasets.bag_wheel`).
        wheel_options: how wheel readings become metres (:class:`WheelReadOptions`).
        imu_options: the IMU's topic and what the bag does not give (:mod:`gtvo.datasets.bag_imu`);
            None: no IMU.
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
    wheel = wheel_options or WheelReadOptions()
    if wheel_topic is not None:
        wheel = replace(wheel, topic=wheel_topic)
    wheel_odometry = bag_wheel_odometry(where, topics, wheel, choice.first, calibration.T_raw_rect,
                                        exclude=(ground_truth_topic,) if ground_truth_topic else ())
    stereo = choice.kind == "stereo"
    return BagSequence(name=(where.stem if where.is_file() else where.resolve().name), kind=choice.kind,
                       camera=calibration.camera, timestamps=times, load_left=load_left,
                       load_right=load_second if stereo else None, load_depth=None if stereo else load_second,
                       gt_poses=gt_poses, source=where, frame_names=names, unpaired=unpaired, topics=choice,
                       calibration_source=calibration.source, wheel_odometry=wheel_odometry,
                       imu=None if imu_options is None else bag_imu(where, topics, imu_options, choice.first,
                                                                     calibration.T_raw_rect))


def _check_gt_topic(topic: str, topics: list[TopicSummary], where: Path) -> None:
    types = {t.name: t.msgtype for t in topics}
    if topic not in types:
        candidates = [t.name for t in topics if t.msgtype in GROUND_TRUTH_TYPES]
        raise InputError(f"--ground-truth-topic {topic}: no such topic in the bag; pose topics: "
                         f"{', '.join(candidates) or 'none'}", path=where)
    if types[topic] not in GROUND_TRUTH_TYPES:
        raise InputError(f"--ground-truth-topic {topic} is {types[topic]}, not PoseStamped, Odometry or "
                         f"TransformStamped", path=where)
