"""Synthetic rectified stereo pairs sampled exactly from a continuous texture (tests only)."""

from __future__ import annotations

import numpy as np

from gtvo.core.camera import PinholeCamera, StereoCamera


def texture(x: np.ndarray, y: np.ndarray, seed: int = 0, n_waves: int = 40,
            min_wavelength: float = 4.0, max_wavelength: float = 40.0) -> np.ndarray:
    """A smooth random texture (sum of random plane waves), values roughly in [0, 255]."""
    rng = np.random.default_rng(seed)
    out = np.zeros(np.broadcast(x, y).shape)
    for _ in range(n_waves):
        theta = rng.uniform(0, np.pi)
        k = 2 * np.pi / rng.uniform(min_wavelength, max_wavelength)
        phase = rng.uniform(0, 2 * np.pi)
        out += np.sin(k * (np.cos(theta) * x + np.sin(theta) * y) + phase)
    return 128.0 + 90.0 * out / np.sqrt(n_waves / 2.0) / 2.0


def stereo_pair(width: int = 320, height: int = 240, plane: tuple[float, float, float] = (12.0, 0.0, 0.0),
                seed: int = 0, noise: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Left/right images of a fronto-slanted plane with disparity ``a + b u + c v`` (left coords).

    The right pixel ``x_r`` sees the left pixel ``u`` with ``u - disp(u, v) = x_r``, i.e.
    ``u = (x_r + a + c v) / (1 - b)``. Returns ``(left, right, disparity_left)``, float32 images.
    """
    a, b, c = plane
    v, u = np.mgrid[0:height, 0:width].astype(float)
    left = texture(u, v, seed)
    right = texture((u + a + c * v) / (1.0 - b), v, seed)
    rng = np.random.default_rng(seed + 1)
    if noise > 0:
        left = left + rng.normal(0, noise, left.shape)
        right = right + rng.normal(0, noise, right.shape)
    disp = a + b * u + c * v
    return left.astype(np.float32), right.astype(np.float32), disp


def camera(width: int = 320, height: int = 240, fx: float = 400.0, baseline: float = 0.5) -> StereoCamera:
    return StereoCamera(PinholeCamera(fx, fx, width / 2.0, height / 2.0, width, height), baseline)
