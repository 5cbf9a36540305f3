"""Tapering windows for the range, Doppler and angle FFTs.

All windows are *symmetric* (scipy ``sym=True``, i.e. not periodic) and
normalised to unit coherent gain::

    sum(w) == n        (mean(w) == 1)

so that a unit-amplitude tone that falls exactly on an FFT bin gives the same
peak (``n``) with every window; only the main-lobe width and sidelobe level
change.  Magnitudes of RA maps are therefore comparable across window choices.
"""
from __future__ import annotations

import numpy as np
from scipy.signal import windows as _sw

from ..errors import ConfigError

#: Names accepted by :func:`get_window`.
WINDOW_NAMES = ("hann", "hamming", "blackman", "taylor", "chebyshev", "rect", "none")

_ALIASES = {"hanning": "hann", "rectangular": "rect", "boxcar": "rect", "ones": "rect",
            "cheb": "chebyshev", "chebwin": "chebyshev"}


def get_window(name, n: int) -> np.ndarray:
    """A length-``n`` window with unit coherent gain (``sum(w) == n``).

    Symmetric windows with zero end points (Hann, Blackman) degenerate for
    ``n <= 2`` (all zeros); there the rectangular window is returned instead.

    Parameters
    ----------
    name : str or None
        ``'hann'`` (scipy ``hann(n, sym=True)``), ``'hamming'``,
        ``'blackman'``, ``'taylor'`` (nbar 4, 30 dB sidelobes), ``'chebyshev'``
        (80 dB sidelobes), ``'rect'`` / ``'none'`` (or ``None``): all ones.
        Case-insensitive.
    n : int
        Window length (>= 1).

    Returns
    -------
    numpy.ndarray
        float64 ``[n]``.

    Raises
    ------
    ConfigError
        An unknown name (the message lists the choices).
    """
    try:
        n = int(n)
    except (TypeError, ValueError):
        raise ConfigError(f"get_window: n must be an integer, got {n!r}") from None
    if n < 1:
        raise ConfigError(f"get_window: n must be >= 1, got {n}")
    key = "rect" if name is None else str(name).strip().lower()
    key = _ALIASES.get(key, key)
    if key in ("rect", "none"):
        w = np.ones(n)
    elif key == "hann":
        w = _sw.hann(n, sym=True)
    elif key == "hamming":
        w = _sw.hamming(n, sym=True)
    elif key == "blackman":
        w = _sw.blackman(n, sym=True)
    elif key == "taylor":
        w = _sw.taylor(n, nbar=4, sll=30, norm=False, sym=True)
    elif key == "chebyshev":
        w = _sw.chebwin(n, at=80, sym=True) if n > 1 else np.ones(1)
    else:
        raise ConfigError(f"get_window: unknown window {name!r}; choose one of "
                          f"{', '.join(WINDOW_NAMES)}")
    w = np.asarray(w, dtype=np.float64)
    total = float(np.sum(w))
    if not np.isfinite(total) or total <= 1e-12:
        w = np.ones(n)
        total = float(n)
    return w * (n / total)
