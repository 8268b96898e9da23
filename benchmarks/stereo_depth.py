"""Benchmark of the front end: point selection + stereo inverse depth.

Prints (markdown tables, for docs/benchmarks.md):

* time of ``select_points`` and ``stereo_inverse_depth`` for 2000 points per KITTI frame, as
  ratios to OpenCV StereoSGBM's full-frame time measured in the same run;
* agreement with StereoSGBM on the points both accept, over all 51 KITTI_sequence_1 frames;
* accuracy against Middlebury 2014 (quarter) ground-truth disparity at the selected points, for
  us and for SGBM, and how well ``V`` predicts our errors;
* (``exposure``) the same Middlebury accuracy when the right camera's exposure differs, as with
  two cameras on their own auto exposure: right image ``clip(g I, 0, 255)`` for gains ``g`` from
  0.5 to 2.5, with the gain equalisation (``equalize_gain``, default) and without it.

Usage: ``python benchmarks/stereo_depth.py [--data ../shared/data] [--frames N] [--parts kitti,middlebury,exposure]``
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gtvo.core.camera import PinholeCamera, StereoCamera  # noqa: E402
from gtvo.errors import InputError  # noqa: E402
from gtvo.frontend import StereoSearchConfig, select_points, stereo_inverse_depth  # noqa: E402
from gtvo.core.image import to_float_gray  # noqa: E402

TARGET = 2000


def sgbm(num_disparities: int) -> cv2.StereoSGBM:
    """The reference matcher (5x5 blocks, OpenCV's usual P1/P2, uniqueness 10, LR check 1 px)."""
    return cv2.StereoSGBM_create(minDisparity=0, numDisparities=num_disparities, blockSize=5, P1=8 * 25,
                                 P2=32 * 25, uniquenessRatio=10, disp12MaxDiff=1, speckleWindowSize=100,
                                 speckleRange=2)


def read_pfm(path: Path) -> np.ndarray:
    """A one-channel PFM image, flipped to top-to-bottom rows."""
    with open(path, "rb") as f:
        if f.readline().strip() != b"Pf":
            raise InputError("not a one-channel PFM file", path=path)
        w, h = (int(x) for x in f.readline().split())
        scale = float(f.readline())
        data = np.frombuffer(f.read(), dtype="<f4" if scale < 0 else ">f4")
    if data.size != w * h:
        raise InputError(f"PFM has {data.size} values, expected {w * h}", path=path)
    return np.flipud(data.reshape(h, w)).astype(np.float64)


def read_middlebury_calib(path: Path) -> dict[str, float]:
    text = path.read_text()
    out: dict[str, float] = {}
    m = re.search(r"cam0\s*=\s*\[\s*([-\d.eE+]+)\s+\S+\s+([-\d.eE+]+)\s*;\s*\S+\s+\S+\s+([-\d.eE+]+)", text)
    if m is None:
        raise InputError("no cam0 matrix", path=path)
    out["f"], out["cx"], out["cy"] = (float(g) for g in m.groups())
    for key in ("doffs", "baseline", "width", "height", "vmax"):
        mm = re.search(rf"{key}\s*=\s*([-\d.eE+]+)", text)
        if mm is None:
            raise InputError(f"no {key}", path=path)
        out[key] = float(mm.group(1))
    return out


def at(img: np.ndarray, px: np.ndarray) -> np.ndarray:
    return img[px[:, 1].astype(np.intp), px[:, 0].astype(np.intp)]


def kitti(data: Path, frames: int | None) -> None:
    root = data / "kitti_stereo_sample" / "KITTI_sequence_1"
    names = sorted((root / "image_l").glob("*.png"))[:frames]
    matcher = sgbm(128)
    t_sel, t_depth, t_sgbm = [], [], []
    diffs, n_pts, n_valid, n_both = [], 0, 0, 0
    counts: dict[str, int] = {}
    cam = None
    for p in names:
        left = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        right = cv2.imread(str(root / "image_r" / p.name), cv2.IMREAD_GRAYSCALE)
        if cam is None:
            h, w = left.shape
            cam = StereoCamera(PinholeCamera(707.0912, 707.0912, 601.8873, 183.1104, w, h), 0.53715)
        t0 = time.perf_counter()
        px = select_points(left, TARGET)
        t1 = time.perf_counter()
        res = stereo_inverse_depth(left, right, cam, px)
        t2 = time.perf_counter()
        ds = matcher.compute(left, right).astype(np.float32) / 16.0
        t3 = time.perf_counter()
        t_sel.append(t1 - t0)
        t_depth.append(t2 - t1)
        t_sgbm.append(t3 - t2)
        s = at(ds, px)
        both = res.valid & (s > 0)
        diffs.append(np.abs(res.disparity - s)[both])
        n_pts += len(px)
        n_valid += int(res.valid.sum())
        n_both += int(both.sum())
        for k, v in res.rejection_counts().items():
            counts[k] = counts.get(k, 0) + v
    d = np.concatenate(diffs)
    sg = np.median(t_sgbm)
    print(f"\n### KITTI_sequence_1, {len(names)} frames, {cam.left.width}x{cam.left.height}, target {TARGET}\n")
    print("| step | median time per frame (ms) | ratio to SGBM full frame |")
    print("|---|---|---|")
    print(f"| select_points | {1e3 * np.median(t_sel):.1f} | {np.median(t_sel) / sg:.2f} |")
    print(f"| stereo_inverse_depth ({n_pts // len(names)} pts) | {1e3 * np.median(t_depth):.1f} | "
          f"{np.median(t_depth) / sg:.2f} |")
    print(f"| OpenCV StereoSGBM (128 disparities, full frame) | {1e3 * sg:.1f} | 1.00 |")
    print("\n| points | accepted | both accept | median abs diff vs SGBM (px) | within 0.5 px | within 1 px | "
          "within 2 px |")
    print("|---|---|---|---|---|---|---|")
    print(f"| {n_pts} | {n_valid / n_pts:.3f} | {n_both} | {np.median(d):.3f} | {np.mean(d < 0.5):.3f} | "
          f"{np.mean(d < 1):.3f} | {np.mean(d < 2):.3f} |")
    print("\nrejections: " + ", ".join(f"{k} {v / n_pts:.3f}" for k, v in counts.items()))


def middlebury_scenes(data: Path):
    """(name, left, right, ground truth, non-occluded mask, camera, max disparity, doffs) per scene."""
    root = data / "stereo_disparity_gt" / "middlebury2014_quarter"
    for sc in sorted(p for p in root.iterdir() if (p / "calib.txt").is_file()):
        cal = read_middlebury_calib(sc / "calib.txt")
        left = to_float_gray(cv2.imread(str(sc / "im0.png"), cv2.IMREAD_COLOR))
        right = to_float_gray(cv2.imread(str(sc / "im1.png"), cv2.IMREAD_COLOR))
        gt = read_pfm(sc / "disp0GT.pfm")
        nocc = cv2.imread(str(sc / "mask0nocc.png"), cv2.IMREAD_GRAYSCALE) == 255
        h, w = left.shape
        cam = StereoCamera(PinholeCamera(cal["f"], cal["f"], cal["cx"], cal["cy"], w, h), cal["baseline"] / 1000.0)
        yield sc.name, left, right, gt, nocc, cam, int(np.ceil(cal["vmax"])) + 2, cal["doffs"]


def exposure(data: Path, gains: tuple[float, ...] = (0.5, 0.7, 1.0, 1.4, 2.0, 2.5)) -> None:
    scenes = list(middlebury_scenes(data))
    print(f"\n### Right camera exposed differently: Middlebury 2014 quarter, {len(scenes)} scenes, "
          f"target {TARGET}; errors against ground truth at the selected non-occluded points\n")
    print("| right gain | right pixels clipped | gain equalisation | accepted | median abs err (px) | bad-1.0 | "
          "bad-2.0 | accepted and within 1 px |")
    print("|---|---|---|---|---|---|---|---|")
    for gain in gains:
        for handling in ("on", "off"):
            errs, n_acc, n_good, n_ok, clipped = [], 0, 0, 0, []
            for _, left, right, gt, nocc, cam, max_disp, doffs in scenes:
                right_g = np.clip(gain * right, 0.0, 255.0)
                clipped.append(np.mean((right_g <= 0) | (right_g >= 255)))
                px = select_points(left, TARGET)
                search = StereoSearchConfig(max_disparity=max_disp, disparity_offset=doffs, sigma_line=0.5,
                                            equalize_gain=handling == "on")
                res = stereo_inverse_depth(left, right_g, cam, px, search)
                g = at(gt, px)
                good = at(nocc, px) & np.isfinite(g)
                ours = res.valid & good
                e = np.abs(res.disparity - g)[ours]
                errs.append(e)
                n_acc += int(ours.sum())
                n_good += int(good.sum())
                n_ok += int(np.sum(e <= 1.0))
            e = np.concatenate(errs)
            print(f"| {gain:.1f} | {np.mean(clipped):.3f} | {handling} | {n_acc / n_good:.2f} | {np.median(e):.3f} | "
                  f"{np.mean(e > 1):.3f} | {np.mean(e > 2):.3f} | {n_ok / n_good:.2f} |")


def middlebury(data: Path) -> None:
    scenes = list(middlebury_scenes(data))
    print(f"\n### Middlebury 2014 quarter, {len(scenes)} scenes, target {TARGET}; errors at the selected "
          "non-occluded points\n")
    print("| scene | ours: accepted | ours: median abs err (px) | ours: bad-1.0 | ours: bad-2.0 | "
          "SGBM at same points: valid | SGBM: median | SGBM: bad-1.0 | SGBM: bad-2.0 | ours within 2 sigma |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    all_ours, all_sg, all_z, acc = [], [], [], []
    for name, left, right, gt, nocc, cam, max_disp, doffs in scenes:
        px = select_points(left, TARGET)
        res = stereo_inverse_depth(left, right, cam, px, StereoSearchConfig(max_disparity=max_disp,
                                                                            disparity_offset=doffs, sigma_line=0.5))
        nd = int(np.ceil((max_disp + 1) / 16.0)) * 16
        l8 = np.clip(left, 0, 255).astype(np.uint8)
        r8 = np.clip(right, 0, 255).astype(np.uint8)
        ds = sgbm(nd).compute(l8, r8).astype(np.float32) / 16.0
        g = at(gt, px)
        good = at(nocc, px) & np.isfinite(g)
        ours = res.valid & good
        e = np.abs(res.disparity - g)[ours]
        s = at(ds, px)
        sv = good & (s > 0)
        es = np.abs(s - g)[sv]
        within2 = np.mean(e < 2 * res.disparity_std[ours])
        # inverse-depth error (1/m) against GT: d = (disp + doffs) / (f b)
        d_gt = (g[ours] + doffs) / (cam.left.fx * cam.baseline)
        all_z.append(np.abs(res.inverse_depth[ours] - d_gt) / d_gt)
        all_ours.append(e)
        all_sg.append(es)
        acc.append((ours.sum(), good.sum(), sv.sum(), within2))
        print(f"| {name} | {ours.sum() / max(good.sum(), 1):.2f} | {np.median(e):.3f} | {np.mean(e > 1):.3f} | "
              f"{np.mean(e > 2):.3f} | {sv.sum() / max(good.sum(), 1):.2f} | {np.median(es):.3f} | "
              f"{np.mean(es > 1):.3f} | {np.mean(es > 2):.3f} | {within2:.2f} |")
    e, es, z = np.concatenate(all_ours), np.concatenate(all_sg), np.concatenate(all_z)
    a = np.array(acc, dtype=float)
    print(f"| **all** | {a[:, 0].sum() / a[:, 1].sum():.2f} | {np.median(e):.3f} | {np.mean(e > 1):.3f} | "
          f"{np.mean(e > 2):.3f} | {a[:, 2].sum() / a[:, 1].sum():.2f} | {np.median(es):.3f} | "
          f"{np.mean(es > 1):.3f} | {np.mean(es > 2):.3f} | {np.average(a[:, 3], weights=a[:, 0]):.2f} |")
    print(f"\nours: median relative inverse-depth error {np.median(z):.4f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "data")
    ap.add_argument("--frames", type=int, default=None, help="KITTI frames to use (default all 51)")
    ap.add_argument("--parts", default="kitti,middlebury,exposure")
    args = ap.parse_args()
    parts = set(args.parts.split(","))
    if "kitti" in parts:
        kitti(args.data, args.frames)
    if "middlebury" in parts:
        middlebury(args.data)
    if "exposure" in parts:
        exposure(args.data)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
