"""Drawing an occupancy grid and a planned path (PNG, matplotlib Agg, written atomically)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gtvo.core.atomic import write_with
from gtvo.planning.occupancy import OccupancyGrid, PlanResult


def plot_plan(grid: OccupancyGrid, result: PlanResult, start_xz: tuple[float, float],
              goal_xz: tuple[float, float], path: str | Path) -> Path:
    """Top view (X right, Z up) of obstacles (black), the robot-radius inflation (grey), the path
    (red), start (green) and goal (blue); saved as PNG at ``path`` atomically."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    image = np.ones(grid.shape + (3,))
    image[grid.occupied] = 0.75
    image[grid.obstacles] = 0.0
    fig, ax = plt.subplots(figsize=(7, 7))
    try:
        ax.imshow(image, origin="lower", extent=grid.extent, interpolation="nearest")
        if result.found:
            ax.plot(result.path_xz[:, 0], result.path_xz[:, 1], "-", color="red", lw=1.5,
                    label=f"path {result.length_m:.2f} m")
        ax.plot(*start_xz, "o", color="green", label="start")
        ax.plot(*goal_xz, "*", color="blue", ms=12, label="goal")
        ax.set_xlabel("X (m)")
        ax.set_ylabel("Z (m)")
        ax.set_title(f"A* on the occupancy grid ({grid.resolution:g} m cells, robot radius {grid.robot_radius:g} m)"
                     + ("" if result.found else ": no path"), fontsize=9)
        ax.legend(loc="best", fontsize=8)
        ax.set_aspect("equal")
        return write_with(path, lambda tmp: fig.savefig(tmp, format="png", dpi=120))
    finally:
        plt.close(fig)
