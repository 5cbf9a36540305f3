"""Sub-facet grids and the exact integral of a linear phase over a triangle.

A triangle of longest edge ``D`` is split into ``n^2`` congruent
sub-triangles (the barycentric grid of step ``1/n``) with
``D / n <= D_max``::

    D_max = min( sqrt(fresnel R / k),  aperture R / (k A),  max_subfacet )

``R`` is the shorter leg (source or receiver side) at the triangle's nearest
corner and ``A = max|tx - c| + max|rx - c|`` the array's extent about its
centre ``c``.  The first bound keeps the quadratic (Fresnel) phase
``k D^2 / R`` of a sub-facet below ``fresnel`` rad, the second the change of
the phase gradient between array elements across it below ``aperture`` rad.

On each sub-facet the path length is replaced by its linear interpolant
between the three corners, whose phase integrates exactly (Gordon, IEEE
Trans. AP-23, 1975, here in divided-difference form)::

    (1/A_t) int_t exp(-j k L_lin(y)) dA(y) = 2 exp(-j k L(v_0)) exp[0, -j t_1, -j t_2],
    t_m = k (L(v_m) - L(v_0)),

with ``exp[z0, z1, z2]`` the second divided difference of ``exp``
(Hermite-Genocchi: ``int_{u, v >= 0, u + v <= 1} exp(u z1 + v z2) du dv``),
evaluated with series near coincident nodes.
"""
from __future__ import annotations

import numpy as np

_SMALL_Z = 1e-2     # series below this |z|
_CLOSE = 1e-4       # |z1 - z2| below which the confluent form is used


def max_subfacet_size(r_near, k, aperture_m, fresnel=0.3, aperture=1.0, cap=None):
    """Largest sub-facet edge ``D_max`` [m] at distance ``r_near`` [m] (module docstring).

    Parameters
    ----------
    r_near : numpy.ndarray
        ``[F]`` shorter leg at the nearest corner [m].
    k : float
        Wavenumber [rad/m].
    aperture_m : float
        Array extent ``A`` [m].
    fresnel, aperture : float
        Phase bounds [rad].
    cap : float or None
        Absolute cap [m].

    Returns
    -------
    numpy.ndarray
        ``[F]`` float64 [m].
    """
    r = np.maximum(np.asarray(r_near, dtype=np.float64), 1e-3)
    d = np.sqrt(fresnel * r / k)
    if aperture_m > 0:
        d = np.minimum(d, aperture * r / (k * aperture_m))
    if cap is not None:
        d = np.minimum(d, float(cap))
    return d


def subdivide(tri: np.ndarray, n: np.ndarray):
    """Split triangle ``f`` into ``n[f]^2`` congruent sub-triangles.

    Parameters
    ----------
    tri : numpy.ndarray
        ``[F, 3, 3]`` corners [m].
    n : numpy.ndarray
        ``[F]`` int >= 1 splits per edge.

    Returns
    -------
    sub : numpy.ndarray
        ``[S, 3, 3]`` sub-triangle corners (same winding as the parent).
    parent : numpy.ndarray
        ``[S]`` int64 index into ``tri``.
    """
    subs, parents = [np.zeros((0, 3, 3))], [np.zeros(0, np.int64)]
    for m in np.unique(n):
        idx = np.flatnonzero(n == m)
        cells = _cells(int(m))                                   # [m^2, 3, 2]
        t = tri[idx]
        e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
        pts = (t[:, None, None, 0, :] + cells[None, ..., 0, None] * e1[:, None, None]
               + cells[None, ..., 1, None] * e2[:, None, None])  # [f, m^2, 3, 3]
        subs.append(pts.reshape(-1, 3, 3))
        parents.append(np.repeat(idx, len(cells)))
    return np.concatenate(subs), np.concatenate(parents)


def _cells(n: int) -> np.ndarray:
    """Barycentric ``(u, v)`` corners ``[n^2, 3, 2]`` of the grid of step ``1/n``."""
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    up = (i + j) <= n - 1
    down = (i + j) <= n - 2
    iu, ju, idn, jdn = i[up], j[up], i[down], j[down]
    upright = np.stack([np.stack([iu, ju], -1), np.stack([iu + 1, ju], -1),
                        np.stack([iu, ju + 1], -1)], axis=1)
    inverted = np.stack([np.stack([idn + 1, jdn], -1), np.stack([idn + 1, jdn + 1], -1),
                         np.stack([idn, jdn + 1], -1)], axis=1)
    return np.concatenate([upright, inverted]).astype(np.float64) / n


