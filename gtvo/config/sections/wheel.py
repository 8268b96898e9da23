"""The ``wheel:`` section of the tree: how a ground robot's wheel odometry is read
(:class:`WheelReadOptions`, what the readers take) and where its base carries the camera
(docs/wheel_odometry.md). Used only when a sequence has wheel odometry."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from gtvo.core.lie import pose_from_xyz_quaternion
from gtvo.core.settings import SettingError, check_settings, setting

WheelModelName = Literal["linear", "diff_drive"]

#: The largest time between two consecutive readings that the readers accept (s); a longer gap is
#: refused, naming the row after it (``wheel.max_gap`` in the config).
MAX_GAP_S = 1.0
#: The nominal track width (m) when none is configured (``wheel.nominal_baseline``).
DEFAULT_NOMINAL_BASELINE = 0.5
#: The fastest a wheel (arcs) or the base (pose) may move between two readings that the readers
#: accept (m/s, 180 km/h; ``wheel.max_speed``): faster is refused, naming the row, as readings in
#: the wrong unit (encoder ticks without ``wheel.tick_scale``, millimetres).
MAX_SPEED_M_S = 50.0

#: ``T_base_cam`` of a forward-looking camera at the base's origin, as ``[x, y, z, qx, qy, qz, qw]``:
#: the rotation that takes the camera's axes (z forward, x right, y down) to a REP 103 base's
#: (x forward, y left, z up), i.e. the columns of ``R_base_cam`` are the camera's x, y, z in the base:
#: ``(0, -1, 0)``, ``(0, 0, -1)``, ``(1, 0, 0)``.
FORWARD_CAMERA_ON_BASE: tuple[float, float, float, float, float, float, float] = (0.0, 0.0, 0.0,
                                                                                 -0.5, 0.5, -0.5, 0.5)


@dataclass(frozen=True)
class WheelReadOptions:
    """What turns logged wheel readings into :class:`gtvo.datasets.wheel.WheelOdometry` (the config's ``wheel:`` section,
    :meth:`WheelConfig.read_options`).

    Attributes:
        topic: the bag topic of the wheel odometry; None: the one candidate (docs/wheel_odometry.md);
            ``"none"``: no wheel odometry from the bag.
        tick_scale: metres per unit of a file's ``left, right`` columns.
        nominal_baseline: the nominal track width b0 (m).
        wheel_radius: metres per radian of a JointState wheel position; None: JointState refused.
        left_joint, right_joint: JointState joint names; None: the names containing left / right.
        max_gap: the longest gap between readings (s) accepted.
        max_speed: the fastest motion between readings (m/s, after ``tick_scale``) accepted.
    """

    topic: str | None = None
    tick_scale: float = 1.0
    nominal_baseline: float = DEFAULT_NOMINAL_BASELINE
    wheel_radius: float | None = None
    left_joint: str | None = None
    right_joint: str | None = None
    max_gap: float = MAX_GAP_S
    max_speed: float = MAX_SPEED_M_S


@dataclass(frozen=True)
class WheelConfig:
    """Wheel odometry: its model, the base-to-camera transform and how readings become metres.

    Attributes:
        model: the calibration model of the wheel odometry: ``diff_drive`` (wheel scales k_L, k_R and
            the track width's scale k_b) or ``linear`` (the notes' 3x3 X on each planar motion).
        base_to_camera: ``T_base_cam``, the camera's (left camera's) pose in the base frame (REP 103:
            x forward, y left, z up), as ``[x, y, z, qx, qy, qz, qw]`` (m; a unit quaternion). The
            default is a forward-looking camera at the base's origin. A bag's ``/tf_static`` from the
            base to the camera replaces it.
        nominal_baseline: the nominal track width b0 (m), the distance between the wheels the robot's
            own odometry uses: wheel arcs become motion with it.
        tick_scale: metres per unit of the ``left, right`` columns of ``wheel_odometry.csv`` (1.0: the
            columns are arc lengths in metres; the metres per encoder tick for tick counts).
        wheel_radius: the nominal wheel radius (m) that turns a ``sensor_msgs/JointState``'s wheel
            angles (rad) into arc lengths; null: JointState topics are refused.
        left_joint, right_joint: the JointState joint names of the left and right wheels; null: the
            one name containing ``left`` and the one containing ``right``.
        topic: the bag topic of the wheel odometry (``--wheel-topic``); null: the one topic of a
            supported type (``nav_msgs/Odometry``, ``geometry_msgs/TwistStamped``, and
            ``sensor_msgs/JointState`` when ``wheel_radius`` is set) when the bag has exactly one;
            ``none``: no wheel odometry from the bag.
        max_gap: the longest time between two wheel readings (s) that is interpolated; a longer gap
            is refused, naming the file and row (or bag topic and message).
        max_speed: the fastest a wheel (arcs, after ``tick_scale``) or the base (pose) may move between
            two readings (m/s); faster is refused, naming the file and row: readings in another unit
            (encoder ticks without ``tick_scale``, millimetres).
        calibration_prior: the calibration's prior mean: the diff-drive ``[k_L, k_R, k_b]`` or the
            linear model's 9 entries of X row-major (scales positive, X invertible); null: nominal (all scales 1, X = I). The window
            estimates the calibration from it (docs/window.md, "Wheel odometry").
        calibration_prior_sigma: the prior's sigma of every calibration parameter (a scale, or an
            entry of X): what a parameter the motion does not observe keeps as its sigma.
        translation_sigma: the wheels' noise on x and y (m) of one step between keyframes, ...
        rotation_sigma: ... on its heading change (rad), ...
        sigma_per_metre: ... both growing by this much (m/m and rad/m) per metre driven: a long step
            (a blind stretch between keyframes) is less certain.
        planar_rotation_sigma: how far the base may roll and pitch between two keyframes (rad): the
            planar-motion terms of the wheel factor (ramps, bumps, the car's suspension).
        planar_height_sigma: how far the base may rise or sink between two keyframes (m), in its own frame.
    """

    model: WheelModelName = "diff_drive"
    base_to_camera: tuple[float, float, float, float, float, float, float] = setting(FORWARD_CAMERA_ON_BASE,
                                                                                     "[-1000, 1000]")
    nominal_baseline: float = setting(DEFAULT_NOMINAL_BASELINE, "(0, 100]")
    tick_scale: float = setting(1.0, "(0, 1000]")
    wheel_radius: float | None = setting(None, "(0, 100]")
    left_joint: str | None = None
    right_joint: str | None = None
    topic: str | None = None
    max_gap: float = setting(MAX_GAP_S, "(0, 3600]")
    max_speed: float = setting(MAX_SPEED_M_S, "(0, 10000]")
    calibration_prior: tuple[float, ...] | None = setting(None, "[-100, 100]")
    calibration_prior_sigma: float = setting(0.1, "(0, 10]")
    translation_sigma: float = setting(0.01, "(0, 100]")
    rotation_sigma: float = setting(0.002, "(0, 10]")
    sigma_per_metre: float = setting(0.01, "[0, 10]")
    planar_rotation_sigma: float = setting(0.01, "(0, 10]")
    planar_height_sigma: float = setting(0.02, "(0, 100]")

    def __post_init__(self) -> None:
        check_settings(self)
        norm = float(np.linalg.norm(self.base_to_camera[3:]))
        if abs(norm - 1.0) > 1e-3:
            raise SettingError("base_to_camera", f"qx, qy, qz, qw must be a unit quaternion, its norm is {norm:.6g}")
        size = {"diff_drive": 3, "linear": 9}[self.model]
        prior = self.calibration_prior
        if prior is not None and len(prior) != size:
            raise SettingError("calibration_prior", f"the {self.model} model has {size} parameters, got {len(prior)}")
        if prior is not None and self.model == "diff_drive" and min(prior) <= 0:
            raise SettingError("calibration_prior", f"the wheel and track-width scales must be positive, got {list(prior)}")
        if prior is not None and self.model == "linear" and abs(np.linalg.det(np.reshape(prior, (3, 3)))) < 1e-6:
            raise SettingError("calibration_prior", f"the linear model's X must be invertible, got {list(prior)}")

    @property
    def T_base_cam(self) -> NDArray[np.float64]:
        """``base_to_camera`` as a 4x4 transform."""
        return pose_from_xyz_quaternion(self.base_to_camera)

    def read_options(self) -> WheelReadOptions:
        """The settings the wheel readers take (:func:`gtvo.datasets.open_sequence`'s ``wheel_options``)."""
        return WheelReadOptions(topic=self.topic, tick_scale=self.tick_scale, nominal_baseline=self.nominal_baseline,
                                wheel_radius=self.wheel_radius, left_joint=self.left_joint,
                                right_joint=self.right_joint, max_gap=self.max_gap,
                                max_speed=self.max_speed)
