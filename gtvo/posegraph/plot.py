"""PNG plot of a pose graph: odometry edges (i, i+1) and loop-closure edges in two colours."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gtvo.core.atomic import write_with
from gtvo.posegraph.graph import PoseGraph


def plot_graph(graph: PoseGraph, path: str | Path, title: str = "") -> Path:
    """Draw ``graph``'s poses and edges (2-D top view, or a 3-D view) into the PNG ``path``."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    from matplotlib.collections import LineCollection  # noqa: PLC0415

    t = graph.translations
    seq = np.abs(graph.ids[graph.edge_i] - graph.ids[graph.edge_j]) == 1
    segs = np.stack([t[graph.edge_i], t[graph.edge_j]], 1)
    fig = plt.figure(figsize=(8, 8), dpi=100)
    if graph.dim == 2:
        ax = fig.add_subplot(111)
        ax.add_collection(LineCollection(segs[~seq], colors="tab:red", linewidths=0.3, alpha=0.5,
                                         label="loop closures"))
        ax.add_collection(LineCollection(segs[seq], colors="tab:blue", linewidths=0.6, label="odometry"))
        ax.set_aspect("equal")
        ax.autoscale()
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
    else:
        from mpl_toolkits.mplot3d.art3d import Line3DCollection  # noqa: PLC0415

        ax = fig.add_subplot(111, projection="3d")
        ax.add_collection(Line3DCollection(segs[~seq], colors="tab:red", linewidths=0.3, alpha=0.5,
                                           label="loop closures"))
        ax.add_collection(Line3DCollection(segs[seq], colors="tab:blue", linewidths=0.6, label="odometry"))
        lo, hi = t.min(0), t.max(0)
        c, r = 0.5 * (lo + hi), 0.5 * float(np.max(hi - lo) + 1e-9)
        ax.set_xlim(c[0] - r, c[0] + r)
        ax.set_ylim(c[1] - r, c[1] + r)
        ax.set_zlim(c[2] - r, c[2] + r)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_zlabel("z [m]")
    ax.legend(loc="upper right")
    ax.set_title(title or Path(graph.source).name)
    try:
        return write_with(path, lambda tmp: fig.savefig(tmp, format="png"))
    finally:
        plt.close(fig)
