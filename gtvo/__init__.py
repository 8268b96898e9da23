"""gtvo: a factor-graph backend for direct stereo visual odometry on GTSAM.

Data flows one way: readers (:mod:`gtvo.datasets`) -> frames and camera
(:mod:`gtvo.core.camera`, :mod:`gtvo.core.image`) -> front end (:mod:`gtvo.frontend`,
:mod:`gtvo.odometry`) -> factors (:mod:`factors`) -> solvers (:mod:`gtvo.frontend.tracking`,
:mod:`gtvo.window`, :mod:`gtvo.posegraph`) -> outputs (:mod:`gtvo.io.trajectory_files`,
:mod:`gtvo.io.outputs`). Conventions (frames, pixel centres, Pose3 tangent order):
``docs/conventions.md``.

The top-level names are the small API most users need (imported on first use, so
``import gtvo`` stays cheap)::

    import gtvo
    seq = gtvo.open_sequence("KITTI_sequence_1")
    vo = gtvo.VisualOdometry(seq.camera, gtvo.OdometryConfig(mode="window"))
    for frame in seq:
        vo.process(frame)
    vo.finish()                                          # the last keyframes' window optimisation
    report = gtvo.run("KITTI_sequence_1", out="out/")   # the whole `gtvo run` job: a gtvo.RunReport
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_EXPORTS = {
    "open_sequence": "gtvo.datasets",
    "Sequence": "gtvo.datasets.sequence",
    "Frame": "gtvo.datasets.sequence",
    "PinholeCamera": "gtvo.core.camera",
    "StereoCamera": "gtvo.core.camera",
    "VisualOdometry": "gtvo.odometry",
    "OdometryConfig": "gtvo.config",
    "SlidingWindowOptimizer": "gtvo.window",
    "Trajectory": "gtvo.evaluation.trajectory",
    "RunReport": "gtvo.report",
    "run": "gtvo.pipeline",
    "batch": "gtvo.batching",
    "InputError": "gtvo.errors",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'gtvo' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
