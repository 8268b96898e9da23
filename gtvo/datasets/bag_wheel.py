"""Wheel odometry from a bag's topics, and the base-to-camera transform from its ``/tf_static``
(docs/wheel_odometry.md, "ROS bags").

* ``nav_msgs/Odometry``: the pose (x, y, yaw of ``pose.pose``); when every message carries the same
  pose (a driver that publishes only its twist), the twist is integrated instead, and the source
  says so.
* ``geometry_msgs/TwistStamped``: the base's velocity (``linear.x``, ``linear.y``, ``angular.z``),
  integrated: each reading's twist held until the next (an exact arc per step).
* ``sensor_msgs/JointState``: the left and right wheel joints' positions (rad) times the nominal
  wheel radius: cumulative arcs.

Times are the messages' header stamps. The topic is chosen by name (``--wheel-topic``) or is the
one candidate of these types; JointState topics are candidates only when a wheel radius is set.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gtvo.core.lie import invert_poses, quaternions_to_rotations, se2_exp
from gtvo.datasets.bag_stream import first_line, open_reader, reader_errors
from gtvo.datasets.bag_topics import TopicSummary
from gtvo.datasets.wheel import FloatArray, WheelOdometry, check_readings
from gtvo.datasets.wheel_files import WheelReadOptions
from gtvo.errors import InputError

ODOMETRY = "nav_msgs/msg/Odometry"
TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
JOINT_STATE = "sensor_msgs/msg/JointState"
WHEEL_TYPES = (ODOMETRY, TWIST_STAMPED, JOINT_STATE)
TF_STATIC = "/tf_static"
#: Base frames looked for in ``/tf_static`` when the wheel messages name none (REP 105).
BASE_FRAMES = ("base_link", "base_footprint")
#: ``--wheel-topic none``: no wheel odometry from the bag.
NO_WHEEL_TOPIC = "none"


def wheel_topic_candidates(topics: list[TopicSummary], options: WheelReadOptions,
                           exclude: tuple[str, ...] = ()) -> list[str]:
    """Topics that can carry wheel odometry (module doc), but for ``exclude`` (the ground truth's)."""
    types = WHEEL_TYPES if options.wheel_radius is not None else (ODOMETRY, TWIST_STAMPED)
    return [t.name for t in topics if t.msgtype in types and t.count > 0 and t.name not in exclude]


def choose_wheel_topic(topics: list[TopicSummary], options: WheelReadOptions, exclude: tuple[str, ...],
                       where: Path) -> str | None:
    """The wheel topic: ``options.topic`` (checked), else the one candidate, else None (no candidate).

    Raises:
        InputError: the named topic is missing or of another type; several candidates and no choice.
    """
    if options.topic == NO_WHEEL_TOPIC:
        return None
    candidates = wheel_topic_candidates(topics, options, exclude)
    if options.topic is not None:
        types = {t.name: t.msgtype for t in topics}
        if types.get(options.topic) not in WHEEL_TYPES:
            found = f"is {types[options.topic]}" if options.topic in types else "is not in the bag"
            raise InputError(f"--wheel-topic {options.topic} {found}; wheel odometry topics (Odometry, TwistStamped, "
                             f"JointState): {', '.join(candidates) or 'none'}", path=where)
        return options.topic
    if len(candidates) > 1:
        raise InputError(f"{len(candidates)} wheel odometry topics ({', '.join(candidates)}): choose one with "
                         f"--wheel-topic TOPIC (config wheel.topic), or --wheel-topic none", path=where)
    return candidates[0] if candidates else None


def _messages(where: Path, topic: str) -> list[tuple[Any, str]]:
    """Every message of ``topic``, deserialised, in log order, with its type."""
    reader = open_reader(where)
    try:
        conns = [c for c in reader.connections if c.topic == topic]
        return [(reader.deserialize(raw, c.msgtype), c.msgtype) for c, _, raw in reader.messages(connections=conns)]
    except reader_errors() as exc:
        raise InputError(f"cannot read {topic}: {first_line(exc)}", path=where) from None
    finally:
        reader.close()


def _stamp(msg: Any) -> float:
    return int(msg.header.stamp.sec) + int(msg.header.stamp.nanosec) * 1e-9


@dataclass(frozen=True)
class StampedMessages:
    """A topic's messages as a reader of timed readings wants them (the wheels' and the IMU's).

    Attributes:
        messages: every message, deserialised, in log order, with its type.
        times: (N,) their header stamps (s).
        rows: (N,) their numbers from 1, as the refusals name them ("message 13").
        source: ``<bag>:<topic>``.
    """

    messages: list[tuple[Any, str]]
    times: FloatArray
    rows: NDArray[np.int64]
    source: str


def stamped_messages(where: Path, topic: str, what: str) -> StampedMessages:
    """``topic``'s messages with their stamps and numbers (``what`` names the stream in the refusal).

    Raises:
        InputError: the topic cannot be read or has no message.
    """
    messages = _messages(where, topic)
    if not messages:
        raise InputError(f"{what} topic {topic} has no message", path=where)
    return StampedMessages(messages, np.array([_stamp(m) for m, _ in messages]), np.arange(1, len(messages) + 1),
                           f"{where}:{topic}")


def _yaw(q: Any) -> float:
    return float(np.arctan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z)))


