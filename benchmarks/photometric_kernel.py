"""The photometric kernel: compiled path against the numpy form, on real KITTI images.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/photometric_kernel.py [KITTI_DIR] [--json OUT]

Host = frame 0 of the KITTI snippet with N high-gradient points and StereoSGBM inverse depths
(``benchmarks/_kitti_sgbm.py``); targets = frames 1..T at their ground-truth poses.
``photometric_residuals`` runs

* ``compiled``: a :class:`GradientImage` target (``factors/_compiled.py``, the default path);
* ``numpy``: the same image behind a plain sampler object, which takes the numpy form (the
  reference the tests compare the compiled path with);

with full Jacobians (the window's linearisation), without host Jacobians (the tracker's) and
residuals only (cost evaluations), each in two access patterns: ``warm`` (the same target again
and again, its image in cache) and ``cycled`` (the next target each call, as the window visits
host-target pairs: 10 full-resolution images are more than the cache holds). Best of 5 repeats
of 20 calls per setting, both paths interleaved in one run; the ratio is the figure to read (the
machine is shared). It also prints the largest difference between the two paths' outputs.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks._kitti_sgbm import load_kitti, read_gray, sgbm_keyframe_points  # noqa: E402
from factors.photometric import GradientImage, pattern_bearings, photometric_residuals, sample_host  # noqa: E402
from gtvo.core.atomic import write_json  # noqa: E402

DEFAULT = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti_stereo_sample" / "KITTI_sequence_1"
MODES = {"full Jacobians": dict(jacobians=True, host_jacobians=True),
         "no host Jacobians": dict(jacobians=True, host_jacobians=False),
         "residuals only": dict(jacobians=False)}


class NumpySampler:
    """A GradientImage behind the plain sampler protocol: photometric_residuals' numpy path."""

    def __init__(self, image: GradientImage) -> None:
        self.image, self.width, self.height = image, image.width, image.height

    def sample(self, u, v):
        return self.image.sample(u, v)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sequence", nargs="?", type=Path, default=DEFAULT)
    ap.add_argument("--points", type=int, nargs="+", default=[300, 1000, 2000])
    ap.add_argument("--targets", type=int, default=10)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    stereo, left, right, poses = load_kitti(args.sequence)
    cam = stereo.left
    host_img = read_gray(left[0])
    host = GradientImage(host_img)
    targets = [GradientImage(read_gray(p)) for p in left[1:1 + args.targets]]
    wrapped = [NumpySampler(t) for t in targets]
    rows = []
    print(f"KITTI {args.sequence.name}: host frame 0, {len(targets)} targets, {cam.width}x{cam.height}")
    print(f"{'points':>6} {'mode':<18} {'access':<7} {'numpy us':>9} {'compiled us':>11} {'ns/residual':>11} "
          f"{'speed-up':>8} {'max diff':>9}")
    for n in args.points:
        px, d, _ = sgbm_keyframe_points(host_img, read_gray(right[0]), stereo, n)
        Ih, hv = sample_host(host, px)
        bearings = pattern_bearings(cam, px)
        n_res = Ih.size
        for mode, kw in MODES.items():
            def call(t: int, imgs) -> object:
                return photometric_residuals(cam, Ih, hv, px, d, poses[0], poses[1 + t], imgs[t], (0.0, 0.0),
                                             (0.0, 0.0), bearings=bearings, **kw)
            a, b = call(0, targets), call(0, wrapped)
            diff = max(float(np.nanmax(np.abs(np.asarray(getattr(a, f), float) - np.asarray(getattr(b, f), float))))
                       for f in ("residual", "J_depth", "J_target", "J_host") if getattr(a, f) is not None)
            for access in ("warm", "cycled"):
                best = {"numpy": np.inf, "compiled": np.inf}
                for _ in range(5):
                    for name, imgs in (("numpy", wrapped), ("compiled", targets)):
                        t0 = time.perf_counter()
                        for k in range(20):
                            call(0 if access == "warm" else k % len(imgs), imgs)
                        best[name] = min(best[name], (time.perf_counter() - t0) / 20)
                ratio = best["numpy"] / best["compiled"]
                rows.append(dict(points=int(px.shape[0]), residuals=n_res, mode=mode, access=access,
                                 numpy_us=best["numpy"] * 1e6, compiled_us=best["compiled"] * 1e6,
                                 compiled_ns_per_residual=best["compiled"] / n_res * 1e9, speedup=ratio,
                                 max_abs_difference=diff))
                print(f"{px.shape[0]:>6} {mode:<18} {access:<7} {best['numpy'] * 1e6:>9.0f} "
                      f"{best['compiled'] * 1e6:>11.0f} {best['compiled'] / n_res * 1e9:>11.1f} {ratio:>7.2f}x "
                      f"{diff:>9.1e}")
    if args.json:
        write_json(args.json, {"sequence": str(args.sequence), "rows": rows})


if __name__ == "__main__":
    main()
