"""An IMU from a bag's ``sensor_msgs/Imu`` topic, and its pose on the camera from ``/tf_static``
(docs/imu.md, "ROS bags"), read as :mod:`gtvo.datasets.bag_wheel` reads the wheels.

Times are the messages' header stamps; ``angular_velocity`` (rad/s) and ``linear_acceleration``
(m/s^2, gravity included: REP 145) in the message's ``header.frame_id``. The topic is chosen by name
(``--imu-topic``, config ``imu.topic``) or is the bag's one ``sensor_msgs/Imu`` topic. ``T_cam_imu``:
``/tf_static`` from the IMU's frame to the left image's frame, composed with the rectification;
else Kalibr's files beside the bag, else ``imu.T_cam_imu``. The noise model: Kalibr's ``imu.yaml``
beside the bag, else the config's, else the default (the message covariances are rarely filled).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gtvo.datasets.bag_topics import TopicSummary
from gtvo.datasets.bag_wheel import TF_STATIC, first_frame_id, stamped_messages, static_transform
from gtvo.datasets.imu import FloatArray, ImuMeasurements, check_imu_readings
from gtvo.datasets.imu_files import ImuCalibration, ImuReadOptions, find_imu_files, imu_from_table, kalibr_calibration
from gtvo.errors import InputError

IMU_TYPE = "sensor_msgs/msg/Imu"
#: ``--imu-topic none``: no IMU from the bag.
NO_IMU_TOPIC = "none"


def choose_imu_topic(topics: list[TopicSummary], options: ImuReadOptions, where: Path) -> str | None:
    """The IMU topic: ``options.topic`` (checked), else the one ``sensor_msgs/Imu`` topic, else None.

    Raises:
        InputError: the named topic is missing or of another type; several candidates and no choice.
    """
    if not options.enabled or options.topic == NO_IMU_TOPIC:
        return None
    candidates = [t.name for t in topics if t.msgtype == IMU_TYPE and t.count > 0]
    if options.topic is not None:
        types = {t.name: t.msgtype for t in topics}
        if types.get(options.topic) != IMU_TYPE:
            found = f"is {types[options.topic]}" if options.topic in types else "is not in the bag"
            raise InputError(f"--imu-topic {options.topic} {found}; sensor_msgs/Imu topics: "
                             f"{', '.join(candidates) or 'none'}", path=where)
        return options.topic
    if len(candidates) > 1:
        raise InputError(f"{len(candidates)} IMU topics ({', '.join(candidates)}): choose one with --imu-topic TOPIC "
                         "(config imu.topic), or --imu-topic none", path=where)
    return candidates[0] if candidates else None


def bag_imu(where: Path, topics: list[TopicSummary], options: ImuReadOptions, camera_topic: str,
            T_raw_rect: FloatArray) -> ImuMeasurements | None:
    """The bag's IMU (module doc), or None without an IMU topic.

    Raises:
        InputError: a refused reading, naming the bag, topic and message number
            (:func:`gtvo.datasets.imu.check_imu_readings`); no extrinsic anywhere.
    """
    topic = choose_imu_topic(topics, options, where)
    if topic is None:
        return None
    stamped = stamped_messages(where, topic, "IMU")
    messages, source = stamped.messages, stamped.source
    gyro = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for m, _ in messages])
    accel = np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z]
                      for m, _ in messages])
    times, gyro, accel = check_imu_readings(stamped.times, gyro, accel, source, stamped.rows, "message",
                                            options.min_rate, options.max_gap)
    calibrations = []
    imu_frame = str(messages[0][0].header.frame_id).lstrip("/")
    if imu_frame and any(t.name == TF_STATIC for t in topics):
        T_imu_raw = static_transform(where, (imu_frame,), first_frame_id(where, camera_topic))
        if T_imu_raw is not None:
            calibrations.append(ImuCalibration(None, np.linalg.inv(T_imu_raw @ T_raw_rect), None,
                                               f"{where}:{TF_STATIC}"))
    _, _, imu_yaml, camchain = find_imu_files(where if where.is_dir() else where.parent)
    calibrations.insert(0, kalibr_calibration(imu_yaml, camchain))
    return imu_from_table(times, gyro, accel, source, options, *calibrations)
