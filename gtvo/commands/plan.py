"""``gtvo plan``: A* between two world points on the occupancy grid of a VO point cloud."""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import TYPE_CHECKING

from gtvo.core.paths import check_not_an_input
from gtvo.core.atomic import check_output_file
from gtvo.errors import InputError

if TYPE_CHECKING:
    import numpy as np


def parse_xz(text: str, name: str) -> tuple[float, float]:
    """Parse ``"X,Z"`` (metres) or raise :class:`InputError` naming the value."""
    parts = text.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        X, Z = float(parts[0]), float(parts[1])
    except ValueError:
        raise InputError(f"--{name} must be X,Z in metres (e.g. 1.5,-2), got {text!r}") from None
    if not (math.isfinite(X) and math.isfinite(Z)):
        raise InputError(f"--{name} must be finite, got {text!r}")
    return X, Z


def _parse_metres(text: str, name: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"--{name} must be a number in metres, got {text!r}") from None
    return value


def _parse_band(text: str) -> tuple[float, float]:
    parts = text.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        low, high = float(parts[0]), float(parts[1])
    except ValueError:
        raise InputError(f"--height-band must be LOW,HIGH in metres, got {text!r}") from None
    return low, high


#: The trajectories gtvo run writes beside its map (``points.ply``), the one the map is placed on first.
RUN_TRAJECTORIES = ("trajectory_loop_closed.tum", "trajectory.tum")


def _trajectory_xz(given: str | None, map_path: str) -> "np.ndarray | None":
    """World ``(X, Z)`` of the camera positions of ``given`` (a TUM file), or of the trajectory
    ``gtvo run`` wrote beside the map (:data:`RUN_TRAJECTORIES`); None when there is none."""
    from pathlib import Path  # noqa: PLC0415

    from gtvo.io.trajectory_files import read_tum  # noqa: PLC0415

    if given is not None:
        path = Path(given)
    else:
        found = [Path(map_path).parent / name for name in RUN_TRAJECTORIES if (Path(map_path).parent / name).is_file()]
        if not found:
            return None
        path = found[0]
    positions = read_tum(path).poses[:, :3, 3]
    return positions[:, [0, 2]]


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``plan`` subcommand."""
    p = subparsers.add_parser(
        "plan", help="plan a path between two points on the map's occupancy grid (A*)",
        description="Build a 2-D occupancy grid from a point cloud in the VO world frame (camera y down; "
                    "the ground plane is found by RANSAC), inflate obstacles by the robot radius and run A* "
                    "between two world (X, Z) points. Exit 0: path found; 1: no path; 2: bad input.")
    p.add_argument("--map", required=True, help="point cloud (.ply) in the VO world frame")
    p.add_argument("--start", required=True, help="start X,Z in metres (write --start=-1.5,2 when X is negative)")
    p.add_argument("--goal", required=True, help="goal X,Z in metres (write --goal=-1.5,2 when X is negative)")
    p.add_argument("--resolution", default="0.1", help="cell size in metres (default 0.1)")
    p.add_argument("--robot-radius", default="0.3", help="obstacle inflation radius in metres (default 0.3)")
    p.add_argument("--height-band", default="0.15,2.0",
                   help="LOW,HIGH: heights above the ground (m) whose points are obstacles (default 0.15,2.0)")
    p.add_argument("--out", help="write a PNG of the grid and the path here, framed on the path, start, goal and "
                                 "trajectory")
    p.add_argument("--trajectory", metavar="FILE.tum", default=None,
                   help="the camera's trajectory (TUM) to draw in the PNG; default: the trajectory_loop_closed.tum "
                        "or trajectory.tum that gtvo run wrote beside the map, when there is one")
    p.add_argument("--json", action="store_true", help="print the result as a JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run ``gtvo plan``; returns 0 when a path is found, 1 when there is none."""
    from gtvo.planning.occupancy import build_occupancy_grid, plan_path, read_point_cloud  # noqa: PLC0415

    start = parse_xz(args.start, "start")
    goal = parse_xz(args.goal, "goal")
    band = _parse_band(args.height_band)
    resolution = _parse_metres(args.resolution, "resolution")
    robot_radius = _parse_metres(args.robot_radius, "robot-radius")
    trajectory_xz = None
    if args.out:
        check_not_an_input(args.out, {"map (--map)": args.map, "trajectory (--trajectory)": args.trajectory}, "--out")
        check_output_file(args.out)
        trajectory_xz = _trajectory_xz(args.trajectory, args.map)
    points = read_point_cloud(args.map)
    grid = build_occupancy_grid(points, resolution=resolution, robot_radius=robot_radius, height_band=band)
    result = plan_path(grid, start, goal)
    if args.out:
        from gtvo.planning.plot import plot_plan  # noqa: PLC0415

        plot_plan(grid, result, start, goal, args.out, trajectory_xz=trajectory_xz)
    if args.json:
        obj = {
            "found": result.found,
            "path_length_m": result.length_m if result.found else None,
            "path": result.path_xz.tolist(),
            "start": list(start),
            "goal": list(goal),
            "resolution_m": grid.resolution,
            "robot_radius_m": grid.robot_radius,
            "grid_shape": list(grid.shape),
            "ground": {"normal": grid.ground.normal.tolist(), "offset_m": grid.ground.offset},
            "expanded": result.expanded,
        }
        print(json.dumps(obj, allow_nan=False))
    elif result.found:
        print(f"path {result.length_m:.3f} m, {len(result.path_xz)} cells")
    else:
        print("no path between start and goal", file=sys.stderr)
    return 0 if result.found else 1
