"""Analytic test images and scenes shared by the factor and tracking tests."""

from __future__ import annotations

import numpy as np

from gtvo.camera import PinholeCamera


class SinusoidImage:
    """A smooth analytic texture with exact intensity and gradient (no interpolation error).

    ``I(u, v) = 128 + sum_k A_k sin(wu_k u + wv_k v + phi_k)``; valid inside ``[border, W-1-border]``.
    """

    def __init__(self, width: int = 160, height: int = 120, seed: int = 0, border: float = 1.0,
                 n_waves: int = 4, wavelength: float = 12.0):
        rng = np.random.default_rng(seed)
        self.width, self.height, self.border = width, height, border
        ang = rng.uniform(0, np.pi, n_waves)
        lam = wavelength * rng.uniform(0.7, 1.5, n_waves)
        self.wu = 2 * np.pi / lam * np.cos(ang)
        self.wv = 2 * np.pi / lam * np.sin(ang)
        self.amp = rng.uniform(15, 30, n_waves)
        self.phi = rng.uniform(0, 2 * np.pi, n_waves)

    def value(self, u, v):
        u = np.asarray(u, float)[..., None]
        v = np.asarray(v, float)[..., None]
        ph = self.wu * u + self.wv * v + self.phi
        return 128 + np.sum(self.amp * np.sin(ph), -1), np.sum(self.amp * self.wu * np.cos(ph), -1), \
            np.sum(self.amp * self.wv * np.cos(ph), -1)

    def sample(self, u, v):
        u = np.asarray(u, float)
        v = np.asarray(v, float)
        ok = (np.isfinite(u) & np.isfinite(v) & (u >= self.border) & (u <= self.width - 1 - self.border)
              & (v >= self.border) & (v <= self.height - 1 - self.border))
        i, gx, gy = self.value(np.where(ok, u, 0), np.where(ok, v, 0))
        out = np.stack([i, gx, gy], -1)
        return np.where(ok[..., None], out, 0.0), ok

    def raster(self) -> np.ndarray:
        v, u = np.mgrid[0:self.height, 0:self.width]
        return self.value(u, v)[0].astype(np.float32)


def small_camera(width: int = 160, height: int = 120) -> PinholeCamera:
    return PinholeCamera(120.0, 118.0, width / 2 - 0.3, height / 2 + 0.2, width, height)
