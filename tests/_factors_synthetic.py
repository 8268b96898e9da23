"""Analytic test images and scenes shared by the factor and tracking tests."""

from __future__ import annotations

import numpy as np

from gtvo.core.camera import PinholeCamera


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


class PlaneSceneImage:
    """The exact image of a textured world plane ``z_world = plane_z`` seen by a camera at ``T_world_cam``.

    Intensity ``128 + sum A sin(k . (x, y) + phi)`` of the world point hit by the pixel's ray;
    gradients by central differences of that analytic function (h = 1e-4 px, error ~1e-8).
    """

    def __init__(self, camera: PinholeCamera, T_world_cam: np.ndarray, plane_z: float = 5.0, seed: int = 3,
                 border: float = 1.0):
        rng = np.random.default_rng(seed)
        self.camera, self.T = camera, np.asarray(T_world_cam, float)
        self.width, self.height, self.border, self.plane_z = camera.width, camera.height, border, plane_z
        n = 5
        ang = rng.uniform(0, np.pi, n)
        lam = rng.uniform(0.25, 0.6, n)  # metres
        self.kx, self.ky = 2 * np.pi / lam * np.cos(ang), 2 * np.pi / lam * np.sin(ang)
        self.amp = rng.uniform(10, 25, n)
        self.phi = rng.uniform(0, 2 * np.pi, n)

    def world_point(self, u, v):
        c = self.camera
        f = np.stack([(u - c.cx) / c.fx, (v - c.cy) / c.fy, np.ones_like(u)], -1)
        R, t = self.T[:3, :3], self.T[:3, 3]
        dw = f @ R.T
        s = (self.plane_z - t[2]) / dw[..., 2]
        return t + s[..., None] * dw, s

    def intensity(self, u, v):
        X, _ = self.world_point(u, v)
        ph = self.kx * X[..., 0, None] + self.ky * X[..., 1, None] + self.phi
        return 128 + np.sum(self.amp * np.sin(ph), -1)

    def inverse_depth(self, u, v):
        """Inverse depth (1/z in this camera) of the plane at pixels."""
        _, s = self.world_point(np.asarray(u, float), np.asarray(v, float))
        return 1.0 / s

    def sample(self, u, v):
        u = np.asarray(u, float)
        v = np.asarray(v, float)
        ok = (np.isfinite(u) & np.isfinite(v) & (u >= self.border) & (u <= self.width - 1 - self.border)
              & (v >= self.border) & (v <= self.height - 1 - self.border))
        us, vs = np.where(ok, u, 0.0), np.where(ok, v, 0.0)
        h = 1e-4
        i = self.intensity(us, vs)
        gx = (self.intensity(us + h, vs) - self.intensity(us - h, vs)) / (2 * h)
        gy = (self.intensity(us, vs + h) - self.intensity(us, vs - h)) / (2 * h)
        return np.where(ok[..., None], np.stack([i, gx, gy], -1), 0.0), ok

    def raster(self) -> np.ndarray:
        v, u = np.mgrid[0:self.height, 0:self.width].astype(float)
        return self.intensity(u, v).astype(np.float32)


def numeric_jacobians(fn, values, keys, h=1e-6):
    """Central differences of ``fn(values) -> vector`` w.r.t. each key, through retract."""
    import gtsam
    out = []
    for k in keys:
        try:
            x = values.atPose3(k)
            dim, kind = 6, "pose"
        except RuntimeError:
            try:
                x = values.atDouble(k)
                dim, kind = 1, "double"
            except RuntimeError:
                x = np.asarray(values.atVector(k), float)
                dim, kind = x.size, "vector"
        cols = []
        for j in range(dim):
            res = []
            for sgn in (1, -1):
                delta = np.zeros(dim)
                delta[j] = sgn * h
                v2 = gtsam.Values(values)
                if kind == "pose":
                    v2.update(k, x.retract(delta))
                elif kind == "double":
                    v2.update(k, float(x + delta[0]))
                else:
                    v2.update(k, x + delta)
                res.append(np.asarray(fn(v2), float))
            cols.append((res[0] - res[1]) / (2 * h))
        out.append(np.stack(cols, -1))
    return out
