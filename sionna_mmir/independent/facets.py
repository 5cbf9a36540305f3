"""Physical-optics weights of the sub-facets of the last (integrated) surface.

Kirchhoff / physical-optics channel of a flat sub-facet ``t`` lit from a
(possibly image) source ``s`` and seen from a receiver ``r`` (scalar,
co-polar; Knott, Shaeffer & Tuley, *Radar Cross Section*, Ch. 5)::

    h = (j / 4 pi) Gamma c_po rho A_t F / (d_s d_r) exp(-j k (d_s + d_r)),
    c_po = (cos_in + cos_t) / 2,   rho = coherent roughness factor,

with ``F`` the exact average of the linear phase over the sub-facet
(:mod:`.quadrature`).  For a flat plate at normal incidence in the far
field this is ``|h| = A / (4 pi R^2)``, i.e. ``sigma = 4 pi A^2 / lambda^2``
in the radar equation ``|h| = lambda sqrt(sigma) / ((4 pi)^{3/2} R^2)``.
The incoherent part (:mod:`.rough`) adds ``lambda sqrt(sigma0 A_t) /
(4 pi)^{3/2}`` with a uniform random phase per sub-facet.
"""
from __future__ import annotations

import numpy as np

from .materials import copol_reflection
from .quadrature import max_subfacet_size, subdivide, triangle_phase_average
from .rough import coherent_factor, kirchhoff_sigma0


def split(tris: np.ndarray, src: np.ndarray, rcv: np.ndarray, k: float, aperture_m: float,
          opts: dict):
    """Sub-facets of ``tris [F, 3, 3]`` for a source ``src`` and receiver ``rcv`` ``[3]``.

    Parameters
    ----------
    tris : numpy.ndarray
        ``[F, 3, 3]`` triangles [m].
    src, rcv : numpy.ndarray
        ``[3]`` (image) source and receiver [m].
    k : float
        Wavenumber [rad/m].
    aperture_m : float
        Array extent [m] (:func:`~.quadrature.max_subfacet_size`).
    opts : dict
        ``fresnel``, ``aperture_phase``, ``max_subfacet``, ``max_split``.

    Returns
    -------
    sub : numpy.ndarray
        ``[S, 3, 3]`` sub-facets.
    parent : numpy.ndarray
        ``[S]`` index into ``tris``.
    """
    r = np.minimum(np.linalg.norm(tris - src, axis=2), np.linalg.norm(tris - rcv, axis=2))
    edge = np.max(np.linalg.norm(tris - np.roll(tris, 1, axis=1), axis=2), axis=1)
    dmax = max_subfacet_size(r.min(axis=1), k, aperture_m, opts["fresnel"],
                             opts["aperture_phase"], opts["max_subfacet"])
    n = np.clip(np.ceil(edge / dmax), 1, opts["max_split"]).astype(np.int64)
    return subdivide(tris, n)


def weights(scene, sub, face, src, rcv, k, frequency_hz, diffuse=False, rng=None):
    """Channel weights ``w [S]`` and centroids ``x [S, 3]`` of sub-facets (module docstring).

    Parameters
    ----------
    scene : SceneMesh
        For normals and materials.
    sub : numpy.ndarray
        ``[S, 3, 3]`` sub-facets [m].
    face : numpy.ndarray
        ``[S]`` scene face of each sub-facet.
    src, rcv : numpy.ndarray
        ``[3]`` (image) source and receiver [m].
    k : float
        Wavenumber [rad/m].
    frequency_hz : float
        Frequency of the material model [Hz].
    diffuse : bool
        Add the incoherent rough-surface term (needs ``rng``).
    rng : numpy.random.Generator or None
        Random phases of the incoherent term.

    Returns
    -------
    x : numpy.ndarray
        ``[S, 3]`` centroids [m].
    w : numpy.ndarray
        ``[S]`` complex128 weights [m^2].
    """
    x = sub.mean(axis=1)
    cr = np.cross(sub[:, 1] - sub[:, 0], sub[:, 2] - sub[:, 0])
    area = 0.5 * np.linalg.norm(cr, axis=1)
    n = cr / (2 * area)[:, None]
    k_in = x - src
    k_in /= np.linalg.norm(k_in, axis=1, keepdims=True)
    u_t = rcv - x
    u_t /= np.linalg.norm(u_t, axis=1, keepdims=True)
    cos_in = np.abs(np.einsum("sk,sk->s", k_in, n))
    cos_t = np.abs(np.einsum("sk,sk->s", u_t, n))
    p = scene.parameters(face, x)
    gamma = copol_reflection(cos_in, p, frequency_hz)
    c_po = 0.5 * (cos_in + cos_t)
    q = k * (k_in - u_t)
    F = triangle_phase_average(q, sub, x)
    w = 1j / (4 * np.pi) * gamma * c_po * coherent_factor(k, p[:, 2], cos_in, cos_t) * F * area
    if diffuse:
        q_z = np.einsum("sk,sk->s", q, n)
        q_t = np.linalg.norm(q - q_z[:, None] * n, axis=1)
        s0 = kirchhoff_sigma0(k, p[:, 2], p[:, 3], np.abs(q_z), q_t, gamma * c_po)
        lam = 2 * np.pi / k
        phase = np.exp(2j * np.pi * rng.random(len(x)))
        w = w + lam * np.sqrt(s0 * area) / (4 * np.pi) ** 1.5 * phase
    return x, w
