"""Element power patterns: isotropic and separable ``cos^q``.

``cos^q`` (directivity-normalised, Balanis, *Antenna Theory*, Sec. 2.6)::

    G(az, el) = G0 cos(az)^q_az cos(el)^q_el     (x > 0, radar frame)
    G0 = 4 pi / (W(q_az) W(q_el + 1)),   W(p) = sqrt(pi) Gamma((p+1)/2) / Gamma(p/2 + 1)

(``W(p)`` is the Wallis integral of ``cos^p`` over ``[-pi/2, pi/2]``; the
``+1`` comes from ``dOmega = cos(el) d(el) d(az)``).  In direction
components ``cos(el) = sqrt(x^2 + y^2)`` and ``cos(az) = x / cos(el)``.
"""
from __future__ import annotations

import numpy as np
from scipy.special import gammaln

from ..errors import ConfigError

#: Exponents of ``"cos"``: 6 dB half-widths of 60 deg (azimuth), 29.5 deg (elevation).
DEFAULT_COS = (2.0, 10.0)


def _log_wallis(p: float) -> float:
    return 0.5 * np.log(np.pi) + gammaln(0.5 * (p + 1.0)) - gammaln(0.5 * p + 1.0)


def pattern_exponents(pattern) -> tuple[float, float] | None:
    """``(q_az, q_el)`` of a pattern spec, ``None`` for isotropic.

    Parameters
    ----------
    pattern : str or tuple
        ``"iso"`` (``G = 1``), ``"cos"`` (:data:`DEFAULT_COS`) or a pair
        ``(q_az, q_el)`` of exponents >= 0.

    Returns
    -------
    tuple of float or None

    Raises
    ------
    ConfigError
        Any other value.
    """
    if isinstance(pattern, str):
        if pattern == "iso":
            return None
        if pattern == "cos":
            return DEFAULT_COS
        raise ConfigError(f"pattern must be 'iso', 'cos' or (q_az, q_el), got {pattern!r}")
    try:
        qa, qe = (float(v) for v in pattern)
    except (TypeError, ValueError):
        raise ConfigError(f"pattern must be 'iso', 'cos' or (q_az, q_el), got {pattern!r}") from None
    if not (np.isfinite(qa) and np.isfinite(qe) and qa >= 0 and qe >= 0):
        raise ConfigError(f"pattern exponents must be finite and >= 0, got {pattern!r}")
    return qa, qe


def power_gain(pattern, directions: np.ndarray) -> np.ndarray:
    """Linear power gain towards unit ``directions`` in the radar frame.

    Parameters
    ----------
    pattern : str or tuple
        See :func:`pattern_exponents`.
    directions : numpy.ndarray
        ``[..., 3]`` unit vectors, radar frame (``+x`` boresight).

    Returns
    -------
    numpy.ndarray
        ``[...]`` gain (float64) (0 behind the array plane for ``cos^q``).
    """
    d = np.asarray(directions, dtype=np.float64)
    return gain_xy(pattern, d[..., 0], d[..., 1])


def gain_xy(pattern, ux, uy) -> np.ndarray:
    """:func:`power_gain` from the radar-frame ``x`` and ``y`` components of unit directions.

    Parameters
    ----------
    pattern : str or tuple
        See :func:`pattern_exponents`.
    ux, uy : numpy.ndarray
        Same shape: boresight and left components.

    Returns
    -------
    numpy.ndarray
        Gain, in the precision of ``ux``.
    """
    q = pattern_exponents(pattern)
    if q is None:
        return np.ones(np.shape(ux))
    qa, qe = q
    x = np.maximum(ux, 0.0)
    rho2 = np.maximum(ux * ux + uy * uy, 1e-30)
    g0 = float(np.exp(np.log(4.0 * np.pi) - _log_wallis(qa) - _log_wallis(qe + 1.0)))
    half = 0.5 * (qe - qa)
    if qa == int(qa) and half == int(half) and half >= 0:      # cos(az)^qa cos(el)^qe by products
        return np.where(x > 0, g0 * x ** int(qa) * rho2 ** int(half), 0.0)
    with np.errstate(divide="ignore"):
        g = g0 * np.exp(qa * np.log(x) + half * np.log(rho2))
    return np.where(x > 0, g, 0.0)
