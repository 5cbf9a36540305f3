"""Range-azimuth figures (matplotlib, Agg canvas: never opens a window).

Figures are built with :class:`matplotlib.figure.Figure` and the Agg canvas
directly (no ``pyplot`` state), so plotting works headless and in threads.
Files are written atomically (temporary file in the target folder, then
``os.replace``).
"""
from __future__ import annotations

import os

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from .errors import InputValueError
from .processing.polar import polar_to_cartesian
from .utils.atomic import atomic_path


def _to_display(ra, db, dynamic_range_db, ref):
    """Linear magnitudes -> display values (dB re ``ref`` clipped, or ``ra / ref``)."""
    ra = np.asarray(ra, dtype=np.float64)
    ref = ref if ref > 0 else 1.0
    if db:
        with np.errstate(divide="ignore"):
            out = 20.0 * np.log10(np.maximum(ra, 0.0) / ref)
        return np.clip(out, -float(dynamic_range_db), 0.0)
    return ra / ref


def _check(ra, ranges_m, azimuths_rad, where):
    ra = np.asarray(ra)
    if np.iscomplexobj(ra):
        raise InputValueError(f"{where}: RA map is complex; pass magnitudes")
    r = np.asarray(ranges_m).reshape(-1)
    a = np.asarray(azimuths_rad).reshape(-1)
    if ra.ndim != 2 or ra.shape != (r.size, a.size):
        raise InputValueError(f"{where}: RA map must be [n_range={r.size}, n_azimuth={a.size}], "
                              f"got {ra.shape}")
    if not np.all(np.isfinite(ra)):
        raise InputValueError(f"{where}: RA map holds NaN or Inf")
    return ra, r, a


def _draw(ax, ra, r, a, *, db, dynamic_range_db, cartesian, ref, vmin, vmax, title, cmap):
    disp = _to_display(ra, db, dynamic_range_db, ref)
    if cartesian:
        img, x, y = polar_to_cartesian(disp, r, a)
        fov, _, _ = polar_to_cartesian(np.ones_like(disp), r, a)
        img = np.where(fov > 0.5, img, np.nan)          # outside the field of view: blank
        dx = x[1] - x[0] if x.size > 1 else 1.0
        dy = y[1] - y[0] if y.size > 1 else 1.0
        extent = (y[0] - dy / 2, y[-1] + dy / 2, x[0] - dx / 2, x[-1] + dx / 2)
        im = ax.imshow(img.T, origin="lower", extent=extent, aspect="equal",
                       vmin=vmin, vmax=vmax, cmap=cmap, interpolation="nearest")
        ax.set_xlim(extent[1], extent[0])            # +y (left) drawn on the left
        ax.set_xlabel("y, left [m]")
        ax.set_ylabel("x, forward [m]")
    else:
        im = ax.pcolormesh(np.rad2deg(a), r, disp, shading="nearest", vmin=vmin, vmax=vmax,
                           cmap=cmap)
        ax.set_xlim(np.rad2deg(a[-1]), np.rad2deg(a[0]))   # positive azimuth (left) on the left
        ax.set_xlabel("azimuth [deg] (+ = left)")
        ax.set_ylabel("range [m]")
    if title:
        ax.set_title(title)
    return im