def _phi1(t, c, s):
    """``phi1(-j t) = (e^{-j t} - 1) / (-j t) = sin(t) / t + j (cos(t) - 1) / t``.

    ``c, s`` are ``cos t``, ``sin t`` (``t`` real).
    """
    small = np.abs(t) < _SMALL_Z
    inv = 1.0 / np.where(small, 1.0, t)
    out = np.empty(t.shape, np.complex128)
    out.real = s * inv
    out.imag = (c - 1) * inv
    if small.any():
        ts = t[small]
        out[small] = (1 - ts * ts / 6) + 1j * (-ts / 2 + ts ** 3 / 24)
    return out


def _phi1_prime(t):
    """``phi1'(-j t) = (cos t + t sin t - 1) / t^2 + j (t cos t - sin t) / t^2``."""
    small = np.abs(t) < _SMALL_Z
    ts = np.where(small, 1.0, t)
    c, s = np.cos(ts), np.sin(ts)
    re = np.where(small, 0.5 - t * t / 8 + t ** 4 / 144, (c + ts * s - 1) / (ts * ts))
    im = np.where(small, -t / 3 + t ** 3 / 30, (ts * c - s) / (ts * ts))
    return re + 1j * im


def _simplex(t1, cs1, t2, cs2):
    """``exp[0, -j t1, -j t2]`` from the phases and their ``(cos, sin)``."""
    dt = t1 - t2
    close = np.abs(dt) < _CLOSE
    out = (_phi1(t1, *cs1) - _phi1(t2, *cs2)) * 1j / np.where(close, 1.0, dt)
    if close.any():
        out[close] = _phi1_prime(0.5 * (t1[close] + t2[close]))
    return out


def simplex_exp(t1, t2):
    """``exp[0, -j t1, -j t2] = int_{u, v >= 0, u + v <= 1} exp(-j (u t1 + v t2)) du dv``.

    Parameters
    ----------
    t1, t2 : numpy.ndarray
        ``[S]`` real phases [rad].

    Returns
    -------
    numpy.ndarray
        ``[S]`` complex128 (``1/2`` at ``t1 = t2 = 0``).
    """
    t1, t2 = np.atleast_1d(np.asarray(t1, np.float64)), np.atleast_1d(np.asarray(t2, np.float64))
    return _simplex(t1, (np.cos(t1), np.sin(t1)), t2, (np.cos(t2), np.sin(t2)))


def simplex_exp_grad(t1, t2, h: float = 1e-4):
    """``E = exp[0, z1, z2]`` at ``z = -j t`` and its complex derivatives in ``z1``, ``z2``.

    Central differences along the imaginary axis (``E`` is entire:
    ``dE/dz = (E(z + j h) - E(z - j h)) / (2 j h)``), error ``~ h^2 / 24``
    plus rounding ``~ 1e-16 / h``; the shifted sines and cosines come from
    the addition theorems (two trigonometric pairs per sub-facet).

    Returns
    -------
    tuple of numpy.ndarray
        ``E, dE/dz1, dE/dz2``, each ``[S]`` complex128.
    """
    t1, t2 = np.asarray(t1, np.float64), np.asarray(t2, np.float64)
    ch, sh = np.cos(h), np.sin(h)
    c1, s1, c2, s2 = np.cos(t1), np.sin(t1), np.cos(t2), np.sin(t2)
    a1, a2 = (c1, s1), (c2, s2)
    m1, p1 = (c1 * ch + s1 * sh, s1 * ch - c1 * sh), (c1 * ch - s1 * sh, s1 * ch + c1 * sh)
    m2, p2 = (c2 * ch + s2 * sh, s2 * ch - c2 * sh), (c2 * ch - s2 * sh, s2 * ch + c2 * sh)
    e = _simplex(t1, a1, t2, a2)
    d1 = (_simplex(t1 - h, m1, t2, a2) - _simplex(t1 + h, p1, t2, a2)) / (2j * h)
    d2 = (_simplex(t1, a1, t2 - h, m2) - _simplex(t1, a1, t2 + h, p2)) / (2j * h)
    return e, d1, d2
