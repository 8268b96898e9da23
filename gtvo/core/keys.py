"""The GTSAM keys of the VO problem, defined once (docs/conventions.md, "Keys").

Every key is ``gtsam.symbol(char, index)`` with one character per kind of variable, as
``gtsam.symbol_shorthand`` does in GTSAM's examples. Graphs built anywhere in gtvo (tracking, the
window, pose graphs, loop closure, the motion model, wheel-odometry calibration) take their keys
from here, so two modules that meet in one graph agree on them.
"""

from __future__ import annotations

import gtsam

#: Pose ``T_world_cam`` of a frame, keyframe or pose-graph node (Pose3; Pose2 in 2-D graphs).
POSE = "x"
#: Inverse depth of a point (double), indexed by a global point index.
INVERSE_DEPTH = "d"
#: Affine brightness ``(a, b)`` of a frame's (left) image (Vector2).
AFFINE = "a"
#: Affine brightness ``(a, b)`` of a frame's right image (Vector2).
RIGHT_AFFINE = "r"
#: Rig offset ``(delta_x, delta_y)`` (px) of the right image against its rectification (Vector2).
RIG_OFFSET = "o"
#: Motion-model state (Vector).
MOTION_STATE = "v"
#: Wheel-odometry calibration parameters (Vector).
CALIBRATION = "c"
#: A keyframe's velocity in the world (Vector3, m/s) when an IMU is used.
VELOCITY = "V"
#: A keyframe's IMU bias ``(b_accel, b_gyro)`` (Vector6).
IMU_BIAS = "B"
#: The tilt of gravity's direction from its initial estimate (Vector3, a rotation vector).
GRAVITY_TILT = "g"


def pose_key(index: int) -> int:
    """Key of the pose of frame / keyframe / pose-graph node ``index`` (``x<index>``)."""
    return gtsam.symbol(POSE, int(index))


def inverse_depth_key(index: int) -> int:
    """Key of the inverse depth of point ``index`` (``d<index>``)."""
    return gtsam.symbol(INVERSE_DEPTH, int(index))


def affine_key(index: int) -> int:
    """Key of the affine brightness ``(a, b)`` of frame ``index``'s left image (``a<index>``)."""
    return gtsam.symbol(AFFINE, int(index))


def right_affine_key(index: int) -> int:
    """Key of the affine brightness ``(a, b)`` of frame ``index``'s right image (``r<index>``)."""
    return gtsam.symbol(RIGHT_AFFINE, int(index))


def rig_offset_key(index: int = 0) -> int:
    """Key of the stereo rig's offset ``(delta_x, delta_y)`` of the right image (``o<index>``; one per
    rig, shared by every keyframe of the window: docs/window.md, "Rig calibration")."""
    return gtsam.symbol(RIG_OFFSET, int(index))


def motion_state_key(index: int) -> int:
    """Key of the motion-model state ``index`` (``v<index>``)."""
    return gtsam.symbol(MOTION_STATE, int(index))


def calibration_key(index: int = 0) -> int:
    """Key of the wheel-odometry calibration variable ``index`` (``c<index>``)."""
    return gtsam.symbol(CALIBRATION, int(index))


def velocity_key(index: int) -> int:
    """Key of keyframe ``index``'s velocity (``V<index>``; docs/imu.md)."""
    return gtsam.symbol(VELOCITY, int(index))


def imu_bias_key(index: int) -> int:
    """Key of keyframe ``index``'s IMU bias (``B<index>``; docs/imu.md)."""
    return gtsam.symbol(IMU_BIAS, int(index))


def gravity_tilt_key(index: int = 0) -> int:
    """Key of the tilt of gravity's direction (``g<index>``; one per run: docs/imu.md)."""
    return gtsam.symbol(GRAVITY_TILT, int(index))


def is_pose_key(key: int) -> bool:
    """Whether ``key`` is a pose key (:func:`pose_key`)."""
    return gtsam.Symbol(key).chr() == ord(POSE)
