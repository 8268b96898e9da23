"""What a run says about its stereo rig: the estimated rig offset for ``report.json`` and the warning.

The window estimates the right image's offset ``(delta_x, delta_y)`` against its rectification
(docs/window.md, "Rig calibration"). :func:`rig_report` gives the estimate with two standard
deviations: the window's marginal one, and the one to read as the error bar, the marginal one
combined with the method's measured error (:data:`METHOD_SIGMA_PX`); :func:`rig_warning` the one
line a run prints when an offset is both larger than :data:`WARN_OFFSET_PX` and clearly measured (more than
:data:`WARN_SIGMAS` standard deviations from zero).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gtvo.odometry.visual_odometry import VisualOdometry
from gtvo.window.problem import RIG_METHOD_SIGMA, rig_honest_sigma

#: An offset above this (px) is reported as a rig problem. Half a pixel is about the disparity
#: error that makes a 1 % scale error at 50 px of disparity (a point ~10 m away on KITTI).
WARN_OFFSET_PX = 0.5
#: ... when it is also this many standard deviations from zero.
WARN_SIGMAS = 3.0
#: The method's own error (px, delta_x and delta_y), added in quadrature to the marginal sigma for
#: the reported one (:data:`gtvo.window.problem.RIG_METHOD_SIGMA`, measured: docs/window.md).
METHOD_SIGMA_PX = RIG_METHOD_SIGMA


def rig_report(vo: VisualOdometry) -> dict[str, Any]:
    """``rig_calibration`` (bool), and when estimated ``rig_offset_px`` ``[delta_x, delta_y]``,
    ``rig_offset_marginal_sigma_px`` (from the final window's marginal covariance, None if it has
    none; for ``delta_x`` while it is held, its last test's, None if never tested),
    ``rig_offset_sigma_px`` (the error bar: the marginal sigma and :data:`METHOD_SIGMA_PX` in
    quadrature; None where the marginal one is), ``rig_offset_x_estimated`` (False: ``delta_x``
    stayed held at 0, the window never filled or its data never put ``delta_x`` more than
    :data:`gtvo.window.problem.RIG_SIGNIFICANCE` error bars from 0), ``rig_offset_x_tested_px``
    (the last test's estimate while held, None if never tested) and ``rig_initial_delta_y_px``
    (the first pair's 2-D search)."""
    if vo.rig_offset is None:
        return {"rig_calibration": False}
    out: dict[str, Any] = {"rig_calibration": True, "rig_offset_px": [float(x) for x in vo.rig_offset]}
    window = vo.window
    cov = window.rig_offset_covariance() if window is not None else None
    sigma = None if cov is None else [float(np.sqrt(max(cov[i, i], 0.0))) for i in range(2)]
    test = None if window is None else window.rig_x_test
    x_estimated = window is not None and window.rig_x_estimated
    if sigma is not None and not x_estimated:
        # held: the final window's marginal says nothing about delta_x; its last test does
        sigma[0] = None if test is None else test[1]
    out["rig_offset_marginal_sigma_px"] = sigma
    out["rig_offset_sigma_px"] = None if sigma is None else [
        None if s is None else rig_honest_sigma(s, axis) for axis, s in enumerate(sigma)]
    out["rig_offset_x_estimated"] = bool(x_estimated)
    out["rig_offset_x_tested_px"] = None if test is None or x_estimated else test[0]
    out["rig_initial_delta_y_px"] = None if vo.rig_initial is None else float(vo.rig_initial.delta_y)
    return out


def rig_warning(report: dict[str, Any]) -> str | None:
    """The warning line for a rig offset estimated large and clearly (None: nothing to say)."""
    offset = report.get("rig_offset_px")
    if not offset:
        return None
    sigma = report.get("rig_offset_sigma_px") or [0.0, 0.0]
    parts = []
    for value, s, axis in zip(offset, sigma, ("horizontally", "vertically")):
        if s is not None and abs(value) > WARN_OFFSET_PX and abs(value) > WARN_SIGMAS * s:
            parts.append(f"{value:+.1f} px {axis}")
    if not parts:
        return None
    return f"the right camera is offset by {' and '.join(parts)} from its calibration: check the rig"