def integrate_twists(times: FloatArray, twists: FloatArray) -> FloatArray:
    """(N, 3) planar poses from (N, 3) body twists ``(vx, vy, wz)`` held from each time to the next."""
    from gtvo.wheel_calibration.motions import integrate_motions  # noqa: PLC0415

    xi = twists[:-1] * np.diff(times)[:, None]
    _, t = se2_exp(xi)
    return integrate_motions(np.column_stack([t, xi[:, 2]]))


def _joint_index(names: list[str], wanted: str | None, side: str, where: str) -> int:
    if wanted is not None:
        if wanted not in names:
            raise InputError(f"no joint {wanted!r} ({side} wheel; wheel.{side}_joint) among {names}", path=where)
        return names.index(wanted)
    hits = [i for i, n in enumerate(names) if side in n.lower()]
    if len(hits) != 1:
        raise InputError(f"{len(hits)} joint names contain {side!r} among {names}: set wheel.{side}_joint",
                         path=where)
    return hits[0]


def _wheel_positions(msg: Any, wheels: tuple[str, str], number: int, where: str) -> list[float]:
    """The two wheel joints' positions of one JointState message (joints looked up by name)."""
    names = list(msg.name)
    if not all(w in names for w in wheels) or len(msg.position) != len(names):
        raise InputError(f"message {number}: no position of joint {wheels[0]!r} and {wheels[1]!r} "
                         f"(joints {names}, {len(msg.position)} positions)", path=where)
    return [float(msg.position[names.index(w)]) for w in wheels]


def read_wheel_topic(where: Path, topic: str, options: WheelReadOptions) -> tuple[WheelOdometry, str | None]:
    """The wheel odometry of ``topic`` (module doc) and the base frame its messages name (or None)."""
    stamped = stamped_messages(where, topic, "wheel odometry")
    messages, times, rows, source = stamped.messages, stamped.times, stamped.rows, stamped.source
    msgtype = messages[0][1]
    base_frame = None
    if msgtype == JOINT_STATE:
        if options.wheel_radius is None:
            raise InputError(f"{topic} is a sensor_msgs/JointState: its wheel angles need the wheel radius "
                             "(config wheel.wheel_radius, m)", path=where)
        first = list(messages[0][0].name)
        wheels = (first[_joint_index(first, options.left_joint, "left", source)],
                  first[_joint_index(first, options.right_joint, "right", source)])
        values = np.array([_wheel_positions(m, wheels, k + 1, source) for k, (m, _) in enumerate(messages)],
                          dtype=np.float64) * options.wheel_radius
        kind = "arcs"
    else:
        if msgtype == ODOMETRY:
            poses = np.array([[m.pose.pose.position.x, m.pose.pose.position.y, _yaw(m.pose.pose.orientation)]
                              for m, _ in messages])
            twists = np.array([[m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.angular.z]
                               for m, _ in messages])
            base_frame = str(messages[0][0].child_frame_id).lstrip("/") or None
        else:
            poses = None
            twists = np.array([[m.twist.linear.x, m.twist.linear.y, m.twist.angular.z] for m, _ in messages])
        check_readings(times, twists if poses is None else poses, "pose", source, rows, "message",
                       options.max_gap)
        if poses is None or np.all(poses == poses[0]):
            if poses is not None:
                source += " (twist integrated: the pose is constant)"
            poses = integrate_twists(times, twists)
        values, kind = poses, "pose"
    times, values = check_readings(times, values, kind, source, rows, "message", options.max_gap, options.max_speed)
    odo = WheelOdometry(times, kind, values, source, options.nominal_baseline)  # type: ignore[arg-type]
    return odo, base_frame


