"""Where the photometric model's scale bias comes from, each candidate measured in isolation on the
synthetic renderer (exact poses, exact depths, controllable sampling; docs/refinement.md, "The
model's scale bias").

One host keyframe of a synthetic loop (noise-free), its points (the front end's selection, true
inverse depths, pattern pixels on one face), and as targets the right image (the stereo term) and
the left images ``k`` frames before and after (the temporal term) at their TRUE poses. For each
term the one number the graph's scale depends on: the common relative change ``eps`` of every
point's inverse depth (for the stereo term: of the disparity ``fx b d``; for a temporal pair with
the depths held: of ``d * |t|``, i.e. of the translation) at which the term's cost is least, and
the Gauss-Newton fixed point with the kernel's analytic derivative (``sum J r = 0``, which is where
the graph stops). Zero for an unbiased model.

Target samplers compared (the host is always the rendered image at its pixels, exact):
* ``kernel``: the factors' own (``GradientImage``: bilinear intensity, bilinear central-difference
  gradients), and ``kernel GN``: the Gauss-Newton fixed point with its gradients;
* ``bilinear``: bilinear interpolation of the rendered image (``gtvo.core.image.bilinear_sample``);
* ``exact``: the scene rendered again at the warped sub-pixel positions with the same pixel model
  (point or area-integrated): no interpolation at all, the model's ideal;
* ``bicubic``: Keys' cubic convolution (a = -0.5) of the rendered image;
* ``spline``: cubic B-spline interpolation (prefiltered) of the rendered image.

``--graph``: the whole-log graph on keyframes at their true poses and depths (:func:`truth_graph`).
``--interpolation spline``: the factors' kernel samples the cubic B-spline and its exact derivative
instead, in this process (:func:`use_spline_kernel`; the ``kernel`` columns and the graph then use it).
``--every-point``: also the points whose pattern touches a crease or a silhouette.

Usage: python benchmarks/scale_bias.py [--supersample 1,2] [--seed 1] [--host 60] [--gaps 1,2,3,5]
       [--pattern dso8|single] [--samplers kernel,bilinear,exact,spline,bicubic] [--every-point] [--interpolation spline]
       python benchmarks/scale_bias.py --graph [--supersample 2] [--frames 150] [--step 5] [--pattern single] [--interpolation spline]
       [--interior]
"""

from __future__ import annotations

import dataclasses
import sys

import numpy as np

from factors.photometric import (
    PATTERN_DSO8,
    PATTERN_SINGLE,
    GradientImage,
    pattern_bearings,
    photometric_residuals,
    sample_host,
    stereo_residuals,
)
from gtvo.core.image import bilinear_sample
from gtvo.datasets.synthetic import SyntheticSequence, make_synthetic_sequence
from gtvo.frontend.stereo_depth import init_keyframe_points

#: the relative inverse-depth changes searched (a grid, then a parabola through the least three)
EPS = np.linspace(-0.005, 0.005, 41)


class ExactSampler:
    """The scene rendered at arbitrary sub-pixel positions of one camera pose, with the sequence's
    pixel model (``supersample`` x ``supersample`` rays spread over the pixel, or its centre)."""

    def __init__(self, seq: SyntheticSequence, T_world_cam: np.ndarray, gain: tuple[float, float] = (0.0, 0.0)):
        self.seq, self.T = seq, np.asarray(T_world_cam, dtype=float)
        self.width, self.height = seq.pinhole.width, seq.pinhole.height
        self.gain = gain

    def sample(self, u, v):
        cam, s = self.seq.pinhole, self.seq._renderer.supersample
        offsets = (np.arange(s) + 0.5) / s - 0.5
        uu = (np.asarray(u, float).reshape(-1)[:, None, None] + offsets[None, None, :])
        vv = (np.asarray(v, float).reshape(-1)[:, None, None] + offsets[None, :, None])
        uu, vv = np.broadcast_arrays(uu, vv)
        x, y = (uu - cam.cx) / cam.fx, (vv - cam.cy) / cam.fy
        R, o = self.T[:3, :3], self.T[:3, 3]
        dirs = tuple((R[k, 0] * x + R[k, 1] * y + R[k, 2]).reshape(-1) for k in range(3))
        sc = self.seq.scene
        t, face = sc._raycast_xyz(o, dirs)
        val = sc._shade_xyz(tuple(o[k] + dirs[k] * t for k in range(3)), face).astype(float)
        val = val.reshape(-1, s * s).mean(axis=1) * np.exp(self.gain[0]) + self.gain[1]
        out = np.zeros(np.shape(u) + (3,))
        out[..., 0] = val.reshape(np.shape(u))
        ok = (np.asarray(u) >= 1) & (np.asarray(u) <= self.width - 2) & (np.asarray(v) >= 1) & (np.asarray(v) <= self.height - 2)
        return out, ok


