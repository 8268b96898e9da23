"""What a run says about its stereo rig, for ``report.json``: the window's rig-offset figures.

The estimate, its state and its error bar live in the window (:class:`gtvo.window.rig.RigOffset`,
``vo.window.rig``); :func:`rig_report` asks it for its figures at the final window's marginal
covariance, and :func:`gtvo.window.rig.rig_warning` gives the warning line.
"""

from __future__ import annotations

from typing import Any

from gtvo.odometry.visual_odometry import VisualOdometry
from gtvo.window.rig import rig_warning

__all__ = ["rig_report", "rig_warning"]


def rig_report(vo: VisualOdometry) -> dict[str, Any]:
    """``{"rig_calibration": False}`` when the run did not estimate the rig offset, else
    :meth:`gtvo.window.rig.RigOffset.report` at the final window's marginal covariance."""
    rig = vo.keyframer.rig
    if rig is None or vo.window is None:
        return {"rig_calibration": False}
    return rig.report(vo.window.rig_offset_covariance())
