"""The tests' short way to a window problem (:class:`gtvo.window.problem.WindowProblem`) from the
pieces the tests hold: a camera, a baseline, keyframes, the window's settings and what else the
problem carries."""

from __future__ import annotations

from typing import Any, Sequence

import gtsam

from factors.params import DEFAULT_PHOTOMETRIC, PhotometricConfig
from gtvo.window import RigVariable, WindowConfig, WindowKeyframe, WindowMembers, WindowProblem, WindowSettings
from gtvo.window.config import MarginalPrior


def problem(camera: Any, baseline: float | None, keyframes: Sequence[WindowKeyframe], config: WindowConfig,
            marginal: MarginalPrior | None = None, targets: list[list[int]] | None = None, *,
            photometric: PhotometricConfig = DEFAULT_PHOTOMETRIC, rig_offset: Any = None,
            rig_hold_x: float | None = None, wheel: Any = None,
            extra_factors: gtsam.NonlinearFactorGraph | None = None, **settings: Any) -> WindowProblem:
    """The problem of ``keyframes`` with these pieces (``settings``: more :class:`WindowSettings` fields)."""
    rig = None if rig_offset is None else RigVariable(rig_offset, rig_hold_x)
    out = WindowProblem.build(WindowMembers(camera, baseline, keyframes, targets),
                              WindowSettings(config, photometric, **settings), marginal, rig, (wheel,))
    if extra_factors is not None:
        out.factors.push_back(extra_factors)
    return out


def refine(camera: Any, baseline: float | None, keyframes: Sequence[WindowKeyframe], window: WindowConfig,
           config: Any = None, *, photometric: PhotometricConfig = DEFAULT_PHOTOMETRIC, progress: bool = False,
           on_iteration: Any = None, wheel: Any = None, **inputs: Any) -> Any:
    """:func:`gtvo.refinement.refine_keyframes` of these pieces (``inputs``: more
    :class:`gtvo.refinement.RefinementInput` fields: loop edges, rig offset, start poses, covariances;
    ``wheel``: the one sensor)."""
    from gtvo.refinement import RefinementInput, refine_keyframes  # noqa: PLC0415

    run = RefinementInput(WindowMembers(camera, baseline, keyframes),
                          WindowSettings(window, photometric, on_iteration=on_iteration), sensors=(wheel,), **inputs)
    return refine_keyframes(run, config, progress)
