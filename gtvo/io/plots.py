"""Trajectory plots: PNG files through matplotlib's Agg backend, written atomically.

* :func:`plot_trajectory_top_view`: estimate (and ground truth) seen from above.
* :func:`plot_errors_over_time`: an error curve (e.g. ATE per pose) against time.
* :func:`load_in_background` (``gtvo run`` after its first frame), :func:`load_now`: matplotlib's
  import and font loaded, and the two plots' figures made with their axes and ticks
  (:data:`PREPARED_SIZES`), before the plots are drawn, so that a run's end does not wait for them.

The top view projects the positions onto a plane (``plane=``):

* ``"xy"``, ``"xz"``, ``"yz"``: a coordinate plane; the first letter is the horizontal axis.
  ``"xz"`` (x right, z up on the page) is the view from above for camera-frame worlds
  (KITTI, a VO run's first camera: y points down), ``"xy"`` for z-up worlds (TUM, EuRoC).
* ``"pca"``: the two largest principal axes of the ground-truth positions (of the estimate
  when there is no ground truth), centred on their mean.
* ``"auto"`` (default): the principal-axis plane's normal (the axis of least spread) is
  compared with the coordinate axes; when it is within 30 degrees of one, the coordinate plane
  normal to that axis is used (``"xz"`` for normal y, ``"xy"`` for z, ``"yz"`` for x) so the
  axes keep their names; otherwise ``"pca"``.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from gtvo.core.atomic import atomic_path
from gtvo.errors import InputError
from gtvo.evaluation.trajectory import FloatArray, Trajectory

Plane = Literal["auto", "pca", "xy", "xz", "yz"]

_AXES = {"x": 0, "y": 1, "z": 2}
#: Axis labels of the ``"xz"`` top view of a world that is the first camera's frame (x right, y down,
#: z forward): a VO run's own world, and KITTI's ground truth.
CAMERA_WORLD_XZ_LABELS = ("x (m, right; world = first camera)", "z (m, forward)")
#: "auto" uses a coordinate plane when the least-spread axis is within this angle of a coordinate axis.
AUTO_PLANE_MAX_TILT_DEG = 30.0


def _principal_axes(points: FloatArray) -> FloatArray:
    """(3, 3) rows: principal directions of ``points``, largest spread first."""
    centred = points - points.mean(axis=0)
    _, _, Vt = np.linalg.svd(centred, full_matrices=True)
    return Vt


def choose_plane(positions: ArrayLike, plane: Plane = "auto") -> str:
    """The plane :func:`plot_trajectory_top_view` uses for ``positions`` (see the module docstring)."""
    if plane in ("xy", "xz", "yz", "pca"):
        return plane
    if plane != "auto":
        raise InputError(f"unknown plot plane {plane!r}: use auto, pca, xy, xz or yz")
    P = np.asarray(positions, dtype=np.float64)
    if len(P) < 3:
        return "xz"
    normal = _principal_axes(P)[2]
    axis = int(np.argmax(np.abs(normal)))
    if np.degrees(np.arccos(min(1.0, abs(normal[axis])))) <= AUTO_PLANE_MAX_TILT_DEG:
        return {0: "yz", 1: "xz", 2: "xy"}[axis]
    return "pca"


def project_to_plane(points: ArrayLike, plane: str,
                     basis_points: ArrayLike | None = None) -> tuple[FloatArray, str, str]:
    """2-D coordinates of (N, 3) ``points`` in ``plane`` and the two axis labels.

    For ``"pca"`` the axes come from ``basis_points`` (default ``points``) and are centred
    on their mean.
    """
    P = np.asarray(points, dtype=np.float64)
    if plane == "pca":
        B = np.asarray(points if basis_points is None else basis_points, dtype=np.float64)
        axes = _principal_axes(B)
        uv = (P - B.mean(axis=0)) @ axes[:2].T
        return uv, "principal axis 1 [m]", "principal axis 2 [m]"
    a, b = _AXES[plane[0]], _AXES[plane[1]]
    return P[:, [a, b]], f"{plane[0]} [m]", f"{plane[1]} [m]"


_loader: threading.Thread | None = None
#: The figure sizes of a run's plots (:func:`plot_trajectory_top_view`, :func:`plot_errors_over_time`):
#: :func:`load_in_background` prepares one figure of each while the run goes.
PREPARED_SIZES: tuple[tuple[float, float], ...] = ((7.0, 6.0), (8.0, 4.0))
#: Ticks made ahead on each axis of a prepared figure (a plot's axes have up to about 10).
PREPARED_TICKS = 12
_prepared: dict[tuple[float, float], list] = {}
#: The plots' margins (fractions of the figure), fixed rather than fitted (``tight_layout``, which lays
#: the text out once more: a third of a plot's time): room for 6-character tick labels and the titles.
_TOP_VIEW_MARGINS = {"left": 0.12, "right": 0.97, "bottom": 0.085, "top": 0.94}
_ERRORS_MARGINS = {"left": 0.1, "right": 0.98, "bottom": 0.125, "top": 0.9}


def load_in_background() -> None:
    """Import matplotlib (its figure, the Agg canvas, the patches) and load its font in a daemon thread,
    so that a run's plots do not wait for them at its end (about 0.7 s of CPU; the thread takes the
    time the run's compiled loops leave, as they release the GIL). Best effort: a failure here is left
    to the plot that needs matplotlib, which then reports it. Called once; later calls do nothing.
    """
    global _loader
    if _loader is None:
        _loader = threading.Thread(target=_load_matplotlib, name="gtvo-plots-import", daemon=True)
        _loader.start()


def _prepare_figure(figsize: tuple[float, float]) -> None:
    """Make a figure of ``figsize`` with its one axes and :data:`PREPARED_TICKS` ticks on each axis (what a
    plot otherwise builds before and while it draws: about a sixth of a run's two plots, measured) and keep
    it for the next plot of that size (:func:`_figure_and_axes`)."""
    fig = _new_figure(figsize, wait=False)
    ax = fig.add_subplot(1, 1, 1)
    for axis in (ax.xaxis, ax.yaxis):
        axis.get_major_ticks(PREPARED_TICKS)
    _prepared.setdefault(figsize, []).append((fig, ax))


def _figure_and_axes(figsize: tuple[float, float]):
    """A new figure of ``figsize`` and its one axes: one :func:`load_in_background` prepared when there
    is one left, else made here."""
    if _loader is not None:
        _loader.join()
    ready = _prepared.get(figsize)
    if ready:
        return ready.pop()
    fig = _new_figure(figsize)
    return fig, fig.add_subplot(1, 1, 1)


def load_now() -> None:
    """What :func:`load_in_background` loads, in the calling thread (it waits for it): for a process
    that must stay on one core, e.g. a ``gtvo batch`` worker; later :func:`load_in_background` calls
    then start nothing."""
    load_in_background()
    if _loader is not None:
        _loader.join()


def _load_matplotlib() -> None:
    try:
        fig = _new_figure((1.0, 1.0), wait=False)
        from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: PLC0415
        from matplotlib.patches import Ellipse  # noqa: PLC0415,F401 - the ellipses' import, done here

        ax = fig.add_subplot(1, 1, 1)
        ax.plot([0.0, 1.0], [0.0, 1.0], label="x")
        ax.legend(loc="best", fontsize=8)
        ax.set_title("x")
        FigureCanvasAgg(fig).draw()  # the font and the renderer's first use
        for size in PREPARED_SIZES:
            _prepare_figure(size)
    except Exception:  # noqa: BLE001,S110 - best effort (docstring)
        pass


def _new_figure(figsize: tuple[float, float], wait: bool = True):
    if wait and _loader is not None:
        _loader.join()  # matplotlib's fonts are shared and not thread-safe: one figure drawn at a time
    import matplotlib  # noqa: PLC0415 - only plotting needs it

    matplotlib.use("Agg")
    from matplotlib.figure import Figure  # noqa: PLC0415

    return Figure(figsize=figsize, dpi=100)


def _label(traj: Trajectory, default: str) -> str:
    return Path(traj.name).name if traj.name else default


def _save(fig, path: str | Path) -> Path:
    path = Path(path)
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png")
    return path


def plane_matrix(plane: str, basis_points: ArrayLike | None = None) -> FloatArray:
    """The (2, 3) linear map of :func:`project_to_plane` (without the ``"pca"`` centring): it
    carries a 3-D covariance ``P`` onto the plane as ``A P A^T``."""
    if plane == "pca":
        if basis_points is None:
            raise InputError("the pca plane needs its basis points")
        return _principal_axes(np.asarray(basis_points, dtype=np.float64))[:2].copy()
    A = np.zeros((2, 3))
    A[0, _AXES[plane[0]]] = A[1, _AXES[plane[1]]] = 1.0
    return A


#: 95 % of a 2-D Gaussian lies inside sqrt(5.991) sigma (chi-square, 2 dof).
_CHI2_2_95 = 5.991464547107979


def _draw_ellipses(ax, centres: FloatArray, covariances: FloatArray, plane: str, basis: FloatArray) -> None:
    """95 % position ellipses projected onto the plot's plane, magnified by a 1-2-5 factor (named in
    the legend) so that the largest spans about 1/20 of the plot when they are smaller than that."""
    from matplotlib.patches import Ellipse  # noqa: PLC0415

    A = plane_matrix(plane, basis)
    uv, _, _ = project_to_plane(centres, plane, basis)
    C = np.einsum("ij,kjl,ml->kim", A, covariances, A)
    half_axes, angles = [], []
    for c in C:
        w, V = np.linalg.eigh(0.5 * (c + c.T))
        half_axes.append(np.sqrt(np.maximum(w, 0.0) * _CHI2_2_95))
        angles.append(np.degrees(np.arctan2(V[1, 1], V[0, 1])))
    half = np.asarray(half_axes)
    extent = float(np.ptp(project_to_plane(basis, plane, basis)[0], axis=0).max()) if len(basis) > 1 else 1.0
    largest = float(half.max()) if half.size else 0.0
    gain = 1.0
    if largest > 0 and 2 * largest < extent / 20:
        raw = extent / 20 / (2 * largest)
        e = 10.0 ** np.floor(np.log10(raw))
        gain = max(m * e for m in (1, 2, 5) if m * e <= raw)
    for k in range(len(C)):
        ax.add_patch(Ellipse((uv[k, 0], uv[k, 1]), 2 * gain * half[k, 1], 2 * gain * half[k, 0], angle=angles[k],
                             fill=False, color="tab:red", lw=0.8,
                             label=(f"95 % position ellipse x {gain:g}" if gain != 1 else "95 % position ellipse")
                             if k == 0 else None))


def plot_trajectory_top_view(est: Trajectory, ref: Trajectory | None = None, path: str | Path = "trajectory.png",
                             title: str = "", plane: Plane = "auto",
                             ellipses: tuple[FloatArray, FloatArray] | None = None,
                             axis_labels: tuple[str, str] | None = None) -> Path:
    """Plot the estimated (and ground-truth) positions seen from above; write a PNG.

    Args:
        est: the estimate, already aligned to ``ref`` if the two should overlap
            (e.g. ``gtvo.evaluation.metrics.align_trajectory``).
        ref: optional ground truth, drawn dashed in grey; it also picks the plane.
        path: output PNG file.
        title: figure title.
        plane: ``"auto"``, ``"pca"``, ``"xy"``, ``"xz"`` or ``"yz"`` (module docstring).
        ellipses: ``(centres (M, 3), position covariances (M, 3, 3))`` in ``est``'s world frame:
            drawn as 95 % ellipses on the plot's plane (magnified, with the factor in the legend,
            when they would be too small to see).
        axis_labels: the two axis labels instead of the plane's own (e.g. a coordinate plane's
            axes named in their frame: :data:`CAMERA_WORLD_XZ_LABELS`).

    Returns:
        ``path``.
    """
    basis = ref.positions if ref is not None else est.positions
    chosen = choose_plane(basis, plane)
    fig, ax = _figure_and_axes((7.0, 6.0))
    if ref is not None:
        uv_ref, xlabel, ylabel = project_to_plane(ref.positions, chosen, basis)
        ax.plot(uv_ref[:, 0], uv_ref[:, 1], "--", color="0.4", lw=1.2, label=_label(ref, "ground truth"))
    uv, xlabel, ylabel = project_to_plane(est.positions, chosen, basis)
    ax.plot(uv[:, 0], uv[:, 1], "-", color="tab:blue", lw=1.2, label=_label(est, "estimate"))
    ax.plot(uv[:1, 0], uv[:1, 1], "o", color="tab:green", ms=5, label="start")
    if ellipses is not None and len(ellipses[0]):
        _draw_ellipses(ax, np.asarray(ellipses[0], float), np.asarray(ellipses[1], float), chosen, basis)
    if axis_labels is not None:
        xlabel, ylabel = axis_labels
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title(title or f"top view ({chosen} plane)")
    fig.subplots_adjust(**_TOP_VIEW_MARGINS)
    return _save(fig, path)


def plot_errors_over_time(times: ArrayLike, errors: ArrayLike, path: str | Path = "errors.png", title: str = "",
                          ylabel: str = "error [m]") -> Path:
    """Plot ``errors`` against ``times - times[0]`` (seconds) with the RMSE as a line; write a PNG."""
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    e = np.asarray(errors, dtype=np.float64).reshape(-1)
    if t.size == 0 or t.size != e.size:
        raise InputError(f"plot_errors_over_time needs equally long non-empty arrays, got {t.size} times "
                         f"and {e.size} errors")
    fig, ax = _figure_and_axes((8.0, 4.0))
    ax.plot(t - t[0], e, "-", color="tab:red", lw=1.0, label="error")
    finite = e[np.isfinite(e)]
    if finite.size:
        rmse = float(np.sqrt(np.mean(finite ** 2)))
        ax.axhline(rmse, color="0.3", ls="--", lw=1.0, label=f"rmse {rmse:.4g}")
    ax.set_xlabel("time since start [s]")
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    if title:
        ax.set_title(title)
    fig.subplots_adjust(**_ERRORS_MARGINS)
    return _save(fig, path)
