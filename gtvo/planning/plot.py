"""Drawing an occupancy grid and a planned path (PNG, matplotlib Agg, written atomically).

The picture is framed on what was planned, not on the whole map: a VO map holds points tens or
hundreds of metres away (KITTI_sequence_1's reach 400 m along Z) around a path of 25 m, which the
whole map's frame would shrink to a stub. :func:`plan_view` picks the frame: the path, start,
goal and the camera's trajectory (when given) with a margin, within the grid.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from gtvo.core.atomic import write_with
from gtvo.planning.occupancy import OccupancyGrid, PlanResult

#: Margin around the framed content: this fraction of its larger side, at least :data:`MIN_MARGIN_M`.
MARGIN_FRACTION = 0.15
MIN_MARGIN_M = 3.0


def plan_view(grid: OccupancyGrid, result: PlanResult, start_xz: tuple[float, float], goal_xz: tuple[float, float],
              trajectory_xz: ArrayLike | None = None) -> tuple[float, float, float, float]:
    """``(x_min, x_max, z_min, z_max)`` (m) the picture shows: the bounding box of the path (when
    found), start, goal and the trajectory's ``(K, 2)`` world ``(X, Z)``, its shorter side grown
    to half the longer one, then by the margin (:data:`MARGIN_FRACTION`, :data:`MIN_MARGIN_M`),
    and cut to the grid's extent."""
    parts = [np.asarray([start_xz, goal_xz], dtype=np.float64)]
    if result.found:
        parts.append(np.asarray(result.path_xz, dtype=np.float64).reshape(-1, 2))
    if trajectory_xz is not None:
        parts.append(np.asarray(trajectory_xz, dtype=np.float64).reshape(-1, 2))
    xz = np.vstack(parts)
    xz = xz[np.all(np.isfinite(xz), axis=1)]
    low, high = xz.min(axis=0), xz.max(axis=0)
    margin = max(MARGIN_FRACTION * float(np.max(high - low)), MIN_MARGIN_M)
    span = high - low
    grow = np.maximum(0.5 * np.max(span) - span, 0.0) / 2  # no side under half the other: context, not a sliver
    low, high = low - grow, high + grow
    x0, x1, z0, z1 = grid.extent
    return (max(x0, low[0] - margin), min(x1, high[0] + margin), max(z0, low[1] - margin), min(z1, high[1] + margin))


def draw_plan(ax: Any, grid: OccupancyGrid, result: PlanResult, start_xz: tuple[float, float],
              goal_xz: tuple[float, float], trajectory_xz: ArrayLike | None = None) -> None:
    """Draw the top view on matplotlib axes ``ax``: obstacles (black), the robot-radius inflation
    (grey), the camera's trajectory (orange, when given), the path (red), start (green) and goal
    (blue), framed by :func:`plan_view`."""
    image = np.ones(grid.shape + (3,))
    image[grid.occupied] = 0.75
    image[grid.obstacles] = 0.0
    ax.imshow(image, origin="lower", extent=grid.extent, interpolation="nearest")
    if trajectory_xz is not None:
        traj = np.asarray(trajectory_xz, dtype=np.float64).reshape(-1, 2)
        ax.plot(traj[:, 0], traj[:, 1], "-", color="tab:orange", lw=1.0, label=f"camera trajectory ({len(traj)} poses)")
    if result.found:
        ax.plot(result.path_xz[:, 0], result.path_xz[:, 1], "-", color="red", lw=1.5,
                label=f"path {result.length_m:.2f} m")
    ax.plot(*start_xz, "o", color="green", label="start")
    ax.plot(*goal_xz, "*", color="blue", ms=12, label="goal")
    x0, x1, z0, z1 = plan_view(grid, result, start_xz, goal_xz, trajectory_xz)
    ax.set_xlim(x0, x1)
    ax.set_ylim(z0, z1)
    ax.set_xlabel("X (m)")
    ax.set_ylabel("Z (m)")
    ax.set_title(f"A* on the occupancy grid ({grid.resolution:g} m cells, robot radius {grid.robot_radius:g} m)"
                 + ("" if result.found else ": no path"), fontsize=9)
    ax.legend(loc="best", fontsize=8)
    ax.set_aspect("equal")


def plot_plan(grid: OccupancyGrid, result: PlanResult, start_xz: tuple[float, float],
              goal_xz: tuple[float, float], path: str | Path, trajectory_xz: ArrayLike | None = None) -> Path:
    """:func:`draw_plan` saved as PNG at ``path`` atomically."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, ax = plt.subplots(figsize=(7, 7))
    try:
        draw_plan(ax, grid, result, start_xz, goal_xz, trajectory_xz)
        return write_with(path, lambda tmp: fig.savefig(tmp, format="png", dpi=120))
    finally:
        plt.close(fig)
