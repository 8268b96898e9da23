"""Front-end speed per KITTI keyframe: point selection and stereo inverse depth.

    python benchmarks/frontend_speed.py [--root CHECKOUT] [--sequence DIR] [--points 300,2000] [--repeats 3]
    python benchmarks/frontend_speed.py --stages [--root CHECKOUT] [--sequence DIR] [--repeats 3]

``--stages``: a whole default run (window mode, preloaded frames, after a warm-up on the first 10)
with the stage clock on this process's CPU time (``time.process_time``, all threads): CPU ms per
frame by stage, the front end's (tracking, point_selection, stereo_search, keyframe_setup, other)
summed, the median over ``--repeats`` runs. Run it for two checkouts alternately (``--root``) and
compare the ratios: a loaded machine inflates both alike.

For every frame of the sequence (preloaded), times ``select_points`` and ``init_keyframe_points``
(selection + stereo search + refinement + checks, what ``VisualOdometry`` runs for each new
keyframe) for each point target; prints the mean ms per frame (best of ``--repeats`` passes) and
its ratio to a reference measured in the same run (one OpenCV StereoSGBM of frame 0, the peers'
settings; median of 5, before and after). A checksum of the selected pixels and inverse depths
tells whether two checkouts compute the same points.

``--root`` imports gtvo from another checkout (e.g. ``git worktree add /tmp/gtvo-old <commit>``),
so an older commit is measured by this same script: run it for both, alternately, to compare
under the same machine load. The script therefore uses nothing but gtvo's public API
(``open_sequence``, ``select_points``, ``init_keyframe_points``) and OpenCV; its SGBM reference has
the settings of ``benchmarks/peers.make_sgbm`` (which it cannot import: that would load this
checkout's gtvo).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    here = Path(__file__).resolve().parents[1]
    ap.add_argument("--root", type=Path, default=here, help="gtvo checkout to measure (default: this one)")
    ap.add_argument("--sequence", type=Path, default=None, help="KITTI folder (default KITTI_sequence_1)")
    ap.add_argument("--points", default="300,2000", help="point targets per keyframe")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--stages", action="store_true", help="CPU ms per frame by stage of a whole default run")
    args = ap.parse_args()
    sys.path.insert(0, str(args.root.resolve()))  # the gtvo measured
    if args.stages:
        return stage_cpu(args.root, args.sequence or here.parent / "shared" / "data" / "kitti_stereo_sample" /
                         "KITTI_sequence_1", args.repeats)
    import cv2  # noqa: PLC0415
    import numpy as np  # noqa: PLC0415

    import gtvo  # noqa: PLC0415
    from gtvo.datasets import open_sequence  # noqa: PLC0415
    from gtvo.frontend import select_points  # noqa: PLC0415
    from gtvo.frontend.stereo_depth import init_keyframe_points  # noqa: PLC0415

    shared = Path(os.environ.get("GTVO_SHARED_DATA") or here.parent / "shared" / "data")
    seq = open_sequence(args.sequence or shared / "kitti_stereo_sample" / "KITTI_sequence_1")
    frames = [seq.frame(i) for i in range(len(seq))]
    lefts = [np.asarray(f.left, dtype=np.float32) for f in frames]
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=128, blockSize=5, P1=8 * 25, P2=32 * 25,
                                 mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    pair = [np.clip(np.rint(np.asarray(x, dtype=np.float32)), 0, 255).astype(np.uint8)
            for x in (frames[0].left, frames[0].right)]

    def reference_ms() -> float:
        ts = []
        for _ in range(5):
            t0 = time.perf_counter()
            sgbm.compute(*pair)
            ts.append(time.perf_counter() - t0)
        return 1000.0 * float(np.median(ts))

    init_keyframe_points(frames[0].left, frames[0].right, seq.camera, target=100)  # compile / warm up
    ref_before = reference_ms()
    rows = []
    for target in (int(t) for t in args.points.split(",")):
        best_sel = best_init = float("inf")
        digest = hashlib.sha1()
        for rep in range(args.repeats):
            t0 = time.perf_counter()
            for img in lefts:
                select_points(img, target=target)
            best_sel = min(best_sel, (time.perf_counter() - t0) / len(frames))
            t0 = time.perf_counter()
            kps = [init_keyframe_points(f.left, f.right, seq.camera, target=target) for f in frames]
            best_init = min(best_init, (time.perf_counter() - t0) / len(frames))
            if rep == 0:
                for kp in kps:
                    digest.update(np.ascontiguousarray(kp.pixels).tobytes())
                    digest.update(np.ascontiguousarray(kp.inverse_depth).tobytes())
        n_pts = int(np.mean([len(kp.pixels) for kp in kps]))
        rows.append((target, n_pts, 1e3 * best_sel, 1e3 * best_init, digest.hexdigest()[:12]))
    ref_after = reference_ms()
    ref = 0.5 * (ref_before + ref_after)
    print(f"gtvo at {Path(gtvo.__file__).resolve().parents[1]}, {seq.name}, {len(frames)} frames")
    print(f"Reference: one StereoSGBM of frame 0 = {ref:.0f} ms (before / after: {ref_before:.0f} / {ref_after:.0f} ms)\n")
    print("| points asked | with depth | select_points ms (x ref) | init_keyframe_points ms (x ref) | checksum |")
    print("|---|---|---|---|---|")
    for target, n_pts, sel, init, digest in rows:
        print(f"| {target} | {n_pts} | {sel:.1f} ({sel / ref:.2f}) | {init:.1f} ({init / ref:.2f}) | {digest} |")
    return 0


FRONT_END_STAGES = ("tracking", "point_selection", "stereo_search", "keyframe_setup", "other")


def stage_cpu(root: Path, sequence: Path, repeats: int) -> int:
    """``--stages``: CPU ms per frame by stage of whole default runs (median over ``repeats``)."""
    import statistics  # noqa: PLC0415

    import gtvo  # noqa: PLC0415
    from gtvo.config import OdometryConfig  # noqa: PLC0415
    from gtvo.core.timing import StageClock  # noqa: PLC0415
    from gtvo.datasets import open_sequence  # noqa: PLC0415
    from gtvo.odometry import VisualOdometry  # noqa: PLC0415

    seq = open_sequence(sequence)
    frames = list(seq)

    def run(part: list) -> dict[str, float]:
        vo = VisualOdometry(seq.camera, OdometryConfig())
        vo.clock = StageClock(timer=time.process_time)
        t0 = time.process_time()
        for f in part:
            vo.process(f)
        vo.finish()
        total = time.process_time() - t0
        vo.close()
        out = {k: 1000.0 * v / len(part) for k, v in vo.clock.snapshot().items()}
        out["front end"] = sum(out[k] for k in FRONT_END_STAGES)
        out["frame"] = 1000.0 * total / len(part)
        return out

    run(frames[:10])  # compiled kernels loaded
    runs = [run(frames) for _ in range(max(1, repeats))]
    print(f"gtvo at {Path(gtvo.__file__).resolve().parents[1]}, {seq.name}, {len(frames)} frames, "
          f"CPU ms per frame (median of {len(runs)})")
    for name in runs[0]:
        if any(r[name] for r in runs):
            print(f"{name:16s} {statistics.median(r[name] for r in runs):8.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