def static_transform(where: Path, parent: tuple[str, ...], child: str) -> FloatArray | None:
    """``T_parent_child`` (4x4) composed from the bag's ``/tf_static`` (through any frames between,
    either direction), for the first of ``parent`` it links to ``child``; None without a link."""
    edges: dict[str, list[tuple[str, FloatArray]]] = {}
    reader = open_reader(where)
    try:
        conns = [c for c in reader.connections if c.topic == TF_STATIC]
        for c, _, raw in reader.messages(connections=conns):
            for tf in reader.deserialize(raw, c.msgtype).transforms:
                p, q = tf.transform.translation, tf.transform.rotation
                T = np.eye(4)
                T[:3, :3] = quaternions_to_rotations([q.x, q.y, q.z, q.w])[0]
                T[:3, 3] = (p.x, p.y, p.z)
                a, b = str(tf.header.frame_id).lstrip("/"), str(tf.child_frame_id).lstrip("/")
                edges.setdefault(a, []).append((b, T))
                edges.setdefault(b, []).append((a, invert_poses(T[None])[0]))
    except reader_errors() as exc:
        raise InputError(f"cannot read {TF_STATIC}: {first_line(exc)}", path=where) from None
    finally:
        reader.close()
    for start in parent:
        seen, queue = {start}, deque([(start, np.eye(4))])
        while queue:
            frame, T = queue.popleft()
            if frame == child:
                return T
            for nxt, step in edges.get(frame, []):
                if nxt not in seen:
                    seen.add(nxt)
                    queue.append((nxt, T @ step))
    return None


def first_frame_id(where: Path, topic: str) -> str:
    """The ``header.frame_id`` of the first message of ``topic`` (a camera's optical frame)."""
    reader = open_reader(where)
    try:
        conns = [c for c in reader.connections if c.topic == topic]
        for c, _, raw in reader.messages(connections=conns):
            return str(reader.deserialize(raw, c.msgtype).header.frame_id).lstrip("/")
    except reader_errors() as exc:
        raise InputError(f"cannot read {topic}: {first_line(exc)}", path=where) from None
    finally:
        reader.close()
    return ""


def bag_wheel_odometry(where: Path, topics: list[TopicSummary], options: WheelReadOptions, camera_topic: str,
                       T_raw_rect: FloatArray, exclude: tuple[str, ...] = ()) -> WheelOdometry | None:
    """The bag's wheel odometry (None without a wheel topic), with ``T_base_cam`` of the rectified
    left camera from ``/tf_static`` when it links the base frame to ``camera_topic``'s frame."""
    topic = choose_wheel_topic(topics, options, exclude, where)
    if topic is None:
        return None
    odo, base_frame = read_wheel_topic(where, topic, options)
    if not any(t.name == TF_STATIC for t in topics):
        return odo
    bases = ((base_frame,) if base_frame else ()) + BASE_FRAMES
    T_base_raw = static_transform(where, bases, first_frame_id(where, camera_topic))
    if T_base_raw is None:
        return odo
    return WheelOdometry(odo.times, odo.kind, odo.values, odo.source, odo.nominal_baseline, T_base_raw @ T_raw_rect)
