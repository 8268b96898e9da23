"""The stereo front end against OpenCV StereoSGBM at the front end's own points, on every shared
Middlebury 2014 (quarter) pair, and the front end's CPU cost.

For each pair (``<data>/stereo_disparity_gt/middlebury2014_quarter``, its README):

1. ``init_keyframe_points(left, right, camera, target=2000)`` on the raw colour pair with the
   default settings (the camera from ``cam0``'s f, cx, cy and the baseline; Middlebury's ``doffs``
   stays in the pixel disparity, ``disparity_offset = 0``);
2. its disparity ``inverse_depth * fx * baseline`` against ``disp0GT.pfm`` at the kept integer
   pixels where the ground truth is finite: mean absolute error, bad-1.0 (share more than 1 px
   off), median signed error, and the share of points whose error is beyond 3 sigma
   (``sigma = sqrt(variance) * fx * baseline``, the disparity standard deviation the front end
   gives the point), and the same share among the points within 1 px of the truth (the inliers);
3. ``cv2.StereoSGBM_create(0, numDisparities = max GT rounded up to 16, 5, 8*25, 32*25, 1, 63,
   10, 100, 1, STEREO_SGBM_MODE_HH)`` on the same colour pair, its disparity / 16 at the same
   pixels where SGBM gives one (> 0): the same errors.

``--gt-check``: how exact the quarter-size ground truth is, judged by the images themselves. At
the points the front end keeps on a smooth, non-occluded surface (ground truth finite, mask 255
and spanning less than 1 px over the 5x5 patch), the right image is sampled at the ground truth
of every patch pixel (``u - gt(u, v)``, the surface's slant included) minus one free shift, and
the zero-mean SSD is minimised over that shift (:func:`ground_truth_shift`; 1-D, then 2-D with a
free vertical shift as well, for the pairs' residual vertical disparity). The median shift is what
the images say the ground truth is off by; it is printed beside gtvo's median signed error at the
same points, and the median of their difference per point (gtvo's bias against the images).

``--cpu N``: process CPU time (``time.process_time``) of ``init_keyframe_points`` over the
Middlebury pairs and the first KITTI_sequence_1 pair, N rounds. To compare two checkouts, run the
script with ``--gtvo CHECKOUT`` for each, alternately, in the same session.

Usage: ``python benchmarks/frontend_middlebury.py [--data DIR] [--cpu N | --gt-check] [--gtvo CHECKOUT]``
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TARGET = 2000


@dataclass(frozen=True)
class PairErrors:
    """Disparity errors of one matcher at one pair's points (px)."""

    points: int
    mean_abs: float
    bad1: float
    median_signed: float

    @staticmethod
    def of(err: np.ndarray) -> "PairErrors":
        if err.size == 0:
            return PairErrors(0, float("nan"), float("nan"), float("nan"))
        return PairErrors(int(err.size), float(np.mean(np.abs(err))), float(np.mean(np.abs(err) > 1.0)),
                          float(np.median(err)))


def read_pfm(path: Path) -> np.ndarray:
    """A one-channel PFM image as float64, rows top to bottom."""
    with open(path, "rb") as f:
        if f.readline().strip() != b"Pf":
            raise SystemExit(f"{path}: not a one-channel PFM file")
        w, h = (int(x) for x in f.readline().split())
        scale = float(f.readline())
        data = np.frombuffer(f.read(), dtype="<f4" if scale < 0 else ">f4")
    if data.size != w * h:
        raise SystemExit(f"{path}: PFM has {data.size} values, expected {w * h}")
    return np.flipud(data.reshape(h, w)).astype(np.float64)


def read_calib(path: Path) -> dict[str, float]:
    """``f``, ``cx``, ``cy`` of cam0 and the baseline (mm) of a Middlebury calib.txt."""
    text = path.read_text()
    m = re.search(r"cam0\s*=\s*\[\s*([-\d.eE+]+)\s+\S+\s+([-\d.eE+]+)\s*;\s*\S+\s+\S+\s+([-\d.eE+]+)", text)
    b = re.search(r"baseline\s*=\s*([-\d.eE+]+)", text)
    if m is None or b is None:
        raise SystemExit(f"{path}: no cam0 matrix or baseline")
    f, cx, cy = (float(g) for g in m.groups())
    return {"f": f, "cx": cx, "cy": cy, "baseline": float(b.group(1))}


