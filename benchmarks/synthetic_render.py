"""Speed and exactness figures of the synthetic sequence (gtvo.datasets.synthetic); prints a Markdown table.

Usage: python benchmarks/synthetic_render.py [--frames 30]

Speed is reported in seconds and as a ratio to a reference measured in the same run (bilinear
sampling of a 320x240 image at every pixel, ``gtvo.core.image.bilinear_sample``), since the machine is
shared. Exactness: |difference| statistics (gray levels) on interior pixels (``interior_mask``):
(a) re-render with the principal point moved by (0.5, 0.5) px vs bilinear sampling of the image,
(b) frame 0 warped onto frame j with exact depth and GT poses (unoccluded pixels),
(c) left vs right at u - fx b / z.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gtvo.core.camera import PinholeCamera  # noqa: E402
from gtvo.core.image import bilinear_sample  # noqa: E402
from gtvo.datasets.synthetic import _cached_scene, make_synthetic_sequence  # noqa: E402


def stats(d: np.ndarray) -> str:
    return f"{np.median(d):.3f} / {np.percentile(d, 90):.3f} / {np.percentile(d, 99):.3f}"


def exactness(seq, j: int) -> tuple[str, str, str]:
    cam = seq.pinhole
    v, u = np.mgrid[0:cam.height, 0:cam.width]
    u, v = u.ravel().astype(float), v.ravel().astype(float)
    interior = seq.interior_mask(0).ravel()
    shifted = PinholeCamera(cam.fx, cam.fy, cam.cx + 0.5, cam.cy + 0.5, cam.width, cam.height)
    ref = seq.scene.render(seq.gt_poses[0], shifted, seq._renderer.supersample).intensity.ravel()
    val, ok = bilinear_sample(seq.left(0), u - 0.5, v - 0.5, border=1)
    shift = np.abs(val - ref)[ok & interior]

    z = seq.true_depth(0).ravel()
    X = cam.backproject(np.stack([u, v], 1), z)
    T = np.linalg.inv(seq.gt_poses[j]) @ seq.gt_poses[0]
    Xj = X @ T[:3, :3].T + T[:3, 3]
    uvj, front = cam.project(Xj)
    Ij, okj = bilinear_sample(seq.left(j), uvj[:, 0], uvj[:, 1], border=1)
    zj, _ = bilinear_sample(seq.true_depth(j), uvj[:, 0], uvj[:, 1], border=1)
    inj, _ = bilinear_sample(seq.interior_mask(j).astype(np.float32), uvj[:, 0], uvj[:, 1])
    keep = front & okj & (np.abs(zj - Xj[:, 2]) < 0.01 * Xj[:, 2]) & interior & (inj == 1)
    warp = np.abs(seq.left(0).ravel() - Ij)[keep]

    ur = u - cam.fx * seq.camera.baseline / z
    Ir, okr = bilinear_sample(seq.right(0), ur, v, border=1)
    zr, _ = bilinear_sample(seq.true_depth(0, "right"), ur, v, border=1)
    keep = okr & (np.abs(zr - z) < 0.01 * z) & interior
    stereo = np.abs(seq.left(0).ravel() - Ir)[keep]
    return stats(shift), stats(warp), stats(stereo)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=30)
    args = parser.parse_args()
    img = np.random.default_rng(0).uniform(0, 255, (240, 320)).astype(np.float32)
    v, u = np.mgrid[0:240, 0:320]
    t = time.perf_counter()
    for _ in range(20):
        bilinear_sample(img, u + 0.3, v + 0.3)
    ref = (time.perf_counter() - t) / 20
    print(f"reference (bilinear_sample, 320x240): {ref * 1e3:.2f} ms\n")
    print("| supersample | scene build s (x ref) | render 30 frames = 60 images s (x ref) "
          "| shift (0.5,0.5) med/p90/p99 | warp 0->3 med/p90/p99 | stereo med/p90/p99 |")
    print("|---|---|---|---|---|---|")
    for ss in (1, 2):
        _cached_scene.cache_clear()
        t = time.perf_counter()
        seq = make_synthetic_sequence(args.frames, supersample=ss)
        build = time.perf_counter() - t
        t = time.perf_counter()
        for i in range(len(seq)):
            seq.left(i)
        render = time.perf_counter() - t
        shift, warp, stereo = exactness(seq, 3)
        print(f"| {ss} | {build:.2f} ({build / ref:.0f}) | {render:.2f} ({render / ref:.0f}) "
              f"| {shift} | {warp} | {stereo} |")


if __name__ == "__main__":
    main()
