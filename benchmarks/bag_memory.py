"""Memory of reading a ROS bag: does the peak resident memory grow with the bag's length?

    python benchmarks/bag_memory.py [--sizes 0.25,1] [--format ros1|ros2|mcap] [--dir DIR] [--keep]

For each size (GB) a stereo bag is generated with ``rosbags``' writer (uncompressed, 752x480
mono8 ``sensor_msgs/Image`` pairs of shifted noise texture on ``/cam/{left,right}/image_rect``,
their CameraInfo, a PoseStamped ground truth per frame) until the file reaches the size. Then a
fresh Python process opens it with ``gtvo.open_sequence`` (one pass over the image headers) with
the ground-truth topic and loads every frame (``seq.frame(i)``: both images decoded), as a run
does, and reports its peak resident memory (``getrusage`` ``ru_maxrss``) and its memory after
the imports. The last line is the ratio of the peak of the largest bag to that of the smallest:
1.0 when memory is flat in the bag's length. The bags are deleted unless ``--keep``.
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

WIDTH, HEIGHT = 752, 480
K = np.array([[450.0, 0.0, 375.5], [0.0, 450.0, 239.5], [0.0, 0.0, 1.0]])
BASELINE_M = 0.11


def write_bag(path: Path, target_bytes: int, mcap: bool = False) -> int:
    """Write a stereo bag of about ``target_bytes``; returns its frame count."""
    from tests._bags import BagWriter  # noqa: PLC0415

    rng = np.random.default_rng(0)
    texture = rng.integers(0, 256, size=(HEIGHT, WIDTH + 408), dtype=np.uint8)
    per_frame = 2 * WIDTH * HEIGHT + 600
    frames = max(1, int(np.ceil(target_bytes / per_frame)))
    P_right = np.hstack([K, [[-K[0, 0] * BASELINE_M], [0.0], [0.0]]])
    with BagWriter(path, mcap=mcap) as bag:
        for i in range(frames):
            ns = 1_000_000_000 + i * 50_000_000
            if i == 0:
                bag.camera_info("/cam/left/camera_info", ns, WIDTH, HEIGHT, K, np.hstack([K, np.zeros((3, 1))]))
                bag.camera_info("/cam/right/camera_info", ns, WIDTH, HEIGHT, K, P_right)
            shift = i % 400
            bag.image("/cam/left/image_rect", ns, texture[:, shift:shift + WIDTH], "mono8")
            bag.image("/cam/right/image_rect", ns, texture[:, shift + 8:shift + 8 + WIDTH], "mono8")
            pose = np.eye(4)
            pose[2, 3] = 0.05 * i
            bag.pose("/ground_truth", ns, pose)
    return frames


def measure(path: Path) -> dict:
    """Open the bag and load every frame in this process; peak and after-import RSS (MiB)."""
    from gtvo.datasets import open_sequence  # noqa: PLC0415

    baseline = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t0 = time.perf_counter()
    seq = open_sequence(path, ground_truth_topic="/ground_truth")
    t_open = time.perf_counter() - t0
    checksum = 0.0
    for i in range(len(seq)):
        frame = seq.frame(i)
        checksum += float(frame.left[0, 0]) + float(frame.right[-1, -1])
    return {"frames": len(seq), "baseline_mib": baseline, "open_s": t_open,
            "read_s": time.perf_counter() - t0 - t_open, "has_gt": seq.has_ground_truth,
            "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def _remove(path: Path) -> None:
    if path.is_dir():
        shutil.rmtree(path)
    else:
        path.unlink()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="0.25,1", help="bag sizes in GB (comma separated)")
    ap.add_argument("--format", choices=("ros1", "ros2", "mcap"), default="ros1",
                    help="ROS1 .bag, ROS2 sqlite3 (.db3) or ROS2 MCAP")
    ap.add_argument("--dir", type=Path, default=None, help="where to write the bags (default: a temporary folder)")
    ap.add_argument("--keep", action="store_true", help="keep the generated bags")
    ap.add_argument("--measure", type=Path, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.measure is not None:
        print(json.dumps(measure(args.measure)))
        return 0
    folder = Path(tempfile.mkdtemp(prefix="gtvo_bag_memory_", dir=args.dir))
    rows = []
    try:
        for gb in (float(s) for s in args.sizes.split(",")):
            path = folder / (f"stereo_{gb:g}GB.bag" if args.format == "ros1" else f"stereo_{gb:g}GB")
            t0 = time.perf_counter()
            write_bag(path, int(gb * 1e9), mcap=args.format == "mcap")
            size = sum(p.stat().st_size for p in ([path] if path.is_file() else path.iterdir()))
            written = time.perf_counter() - t0
            out = subprocess.run([sys.executable, __file__, "--measure", str(path)], check=True,
                                 capture_output=True, text=True).stdout
            row = {"bag_gb": size / 1e9, "write_s": written, **json.loads(out.strip().splitlines()[-1])}
            rows.append(row)
            print(f"{path.name}: {row['bag_gb']:.3f} GB, {row['frames']} stereo frames, peak RSS "
                  f"{row['peak_mib']:.0f} MiB (after imports {row['baseline_mib']:.0f} MiB), "
                  f"open {row['open_s']:.1f} s, read {row['read_s']:.1f} s, ground truth {row['has_gt']}", flush=True)
            if not args.keep:
                _remove(path)
    finally:
        if not args.keep:
            shutil.rmtree(folder, ignore_errors=True)
    if len(rows) > 1:
        first, last = rows[0], rows[-1]
        print(f"bag {last['bag_gb'] / first['bag_gb']:.2f}x longer: peak RSS ratio "
              f"{last['peak_mib'] / first['peak_mib']:.3f} ({last['peak_mib'] - first['peak_mib']:+.0f} MiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
