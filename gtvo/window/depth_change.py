"""What a change of a keyframe's depths means for the frames tracked against it.

Direct tracking measures the flow of a keyframe's points into a frame; the translational part of
that flow is ``rho_n * t`` (inverse depth times the frame's translation relative to the keyframe),
so the tracked translation is only known in the scale of the depths it was tracked with. When the
window replaces a keyframe's depths by others of a different scale (the rig calibration releasing
``delta_x``: every disparity moves by the offset, docs/window.md, "Rig calibration"), the
translations of the frames already tracked against that keyframe are stale by the same factor,
while the keyframe poses are solved again. :func:`tracked_translation_scale` is the factor that
keeps their measured flow: ``t_new = s t_old``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from gtvo.errors import InputError

#: Fewest points with an inverse depth before and after for :func:`tracked_translation_scale`
#: (fewer: 1, the tracked translations are left as they are).
MIN_SCALE_POINTS = 10


def tracked_translation_scale(old_inverse_depth: ArrayLike, new_inverse_depth: ArrayLike) -> float:
    """The factor ``s`` by which a translation tracked against a keyframe with the inverse depths
    ``old_inverse_depth`` becomes one against ``new_inverse_depth`` (same points, (N,)).

    Keeping each point's translational flow, ``rho_new,n s t = rho_old,n t`` in the least-squares
    sense over the points positive in both: ``s = sum(rho_old rho_new) / sum(rho_new^2)``. A
    uniform depth scale ``rho_new = rho_old / k`` gives ``s = k`` exactly; a constant disparity
    change (a rig offset) weights the near points, whose flow dominates the tracking, most.
    1.0 when fewer than :data:`MIN_SCALE_POINTS` points qualify.
    """
    old = np.asarray(old_inverse_depth, dtype=float).reshape(-1)
    new = np.asarray(new_inverse_depth, dtype=float).reshape(-1)
    if old.shape != new.shape:
        raise InputError(f"inverse depths before and after must match, got {old.size} and {new.size} points")
    ok = np.isfinite(old) & np.isfinite(new) & (old > 0) & (new > 0)
    if np.count_nonzero(ok) < MIN_SCALE_POINTS:
        return 1.0
    return float(np.sum(old[ok] * new[ok]) / np.sum(new[ok] ** 2))
