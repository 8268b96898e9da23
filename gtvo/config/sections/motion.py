"""The ``motion_model`` section: the initial guess of each frame's pose, and the noise of the planar
constant-acceleration Kalman filter (:mod:`gtvo.motion.model`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.core.settings import check_nested, check_settings, setting
from gtvo.errors import InputError

MotionModelName = Literal["constant-velocity", "kalman"]

#: Default standard deviations of the initial rates ``(dX, dZ, dtheta)`` (m/s, m/s, rad/s) of
#: :class:`gtvo.motion.model.ConstantAccelerationFilter`.
INITIAL_RATE_SIGMAS: tuple[float, float, float] = (1.0, 1.0, 0.5)


def check_sigmas(name: str, values: ArrayLike, n: int, allow_zero: bool = False) -> NDArray[np.float64]:
    """``values`` as ``n`` finite positive (or, with ``allow_zero``, non-negative) standard deviations.

    Raises:
        InputError: naming ``name`` and the values.
    """
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if v.shape != (n,) or not np.all(np.isfinite(v)) or np.any(v < 0) or (not allow_zero and np.any(v == 0)):
        raise InputError(f"{name} must be {n} finite {'non-negative' if allow_zero else 'positive'} numbers, "
                         f"got {np.asarray(values).tolist()!r}")
    return v


@dataclass(frozen=True)
class MotionNoiseConfig:
    """Noise of the planar model.

    Attributes:
        accel_sigmas: ``(k1, k2, k3)``: standard deviations of the X, Z accelerations (m/s^2)
            and of the angular acceleration (rad/s^2).
        measurement_sigmas: standard deviations of the measured ``(X, Z, theta)`` (m, m, rad);
            ``Q = diag(sigmas^2)``.
    """

    accel_sigmas: tuple[float, float, float] = setting((1.0, 1.0, 0.5), "[0, 1000]")
    measurement_sigmas: tuple[float, float, float] = setting((0.05, 0.05, 0.01), "[1e-6, 1000]")

    def __post_init__(self) -> None:
        check_settings(self)
        check_sigmas("accel_sigmas", self.accel_sigmas, 3, allow_zero=True)
        check_sigmas("measurement_sigmas", self.measurement_sigmas, 3)

    @property
    def Q(self) -> NDArray[np.float64]:
        """Measurement covariance ``Q = diag(measurement_sigmas^2)``."""
        return np.diag(np.square(np.asarray(self.measurement_sigmas, dtype=np.float64)))


@dataclass(frozen=True)
class MotionModelConfig:
    """The initial guesses of each frame's pose.

    Attributes:
        model: ``constant-velocity`` or ``kalman`` (the constant-acceleration filter of :mod:`gtvo.motion.model`).
        accept_rms_factor: tracking tries the motion model's guess first and accepts it at once when
            its whitened RMS is below this factor times the previous frame's; otherwise it also tries
            "no motion" and "keyframe pose" and keeps the lowest-cost success (0: always try all).
        kalman_noise: the Kalman filter's acceleration and measurement noise (``model: kalman``).
        kalman_initial_rate_sigmas: the Kalman filter's initial rate uncertainty ``(dX, dZ, dtheta)``
            (m/s, m/s, rad/s).
    """

    model: MotionModelName = "constant-velocity"
    accept_rms_factor: float = setting(1.1, "[0, 100]")
    kalman_noise: MotionNoiseConfig = field(default_factory=MotionNoiseConfig)
    kalman_initial_rate_sigmas: tuple[float, float, float] = setting(INITIAL_RATE_SIGMAS, "[1e-6, 1000]")

    def __post_init__(self) -> None:
        check_nested(self)

    @classmethod
    def from_name(cls, name: str) -> "MotionModelConfig":
        """The model ``name`` with the default settings (``motion_model="kalman"``)."""
        return cls(model=name)  # type: ignore[arg-type]


