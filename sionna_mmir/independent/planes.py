"""Planar pieces: the faces of a scene grouped by the plane they lie in.

Faces are grouped by their plane ``(n, d)`` (unit normal up to sign,
``n . y = d``) rounded to ``tol`` (about 1e-5 rad / 1e-5 m by default).  A
piece may hold disjoint parts of one plane (wall segments around an
opening) and parts of several objects.  Rounding can split a plane into two
pieces at a bin edge; image theory is additive over a partition of the
mirror, so this costs time, not accuracy.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .mesh import SceneMesh


@dataclass
class Piece:
    """One planar piece.

    Attributes
    ----------
    normal : numpy.ndarray
        ``[3]`` unit normal (sign canonical: first non-zero component > 0).
    offset : float
        ``d`` of ``normal . y = d`` [m].
    faces : numpy.ndarray
        ``[m]`` int64 face indices into the scene.
    triangles : numpy.ndarray
        ``[m, 3, 3]`` their corners projected onto the plane [m].
    """

    normal: np.ndarray
    offset: float
    faces: np.ndarray
    triangles: np.ndarray

    def __post_init__(self):
        self.tri_lo = self.triangles.min(axis=1)               # [m, 3] per-triangle boxes
        self.tri_hi = self.triangles.max(axis=1)
        self.lo, self.hi = self.tri_lo.min(axis=0), self.tri_hi.max(axis=0)

    def mirror(self, points: np.ndarray) -> np.ndarray:
        """Mirror images of ``points [..., 3]`` in the piece's plane."""
        s = points @ self.normal - self.offset
        return points - 2.0 * s[..., None] * self.normal

    def reflection(self) -> np.ndarray:
        """``[3, 3]`` linear part of :meth:`mirror` (``I - 2 n n^T``)."""
        return np.eye(3) - 2.0 * np.outer(self.normal, self.normal)


def planar_pieces(scene: SceneMesh, tol: float = 1e-5) -> list[Piece]:
    """Group the faces of ``scene`` into :class:`Piece` objects.

    Parameters
    ----------
    scene : SceneMesh
        The scene.
    tol : float
        Rounding of the normal components and of ``d`` [m].

    Returns
    -------
    list of Piece
    """
    tri = scene.triangles
    n = scene.normals
    first = np.argmax(np.abs(n) > 1e-9, axis=1)
    sign = np.sign(n[np.arange(len(n)), first])
    n = n * sign[:, None]
    d = np.einsum("fk,fk->f", n, tri.mean(axis=1))
    key = np.round(np.column_stack([n, d]) / tol).astype(np.int64)
    _, label = np.unique(key, axis=0, return_inverse=True)
    label = label.ravel()
    pieces = []
    for g in range(label.max() + 1):
        faces = np.flatnonzero(label == g)
        w = np.linalg.norm(np.cross(tri[faces, 1] - tri[faces, 0], tri[faces, 2] - tri[faces, 0]),
                           axis=1)
        nn = (n[faces] * w[:, None]).sum(axis=0)
        nn /= np.linalg.norm(nn)
        dd = float(np.sum(d[faces] * w) / w.sum())
        t = tri[faces]
        t = t - ((t @ nn) - dd)[..., None] * nn
        pieces.append(Piece(nn, dd, faces, t))
    return pieces
