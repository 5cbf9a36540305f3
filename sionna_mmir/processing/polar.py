"""Range-azimuth (polar) maps to a Cartesian bird's-eye grid.

Radar frame: ``x`` forward (boresight), ``y`` to the left; a bin at range
``r`` and azimuth ``az`` is at ``(x, y) = (r cos az, r sin az)``.
"""
from __future__ import annotations

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from ..errors import InputValueError


def polar_to_cartesian(ra, ranges_m, azimuths_rad, x_res: float | None = None,
                       y_res: float | None = None, max_range: float | None = None):
    """Resample a range-azimuth map onto a Cartesian ``(y, x)`` grid.

    Bilinear interpolation in ``(range, azimuth)``
    (``scipy.interpolate.RegularGridInterpolator``); pixels outside the field
    of view (range beyond ``min(max_range, ranges_m[-1])``, below
    ``ranges_m[0]`` or azimuth outside ``azimuths_rad``) are 0.  Repeated
    azimuths (clipped at +-90 deg) are dropped.

    Parameters
    ----------
    ra : array_like
        Real ``[n_range, n_azimuth]`` (e.g. magnitudes).
    ranges_m : array_like
        ``[n_range]`` increasing [m].
    azimuths_rad : array_like
        ``[n_azimuth]`` increasing [rad] (positive = left).
    x_res : float, optional
        Pixel size along x [m]; default the range bin width.
    y_res : float, optional
        Pixel size along y [m]; default ``x_res``.
    max_range : float, optional
        Extent [m]; default ``ranges_m[-1]``.

    Returns
    -------
    image : numpy.ndarray
        ``[ny, nx]``.
    x_m : numpy.ndarray
        ``[nx]`` from 0 to ``max_range`` (pixel centres) [m].
    y_m : numpy.ndarray
        ``[ny]`` symmetric about 0 covering ``max_range * sin(max |az|)``,
        increasing (row 0 = rightmost, most negative y) [m].
    """
    where = "polar_to_cartesian"
    img = np.asarray(ra)
    r = np.asarray(ranges_m, dtype=np.float64).reshape(-1)
    az = np.asarray(azimuths_rad, dtype=np.float64).reshape(-1)
    if np.iscomplexobj(img):
        raise InputValueError(f"{where}: ra is complex; pass magnitudes")
    if img.ndim != 2 or img.shape != (r.size, az.size):
        raise InputValueError(f"{where}: ra must be [n_range={r.size}, n_azimuth={az.size}], "
                              f"got {img.shape}")
    if not (np.all(np.isfinite(img)) and np.all(np.isfinite(r)) and np.all(np.isfinite(az))):
        raise InputValueError(f"{where}: inputs hold NaN or Inf")
    if r.size < 2 or np.any(np.diff(r) <= 0):
        raise InputValueError(f"{where}: ranges_m must be strictly increasing (>= 2 bins)")
    if np.any(np.diff(az) < 0):
        raise InputValueError(f"{where}: azimuths_rad must be increasing")
    keep = np.concatenate([[True], np.diff(az) > 0])
    az, img = az[keep], img[:, keep]
    if az.size < 2:
        raise InputValueError(f"{where}: need at least 2 distinct azimuths")
    dr = float(r[1] - r[0])
    x_res = dr if x_res is None else float(x_res)
    y_res = x_res if y_res is None else float(y_res)
    rmax = float(r[-1]) if max_range is None else float(max_range)
    if x_res <= 0 or y_res <= 0 or rmax <= 0:
        raise InputValueError(f"{where}: x_res, y_res and max_range must be positive")
    nx = int(np.floor(rmax / x_res)) + 1
    x = np.arange(nx) * x_res
    ymax = rmax * np.sin(min(np.pi / 2, max(abs(az[0]), abs(az[-1]))))
    ny_half = int(np.floor(ymax / y_res))
    y = np.arange(-ny_half, ny_half + 1) * y_res
    yy, xx = np.meshgrid(y, x, indexing="ij")
    rr = np.hypot(xx, yy)
    aa = np.arctan2(yy, xx)
    inside = (rr >= r[0]) & (rr <= min(rmax, r[-1])) & (aa >= az[0]) & (aa <= az[-1])
    interp = RegularGridInterpolator((r, az), img.astype(np.float64), method="linear",
                                     bounds_error=False, fill_value=0.0)
    out = np.zeros(rr.shape, dtype=np.float64)
    out[inside] = interp(np.stack([rr[inside], aa[inside]], axis=-1))
    return out.astype(img.dtype if np.issubdtype(img.dtype, np.floating) else np.float64), x, y
