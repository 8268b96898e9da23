"""The photometric model's parameters in one object: :class:`PhotometricConfig`.

The tracker and the window weigh the same residuals (:mod:`factors.photometric`) with the same
noise, robust kernel and pattern, on images clipped at the same grey levels: one frozen object
carries those four settings (GTSAM's parameter objects, e.g. ``SmartProjectionParams``), in place
of a module global read at call time. ``gtvo.config.OdometryConfig.photometric`` holds the run's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from factors.gtsam_factors import DEFAULT_HUBER_K, DEFAULT_SIGMA_INTENSITY
from factors.photometric import DEFAULT_CLIP_RANGE, PATTERN_DSO8
from gtvo.core.settings import SettingError, check_settings, setting

#: DSO's 8-pixel pattern as a tuple of offsets (the default of :attr:`PhotometricConfig.pattern`).
PATTERN_DSO8_OFFSETS: tuple[tuple[float, float], ...] = tuple((float(u), float(v)) for u, v in PATTERN_DSO8)


#: The largest ``|du|``, ``|dv|`` of a pattern offset (px).
MAX_PATTERN_OFFSET = 8.0


@dataclass(frozen=True)
class PhotometricConfig:
    """Parameters of the photometric residuals shared by the tracker and the window.

    Attributes:
        sigma_intensity: the image noise sigma_I (grey levels) in the weight ``W`` of a residual.
        huber_k: Huber threshold on the whitened pattern norm of a point; None: no robust loss.
        pattern: the residual pattern, offsets ``(du, dv)`` in pixels of the pyramid level used
            (default DSO's 8 pixels), each within +-8 px (the keyframes' point selection keeps
            that border free).
        clip_range: ``(lo, hi)`` grey levels at or beyond which the sensor clipped: a sample whose
            bilinear cell touches such a pixel is invalid (:class:`factors.photometric.GradientImage`),
            and the stereo gain estimate leaves such patches out; None: no check.
    """

    sigma_intensity: float = setting(DEFAULT_SIGMA_INTENSITY, "[0.01, 100]")
    huber_k: float | None = setting(DEFAULT_HUBER_K, "[0.01, 100]")
    pattern: tuple[tuple[float, float], ...] = PATTERN_DSO8_OFFSETS
    clip_range: tuple[float, float] | None = setting(DEFAULT_CLIP_RANGE, "[0, 255]")

    def __post_init__(self) -> None:
        check_settings(self)
        pat = np.asarray(self.pattern, dtype=float)
        if (pat.ndim != 2 or pat.shape[1] != 2 or pat.shape[0] < 1 or not np.all(np.isfinite(pat))
                or not np.all(np.abs(pat) <= MAX_PATTERN_OFFSET)):
            raise SettingError("pattern", f"must be a list of (du, dv) offsets within +-{MAX_PATTERN_OFFSET:g} px, "
                                          f"got {self.pattern!r}")
        object.__setattr__(self, "pattern", tuple((float(u), float(v)) for u, v in pat))
        clip = self.clip_range
        if clip is not None and (len(clip) != 2 or not clip[0] < clip[1]):
            raise SettingError("clip_range", f"must be (lo, hi) with lo < hi, or None, got {clip!r}")

    @property
    def pattern_array(self) -> NDArray[np.float64]:
        """:attr:`pattern` as a (P, 2) array (a new one each call)."""
        return np.array(self.pattern, dtype=np.float64).reshape(-1, 2)


#: The default photometric model (the default argument of the functions that take one).
DEFAULT_PHOTOMETRIC = PhotometricConfig()
