"""3-D scatter pictures of occupancy point clouds (matplotlib, Agg canvas)."""
from __future__ import annotations

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..radar.config import rotation_matrix
from ..utils.atomic import atomic_path

#: Largest number of reference points drawn (a random subset beyond it).
MAX_REFERENCE_DRAWN = 20_000


def _draw(ax, cloud, reference, position, orientation, title, extent):
    ref = np.asarray(reference, float)
    if len(ref) > MAX_REFERENCE_DRAWN:
        ref = ref[np.random.default_rng(0).choice(len(ref), MAX_REFERENCE_DRAWN, replace=False)]
    ax.scatter(ref[:, 0], ref[:, 1], ref[:, 2], s=0.6, c="0.45", alpha=0.5, linewidths=0,
               label="reference (clean mesh)")
    if cloud is not None and len(cloud):
        sc = ax.scatter(cloud.points[:, 0], cloud.points[:, 1], cloud.points[:, 2], s=1.5,
                        c=cloud.intensity, cmap="plasma", vmin=0.0, vmax=1.0, linewidths=0,
                        label="radar points")
        ax.figure.colorbar(sc, ax=ax, shrink=0.6, pad=0.02, label="normalised intensity")
    pos = np.asarray(position, float)
    ax.scatter(*pos, s=60, c="red", label="radar")
    bore = rotation_matrix(orientation) @ np.array([1.5, 0.0, 0.0])
    ax.quiver(*pos, *bore, color="green", linewidth=2, arrow_length_ratio=0.25)
    lo, hi = extent
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(hi - lo)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_title(title, fontsize=9)
    ax.view_init(elev=22, azim=-125)


def save_occupancy_figure(path, panels: dict, reference, position, orientation,
                          title: str = "") -> None:
    """Write a PNG with one 3-D scatter panel per point cloud (atomically).

    Parameters
    ----------
    path : str or os.PathLike
        Output PNG.
    panels : dict
        Label -> :class:`~.point_cloud.PointCloud` (coloured by intensity),
        or None for the reference alone.
    reference : array_like, shape (m, 3)
        Reference points [m] (grey).
    position : array_like, shape (3,)
        Radar position [m] (red dot).
    orientation : array_like, shape (3,)
        Radar ``(yaw, pitch, roll)`` [rad] (green boresight arrow).
    title : str, optional
        Figure title.
    """
    ref = np.asarray(reference, float).reshape(-1, 3)
    pts = [ref, np.asarray(position, float).reshape(1, 3)]
    pts += [c.points for c in panels.values() if c is not None and len(c)]
    allp = np.concatenate(pts)
    lo, hi = allp.min(axis=0) - 0.2, allp.max(axis=0) + 0.2
    fig = Figure(figsize=(6.0 * len(panels), 5.0))
    FigureCanvasAgg(fig)
    for k, (label, cloud) in enumerate(panels.items()):
        ax = fig.add_subplot(1, len(panels), k + 1, projection="3d")
        n = 0 if cloud is None else len(cloud)
        _draw(ax, cloud, ref, position, orientation, f"{label} ({n} points)", (lo, hi))
        if k == 0:
            leg = ax.legend(loc="upper left", fontsize=7)
            for handle, size in zip(leg.legend_handles, (20, 20, 40)):
                handle.set_sizes([size])
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