def plot_range_azimuth(ra, ranges_m, azimuths_rad, ax=None, db: bool = True,
                       dynamic_range_db: float = 40.0, cartesian: bool = False,
                       title: str | None = None, cmap: str = "viridis"):
    """Draw one RA magnitude map.

    Parameters
    ----------
    ra : array_like
        real ``[n_range, n_azimuth]`` magnitudes
    ranges_m : array_like
        ``[n_range]`` [m]
    azimuths_rad : array_like
        ``[n_azimuth]`` [rad], increasing (positive = left)
    ax : matplotlib.axes.Axes, optional
        default a new Agg Figure's
    db : bool, optional
        show ``20 log10(ra / max ra)`` clipped to
        ``[-dynamic_range_db, 0]`` dB; else ``ra / max ra``
    dynamic_range_db : float, optional
        dB range shown
    cartesian : bool, optional
        bird's-eye ``(y, x)`` [m] instead of (azimuth [deg],
        range [m])
    title : str, optional
        axes title
    cmap : str, optional
        matplotlib colour map

    Returns
    -------
    matplotlib.axes.Axes
        its figure is ``ax.figure``; the colour mapping is
        ``ax.collections`` / ``ax.images``
    """
    ra, r, a = _check(ra, ranges_m, azimuths_rad, "plot_range_azimuth")
    if ax is None:
        fig = Figure(figsize=(5, 4))
        FigureCanvasAgg(fig)
        ax = fig.add_subplot(1, 1, 1)
    vmin, vmax = (-float(dynamic_range_db), 0.0) if db else (0.0, 1.0)
    im = _draw(ax, ra, r, a, db=db, dynamic_range_db=dynamic_range_db, cartesian=cartesian,
               ref=float(np.max(ra)), vmin=vmin, vmax=vmax, title=title, cmap=cmap)
    ax.figure.colorbar(im, ax=ax, label="dB re peak" if db else "normalised magnitude")
    return ax


def save_ra_panels(panels: dict, ranges_m, azimuths_rad, path, cartesian: bool = True,
                   db: bool = True, dynamic_range_db: float = 40.0,
                   normalize_each: bool = True, panel_size=(4.0, 4.0), dpi: int = 100,
                   suptitle: str | None = None, cmap: str = "viridis") -> str:
    """Write side-by-side RA panels (e.g. measured / mmIR / Sionna RT) to a PNG.

    All panels share one colour scale and one colour bar.  The file is
    written atomically.

    Parameters
    ----------
    panels : dict
        ``{title: ra [n_range, n_azimuth]}``, drawn left to right
    ranges_m : array_like
        ``[n_range]`` [m], shared by all panels
    azimuths_rad : array_like
        ``[n_azimuth]`` [rad], shared
    path : str or os.PathLike
        output file (``.png``); parent folders are created
    cartesian : bool, optional
        bird's-eye view (``x`` forward, ``y`` left) [m];
        ``False``: range [m] vs azimuth [deg]
    db : bool, optional
        dB display clipped to ``dynamic_range_db``
    normalize_each : bool, optional
        each panel relative to its own peak (default; maps of
        different absolute scale) or all to the global peak
    panel_size : tuple, optional
        inches per panel ``(w, h)``; the figure is
        ``(w * n + 1, h)`` inches at ``dpi`` (the extra inch
        holds the shared colour bar), so the PNG is exactly
        ``round((w n + 1) dpi) x round(h dpi)`` pixels
    dpi : int, optional
        resolution [dots per inch]
    suptitle : str, optional
        figure title
    cmap : str, optional
        matplotlib colour map

    Returns
    -------
    str
        the path written
    """
    if not isinstance(panels, dict) or not panels:
        raise InputValueError("save_ra_panels: panels must be a non-empty {title: ra} dict")
    checked = {k: _check(v, ranges_m, azimuths_rad, f"save_ra_panels[{k!r}]")
               for k, v in panels.items()}
    n = len(checked)
    pw, ph = (float(panel_size[0]), float(panel_size[1]))
    fig = Figure(figsize=(pw * n + 1.0, ph), dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, n, squeeze=False)[0]
    global_ref = max(float(np.max(v[0])) for v in checked.values())
    vmin, vmax = (-float(dynamic_range_db), 0.0) if db else (0.0, 1.0)
    im = None
    for ax, (name, (ra, r, a)) in zip(axes, checked.items()):
        ref = float(np.max(ra)) if normalize_each else global_ref
        im = _draw(ax, ra, r, a, db=db, dynamic_range_db=dynamic_range_db,
                   cartesian=cartesian, ref=ref, vmin=vmin, vmax=vmax, title=str(name),
                   cmap=cmap)
    label = ("dB re " + ("each panel's peak" if normalize_each else "global peak")) if db \
        else "normalised magnitude"
    fig.colorbar(im, ax=list(axes), label=label, shrink=0.9)
    if suptitle:
        fig.suptitle(suptitle)
    path = os.fspath(path)
    with atomic_path(path, suffix=".png.part") as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)
    return path
