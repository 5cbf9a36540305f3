"""Physical-optics weights of the sub-facets of the last (integrated) surface.

Kirchhoff / physical-optics channel of a flat sub-facet ``t`` lit from a
(possibly image) source ``s`` and seen from a receiver ``r`` (scalar,
co-polar; Knott, Shaeffer & Tuley, *Radar Cross Section*, Ch. 5)::

    h = (j / 4 pi) Gamma c_po rho A_t F / (d_s d_r) exp(-j k (d_s + d_r)),
    c_po = (cos_in + cos_t) / 2,   rho = coherent roughness factor,

with ``F`` the average of the phase over the sub-facet (:mod:`.quadrature`,
applied per pair in :mod:`.accumulate`).  For a flat plate at normal incidence in the far
field this is ``|h| = A / (4 pi R^2)``, i.e. ``sigma = 4 pi A^2 / lambda^2``
in the radar equation ``|h| = lambda sqrt(sigma) / ((4 pi)^{3/2} R^2)``.
The incoherent part (:mod:`.rough`) adds ``lambda sqrt(sigma0 A_t) /
(4 pi)^{3/2}`` with a uniform random phase per sub-facet.
"""
from __future__ import annotations

import numpy as np

from .materials import copol_reflection
from .quadrature import max_subfacet_size, subdivide
from .rough import coherent_factor, kirchhoff_sigma0


def _near(tris, src, rcv):
    """Shorter leg at the nearest corner ``[F]`` [m]."""
    return np.minimum(np.linalg.norm(tris - src, axis=2),
                      np.linalg.norm(tris - rcv, axis=2)).min(axis=1)


def _longest_edge(tris):
    return np.max(np.linalg.norm(tris - np.roll(tris, 1, axis=1), axis=2), axis=1)


def presplit(tris, src, rcv, ratio: float = 0.25, max_level: int = 10):
    """Midpoint-split (4:1) triangles until the longest edge is ``<= ratio`` x their range.

    Keeps the sub-facet size (which grows with range) nearly uniform inside
    each piece, so that far parts of a large triangle are not split as
    finely as its near corner.

    Returns
    -------
    tris : numpy.ndarray
        ``[F', 3, 3]`` pieces.
    parent : numpy.ndarray
        ``[F']`` index into the input.
    """
    done, done_parent = [], []
    parent = np.arange(len(tris))
    for _ in range(max_level):
        big = _longest_edge(tris) > ratio * _near(tris, src, rcv)
        done.append(tris[~big])
        done_parent.append(parent[~big])
        tris, parent = tris[big], parent[big]
        if not len(tris):
            break
        m = 0.5 * (tris + np.roll(tris, -1, axis=1))            # midpoints of edges 01, 12, 20
        p0, p1, p2, m01, m12, m20 = tris[:, 0], tris[:, 1], tris[:, 2], m[:, 0], m[:, 1], m[:, 2]
        tris = np.concatenate([np.stack(c, axis=1) for c in
                               ((p0, m01, m20), (m01, p1, m12), (m20, m12, p2), (m01, m12, m20))])
        parent = np.tile(parent, 4)
    done.append(tris)
    done_parent.append(parent)
    return np.concatenate(done), np.concatenate(done_parent)


