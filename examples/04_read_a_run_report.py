"""
Reading what a run wrote: report.json (what ran, how it went, how accurate it was) and
covariances.npz (every keyframe's 6x6 pose covariance), with nothing but json and numpy, as any
other program would. The run itself is gtvo.run on 20 frames of gtvo's synthetic stereo sequence
(exact ground truth), written into a temporary folder: the same job and outputs as `gtvo run`.
Keys of the report: docs/evaluation.md; the covariances: docs/window.md, "Pose covariances".
Run from the checkout's root: python examples/04_read_a_run_report.py
"""

import json
import tempfile
from pathlib import Path

import numpy as np

import gtvo
from gtvo.datasets.synthetic import make_synthetic_sequence


def main():
    """Main runner."""
    with tempfile.TemporaryDirectory() as scratch:
        # 1. Run: the whole `gtvo run` job (odometry, evaluation against the ground truth, outputs)
        out = Path(scratch) / "run"
        gtvo.run(make_synthetic_sequence(n_frames=20), out=out)
        print("the run wrote:", ", ".join(sorted(p.name for p in out.iterdir() if not p.name.startswith("."))))

        # 2. report.json: what ran and how it went
        report = json.loads((out / "report.json").read_text())
        print(f"{report['sequence']}: {report['frames']} frames, {report['keyframes']} keyframes, "
              f"mode {report['mode']} (tracker {report['tracker_solver']}, window {report['window_solver']}), "
              f"{report['frames_per_second']:.1f} frames/s")
        outcomes = report["frame_outcomes"]
        print(f"outcomes: {outcomes['tracked']} tracked, {outcomes['keyframe']} keyframes, "
              f"{len(outcomes['lost'])} lost, {len(outcomes['suspect'])} suspect")

        # 3. report.json: accuracy against the ground truth (present when the input has one)
        print(f"ATE {report['ate_rmse_m'] * 100:.2f} cm, RPE {report['rpe_trans_rmse_m'] * 100:.2f} cm, "
              f"drift {report['drift_percent']:.2f} % over {report['path_length_m']:.2f} m")

        # 4. covariances.npz: one 6x6 covariance per keyframe, rotation (rad) first, then translation (m)
        with np.load(out / "covariances.npz") as npz:
            frame_index, covariance = npz["frame_index"], npz["covariance"]
            print(f"{len(frame_index)} keyframe covariances, {npz['source']}; order {npz['tangent_order']}")
        for index, P in zip(frame_index, covariance):
            sigma = np.sqrt(np.diag(P))
            print(f"  keyframe {index:2d}: position sigma {np.linalg.norm(sigma[3:]) * 1000:.1f} mm, "
                  f"rotation sigma {np.degrees(np.linalg.norm(sigma[:3])):.3f} deg")

        # 5. The report summarises them over the keyframes but the first (the gauge, fixed by a prior)
        median_mm = np.median([np.sqrt(np.trace(P[3:, 3:])) for P in covariance[1:]]) * 1000
        print(f"median position sigma: {median_mm:.1f} mm "
              f"(report: {report['covariance_position_sigma_m_median'] * 1000:.1f} mm)")


if __name__ == "__main__":
    main()
