"""A 2-D occupancy grid from the VO's point cloud, and planning on it.

The map is in the VO's world frame (the first left camera: x right, y **down**, z forward), so
the ground is a plane *below* the camera, at positive y, and it is found, not assumed:

1. voxel down-sampling (open3d ``voxel_down_sample``);
2. ground plane: repeated RANSAC (open3d ``segment_plane``); a plane is the ground when its normal
   is within ``max_ground_tilt_deg`` of the y axis and it lies below the world origin (the first
   camera); other planes (walls, which may hold more points) are removed and the search goes on.
   The normal is oriented up (towards -y), so ``height(p) = n . p + offset`` is the height above
   the ground and the first camera has ``height = offset > 0``;
3. obstacles: points with ``height_band[0] <= height <= height_band[1]`` (above the ground and
   its noise, below what a robot passes under);
4. the grid: cells of ``resolution`` metres over world (X, Z) (the ground plane's tilt against
   the world x-z plane is ignored in the cell coordinates); cell ``(row, col)`` has centre
   ``X = x_min + (col + 0.5) res``, ``Z = z_min + (row + 0.5) res``; a cell with an obstacle
   point is an obstacle; unobserved cells are free (the planner is optimistic about them);
5. inflation by the robot radius: every cell whose centre lies within ``robot_radius`` of an
   obstacle cell's centre is occupied (``scipy.ndimage.distance_transform_edt``), so the robot
   can be planned as a point.

Planning (:func:`plan_path`) runs :func:`gtvo.planning.astar.astar_banded` between the cells of
two world points and returns the path as world (X, Z) cell centres with its length in metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from gtvo.core.native_output import captured_native_stderr
from gtvo.core.optional import require_open3d
from gtvo.errors import InputError, not_a_file, show
from gtvo.planning.astar import astar_banded

FloatArray = NDArray[np.float64]

#: Largest grid :func:`build_occupancy_grid` will allocate (cells).
MAX_CELLS = 50_000_000


def read_point_cloud(path: str | Path) -> FloatArray:
    """Read the points (N, 3) of a point-cloud file (``.ply``, ``.pcd``...) with open3d.

    Non-finite points are dropped. Raises :class:`InputError` for a missing, unreadable or empty file.
    """
    path = Path(path)
    if not path.is_file():
        raise not_a_file(path, "point cloud")
    o3d = require_open3d()
    _check_ply_complete(path)
    try:
        # open3d reports a bad file by a warning on stdout and its PLY reader (RPly) by a line on
        # stderr, and returns what it read: both kept out of the console; an RPly error makes the
        # file corrupt, said in gtvo's one line
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error), \
                captured_native_stderr() as native:
            pcd = o3d.io.read_point_cloud(str(path), remove_nan_points=False, remove_infinite_points=False)
    except Exception as exc:  # open3d raises RuntimeError for unknown formats
        raise InputError(f"cannot read point cloud ({exc})", path=path) from None
    if any(line.startswith("RPly") for line in native.lines()):
        raise InputError(f"corrupt point cloud ({native.summary()})", path=path)
    points = np.asarray(pcd.points, dtype=np.float64)
    points = points[np.all(np.isfinite(points), axis=1)]
    if points.shape[0] == 0:
        raise InputError("point cloud has no (finite) points or is not a point-cloud file", path=path)
    return points


_PLY_SIZES = {b"char": 1, b"uchar": 1, b"int8": 1, b"uint8": 1, b"short": 2, b"ushort": 2, b"int16": 2,
              b"uint16": 2, b"int": 4, b"uint": 4, b"int32": 4, b"uint32": 4, b"float": 4, b"float32": 4,
              b"double": 8, b"float64": 8}


def _check_ply_complete(path: Path) -> None:
    """Raise :class:`InputError` when a PLY file is shorter than its header declares (a truncated
    copy or an interrupted write: open3d would read garbage there). The elements from the first
    one with a list property on (faces) have no known size and are left to open3d, as are files
    that are not PLY."""
    with open(path, "rb") as f:
        if f.readline().strip() != b"ply":
            return
        fmt, elements = None, []  # elements: [count, bytes per item or None (has a list), properties]
        for _ in range(1000):
            line = f.readline()
            if not line:
                raise InputError("truncated or corrupt point cloud: the PLY header has no end_header", path=path)
            parts = line.split()
            if not parts:
                continue
            if parts[0] == b"end_header":
                break
            try:
                if parts[0] == b"format":
                    fmt = parts[1]
                elif parts[0] == b"element":
                    elements.append([int(parts[2]), 0, 0])
                elif parts[0] == b"property" and elements:
                    size = None if parts[1] == b"list" else _PLY_SIZES.get(parts[1])
                    elements[-1][1] = None if size is None or elements[-1][1] is None else elements[-1][1] + size
                    elements[-1][2] += 1
            except (IndexError, ValueError):
                raise InputError(f"corrupt PLY header line {line.strip()[:40]!r}", path=path) from None
        else:
            return
        body = f.read()
    # the elements before the first one with a list property have a known size
    fixed = []
    for n, size, props in elements:
        if size is None:
            break
        fixed.append((n, size, props))
    if fmt == b"ascii":
        needed = sum(n * props for n, _, props in fixed)
        have = len(body.split())
        if have < needed:
            raise InputError(f"truncated point cloud: the header declares {needed} values, the file has {have}",
                             path=path)
    elif fmt in (b"binary_little_endian", b"binary_big_endian"):
        needed = sum(n * size for n, size, _ in fixed)
        if len(body) < needed:
            raise InputError(f"truncated point cloud: the header declares {needed} bytes of data, the file has "
                             f"{len(body)}", path=path)


@dataclass(frozen=True)
class GroundPlane:
    """The ground: ``height(p) = normal . p + offset`` (metres above it); ``normal`` points up (-y)."""

    normal: FloatArray
    offset: float

    def height(self, points: ArrayLike) -> FloatArray:
        """Height above the ground of (N, 3) points."""
        return np.asarray(points, dtype=np.float64) @ self.normal + self.offset


def fit_ground_plane(points: ArrayLike, distance_threshold: float = 0.05, max_ground_tilt_deg: float = 30.0,
                     max_planes: int = 6, seed: int = 0) -> GroundPlane:
    """Find the ground plane of a y-down point cloud by repeated RANSAC (see the module notes)."""
    o3d = require_open3d()
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 3:
        raise InputError(f"need at least 3 points (N, 3) to find the ground, got shape {pts.shape}")
    o3d.utility.random.seed(seed)
    cos_tilt = math.cos(math.radians(max_ground_tilt_deg))
    remaining = pts
    for _ in range(max_planes):
        if remaining.shape[0] < 3:
            break
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(remaining))
        model, inliers = pcd.segment_plane(distance_threshold, 3, 1000)
        model = np.asarray(model, dtype=np.float64).reshape(4)
        norm = np.linalg.norm(model[:3])
        if len(inliers) < 3 or not np.isfinite(norm) or norm == 0:
            break
        normal, offset = model[:3] / norm, model[3] / norm
        if normal[1] > 0:  # orient up: towards -y (y is down)
            normal, offset = -normal, -offset
        if -normal[1] >= cos_tilt and offset > 0:  # level enough, and the first camera is above it
            return GroundPlane(normal, float(offset))
        keep = np.ones(remaining.shape[0], dtype=bool)
        keep[np.asarray(inliers, dtype=np.int64)] = False
        remaining = remaining[keep]
    raise InputError(f"no ground plane found: no plane within {max_ground_tilt_deg} deg of level below the camera")


@dataclass(frozen=True)
class OccupancyGrid:
    """A 2-D grid over world (X, Z).

    Attributes:
        occupied: ``(rows, cols)`` bool, obstacles inflated by the robot radius (what A* sees).
        obstacles: ``(rows, cols)`` bool, cells holding an obstacle point (before inflation).
        resolution: cell size in metres.
        x_min, z_min: world X, Z of the grid's lower corner (cell (0, 0) spans
            ``[x_min, x_min + res) x [z_min, z_min + res)``).
        ground: the ground plane found.
        robot_radius: inflation radius in metres.
    """

    occupied: NDArray[np.bool_]
    obstacles: NDArray[np.bool_]
    resolution: float
    x_min: float
    z_min: float
    ground: GroundPlane
    robot_radius: float

    @property
    def shape(self) -> tuple[int, int]:
        """``(rows, cols)``: rows along Z, columns along X."""
        return self.occupied.shape  # type: ignore[return-value]

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(x_min, x_max, z_min, z_max)`` in metres."""
        rows, cols = self.shape
        return (self.x_min, self.x_min + cols * self.resolution, self.z_min, self.z_min + rows * self.resolution)

    def world_to_cell(self, X: ArrayLike, Z: ArrayLike) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """``(row, col)`` of world points (not bounds-checked; see :meth:`contains`)."""
        col = np.floor((np.asarray(X, dtype=np.float64) - self.x_min) / self.resolution).astype(np.int64)
        row = np.floor((np.asarray(Z, dtype=np.float64) - self.z_min) / self.resolution).astype(np.int64)
        return row, col

    def cell_to_world(self, row: ArrayLike, col: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """World ``(X, Z)`` of cell centres."""
        X = self.x_min + (np.asarray(col, dtype=np.float64) + 0.5) * self.resolution
        Z = self.z_min + (np.asarray(row, dtype=np.float64) + 0.5) * self.resolution
        return X, Z

    def contains(self, X: float, Z: float) -> bool:
        """Whether world ``(X, Z)`` falls in the grid."""
        row, col = self.world_to_cell(X, Z)
        return bool(0 <= row < self.shape[0] and 0 <= col < self.shape[1])


def build_occupancy_grid(points: ArrayLike, resolution: float = 0.1, robot_radius: float = 0.3,
                         height_band: tuple[float, float] = (0.15, 2.0), voxel_size: float | None = None,
                         ground_threshold: float = 0.05, margin: float = 1.0) -> OccupancyGrid:
    """Occupancy grid of a y-down point cloud (N, 3) in the VO world frame (see the module notes).

    Args:
        resolution: cell size (m).
        robot_radius: obstacle inflation radius (m), >= 0.
        height_band: ``(low, high)`` heights above the ground (m) whose points are obstacles.
        voxel_size: down-sampling voxel (m); default ``resolution / 2``.
        ground_threshold: RANSAC inlier distance for the ground plane (m).
        margin: free border around the points' extent (m).
    """
    for name, value, positive in (("resolution", resolution, True), ("robot_radius", robot_radius, False),
                                  ("ground_threshold", ground_threshold, True), ("margin", margin, False)):
        v = float(value)
        if not math.isfinite(v) or v < 0 or (positive and v == 0):
            raise InputError(f"{name} must be a finite {'positive' if positive else 'non-negative'} number, got {show(value)}")
    low, high = (float(v) for v in height_band)
    if not (math.isfinite(low) and math.isfinite(high) and low < high):
        raise InputError(f"height_band must be (low, high) with low < high, got {show(height_band)}")
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"points must be an (N, 3) array, got shape {pts.shape}")
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if pts.shape[0] < 3:
        raise InputError(f"need at least 3 finite points to build a map, got {pts.shape[0]}")
    o3d = require_open3d()
    voxel = float(voxel_size) if voxel_size is not None else 0.5 * resolution
    if not (math.isfinite(voxel) and voxel > 0):
        raise InputError(f"voxel_size must be a finite positive number, got {show(voxel_size)}")
    extent = pts.max(axis=0) - pts.min(axis=0) + 2 * margin
    cells = float(np.ceil(extent[0] / resolution) + 1) * float(np.ceil(extent[2] / resolution) + 1)
    if cells > MAX_CELLS or float(np.max(extent)) / voxel > 2.0 ** 30:  # (open3d's voxel index is int32)
        raise InputError(f"the map spans {extent[0]:.4g} x {extent[2]:.4g} m (X x Z): too large for a grid at "
                         f"{resolution} m (corrupt points, or use a coarser resolution)")
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)).voxel_down_sample(voxel)
    pts = np.asarray(pcd.points, dtype=np.float64)
    ground = fit_ground_plane(pts, distance_threshold=ground_threshold)
    height = ground.height(pts)
    obstacle_pts = pts[(height >= low) & (height <= high)]

    x_min = float(pts[:, 0].min()) - margin
    z_min = float(pts[:, 2].min()) - margin
    cols = int(math.ceil((float(pts[:, 0].max()) + margin - x_min) / resolution)) + 1
    rows = int(math.ceil((float(pts[:, 2].max()) + margin - z_min) / resolution)) + 1
    if rows * cols > MAX_CELLS:
        raise InputError(f"grid of {rows}x{cols} cells is too large: use a coarser resolution than {resolution} m")
    obstacles = np.zeros((rows, cols), dtype=bool)
    grid = OccupancyGrid(obstacles, obstacles, float(resolution), x_min, z_min, ground, float(robot_radius))
    r, c = grid.world_to_cell(obstacle_pts[:, 0], obstacle_pts[:, 2])
    obstacles[r, c] = True
    if obstacles.any():
        dist = ndimage.distance_transform_edt(~obstacles) * resolution  # to the nearest obstacle cell centre
        occupied = dist <= robot_radius + 1e-9
    else:
        occupied = obstacles.copy()
    return OccupancyGrid(occupied, obstacles, float(resolution), x_min, z_min, ground, float(robot_radius))