def _keys(x):
    """Keys' cubic convolution kernel (a = -0.5) at offsets ``x``."""
    ax = np.abs(x)
    return np.where(ax <= 1, 1.5 * ax ** 3 - 2.5 * ax ** 2 + 1,
                    np.where(ax < 2, -0.5 * ax ** 3 + 2.5 * ax ** 2 - 4 * ax + 2, 0.0))


class BilinearSampler:
    """Bilinear interpolation of an image (intensity only; what the kernel sampled before the spline)."""

    def __init__(self, image: np.ndarray):
        self.img = np.asarray(image, np.float32)
        self.height, self.width = self.img.shape

    def sample(self, u, v):
        vals, ok = bilinear_sample(self.img, u, v, border=1.0)
        out = np.zeros(np.shape(u) + (3,))
        out[..., 0] = vals
        return out, ok


class BicubicSampler:
    """Keys' cubic convolution of an image (intensity only)."""

    def __init__(self, image: np.ndarray):
        self.img = np.asarray(image, float)
        self.height, self.width = self.img.shape

    def sample(self, u, v):
        u, v = np.asarray(u, float), np.asarray(v, float)
        ok = (u >= 2) & (u <= self.width - 3) & (v >= 2) & (v <= self.height - 3)
        uc, vc = np.where(ok, u, 2.0), np.where(ok, v, 2.0)
        x0, y0 = np.floor(uc).astype(int), np.floor(vc).astype(int)
        acc = np.zeros(u.shape)
        for j in range(-1, 3):
            wy = _keys(vc - (y0 + j))
            for i in range(-1, 3):
                acc += wy * _keys(uc - (x0 + i)) * self.img[y0 + j, x0 + i]
        out = np.zeros(u.shape + (3,))
        out[..., 0] = np.where(ok, acc, 0.0)
        return out, ok


class SplineSampler:
    """Cubic B-spline interpolation of an image (prefiltered: it passes through the pixels; intensity only)."""

    def __init__(self, image: np.ndarray):
        from scipy import ndimage
        self._ndimage = ndimage
        self.coef = ndimage.spline_filter(np.asarray(image, float), order=3, mode="mirror")
        self.height, self.width = self.coef.shape

    def sample(self, u, v):
        u, v = np.asarray(u, float), np.asarray(v, float)
        ok = (u >= 2) & (u <= self.width - 3) & (v >= 2) & (v <= self.height - 3)
        val = self._ndimage.map_coordinates(self.coef, [v.reshape(-1), u.reshape(-1)], order=3, prefilter=False,
                                            mode="mirror").reshape(u.shape)
        out = np.zeros(u.shape + (3,))
        out[..., 0] = np.where(ok, val, 0.0)
        return out, ok


def host_points(seq: SyntheticSequence, host: int, margin: int = 4, every_point: bool = False):
    """The front end's points of frame ``host`` whose pattern sees one face: pixels, true inverse depths."""
    kp = init_keyframe_points(seq.left(host), seq.right(host), seq.camera, target=2000)
    px = np.asarray(kp.pixels, float)
    u, v = px[:, 0].astype(int), px[:, 1].astype(int)
    inside = seq.interior_mask(host, margin=margin)[v, u] | every_point
    z = seq.true_depth(host)[v, u].astype(float)
    return px[inside], 1.0 / z[inside]


def best_eps(cost_of_eps) -> float:
    """Least cost over ``EPS`` refined by a parabola through the three around the grid minimum."""
    c = np.array([cost_of_eps(e) for e in EPS])
    k = int(np.clip(np.argmin(c), 1, len(EPS) - 2))
    a, b = c[k - 1] - 2 * c[k] + c[k + 1], c[k + 1] - c[k - 1]
    return float(EPS[k] - 0.5 * b / a * (EPS[1] - EPS[0])) if a > 0 else float(EPS[k])


def gn_eps(residuals_of_eps, iterations: int = 6) -> float:
    """Gauss-Newton on the common scale with the kernel's ``J_depth``: where ``sum J r = 0``."""
    e = 0.0
    for _ in range(iterations):
        r, J = residuals_of_eps(e)
        e -= float(np.sum(J * r) / np.sum(J * J))
    return e


