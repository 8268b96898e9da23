"""The whole-log refinement: one photometric graph over every keyframe of a run, after the window
pass, with the accepted loop edges in the same graph (docs/refinement.md).

:func:`refine_keyframes` builds the window's problem (:class:`gtvo.window.problem.WindowProblem`)
over every keyframe of a :class:`RefinementInput` with the targets of :func:`covisible_targets` and the loop edges
(:func:`loop_factors`), and solves it with the window's solvers; :class:`RefineConfig` is the
tree's ``refine`` section. :func:`gtvo.run` runs it when ``refine.enabled``
(:mod:`gtvo.refinement.run` joins it to a run's outputs).
"""

from gtvo.config.sections.refine import RefineConfig
from gtvo.refinement.graph import covisible_targets, loop_factors
from gtvo.refinement.solve import RefinementInput, RefinementResult, refine_keyframes

__all__ = ["RefineConfig", "RefinementInput", "RefinementResult", "covisible_targets", "loop_factors",
           "refine_keyframes"]
