"""A stereo sequence whose right images are shifted on load: a simulated rig rectification error.

:func:`shift_right_images` wraps a :class:`gtvo.datasets.sequence.Sequence` so that every right
image is moved by ``(sx, sy)`` pixels (``cv2.warpAffine``, border replicated; a positive ``sx``
moves the image content to the right) when it is loaded. Bilinear by default: a fractional shift
then also blurs the image (half a pixel is the 2-tap box filter), which a real rig offset does not;
``interpolation="lanczos4"`` moves the content with almost no blur (docs/benchmarks.md, "Rig
calibration", compares the two). Nothing is written to disk. Used by
``benchmarks/rig_calibration.py`` and the tests of the window's rig calibration (docs/window.md,
"Rig calibration"): the rig offset the odometry should find is then ``(delta_x, delta_y) = (sx, sy)``.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.datasets.sequence import Sequence
from gtvo.errors import InputError


#: the interpolations :func:`shift_image` offers, by name
INTERPOLATIONS: dict[str, int] = {"linear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC, "lanczos4": cv2.INTER_LANCZOS4}


def _interpolation_flag(interpolation: str) -> int:
    if interpolation not in INTERPOLATIONS:
        raise InputError(f"image shift interpolation must be one of {sorted(INTERPOLATIONS)}, got {interpolation!r}")
    return INTERPOLATIONS[interpolation]


def shift_image(image: ArrayLike, shift: tuple[float, float], interpolation: str = "linear") -> NDArray:
    """``image`` with its content moved by ``shift = (sx, sy)`` px (``interpolation`` one of
    :data:`INTERPOLATIONS`, border replicated), same dtype (integers rounded and clipped)."""
    flag = _interpolation_flag(interpolation)
    img = np.asarray(image)
    sx, sy = (float(s) for s in shift)
    M = np.array([[1.0, 0.0, sx], [0.0, 1.0, sy]], dtype=np.float64)
    out = cv2.warpAffine(img.astype(np.float32), M, (img.shape[1], img.shape[0]), flags=flag,
                         borderMode=cv2.BORDER_REPLICATE)
    if np.issubdtype(img.dtype, np.integer):
        return np.clip(np.rint(out), np.iinfo(img.dtype).min, np.iinfo(img.dtype).max).astype(img.dtype)
    return out.astype(img.dtype)


def shift_right_images(seq: Sequence, shift: tuple[float, float], interpolation: str = "linear") -> Sequence:
    """A copy of the stereo ``seq`` whose right images are shifted by ``shift = (sx, sy)`` px on load
    (:func:`shift_image` with ``interpolation``)."""
    _interpolation_flag(interpolation)
    if seq.kind != "stereo" or seq.load_right is None:
        raise InputError(f"shift_right_images needs a stereo sequence, got a {seq.kind} one", path=seq.source)
    sx, sy = (float(s) for s in shift)
    if not (np.isfinite(sx) and np.isfinite(sy)):
        raise InputError(f"right-image shift must be finite, got {shift!r}")
    load = seq.load_right

    def load_shifted(i: int) -> NDArray:
        return shift_image(load(i), (sx, sy), interpolation)

    return dataclasses.replace(seq, name=f"{seq.name}+right({sx:+g},{sy:+g})px", load_right=load_shifted)