@dataclass(frozen=True)
class PlanResult:
    """A planned path on the grid.

    Attributes:
        found: whether a path exists.
        path_xz: ``(K, 2)`` world ``(X, Z)`` of the path's cell centres (empty if not found).
        cells: ``(K, 2)`` ``(row, col)`` cells.
        length_m: path length in metres (``inf`` if not found): the grid path's cost
            (straight steps ``res``, diagonal ``sqrt(2) res``).
        expanded: nodes A* closed.
    """

    found: bool
    path_xz: FloatArray
    cells: NDArray[np.int64]
    length_m: float
    expanded: int


def plan_path(grid: OccupancyGrid, start_xz: tuple[float, float], goal_xz: tuple[float, float]) -> PlanResult:
    """Shortest path between two world points on the inflated grid.

    Raises :class:`InputError` when start or goal is outside the map or inside an (inflated) obstacle.
    """
    cells = []
    for name, (X, Z) in (("start", start_xz), ("goal", goal_xz)):
        if not (math.isfinite(X) and math.isfinite(Z)):
            raise InputError(f"{name} ({X}, {Z}) is not finite")
        if not grid.contains(X, Z):
            x0, x1, z0, z1 = grid.extent
            raise InputError(f"{name} (X, Z) = ({X:g}, {Z:g}) is outside the map "
                             f"(X in [{x0:.2f}, {x1:.2f}], Z in [{z0:.2f}, {z1:.2f}])")
        row, col = grid.world_to_cell(X, Z)
        if grid.occupied[row, col]:
            raise InputError(f"{name} (X, Z) = ({X:g}, {Z:g}) is inside an obstacle or within the robot "
                             f"radius ({grid.robot_radius:g} m) of one")
        cells.append((int(row), int(col)))
    res = astar_banded(grid.occupied, cells[0], cells[1])
    if not res.found:
        return PlanResult(False, np.empty((0, 2)), np.empty((0, 2), dtype=np.int64), math.inf, res.expanded)
    X, Z = grid.cell_to_world(res.path[:, 0], res.path[:, 1])
    return PlanResult(True, np.column_stack([X, Z]), res.path, res.cost * grid.resolution, res.expanded)
