"""Sub-facet splitting and the exact linear-phase integral over a triangle.

A triangle of longest edge ``D`` is split into ``n^2`` congruent
sub-triangles (the barycentric grid of step ``1/n``) with
``D / n <= D_max``::

    D_max = min( sqrt(fresnel R / k),  aperture R / (k A),  max_subfacet )

``R`` is the shorter leg (source or receiver side) at the triangle's nearest
corner and ``A = max|tx - c| + max|rx - c|`` the array's extent about its
centre ``c``.  The first bound keeps the quadratic (Fresnel) phase
``k D^2 / R`` of a sub-facet below ``fresnel`` rad, the second the change of
the linear phase gradient between array elements across it below
``aperture`` rad.  The remaining linear phase is integrated exactly
(Gordon, IEEE Trans. AP-23, 1975, in divided-difference form)::

    F = (1/A_t) int_t exp(-j q.(y - x)) dA(y) = 2 exp(-j q.(P0 - x)) exp[0, -j a, -j b]

with ``a = q.(P1 - P0)``, ``b = q.(P2 - P0)`` and ``exp[z0, z1, z2]`` the
second divided difference of ``exp`` (Hermite-Genocchi:
``int_simplex exp(u z1 + v z2) du dv``).  ``x`` is the sub-facet centroid.
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


def _phi1(z):
    """``(e^z - 1) / z``."""
    small = np.abs(z) < _SMALL_Z
    zs = np.where(small, 1.0, z)
    return np.where(small, 1 + z / 2 + z * z / 6 + z ** 3 / 24, (np.exp(zs) - 1) / zs)


def _phi1_prime(z):
    """``d/dz (e^z - 1) / z = ((z - 1) e^z + 1) / z^2``."""
    small = np.abs(z) < _SMALL_Z
    zs = np.where(small, 1.0, z)
    series = 0.5 + z / 3 + z * z / 8 + z ** 3 / 30 + z ** 4 / 144
    return np.where(small, series, ((zs - 1) * np.exp(zs) + 1) / (zs * zs))


def triangle_phase_average(q: np.ndarray, tri: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``F`` of the module docstring.

    Parameters
    ----------
    q : numpy.ndarray
        ``[S, 3]`` phase gradient [rad/m].
    tri : numpy.ndarray
        ``[S, 3, 3]`` triangle corners [m].
    x : numpy.ndarray
        ``[S, 3]`` phase reference point [m].

    Returns
    -------
    numpy.ndarray
        ``[S]`` complex128, ``|F| <= 1``.
    """
    z1 = -1j * np.einsum("sk,sk->s", q, tri[:, 1] - tri[:, 0])
    z2 = -1j * np.einsum("sk,sk->s", q, tri[:, 2] - tri[:, 0])
    dz = z1 - z2
    close = np.abs(dz) < _CLOSE
    dd = np.where(close, _phi1_prime(0.5 * (z1 + z2)),
                  (_phi1(z1) - _phi1(z2)) / np.where(close, 1.0, dz))
    return 2.0 * np.exp(-1j * np.einsum("sk,sk->s", q, tri[:, 0] - x)) * dd
