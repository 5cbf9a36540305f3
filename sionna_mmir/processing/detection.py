"""Target detection on range-azimuth maps.

:func:`strongest_return` finds the largest cell of a range-azimuth power map
inside a range window.
"""
from __future__ import annotations

import numpy as np

from ..errors import InputValueError


def strongest_return(ra, ranges, az, r_min: float, r_max: float):
    """The range-azimuth maximum within ``[r_min, r_max]``.

    Parameters
    ----------
    ra : numpy.ndarray
        Range-azimuth power ``[range, azimuth]``.
    ranges : numpy.ndarray
        Range bin centres [m].
    az : numpy.ndarray
        Azimuth bin centres [rad].
    r_min, r_max : float
        Range window [m].

    Returns
    -------
    tuple
        ``(range [m], azimuth [rad], value)``.
    """
    sel = (ranges >= r_min) & (ranges <= r_max)
    if not sel.any():
        raise InputValueError(f"no range bins between {r_min} and {r_max} m")
    sub = ra[sel]
    i, j = np.unravel_index(np.argmax(sub), sub.shape)
    return float(ranges[sel][i]), float(az[j]), float(sub[i, j])
