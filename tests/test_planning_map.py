"""Occupancy grid from a y-down point cloud, planning on it, and the ``gtvo plan`` command."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gtvo import cli
from gtvo.errors import InputError
from gtvo.planning.occupancy import build_occupancy_grid, fit_ground_plane, plan_path, read_point_cloud

CAMERA_HEIGHT = 1.6      # the first camera is 1.6 m above the ground (y down: ground at y ~ +1.6)
TILT = 0.05              # the ground is pitched by 0.05 rad against the world x-z plane
GAP = (1.0, 2.5)         # the wall at Z = 5 has a gap for X in this range


# every test here reads, writes or processes point clouds with open3d
pytestmark = pytest.mark.usefixtures("open3d")

def _ground_y(X, Z):
    return CAMERA_HEIGHT + np.tan(TILT) * Z


def _wall(rng, n, x0, z0, x1, z1, gap=None):
    """Points of a vertical wall from (x0, z0) to (x1, z1), 2.5 m high, optionally with a gap in X."""
    u = rng.uniform(0, 1, n)
    X, Z = x0 + u * (x1 - x0), z0 + u * (z1 - z0) + rng.normal(0, 0.01, n)
    if gap is not None:
        keep = (X < gap[0]) | (X > gap[1])
        X, Z = X[keep], Z[keep]
    return np.column_stack([X, _ground_y(X, Z) - rng.uniform(0.0, 2.5, X.size), Z])


def synthetic_cloud(seed: int = 0) -> np.ndarray:
    """A closed 10 x 12 m room on a tilted, noisy ground; a dense wall across Z = 5 with a gap;
    some ceiling points far above the robot (they must not count as obstacles). The walls hold
    more points than the ground: the largest plane is NOT the ground."""
    rng = np.random.default_rng(seed)
    n = 20000
    X = rng.uniform(-5, 5, n)
    Z = rng.uniform(-1, 11, n)
    ground = np.column_stack([X, _ground_y(X, Z) + rng.normal(0, 0.01, n), Z])
    walls = [_wall(rng, 30000, -5, 5, 5, 5, gap=GAP),
             _wall(rng, 8000, -5, -1, -5, 11), _wall(rng, 8000, 5, -1, 5, 11),
             _wall(rng, 8000, -5, -1, 5, -1), _wall(rng, 8000, -5, 11, 5, 11)]
    k = 2000
    Xc, Zc = rng.uniform(-5, 5, k), rng.uniform(-1, 11, k)
    ceiling = np.column_stack([Xc, _ground_y(Xc, Zc) - 3.5, Zc])
    return np.vstack([ground, *walls, ceiling])


def _write_ply(path, points):
    import open3d as o3d
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    assert o3d.io.write_point_cloud(str(path), pcd)
    return path


@pytest.mark.slow
def test_ground_is_found_below_the_camera_not_the_bigger_wall():
    pts = synthetic_cloud()
    ground = fit_ground_plane(pts)
    assert ground.offset == pytest.approx(CAMERA_HEIGHT * np.cos(TILT), abs=0.02)
    expected_normal = np.array([0.0, -np.cos(TILT), np.sin(TILT)])
    assert np.degrees(np.arccos(np.clip(ground.normal @ expected_normal, -1, 1))) < 1.0
    on_ground = np.array([[0.0, _ground_y(0.0, 8.0), 8.0]])
    assert ground.height(on_ground)[0] == pytest.approx(0.0, abs=0.02)


def test_grid_and_path_through_the_gap():
    grid = build_occupancy_grid(synthetic_cloud(), resolution=0.1, robot_radius=0.3)
    # cell <-> world round trip
    X, Z = grid.cell_to_world(*grid.world_to_cell(1.234, 4.321))
    assert abs(X - 1.234) <= 0.05 + 1e-12 and abs(Z - 4.321) <= 0.05 + 1e-12
    # the wall is an obstacle, the gap is not, the ground and ceiling are not
    r, c = grid.world_to_cell(np.array([-3.0, 1.75, 0.0]), np.array([5.0, 5.0, 2.0]))
    assert grid.obstacles[r[0], c[0]] and not grid.occupied[r[1], c[1]] and not grid.obstacles[r[2], c[2]]
    assert grid.occupied[grid.world_to_cell(-3.0, 5.25)]  # inflated by the robot radius
    res = plan_path(grid, (-2.0, 1.0), (-2.0, 9.0))
    assert res.found
    # the path crosses Z = 5 through the gap, never through occupied cells
    crossing = res.path_xz[np.argmin(np.abs(res.path_xz[:, 1] - 5.0)), 0]
    assert GAP[0] + 0.25 <= crossing <= GAP[1] - 0.25
    assert not grid.occupied[res.cells[:, 0], res.cells[:, 1]].any()
    # longer than the straight 8 m, shorter than a generous detour bound
    straight_via_gap = 2 * np.hypot(2.0 + GAP[0] + 0.3, 4.0)
    assert 8.0 < res.length_m < straight_via_gap + 1.0
    seg = np.linalg.norm(np.diff(res.path_xz, axis=0), axis=1).sum()
    assert res.length_m == pytest.approx(seg, rel=1e-9)


def test_robot_too_wide_for_the_gap_has_no_path():
    grid = build_occupancy_grid(synthetic_cloud(), resolution=0.1, robot_radius=0.9)
    res = plan_path(grid, (-2.0, 1.0), (-2.0, 9.0))
    assert not res.found and res.path_xz.shape == (0, 2) and res.length_m == np.inf


def test_plan_bad_points():
    grid = build_occupancy_grid(synthetic_cloud(), resolution=0.2, robot_radius=0.3)
    with pytest.raises(InputError, match="outside the map"):
        plan_path(grid, (100.0, 0.0), (0.0, 8.0))
    with pytest.raises(InputError, match="obstacle"):
        plan_path(grid, (-3.0, 5.0), (0.0, 8.0))
    with pytest.raises(InputError):
        build_occupancy_grid(np.zeros((2, 3)))
    with pytest.raises(InputError):
        build_occupancy_grid(synthetic_cloud(), resolution=0.0)
    with pytest.raises(InputError, match="no ground plane"):
        # only a wall: no level plane below the camera
        fit_ground_plane(_wall(np.random.default_rng(1), 5000, -5, 5, 5, 5))


@pytest.mark.parametrize("ascii_ply", [False, True])
def test_truncated_point_cloud_is_refused(tmp_path, ascii_ply):
    """A PLY shorter than its header declares (an interrupted copy) is an InputError naming the
    file, not a map of garbage points: open3d alone returns what it could read without failing."""
    import open3d as o3d
    pts = synthetic_cloud()[:500]
    good = tmp_path / "good.ply"
    assert o3d.io.write_point_cloud(str(good), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)),
                                    write_ascii=ascii_ply)
    np.testing.assert_allclose(read_point_cloud(good), pts, rtol=1e-5, atol=1e-4)  # (ASCII: 6 digits)
    data = good.read_bytes()
    for cut in (len(data) // 2, len(data) - 13):
        bad = tmp_path / f"cut{cut}.ply"
        bad.write_bytes(data[:cut])
        with pytest.raises(InputError, match="truncated") as exc:
            read_point_cloud(bad)
        assert str(bad) in str(exc.value)


def test_map_of_absurd_extent_is_refused():
    pts = synthetic_cloud()
    pts[0] = (1e200, 0.0, 1e200)  # one corrupt point
    with pytest.raises(InputError, match="too large for a grid"):
        build_occupancy_grid(pts, resolution=0.2)


@pytest.fixture
def plan_cli():
    """``gtvo`` main() with every command registered."""
    return cli.main


@pytest.mark.slow
def test_cli_json_and_png(tmp_path, plan_cli, capsys):
    ply = _write_ply(tmp_path / "points.ply", synthetic_cloud())
    png = tmp_path / "out" / "path.png"
    rc = plan_cli(["plan", "--map", str(ply), "--start=-2,1", "--goal=-2,9", "--resolution", "0.1",
                   "--robot-radius", "0.3", "--out", str(png), "--json"])
    out = capsys.readouterr().out
    assert rc == 0
    obj = json.loads(out)
    assert obj["found"] and 8.0 < obj["path_length_m"] < 13.0
    path = np.array(obj["path"])
    assert path.shape[1] == 2 and np.allclose(path[0], [-2, 1], atol=0.1) and np.allclose(path[-1], [-2, 9], atol=0.1)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not [p for p in png.parent.iterdir() if p.name.startswith(".")]  # no temporary left
    assert len(read_point_cloud(ply)) == len(synthetic_cloud())
    # no path: exit 1, JSON still printed
    rc = plan_cli(["plan", "--map", str(ply), "--start=-2,1", "--goal=-2,9", "--robot-radius", "0.9", "--json"])
    assert rc == 1 and json.loads(capsys.readouterr().out)["path_length_m"] is None


@pytest.mark.parametrize("args,needle", [
    (["--map", "MISSING.ply", "--start", "0,1", "--goal", "0,9"], "not found"),
    (["--map", "PLY", "--start", "1,x", "--goal", "0,9"], "--start"),
    (["--map", "PLY", "--start", "1", "--goal", "0,9"], "--start"),
    (["--map", "PLY", "--start", "0,1", "--goal", "0,9", "--resolution", "abc"], "--resolution"),
    (["--map", "PLY", "--start", "0,1", "--goal", "50,9"], "outside the map"),
    (["--map", "EMPTY", "--start", "0,1", "--goal", "0,9"], "corrupt point cloud (RPly: Wrong magic number"),
])
def test_cli_bad_input_exit_2_one_line(tmp_path, plan_cli, capsys, args, needle):
    ply = _write_ply(tmp_path / "points.ply", synthetic_cloud()[::4])
    empty = tmp_path / "empty.ply"
    empty.write_text("this is not a ply file\n")
    args = [str(tmp_path / a) if a == "MISSING.ply" else str(ply) if a == "PLY" else str(empty) if a == "EMPTY" else a
            for a in args]
    rc = plan_cli(["plan", *args])
    err = capsys.readouterr().err
    assert rc == 2
    assert len(err.strip().splitlines()) == 1 and needle in err
