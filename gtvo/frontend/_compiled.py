"""Compiled loops (numba) of the front end; each is the loop form of numpy code in
:mod:`gtvo.frontend.point_selection` and is tested against it.

* :func:`pick_cells`: step 3 of the point-selection rule, the hierarchical per-cell pick of the
  pixel of largest gradient above the threshold. The numpy form padded and reshaped two full-size
  arrays per level (about half of ``select_points``' time on KITTI).
"""

from __future__ import annotations

import numpy as np

from gtvo._jit import jit


@jit
def pick_cells(score, thr, border, cell, level_factors):
    """Boolean map (H, W) of picks: for each level ``l`` with side ``c = cell * 2^l`` and every
    ``c x c`` cell (the last row / column of cells cut by the image edge) that holds no pick of an
    earlier level, the pixel of largest ``score`` with ``score > thr * level_factors[l]`` within
    ``border`` of no image edge; ties go to the first pixel in row-major order within the cell
    (``np.argmax``'s). ``score``, ``thr`` and ``level_factors`` are float32, compared in float32
    as the numpy form does."""
    h, w = score.shape
    picked = np.zeros((h, w), dtype=np.bool_)
    for lvl in range(level_factors.shape[0]):
        c = cell * (1 << lvl)
        f = level_factors[lvl]
        for y0 in range(0, h, c):
            y1 = min(y0 + c, h)
            for x0 in range(0, w, c):
                x1 = min(x0 + c, w)
                has_pick = False
                best = np.float32(-1.0)
                by = -1
                bx = -1
                for y in range(y0, y1):
                    inside_y = y >= border and y < h - border
                    for x in range(x0, x1):
                        if picked[y, x]:
                            has_pick = True
                        if inside_y and x >= border and x < w - border:
                            s = score[y, x]
                            if s > thr[y, x] * f and s > best:
                                best = s
                                by = y
                                bx = x
                    if has_pick:
                        break
                if not has_pick and by >= 0:
                    picked[by, bx] = True
    return picked