def measure(seq: SyntheticSequence, host: int, gaps: list[int], pattern=PATTERN_DSO8, which=("bilinear", "exact", "bicubic"),
            every_point: bool = False) -> None:
    cam, b = seq.pinhole, seq.camera.baseline
    px, d = host_points(seq, host, every_point=every_point)
    left = GradientImage(seq.left(host))
    Ih, hv = sample_host(left, px, pattern)
    f = pattern_bearings(cam, px, pattern)
    T_h = seq.gt_poses[host]
    right_pose = T_h @ np.linalg.inv(seq.camera.T_right_left)
    targets = {"stereo": (right_pose, seq.right(host), seq.affine_right[host], seq.affine_left[host])}
    for g in gaps:
        for k in (host - g, host + g):
            targets[f"temporal {k - host:+d}"] = (seq.gt_poses[k], seq.left(k), seq.affine_left[k], seq.affine_left[host])
    print(f"host {host}: {len(px)} points, median depth {np.median(1 / d):.1f} m, "
          f"median disparity {np.median(cam.fx * b * d):.2f} px")
    for name, (T_t, img, aff_t, aff_h) in targets.items():
        samplers = {"kernel": GradientImage(img), "bilinear": BilinearSampler(img),
                    "exact": ExactSampler(seq, T_t, tuple(aff_t)),
                    "bicubic": BicubicSampler(img), "spline": SplineSampler(img)}
        samplers = {k: samplers[k] for k in which}
        row = []
        grad = GradientImage(img)

        def res(sampler, e, name=name, T_t=T_t, aff_h=aff_h, aff_t=aff_t):
            if name == "stereo":
                return stereo_residuals(cam, b, Ih, hv, px, d * (1 + e), sampler, aff_h, aff_t, pattern,
                                        bearings=f)
            return photometric_residuals(cam, Ih, hv, px, d * (1 + e), T_h, T_t, sampler, aff_h, aff_t,
                                         pattern, bearings=f)

        base = res(grad, 0.0).valid
        for label, sampler in samplers.items():
            def cost(e, sampler=sampler, res=res, base=base):
                lin = res(sampler, e)
                return float(np.sum(np.where(base & lin.valid, lin.residual, 0.0) ** 2))
            row.append(f"{label} min {100 * best_eps(cost):+.4f} %")

        def r_and_j(e, res=res, grad=grad, base=base):
            lin = res(grad, e)
            ok = base & lin.valid
            return np.where(ok, lin.residual, 0.0), np.where(ok, lin.J_depth * (d * (1 + e))[:, None], 0.0)
        row.append(f"kernel GN {100 * gn_eps(r_and_j):+.4f} %")
        print(f"  {name:12s} " + " | ".join(row), flush=True)


def main(argv: list[str]) -> None:
    def arg(name, default):
        return argv[argv.index(name) + 1] if name in argv else default
    seed, host = int(arg("--seed", 1)), int(arg("--host", 60))
    pattern = PATTERN_SINGLE if arg("--pattern", "dso8") == "single" else PATTERN_DSO8
    if arg("--interpolation", "bilinear") == "spline":
        use_spline_kernel()
    if "--graph" in argv:
        for s in (int(x) for x in arg("--supersample", "2").split(",")):
            truth_graph(seed, s, int(arg("--frames", 150)), int(arg("--step", 5)), single=pattern is PATTERN_SINGLE,
                        interior="--interior" in argv)
        return
    gaps = [int(x) for x in arg("--gaps", "1,2,3,5").split(",")]
    which = tuple(arg("--samplers", "kernel,bilinear,exact,spline").split(","))
    for s in (int(x) for x in arg("--supersample", "1,2").split(",")):
        seq = make_synthetic_sequence(n_frames=300, noise_sigma=0.0, seed=seed, motion="loop", supersample=s)
        print(f"supersample {s}, seed {seed}: relative inverse-depth (disparity, d|t|) change at the least cost")
        measure(seq, host, gaps, pattern, which, "--every-point" in argv)


def use_spline_kernel() -> None:
    """Swap the compiled kernel's bilinear sampler for cubic B-spline interpolation with its exact
    derivative, in this process only (an experiment on the graph: ``refine_oracle.py
    --interpolation spline``). Call before any kernel runs. Packed records hold the spline
    coefficients in the intensity's channel; the clipped-cell flags are not checked."""
    import numba
    from scipy import ndimage

    from factors import _compiled

    @numba.njit(nogil=True)
    def _spline(packed, has_clip, width, height, border, u, v):
        if not (u >= border and u <= width - 1 - border and v >= border and v <= height - 1 - border):
            return False, 0.0, 0.0, 0.0
        x0 = min(max(int(u), 1), width - 3)
        y0 = min(max(int(v), 1), height - 3)
        tx, ty = u - x0, v - y0
        wx = ((1 - tx) ** 3 / 6, (3 * tx ** 3 - 6 * tx ** 2 + 4) / 6, (-3 * tx ** 3 + 3 * tx ** 2 + 3 * tx + 1) / 6,
              tx ** 3 / 6)
        dx = (-(1 - tx) ** 2 / 2, 1.5 * tx ** 2 - 2 * tx, -1.5 * tx ** 2 + tx + 0.5, tx ** 2 / 2)
        wy = ((1 - ty) ** 3 / 6, (3 * ty ** 3 - 6 * ty ** 2 + 4) / 6, (-3 * ty ** 3 + 3 * ty ** 2 + 3 * ty + 1) / 6,
              ty ** 3 / 6)
        dy = (-(1 - ty) ** 2 / 2, 1.5 * ty ** 2 - 2 * ty, -1.5 * ty ** 2 + ty + 0.5, ty ** 2 / 2)
        intensity = gx = gy = 0.0
        for j in range(4):
            row = (y0 - 1 + j) * width + x0 - 1
            ri = rx = 0.0
            for i in range(4):
                c = packed[row + i, 0]
                ri += wx[i] * c
                rx += dx[i] * c
            intensity += wy[j] * ri
            gx += wy[j] * rx
            gy += dy[j] * ri
        return True, intensity, gx, gy

    def pack(img, lo, hi, check_clip):
        packed, _, finite = pack_bilinear(img, lo, hi, check_clip)
        packed[..., 0] = ndimage.spline_filter(np.asarray(img, float), order=3, mode="mirror")
        return packed, False, finite

    pack_bilinear = _compiled.pack_gradient_image
    _compiled._bilinear = _spline
    _compiled.pack_gradient_image = pack
    _compiled.sample_stack = numba.njit(nogil=True)(_compiled.sample_stack.py_func)
    _compiled.warp_residuals = numba.njit(nogil=True)(_compiled.warp_residuals.py_func)


