"""Which keyframe points go into the exported map (``points.ply``): those whose depth is known.

A keyframe point is an inverse depth ``d`` (1/m) with the variance ``V`` of its stereo (or RGB-D
sensor) measurement. Back-projecting ``1/d`` is only meaningful while ``d`` is clearly positive:
first-order propagation gives the relative depth sigma ``sigma_z / z = sqrt(V) / d``, and once
``sqrt(V) / d`` reaches 1/3 the 3-sigma interval of ``d`` contains 0, i.e. the measurement does not
exclude a point at infinity; a window optimisation that drove ``d`` towards 0 (a point that left
the window's constraints) shows up the same way. A point is written when

* ``d > 0`` and ``d``, ``V`` are finite;
* ``sqrt(V) / d <= MAX_RELATIVE_DEPTH_SIGMA`` (1/3: its depth is bounded at 3 sigma). ``V`` is
  the measurement's own variance; the window only adds information, so this is conservative;
* when a window optimisation included its keyframe (window mode): the window compared it with
  at least ``MIN_OBSERVING_KEYFRAMES - 1`` other keyframes (it was seen, projected in front and
  inside the image, from ``MIN_OBSERVING_KEYFRAMES`` = 2 keyframes, its host included) in some
  optimisation. A point no other keyframe saw kept only its stereo depth while the window checked
  its neighbours against each other. A keyframe no optimisation included (track mode, or a
  window run that never had two keyframes: a static camera) is exported as measured, under the
  first two rules alone.

Points left out are counted per reason (:class:`MapPoints`); docs/evaluation.md, "The map".
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

#: Largest relative depth sigma ``sqrt(V) / d`` of an exported point: 3 sigma of ``d`` exclude 0.
MAX_RELATIVE_DEPTH_SIGMA = 1.0 / 3.0
#: Keyframes (host included) that must have seen a point in a window optimisation (window mode).
MIN_OBSERVING_KEYFRAMES = 2

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class MapPoints:
    """The exported map: points in the world frame, their intensities, and what was left out.

    Attributes:
        points: (N, 3) world points (m), the world frame being the first camera.
        intensity: (N,) grey levels of the points in their host image.
        left_out: points not exported, per reason (``"not_positive_or_finite"``,
            ``"depth_uncertain"``, ``"too_few_observing_keyframes"``); a point counts under the
            first reason that applies.
    """

    points: FloatArray
    intensity: FloatArray
    left_out: dict[str, int] = field(default_factory=dict)

    @property
    def written(self) -> int:
        """The number of exported points."""
        return int(self.points.shape[0])

    @property
    def left_out_total(self) -> int:
        """The number of points left out for any reason."""
        return int(sum(self.left_out.values()))


def constrained_mask(inverse_depth: FloatArray, variance: FloatArray, observing_keyframes: NDArray | None = None,
                     max_relative_sigma: float = MAX_RELATIVE_DEPTH_SIGMA,
                     min_observing_keyframes: int = MIN_OBSERVING_KEYFRAMES) -> tuple[NDArray[np.bool_], dict[str, int]]:
    """Which points have a depth the estimate constrains (rules in the module doc).

    Args:
        inverse_depth, variance: (N,) ``d`` (1/m) and its variance ``V`` (1/m^2).
        observing_keyframes: (N,) keyframes that saw each point, host included; None when no
            window optimisation included the point's keyframe (the rule is then not applied).

    Returns:
        ``(keep, left_out)``: the (N,) mask and the counts of points left out per reason.
    """
    d = np.asarray(inverse_depth, dtype=float).reshape(-1)
    V = np.asarray(variance, dtype=float).reshape(-1)
    valid = np.isfinite(d) & np.isfinite(V) & (d > 0) & (V >= 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        certain = valid & (np.sqrt(np.where(valid, V, 0.0)) <= max_relative_sigma * np.where(valid, d, 0.0))
    keep = certain.copy()
    left_out = {"not_positive_or_finite": int(np.count_nonzero(~valid)),
                "depth_uncertain": int(np.count_nonzero(valid & ~certain))}
    if observing_keyframes is not None:
        seen = np.asarray(observing_keyframes).reshape(-1) >= min_observing_keyframes
        keep &= seen
        left_out["too_few_observing_keyframes"] = int(np.count_nonzero(certain & ~seen))
    return keep, left_out
