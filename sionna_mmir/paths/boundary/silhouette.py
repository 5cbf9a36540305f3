"""Silhouette edges of the scene seen from one point, and stratified samples on them.

An edge ``{a, b}`` of the mesh is a *silhouette* from the viewpoint ``c``
when the geometry next to it lies on one side only of the plane through
``c``, ``a`` and ``b``: a boundary edge (one adjacent face), or an interior
edge whose two apex vertices lie on the same side of that plane (one face
turned towards ``c``, the other away).  Across a silhouette the first
surface a ray from ``c`` meets jumps from the edge's own faces (the *near*
side) to whatever lies behind (the *far* side); these are the visibility
discontinuities whose motion the boundary term integrates.

The candidate edges -- boundary edges and interior edges that are not flat
(:func:`~sionna_mmir.scene.edges.find_diffracting_edges` with a small crease
angle; a flat edge never bounds a silhouette) -- depend only on the mesh
topology and are cached per face array; which of them are silhouettes is
decided per call from the current vertex positions and viewpoint.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...scene.edges import find_diffracting_edges

#: interior edges flatter than this never bound a silhouette [deg]
FLAT_DEG = 0.5


@dataclass
class EdgeSamples:
    """Points on silhouette edges (``M`` samples, detached NumPy float64).

    Parameters
    ----------
    v0, v1 : numpy.ndarray
        ``int64 [M]`` global vertex ids of each sample's edge.
    t : numpy.ndarray
        ``[M]`` position along the edge, ``x = (1 - t) p0 + t p1``.
    point : numpy.ndarray
        ``[M, 3]`` sample points [m].
    far : numpy.ndarray
        ``[M, 3]`` unit vectors perpendicular to the ray from the viewpoint
        and to the edge, pointing to the far side (away from the edge's faces).
    faces : numpy.ndarray
        ``int64 [M, 2]`` adjacent global face ids (``-1`` for none).
    inv_density : numpy.ndarray
        ``[M]`` ``1 / (M p_l)``: the estimator weight of each sample per
        unit edge length [m].
    """

    v0: np.ndarray
    v1: np.ndarray
    t: np.ndarray
    point: np.ndarray
    far: np.ndarray
    faces: np.ndarray
    inv_density: np.ndarray

    def __len__(self) -> int:
        return int(self.t.shape[0])


class SilhouetteEdges:
    """Candidate edges of a global mesh (vertex ids and apexes), cached by topology.

    Parameters
    ----------
    faces : numpy.ndarray
        ``int64 [F, 3]`` global face table.
    positions : numpy.ndarray
        ``[Nv, 3]`` vertex positions [m] (used to drop flat interior edges).
    """

    def __init__(self, faces, positions):
        es = find_diffracting_edges(positions, faces, crease_angle_deg=FLAT_DEG)
        self.v0, self.v1, self.a0, self.a1 = es.v0, es.v1, es.a0, es.a1
        self.faces = es.faces

    @classmethod
    def cached(cls, owner, faces, positions) -> "SilhouetteEdges":
        """The candidates of ``faces``, kept on ``owner`` while the face table is unchanged."""
        key = (faces.shape, hash(faces.tobytes()))
        hit = getattr(owner, "_mmir_silhouette", None)
        if hit is None or hit[0] != key:
            hit = (key, cls(faces, positions))
            owner._mmir_silhouette = hit
        return hit[1]

    def silhouettes(self, V, c, bore=None, cos_cone=-1.0):
        """Indices of the candidates that are silhouettes from ``c`` and lie
        (in part) inside the cone ``dot(d, bore) >= cos_cone``."""
        p0, p1 = V[self.v0] - c, V[self.v1] - c
        m = np.cross(p0, p1)
        s0 = np.einsum("ij,ij->i", m, V[self.a0] - c)
        s1 = np.einsum("ij,ij->i", m, V[self.a1] - c)
        sil = (s0 * s1 > 0) | (self.a0 == self.a1)
        sil &= np.linalg.norm(m, axis=1) > 1e-12
        if bore is not None:
            u0 = p0 @ bore / np.maximum(np.linalg.norm(p0, axis=1), 1e-12)
            u1 = p1 @ bore / np.maximum(np.linalg.norm(p1, axis=1), 1e-12)
            sil &= np.maximum(u0, u1) >= cos_cone - 0.05
        return np.flatnonzero(sil)

    def sample(self, V, c, M: int, seed: int, bore=None, cos_cone=-1.0) -> EdgeSamples | None:
        """``M`` stratified samples on the silhouettes from ``c``, spread in
        proportion to each edge's angular length (``None`` if there are none).

        Parameters
        ----------
        V : numpy.ndarray
            ``[Nv, 3]`` vertex positions [m].
        c : numpy.ndarray
            ``[3]`` viewpoint [m].
        M : int
            Number of samples.
        seed : int
            Seed of the strata offsets.
        bore, cos_cone : numpy.ndarray, float
            Keep edges reaching into the cone about ``bore``.
        """
        idx = self.silhouettes(V, c, bore, cos_cone)
        if idx.size == 0:
            return None
        P0, P1 = V[self.v0[idx]], V[self.v1[idx]]
        d0 = (P0 - c) / np.linalg.norm(P0 - c, axis=1, keepdims=True)
        d1 = (P1 - c) / np.linalg.norm(P1 - c, axis=1, keepdims=True)
        ang = np.linalg.norm(d1 - d0, axis=1) + 1e-12           # chord on the unit sphere
        cdf = np.cumsum(ang)
        total = cdf[-1]
        u = (np.arange(M) + np.random.default_rng(int(seed)).random(M)) / M * total
        e = np.minimum(np.searchsorted(cdf, u, side="right"), idx.size - 1)
        t = (u - (cdf[e] - ang[e])) / ang[e]
        t = np.clip(t, 1e-4, 1.0 - 1e-4)
        length = np.linalg.norm(P1 - P0, axis=1)
        point = P0[e] + t[:, None] * (P1 - P0)[e]
        # density per unit edge length of the chosen edge: (ang / total) / length
        inv_density = total / (ang[e] / np.maximum(length[e], 1e-12)) / M
        ray = point - c
        ray /= np.linalg.norm(ray, axis=1, keepdims=True)
        tang = (P1 - P0)[e] / np.maximum(length[e], 1e-12)[:, None]
        n = np.cross(ray, tang)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        apex = V[self.a0[idx][e]]
        n *= -np.sign(np.einsum("ij,ij->i", n, apex - point))[:, None]
        return EdgeSamples(v0=self.v0[idx][e], v1=self.v1[idx][e], t=t, point=point, far=n,
                           faces=self.faces[idx][e], inv_density=inv_density)