def truth_graph(seed: int, supersample: int, frames: int, step: int, span: int = 10, single: bool = False,
                interior: bool = False) -> None:
    """The whole-log graph on keyframes every ``step`` frames at their TRUE poses, their points
    (the front end's selection) at their TRUE inverse depths, started there (no window pass, no
    window or loop edges: the photometric, stereo, affine and motion terms alone). Printed: how
    far its optimum is from the truth, as the local scale error (the relative error of the
    distance between keyframes ``span`` apart: mean / RMS / max), the Sim(3) scale, the SE(3) ATE."""
    import gtsam

    from gtvo.config import OdometryConfig
    from gtvo.evaluation.alignment import umeyama_alignment
    from gtvo.refinement import RefineConfig, RefinementInput, refine_keyframes
    from gtvo.window import WindowKeyframe, WindowMembers, WindowSettings

    seq = make_synthetic_sequence(n_frames=300, noise_sigma=0.0, seed=seed, motion="loop", supersample=supersample)
    cfg = OdometryConfig()
    if single:  # one pixel, no pattern
        cfg = dataclasses.replace(cfg, photometric=dataclasses.replace(cfg.photometric, pattern=((0.0, 0.0),)))
    kfs = []
    for i in range(0, frames, step):
        left, right = seq.left(i), seq.right(i)
        pts = init_keyframe_points(left, right, seq.camera, target=2000)
        px = np.asarray(pts.pixels)
        keep = seq.interior_mask(i, margin=4)[px[:, 1].astype(int), px[:, 0].astype(int)] if interior else slice(None)
        px, variance = px[keep], np.asarray(pts.variance)[keep]
        z = seq.true_depth(i)[px[:, 1].astype(int), px[:, 0].astype(int)].astype(float)
        kfs.append(WindowKeyframe(i, gtsam.Pose3(seq.gt_poses[i]), np.zeros(2), GradientImage(left), px, 1.0 / z,
                                  variance, right=GradientImage(right), timestamp=0.1 * i))
    run = RefinementInput(WindowMembers(seq.pinhole, seq.camera.baseline, kfs),
                          WindowSettings(cfg.window, cfg.photometric), None,
                          start_poses={kf.index: seq.gt_poses[kf.index] for kf in kfs})
    out = refine_keyframes(run, RefineConfig(enabled=True, max_iterations=20, window_edges=False))
    est = np.array([kf.pose.translation() for kf in out.keyframes])
    gt = np.array([seq.gt_poses[kf.index][:3, 3] for kf in out.keyframes])
    local = 100 * (np.linalg.norm(est[span:] - est[:-span], axis=1) / np.linalg.norm(gt[span:] - gt[:-span], axis=1) - 1)
    ate = float(np.sqrt(np.mean(np.sum((umeyama_alignment(est, gt).apply(est) - gt) ** 2, axis=1))))
    print(f"truth graph: loop seed {seed}, supersample {supersample}, {len(kfs)} keyframes every {step} frames, "
          f"pattern of {len(cfg.photometric.pattern)} px, {'interior points' if interior else 'every point'}: "
          f"local scale error over {span} keyframes mean {np.mean(local):+.3f} / RMS {np.sqrt(np.mean(local ** 2)):.3f}"
          f" / max {np.max(np.abs(local)):.3f} %, Sim(3) scale {umeyama_alignment(est, gt, with_scale=True).scale:.5f},"
          f" SE(3) ATE {1000 * ate:.2f} mm", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
