"""The picture of `gtvo plan`: framed on the path, start, goal and the camera's trajectory (not on
the whole map, whose points reach hundreds of metres), with the trajectory drawn; the trajectory
that `gtvo run` wrote beside the map is found. No open3d: the grid is made here."""

from __future__ import annotations

import numpy as np
import pytest

from gtvo import cli
from gtvo.evaluation.trajectory import Trajectory
from gtvo.io.trajectory_files import write_tum
from gtvo.planning.occupancy import GroundPlane, OccupancyGrid, plan_path
from gtvo.planning.plot import MIN_MARGIN_M, draw_plan, plan_view


def far_reaching_grid() -> OccupancyGrid:
    """A map like KITTI_sequence_1's: X in [-60, 60] m, Z in [-5, 400] m at 0.5 m cells, an
    obstacle row across Z = 12 with a gap at X in [2, 4]."""
    res, x_min, z_min = 0.5, -60.0, -5.0
    rows, cols = int(405 / res), int(120 / res)
    obstacles = np.zeros((rows, cols), dtype=bool)
    obstacles[int((12 - z_min) / res), :] = True
    obstacles[int((12 - z_min) / res), int((2 - x_min) / res):int((4 - x_min) / res)] = False
    return OccupancyGrid(obstacles, obstacles.copy(), res, x_min, z_min, GroundPlane(np.array([0.0, -1.0, 0.0]), 1.6),
                         0.0)


def camera_path(n: int = 40) -> np.ndarray:
    """(n, 4, 4) poses driving from Z = 0 to Z = 30 m with a slight curve to X = 2 m."""
    poses = np.tile(np.eye(4), (n, 1, 1))
    s = np.linspace(0.0, 1.0, n)
    poses[:, 0, 3], poses[:, 2, 3] = 2.0 * s ** 2, 30.0 * s
    return poses


def test_the_view_frames_the_path_and_trajectory_not_the_whole_map():
    grid = far_reaching_grid()
    result = plan_path(grid, (0.0, 5.0), (0.0, 30.0))
    assert result.found and 25.0 < result.length_m < 35.0
    x0, x1, z0, z1 = plan_view(grid, result, (0.0, 5.0), (0.0, 30.0))
    assert z1 - z0 < 60.0 and x1 - x0 < 60.0  # not the 405 m of the map
    assert z0 <= 5.0 - MIN_MARGIN_M and z1 >= 30.0 + MIN_MARGIN_M and x0 <= -MIN_MARGIN_M
    traj = camera_path()[:, :3, 3][:, [0, 2]]
    tx0, tx1, tz0, tz1 = plan_view(grid, result, (0.0, 5.0), (0.0, 30.0), traj)
    assert tz0 <= 0.0 - MIN_MARGIN_M and tz1 < 60.0  # the trajectory's start (Z = 0) is in the frame
    # never beyond the grid
    gx0, gx1, gz0, gz1 = grid.extent
    wide = plan_view(grid, result, (0.0, 5.0), (0.0, 30.0), np.array([[-500.0, -500.0], [500.0, 900.0]]))
    assert wide == (gx0, gx1, gz0, gz1)


def test_the_picture_draws_the_trajectory_within_its_frame():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    grid = far_reaching_grid()
    result = plan_path(grid, (0.0, 5.0), (0.0, 30.0))
    traj = camera_path()[:, :3, 3][:, [0, 2]]
    fig, ax = plt.subplots()
    try:
        draw_plan(ax, grid, result, (0.0, 5.0), (0.0, 30.0), traj)
        labels = [line.get_label() for line in ax.get_lines()]
        assert "camera trajectory (40 poses)" in labels and any(lb.startswith("path ") for lb in labels)
        (x0, x1), (z0, z1) = ax.get_xlim(), ax.get_ylim()
        assert z1 - z0 < 60.0 and z0 <= 0.0 and z1 >= 30.0
    finally:
        plt.close(fig)


@pytest.mark.parametrize("beside", [(), ("trajectory.tum",), ("trajectory.tum", "trajectory_loop_closed.tum")])
def test_cli_draws_the_trajectory_beside_the_map_or_the_one_given(tmp_path, monkeypatch, capsys, beside):
    import gtvo.planning.occupancy as occupancy
    import gtvo.planning.plot as plot

    grid = far_reaching_grid()
    monkeypatch.setattr(occupancy, "read_point_cloud", lambda path: np.zeros((3, 3)))
    monkeypatch.setattr(occupancy, "build_occupancy_grid", lambda points, **kw: grid)
    drawn = {}
    monkeypatch.setattr(plot, "plot_plan", lambda *a, trajectory_xz=None: drawn.update(traj=trajectory_xz))
    ply = tmp_path / "points.ply"
    ply.write_text("stand-in\n")
    poses = camera_path()
    for k, name in enumerate(beside):  # the loop-closed one is 1 m to the side: the map is placed on it
        shifted = poses.copy()
        shifted[:, 0, 3] += k
        write_tum(tmp_path / name, Trajectory(0.1 * np.arange(len(poses)), shifted))
    args = ["plan", "--map", str(ply), "--start", "0,5", "--goal", "0,30", "--out", str(tmp_path / "plan.png")]
    assert cli.main(args) == 0, capsys.readouterr().err
    if not beside:
        assert drawn["traj"] is None
    else:
        expected = poses[:, :3, 3][:, [0, 2]] + [len(beside) - 1, 0.0]
        np.testing.assert_allclose(drawn["traj"], expected, atol=1e-9)
    given = tmp_path / "other.tum"
    write_tum(given, Trajectory(np.arange(3.0), poses[:3]))
    assert cli.main(args + ["--trajectory", str(given)]) == 0
    assert drawn["traj"].shape == (3, 2)
    capsys.readouterr()
    assert cli.main(args + ["--trajectory", str(tmp_path / "missing.tum")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "missing.tum" in err
