"""Plot of the trajectories integrated from raw, calibrated and reference motions (PNG)."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np
from numpy.typing import ArrayLike

from gtvo.core.atomic import write_with
from gtvo.wheel_calibration.motions import integrate_motions


def plot_trajectories(path: str | Path, motions: Mapping[str, ArrayLike], title: str = "Odometry calibration") -> Path:
    """Integrate each named motion array from the origin and plot the x-y paths into a PNG (atomic write)."""
    import matplotlib  # noqa: PLC0415
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, ax = plt.subplots(figsize=(7, 7))
    for name, u in motions.items():
        poses = integrate_motions(np.asarray(u))
        ax.plot(poses[:, 0], poses[:, 1], label=name, linewidth=1.2)
    ax.plot([0.0], [0.0], "ko", label="start")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.axis("equal")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    try:
        return write_with(path, lambda tmp: fig.savefig(tmp, dpi=120, format="png"))
    finally:
        plt.close(fig)