def split(tris: np.ndarray, src: np.ndarray, rcv: np.ndarray, k: float, aperture_m: float,
          opts: dict, aperture_phase: float | None = None, vis_cell: float | None = None):
    """Sub-facets of ``tris [F, 3, 3]`` for a source ``src`` and receiver ``rcv`` ``[3]``.

    Triangles are first split by :func:`presplit`, then each piece into
    ``n^2`` congruent sub-facets with ``D / n <= D_max`` at the piece's range
    (:func:`~.quadrature.max_subfacet_size`).  With ``vis_cell`` the split is
    done in two levels: visibility cells of edge ``<= max(vis_cell, D_max)``,
    each split into congruent sub-facets (that share its visibility).

    Parameters
    ----------
    tris : numpy.ndarray
        ``[F, 3, 3]`` triangles [m].
    src, rcv : numpy.ndarray
        ``[3]`` (image) source and receiver [m].
    k : float
        Wavenumber [rad/m].
    aperture_m : float
        Array extent [m].
    opts : dict
        ``fresnel``, ``aperture_phase``, ``max_subfacet``, ``max_split``.
    aperture_phase : float or None
        Overrides ``opts["aperture_phase"]``.
    vis_cell : float or None
        Edge of the visibility cells [m]; None: every sub-facet is one.

    Returns
    -------
    sub : numpy.ndarray
        ``[S, 3, 3]`` sub-facets.
    parent : numpy.ndarray
        ``[S]`` index into ``tris``.
    cells : numpy.ndarray
        ``[C, 3, 3]`` visibility cells (``sub`` itself without ``vis_cell``).
    cell : numpy.ndarray
        ``[S]`` index into ``cells``.
    """
    pieces, owner = presplit(tris, src, rcv)
    ap = opts["aperture_phase"] if aperture_phase is None else aperture_phase
    dmax = max_subfacet_size(_near(pieces, src, rcv), k, aperture_m, opts["fresnel"], ap,
                             opts["max_subfacet"])
    edge = _longest_edge(pieces)
    n = np.clip(np.ceil(edge / dmax), 1, opts["max_split"]).astype(np.int64)
    if vis_cell is None:
        sub, piece = subdivide(pieces, n)
        return sub, owner[piece], sub, np.arange(len(sub))
    n2 = np.minimum(np.floor(vis_cell / dmax), n).astype(np.int64)     # sub-facets per cell edge
    n1 = np.ceil(n / np.maximum(n2, 1)).astype(np.int64)
    n2 = np.ceil(n / n1).astype(np.int64)
    single = (n2 <= 1) | (n1 * n2 > 1.07 * n)               # no gain, or too many extra cells
    n1, n2 = np.where(single, n, n1), np.where(single, 1, n2)
    cells, cpiece = subdivide(pieces, n1)
    sub, cell = subdivide(cells, n2[cpiece])
    return sub, owner[cpiece[cell]], cells, cell


def weights(scene, sub, face, src, rcv, k, frequency_hz, diffuse=False, rng=None):
    """Coherent and incoherent channel weights of sub-facets (module docstring).

    The phase average ``F`` and the per-pair terms are applied later
    (:mod:`.accumulate`); here are the angle-dependent factors at the
    centroid, seen from the array centre.

    Parameters
    ----------
    scene : SceneMesh
        For materials.
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
        Also return the incoherent rough-surface term (needs ``rng``).
    rng : numpy.random.Generator or None
        Random phases of the incoherent term.

    Returns
    -------
    w_coh : numpy.ndarray
        ``[S]`` complex128 ``(j / 4 pi) Gamma c_po rho A`` [m^2].
    w_diff : numpy.ndarray or None
        ``[S]`` complex128 ``lambda sqrt(sigma0 A) / (4 pi)^{3/2} e^{j psi}`` [m^2].
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
    w_coh = 1j / (4 * np.pi) * gamma * c_po * coherent_factor(k, p[:, 2], cos_in, cos_t) * area
    if not diffuse:
        return w_coh, None
    q = k * (k_in - u_t)
    q_z = np.einsum("sk,sk->s", q, n)
    q_t = np.linalg.norm(q - q_z[:, None] * n, axis=1)
    s0 = kirchhoff_sigma0(k, p[:, 2], p[:, 3], np.abs(q_z), q_t, gamma * c_po)
    phase = np.exp(2j * np.pi * rng.random(len(x)))
    return w_coh, (2 * np.pi / k) * np.sqrt(s0 * area) / (4 * np.pi) ** 1.5 * phase