def pairs(data: Path):
    """(name, left BGR, right BGR, ground truth, StereoCamera) of every shared Middlebury pair."""
    from gtvo.core.camera import PinholeCamera, StereoCamera

    root = data / "stereo_disparity_gt" / "middlebury2014_quarter"
    scenes = sorted(p for p in root.iterdir() if (p / "calib.txt").is_file()) if root.is_dir() else []
    if not scenes:
        raise SystemExit(f"{root}: no Middlebury pairs")
    for sc in scenes:
        cal = read_calib(sc / "calib.txt")
        left = cv2.imread(str(sc / "im0.png"), cv2.IMREAD_COLOR)
        right = cv2.imread(str(sc / "im1.png"), cv2.IMREAD_COLOR)
        gt = read_pfm(sc / "disp0GT.pfm")
        h, w = gt.shape
        cam = StereoCamera(PinholeCamera(cal["f"], cal["f"], cal["cx"], cal["cy"], w, h), cal["baseline"] / 1000.0)
        yield sc.name, left, right, gt, cam


def sgbm_disparity(left: np.ndarray, right: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """OpenCV SGBM (5x5 blocks, HH mode) over the ground truth's range; <= 0 where it gives none."""
    nd = int(np.ceil(np.max(gt[np.isfinite(gt)]) / 16.0)) * 16
    sg = cv2.StereoSGBM_create(0, nd, 5, 8 * 25, 32 * 25, 1, 63, 10, 100, 1, cv2.STEREO_SGBM_MODE_HH)
    return sg.compute(left, right).astype(np.float32) / 16.0


def table(data: Path) -> None:
    from gtvo.frontend import init_keyframe_points

    print(f"\n### Middlebury 2014 quarter: init_keyframe_points(target={TARGET}) against SGBM at the same "
          "points\n")
    print("| pair | points | gtvo: mean abs (px) | gtvo: bad-1.0 | gtvo: median signed (px) | gtvo: beyond 3 sigma | "
          "gtvo: inliers beyond 3 sigma | "
          "SGBM: points | SGBM: mean abs | SGBM: bad-1.0 | SGBM: median signed | gtvo at or below SGBM |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    wins = 0
    names = []
    for name, left, right, gt, cam in pairs(data):
        kp = init_keyframe_points(left, right, cam, target=TARGET)
        fxb = cam.left.fx * cam.baseline
        px = kp.pixels.astype(np.intp)
        g = gt[px[:, 1], px[:, 0]]
        fin = np.isfinite(g)
        disp = kp.inverse_depth * fxb
        err = (disp - g)[fin]
        sigma = np.sqrt(kp.variance[fin]) * fxb
        beyond = float(np.mean(np.abs(err) > 3.0 * sigma)) if err.size else float("nan")
        inl = np.abs(err) <= 1.0
        beyond_inl = float(np.mean(np.abs(err[inl]) > 3.0 * sigma[inl])) if inl.any() else float("nan")
        s = sgbm_disparity(left, right, gt)[px[:, 1], px[:, 0]]
        sv = fin & (s > 0)
        ours, theirs = PairErrors.of(err), PairErrors.of((s - g)[sv])
        win = ours.mean_abs <= theirs.mean_abs and ours.bad1 <= theirs.bad1
        wins += win
        names.append(name)
        print(f"| {name} | {ours.points} | {ours.mean_abs:.2f} | {100 * ours.bad1:.1f} % | {ours.median_signed:+.3f} | "
              f"{100 * beyond:.1f} % | {100 * beyond_inl:.1f} % | {theirs.points} | {theirs.mean_abs:.2f} | {100 * theirs.bad1:.1f} % | "
              f"{theirs.median_signed:+.3f} | {'yes' if win else 'no'} |")
    print(f"\ngtvo at or below SGBM in both mean abs and bad-1.0 on {wins} of {len(names)} pairs")


#: The 5x5 patch of the ground-truth check, offsets (du, dv) row by row.
_PATCH = np.array([[du, dv] for dv in range(-2, 3) for du in range(-2, 3)], dtype=np.float64)


def _keys_weights(t: np.ndarray) -> np.ndarray:
    """Keys' cubic convolution weights (``a = -1/2``) of the taps ``floor - 1 .. floor + 2`` for the
    fractions ``t`` (any shape): (..., 4)."""
    t2, t3 = t * t, t * t * t
    return 0.5 * np.stack([-t3 + 2 * t2 - t, 3 * t3 - 5 * t2 + 2, -3 * t3 + 4 * t2 + t, t3 - t2], -1)


def _sample_cubic(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Separable Keys cubic samples of an image at real positions (equal shapes), taps clamped to
    the image (exact positions: OpenCV's remap rounds them to 1/32 px)."""
    h, w = image.shape
    fx, fy = np.floor(x), np.floor(y)
    wx, wy = _keys_weights(x - fx), _keys_weights(y - fy)
    taps = np.arange(-1, 3)
    xs = np.clip(fx[..., None].astype(np.intp) + taps, 0, w - 1)
    ys = np.clip(fy[..., None].astype(np.intp) + taps, 0, h - 1)
    img = np.asarray(image, dtype=np.float64)
    rows = img[ys[..., :, None], xs[..., None, :]]  # (..., 4 rows, 4 columns)
    return np.einsum("...ij,...i,...j->...", rows, wy, wx)


def ground_truth_shift(left: np.ndarray, right: np.ndarray, gt: np.ndarray, pixels: np.ndarray,
                       vertical: bool = False, iterations: int = 8) -> np.ndarray:
    """Per pixel, the shift ``s`` (px, (N,)) that best aligns the left 5x5 patch with the right
    image sampled at ``(u_k - gt(u_k, v_k) - s, v_k [+ t])``: Gauss-Newton on the zero-mean
    residual with cubic samples (numerical slopes, 0.05 px). ``gt`` is read at every patch
    pixel, so a slanted surface needs no shift; the shift is the images' disagreement with the
    ground truth. ``vertical``: a free vertical shift ``t`` too (returned shifts still ``s``).
    Samples by separable Keys cubic convolution at exact positions.
    NaN where the patch leaves the image or the ground truth is not finite over it.

    Args:
        left, right: float32 gray images (H, W).
        gt: the left image's disparity (H, W), inf where unknown.
        pixels: (N, 2) integer ``(u, v)``.
    """
    h, w = gt.shape
    uu = pixels[:, :1] + _PATCH[:, 0]
    vv = pixels[:, 1:] + _PATCH[:, 1]
    ok = (uu >= 2).all(1) & (uu <= w - 3).all(1) & (vv >= 2).all(1) & (vv <= h - 3).all(1)
    ui, vi = np.clip(uu, 0, w - 1).astype(np.intp), np.clip(vv, 0, h - 1).astype(np.intp)
    g = gt[vi, ui]
    ok &= np.isfinite(g).all(1)
    g = np.where(np.isfinite(g), g, 0.0)
    lc = left[vi, ui].astype(np.float64)
    lc -= lc.mean(1, keepdims=True)
    p = np.zeros((pixels.shape[0], 2))
    eps = 0.05
    for _ in range(iterations):
        x, y = uu - g - p[:, :1], vv + p[:, 1:]
        r = lc - _sample_cubic(right, x, y)
        r -= r.mean(1, keepdims=True)  # zero-mean residual: lc - (R - mean R)
        jx = (_sample_cubic(right, x + eps, y) - _sample_cubic(right, x - eps, y)) / (2 * eps)  # dr/ds
        jy = (_sample_cubic(right, x, y - eps) - _sample_cubic(right, x, y + eps)) / (2 * eps)  # dr/dt
        jx -= jx.mean(1, keepdims=True)
        jy -= jy.mean(1, keepdims=True)
        if vertical:
            a = np.stack([np.stack([(jx * jx).sum(1), (jx * jy).sum(1)], -1),
                          np.stack([(jx * jy).sum(1), (jy * jy).sum(1)], -1)], -2) + 1e-6 * np.eye(2)
            b = np.stack([(jx * r).sum(1), (jy * r).sum(1)], -1)
            p -= np.clip(np.linalg.solve(a, b[..., None])[..., 0], -0.3, 0.3)
        else:
            jtj = (jx * jx).sum(1)
            p[:, 0] -= np.clip((jx * r).sum(1) / np.maximum(jtj, 1e-6), -0.3, 0.3)
    return np.where(ok & (np.abs(p) < 1.0).all(1), p[:, 0], np.nan)


def gt_check(data: Path) -> None:
    from gtvo.core.image import to_float_gray
    from gtvo.frontend import init_keyframe_points

    print("\n### Middlebury 2014 quarter: the images against the ground truth at gtvo's smooth, non-occluded "
          "points\n")
    print("| pair | points | images' shift from GT, median (px) | the same with a free vertical shift | "
          "gtvo: median signed error at these points (px) | gtvo: median of (error - images' shift) (px) |")
    print("|---|---|---|---|---|---|")
    root = data / "stereo_disparity_gt" / "middlebury2014_quarter"
    for name, left, right, gt, cam in pairs(data):
        kp = init_keyframe_points(left, right, cam, target=TARGET)
        px = kp.pixels.astype(np.intp)
        mask = cv2.imread(str(root / name / "mask0nocc.png"), cv2.IMREAD_GRAYSCALE)
        ui = np.clip(px[:, :1] + _PATCH[:, 0].astype(np.intp), 0, gt.shape[1] - 1)
        vi = np.clip(px[:, 1:] + _PATCH[:, 1].astype(np.intp), 0, gt.shape[0] - 1)
        g = gt[vi, ui]
        smooth = (mask[vi, ui] == 255).all(1) & np.isfinite(g).all(1)
        smooth &= np.where(smooth, np.ptp(np.where(np.isfinite(g), g, 0.0), axis=1), np.inf) < 1.0
        lf, rf = to_float_gray(left), to_float_gray(right)
        s1 = ground_truth_shift(lf, rf, gt, px[smooth])
        s2 = ground_truth_shift(lf, rf, gt, px[smooth], vertical=True)
        err = kp.inverse_depth[smooth] * cam.left.fx * cam.baseline - gt[px[smooth, 1], px[smooth, 0]]
        both = np.isfinite(s1) & np.isfinite(s2)
        print(f"| {name} | {int(both.sum())} | {np.median(s1[both]):+.3f} | {np.median(s2[both]):+.3f} | "
              f"{np.median(err[both]):+.3f} | {np.median(err[both] - s1[both]):+.3f} |")


def cpu(data: Path, rounds: int) -> None:
    from gtvo.frontend import init_keyframe_points
    from gtvo.core.camera import PinholeCamera, StereoCamera

    work = [(left, right, cam) for _, left, right, _, cam in pairs(data)]
    kitti = data / "kitti_stereo_sample" / "KITTI_sequence_1"
    P = np.loadtxt(kitti / "calib.txt").reshape(2, 3, 4)
    kl = cv2.imread(str(sorted((kitti / "image_l").glob("*.png"))[0]), cv2.IMREAD_GRAYSCALE)
    kr = cv2.imread(str(sorted((kitti / "image_r").glob("*.png"))[0]), cv2.IMREAD_GRAYSCALE)
    kcam = StereoCamera(PinholeCamera.from_matrix(P[0][:, :3], kl.shape[1], kl.shape[0]),
                        float(-P[1][0, 3] / P[1][0, 0]))
    work.append((kl, kr, kcam))
    for left, right, cam in work:  # compile and warm up
        init_keyframe_points(left, right, cam, target=TARGET)
    t0 = time.process_time()
    for _ in range(rounds):
        for left, right, cam in work:
            init_keyframe_points(left, right, cam, target=TARGET)
    t = time.process_time() - t0
    print(f"init_keyframe_points CPU: {t:.3f} s for {rounds} rounds of {len(work)} pairs "
          f"({len(work) - 1} Middlebury + 1 KITTI), gtvo from {sys.path[0]}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--cpu", type=int, default=0, help="rounds of the CPU measurement (0: the table)")
    ap.add_argument("--gt-check", action="store_true", help="the images' shift from the ground truth per pair")
    ap.add_argument("--gtvo", type=Path, default=ROOT, help="checkout whose gtvo is measured")
    args = ap.parse_args()
    sys.path.insert(0, str(args.gtvo.resolve()))
    if args.cpu > 0:
        cpu(args.data, args.cpu)
    elif args.gt_check:
        gt_check(args.data)
    else:
        table(args.data)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
