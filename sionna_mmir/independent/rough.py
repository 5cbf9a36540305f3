"""Rough surfaces: coherent (Rayleigh) loss and the incoherent Kirchhoff sigma0.

Model: a surface with Gaussian heights of rms ``sigma_h`` and Gaussian
correlation ``exp(-r^2 / l_c^2)`` under the scalar Kirchhoff (physical
optics) approximation, mean-surface Fresnel coefficient ``Gamma`` at the
local angle (Beckmann & Spizzichino 1963; Ulaby, Moore & Fung, *Microwave
Remote Sensing* II, Sec. 12-3).  With the path-phase gradient
``q = k (k_in - u_t)`` (``k_in`` incident propagation direction, ``u_t``
unit vector to the receiver), ``q_z = k (cos_in + cos_t)`` its normal and
``q_t`` its tangential magnitude, ``g = (q_z sigma_h)^2``:

* coherent field factor ``exp(-g / 2)`` (power ``exp(-g)``; monostatic
  ``exp(-(2 k sigma_h cos)^2)``);
* incoherent bistatic sigma0 (dimensionless, per unit area)::

      sigma0 = k^2 l_c^2 |Gamma c_po|^2 exp(-g) sum_{n>=1} g^n / (n! n) exp(-q_t^2 l_c^2 / (4 n))

  with ``c_po = (cos_in + cos_t) / 2``; monostatic it is the familiar
  ``(k l cos)^2 |Gamma|^2 exp(-4 k^2 s^2 cos^2) sum (4k^2 s^2 cos^2)^n / (n! n)
  exp(-(k l sin)^2 / n)``.

Limits: valid for ``k l_c >~ 6`` and gentle slopes (``sigma_h / l_c <~ 0.3``);
no shadowing function, no multiple scattering on the surface, and
depolarisation is ignored (the co-polar ``Gamma``).
"""
from __future__ import annotations

import numpy as np
from scipy.special import gammaln, logsumexp

_CHUNK = 100_000


def coherent_factor(k: float, sigma_h, cos_in, cos_out) -> np.ndarray:
    """Field factor ``exp(-(k sigma_h (cos_in + cos_out))^2 / 2)`` ``[N]``.

    Parameters
    ----------
    k : float
        Wavenumber [rad/m].
    sigma_h : array_like
        ``[N]`` rms height [m].
    cos_in, cos_out : array_like
        ``[N]`` cosines of the incident and outgoing angles.
    """
    g = (k * np.asarray(sigma_h) * (np.abs(cos_in) + np.abs(cos_out))) ** 2
    return np.exp(-0.5 * g)


def kirchhoff_sigma0(k: float, sigma_h, l_c, q_z, q_t, gamma_cpo) -> np.ndarray:
    """Incoherent sigma0 of the module docstring ``[N]`` (dimensionless).

    Parameters
    ----------
    k : float
        Wavenumber [rad/m].
    sigma_h, l_c : array_like
        ``[N]`` rms height and correlation length [m].
    q_z, q_t : array_like
        ``[N]`` normal and tangential magnitudes of the phase gradient [rad/m].
    gamma_cpo : array_like
        ``[N]`` ``|Gamma c_po|`` (complex allowed; its magnitude is used).

    Returns
    -------
    numpy.ndarray
        ``[N]`` float64.
    """
    sigma_h, l_c, q_z, q_t = (np.asarray(v, dtype=np.float64) for v in (sigma_h, l_c, q_z, q_t))
    amp2 = np.abs(np.asarray(gamma_cpo)) ** 2
    out = np.zeros(len(sigma_h))
    g = (q_z * sigma_h) ** 2
    for s in range(0, len(g), _CHUNK):
        sl = slice(s, s + _CHUNK)
        gs = g[sl]
        live = gs > 1e-12
        if not live.any():
            continue
        gmax = float(gs.max())
        n = np.arange(1, int(np.ceil(gmax + 8 * np.sqrt(gmax) + 12)) + 1, dtype=np.float64)
        lg = np.log(np.where(live, gs, 1.0))[:, None]
        terms = (n * lg - gammaln(n + 1) - np.log(n)
                 - (q_t[sl, None] * l_c[sl, None]) ** 2 / (4 * n))
        series = logsumexp(terms, axis=1) - gs
        val = (k * l_c[sl]) ** 2 * amp2[sl] * np.exp(series)
        out[sl] = np.where(live, val, 0.0)
    return out
