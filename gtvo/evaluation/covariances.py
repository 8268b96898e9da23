"""A run's keyframe pose covariances as data (:class:`KeyframeCovariances`) and their summary in
``report.json`` (:func:`covariance_summary`): pure math, no I/O. The file ``covariances.npz`` and
the ellipses of ``trajectory.png`` are :mod:`gtvo.io.covariances`' (docs/window.md, "Pose covariances")."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, TypedDict

import numpy as np
from numpy.typing import NDArray

from gtvo.errors import InputError

FloatArray = NDArray[np.float64]

#: GTSAM's Pose3 tangent order, the order of every 6x6 covariance gtvo writes.
TANGENT_ORDER = "rx, ry, rz, tx, ty, tz (GTSAM Pose3 tangent: rotation [rad] first, then translation [m])"
#: The perturbation convention and the frame the covariances are expressed in.
TANGENT_FRAME = ("right perturbation T = T_hat * Exp(xi): xi in the pose's own body (left camera) frame; "
                 "uncertainty relative to the world frame fixed by the first pose (the gauge)")


@dataclass
class KeyframeCovariances:
    """The keyframes' pose covariances of a run (one row per keyframe that has one).

    Attributes:
        frame_index: (K,) frame indices; timestamp: (K,) seconds.
        covariance: (K, 6, 6) in :data:`TANGENT_ORDER`, :data:`TANGENT_FRAME`.
        source: how they were computed (e.g. ``"gtsam.Marginals of the window"``).
        inflation: the factor they were multiplied by (1.0: the window's own).
    """

    frame_index: NDArray[np.int64]
    timestamp: FloatArray
    covariance: FloatArray
    source: str
    inflation: float = 1.0

    def __post_init__(self) -> None:
        self.frame_index = np.asarray(self.frame_index, dtype=np.int64).reshape(-1)
        self.timestamp = np.asarray(self.timestamp, dtype=float).reshape(-1)
        self.covariance = np.asarray(self.covariance, dtype=float).reshape(-1, 6, 6)
        k = len(self.frame_index)
        if len(self.timestamp) != k or len(self.covariance) != k:
            raise InputError(f"covariances: {k} frame indices, {len(self.timestamp)} timestamps and "
                             f"{len(self.covariance)} covariances must match")

    def __len__(self) -> int:
        return int(len(self.frame_index))

    def arrays(self) -> dict[str, Any]:
        """The arrays of ``covariances.npz`` (module docstring)."""
        return {"frame_index": self.frame_index, "timestamp": self.timestamp, "covariance": self.covariance,
                "tangent_order": np.str_(TANGENT_ORDER), "frame": np.str_(TANGENT_FRAME),
                "source": np.str_(self.source), "inflation": np.float64(self.inflation)}


def sigmas(covariance: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Per pose: position sigma (m) and rotation sigma (deg), the square roots of the traces of the
    translation and rotation blocks (the RMS of the 3-D error's norm; NaN for an undetermined pose)."""
    P = np.asarray(covariance, dtype=float).reshape(-1, 6, 6)
    with np.errstate(invalid="ignore"):
        pos = np.sqrt(np.maximum(np.trace(P[:, 3:, 3:], axis1=1, axis2=2), 0.0))
        rot = np.degrees(np.sqrt(np.maximum(np.trace(P[:, :3, :3], axis1=1, axis2=2), 0.0)))
    return pos, rot


class WrittenCovariances(TypedDict, total=False):
    """The keys of :class:`CovarianceSummary` present when covariances were written."""

    covariances_file: str
    covariance_keyframes: int
    covariance_source: str
    covariance_inflation: float
    covariance_undetermined: int
    covariance_position_sigma_m_median: float | None
    covariance_position_sigma_m_max: float | None
    covariance_rotation_sigma_deg_median: float | None
    covariance_rotation_sigma_deg_max: float | None


class CovarianceSummary(WrittenCovariances):
    """A run's covariances in ``report.json`` (:func:`covariance_summary`): ``covariances`` says
    whether they were written, the other keys only when they were."""

    covariances: str


def covariance_summary(cov: KeyframeCovariances) -> CovarianceSummary:
    """The ``report.json`` keys of a run's covariances: ``covariances`` = ``"written"``,
    ``covariances_file``, ``covariance_keyframes``, ``covariance_source``, ``covariance_inflation``
    and the median and largest position sigma (m) and rotation sigma (deg) over the keyframes but
    the first (the gauge, whose covariance is the gauge prior's). A run without covariances has
    ``covariances`` = the reason instead (:func:`gtvo.odometry.summary.summarize_odometry`).
    """
    if not len(cov):
        return {"covariances": "none computed (no window optimisation)"}
    pos, rot = sigmas(cov.covariance[1:] if len(cov) > 1 else cov.covariance)
    ok = np.isfinite(pos) & np.isfinite(rot)
    out: dict[str, Any] = {"covariances": "written", "covariances_file": "covariances.npz",
                           "covariance_keyframes": len(cov), "covariance_source": cov.source,
                           "covariance_inflation": cov.inflation,
                           # keyframes whose window's system was singular at the optimum (NaN in the file)
                           "covariance_undetermined": int(np.count_nonzero(~np.all(np.isfinite(cov.covariance),
                                                                                  axis=(1, 2))))}
    for name, v in (("position_sigma_m", pos[ok]), ("rotation_sigma_deg", rot[ok])):
        out[f"covariance_{name}_median"] = float(np.median(v)) if v.size else None
        out[f"covariance_{name}_max"] = float(np.max(v)) if v.size else None
    return out  # type: ignore[return-value]
