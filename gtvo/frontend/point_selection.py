"""Gradient-based point selection spread over the image (DSO's PixelSelector, simplified).

Rule (docs/frontend.md, "Point selection"):

1. ``G = |grad I|`` (central differences, :func:`gtvo.core.image.image_gradients`).
2. The image is split into ``block x block`` blocks (32 px; partial edge blocks are completed
   by mirroring); each block's threshold is the
   median of ``G`` over the block plus ``threshold_offset`` (DSO: 7 grey levels); the block
   thresholds are smoothed over 3x3 neighbouring blocks and spread to a per-pixel map ``T``.
3. With a cell size ``s``: in every ``s x s`` cell the pixel of largest ``G`` with
   ``G > T`` is picked; every ``2s x 2s`` cell that got no pick tries again with the lower
   threshold ``downweight * T``; every ``4s x 4s`` cell still empty tries ``downweight^2 * T``.
   So low-texture regions still get (fewer) points.
4. ``s`` is adapted (``s <- s * sqrt(count / target)``, a few iterations) to reach the target
   count; a surplus is removed by a seeded random subsample (keeps the spread uniform).

Pixels within ``border`` of the image edge are never picked.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from gtvo.config.sections.frontend import DEFAULT_BORDER, PATTERN_RADIUS, PointSelectionConfig
from gtvo.core.timing import timed
from gtvo.errors import InputError
from gtvo.frontend._compiled import block_medians, gradient_norm, pick_cells, smooth_block_thresholds
from gtvo.core.image import FloatImage, image_gradients, to_float_gray



#: The default point selection (the default argument of :func:`select_points`).
DEFAULT_POINT_SELECTION = PointSelectionConfig()
_DEFAULT = DEFAULT_POINT_SELECTION


def gradient_magnitude(image: NDArray) -> NDArray[np.float32]:
    """``G = sqrt(gx^2 + gy^2)`` of a gray image, central differences, float32 (H, W).

    One compiled pass (:func:`gtvo.frontend._compiled.gradient_norm`) without the gradient images:
    the same float32 values as ``np.sqrt(gx * gx + gy * gy)`` of
    :func:`gtvo.core.image.image_gradients`, its numpy form (kept for images under 2x2, for which
    that raises).
    """
    return _magnitude(to_float_gray(image))


def _magnitude(img: NDArray[np.float32]) -> NDArray[np.float32]:
    """:func:`gradient_magnitude` of a float32 gray image (converted and checked by the caller)."""
    if min(img.shape) < 2:
        gx, gy = image_gradients(img)
        return np.sqrt(gx * gx + gy * gy)
    return gradient_norm(np.ascontiguousarray(img))


def block_gradient_thresholds(grad_mag: NDArray, block: int = _DEFAULT.block,
                              threshold_offset: float = _DEFAULT.threshold_offset) -> NDArray[np.float32]:
    """Per-pixel threshold map ``T`` (H, W): block median of ``grad_mag`` + offset, 3x3-smoothed.

    Args:
        grad_mag: gradient magnitude (H, W).
        block: block side in pixels (DSO: 32).
        threshold_offset: the constant added to the median (DSO's ``minGradHistAdd`` = 7).
    """
    g = np.asarray(grad_mag, dtype=np.float32)
    full = np.repeat(np.repeat(_threshold_grid(g, block, threshold_offset), block, axis=0), block, axis=1)
    return np.ascontiguousarray(full[:g.shape[0], :g.shape[1]])


def _threshold_grid(grad_mag: NDArray[np.float32], block: int, threshold_offset: float) -> NDArray[np.float32]:
    """:func:`block_gradient_thresholds` per block, (ceil(H / block), ceil(W / block)) float32: what
    the map holds for each block's pixels (compiled loops; the numpy form is the tests' reference:
    ``np.median`` of each block of the mirror-padded image, ``np.nanmean`` over the 9 shifted grids)."""
    if block < 1:
        raise InputError(f"block size must be >= 1, got {block}")
    # partial blocks at the right/bottom edge are completed by mirroring
    med = block_medians(np.ascontiguousarray(grad_mag), int(block))  # np.median of each block, exactly
    # 3x3 smoothing over neighbouring blocks (edge blocks average over the blocks that exist)
    return smooth_block_thresholds(med, np.float32(threshold_offset))


def select_points(image: NDArray, target: int = 2000,
                  config: PointSelectionConfig = DEFAULT_POINT_SELECTION) -> NDArray[np.float64]:
    """Select about ``target`` well-spread high-gradient pixels of a gray image.

    Args:
        image: gray (H, W) or BGR image, any dtype; converted by :func:`gtvo.core.image.to_float_gray`.
        target: wanted number of points; the result has at most ``target`` (fewer on images
            without enough texture).
        config: the selection's settings (:class:`PointSelectionConfig`: border, threshold
            blocks, cell levels, iterations adapting the cell size, the subsample's seed).

    Returns:
        (N, 2) float64 pixel coordinates ``(u, v)`` (integers, pixel centres), sorted by row then
        column. Empty (0, 2) when nothing passes the thresholds (e.g. a flat image).
    """
    return select_points_float(to_float_gray(image), target, config)


@timed("point_selection")
def select_points_float(img: FloatImage, target: int = 2000,
                        config: PointSelectionConfig = DEFAULT_POINT_SELECTION) -> NDArray[np.float64]:
    """:func:`select_points` of a float32 gray image :func:`gtvo.core.image.to_float_gray` made
    already (a frame's image, converted where it was read), not converted or checked again."""
    if int(target) < 1:
        raise InputError(f"point-selection target must be >= 1, got {target}")
    h, w = img.shape
    border, block, levels, downweight = int(config.border), int(config.block), config.levels, config.downweight
    if 2 * border >= min(h, w):
        raise InputError(f"point-selection border {border} does not fit a {w}x{h} image")
    target = int(target)
    score = _magnitude(img)
    thr = _threshold_grid(score, block, config.threshold_offset)  # block_gradient_thresholds per block
    # the threshold factor of each cell level, float32 as numpy's float32 x Python float product
    factors = np.array([downweight ** lvl for lvl in range(levels)], dtype=np.float32)

    area = float((h - 2 * border) * (w - 2 * border))
    cell = max(1.0, np.sqrt(area / target))
    tried: dict[int, NDArray[np.int64]] = {}  # cell size -> its picks (flat indices, row-major)
    for _ in range(config.max_iterations):
        c = int(max(1, round(cell)))
        if c not in tried:
            tried[c] = pick_cells(score, thr, int(block), border, c, factors)
        n = int(tried[c].size)
        if target <= n <= (1 + config.tolerance) * target or n == 0:
            break
        new_cell = cell * np.sqrt(n / target)
        if int(max(1, round(new_cell))) == c:  # no integer change possible: nudge one step
            new_cell = c + (1 if n > target else -1)
            if new_cell < 1:
                break
        cell = new_cell
    # The best tried cell size: the smallest surplus, else the largest count.
    counts = {c: int(m.size) for c, m in tried.items()}
    over = [c for c, n in counts.items() if n >= target]
    best_c = min(over, key=lambda c: counts[c]) if over else max(counts, key=lambda c: counts[c])
    vs, us = np.divmod(tried[best_c], w)  # np.nonzero of the pick map
    if us.size > target:
        keep = np.sort(np.random.default_rng(config.seed).choice(us.size, size=target, replace=False))
        us, vs = us[keep], vs[keep]
    return np.column_stack([us, vs]).astype(np.float64)
