"""Planar convex polygons in 3-D: half-space clipping and central projection.

A polygon is a ``[m, 3]`` float64 array of corners in order (metres).  A
half-space is ``(n, d)``: the points with ``n . y - d >= 0``.  Clipping a
convex polygon by a half-space is one Sutherland-Hodgman pass (Sutherland &
Hodgman, CACM 17, 1974); intersecting with a triangle is three passes, one
per edge (the plane through the edge that contains the triangle normal).
"""
from __future__ import annotations

import numpy as np

#: Polygons smaller than this are dropped [m^2].
MIN_POLY_AREA = 1e-10


def clip(poly: np.ndarray, n: np.ndarray, d: float) -> np.ndarray:
    """Part of ``poly`` with ``n . y >= d``.

    Parameters
    ----------
    poly : numpy.ndarray
        ``[m, 3]`` convex polygon.
    n : numpy.ndarray
        ``[3]`` half-space normal.
    d : float
        Offset.

    Returns
    -------
    numpy.ndarray
        ``[m', 3]`` (``m' = 0`` when nothing is left).
    """
    if len(poly) == 0:
        return poly
    s = (poly @ n - d).tolist()
    if min(s) >= 0:
        return poly
    if max(s) <= 0:
        return poly[:0]
    out = []
    m = len(poly)
    for i in range(m):
        j = (i + 1) % m
        if s[i] >= 0:
            out.append(poly[i])
        if (s[i] >= 0) != (s[j] >= 0):
            t = s[i] / (s[i] - s[j])
            out.append(poly[i] + t * (poly[j] - poly[i]))
    return np.asarray(out) if len(out) >= 3 else poly[:0]


def triangle_halfspaces(tri: np.ndarray):
    """The three inward edge half-spaces ``[(n, d)]`` of a triangle ``[3, 3]``."""
    normal = np.cross(tri[1] - tri[0], tri[2] - tri[0])
    ne = np.cross(normal[None], np.roll(tri, -1, axis=0) - tri)
    d = np.einsum("ik,ik->i", ne, tri)
    return [(ne[i], float(d[i])) for i in range(3)]


def clip_to_triangle(poly: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Intersection of a convex polygon with a coplanar triangle ``[3, 3]``."""
    for n, d in triangle_halfspaces(tri):
        poly = clip(poly, n, d)
        if len(poly) == 0:
            break
    return poly


def project(poly: np.ndarray, source: np.ndarray, n: np.ndarray, d: float) -> np.ndarray:
    """Central projection of ``poly`` from ``source`` onto the plane ``n . y = d``.

    Every corner must lie strictly between the source and the plane (the
    caller clips first); corner ``y`` maps to ``source + t (y - source)``
    with ``t = (d - n . source) / (n . (y - source))``.
    """
    v = poly - source
    t = (d - n @ source) / (v @ n)
    return source + t[:, None] * v


def area(poly: np.ndarray) -> float:
    """Area of a planar polygon [m^2]."""
    if len(poly) < 3:
        return 0.0
    c = np.cross(poly[1:-1] - poly[0], poly[2:] - poly[0]).sum(axis=0)
    return 0.5 * float(np.sqrt(c @ c))


def fan(poly: np.ndarray) -> np.ndarray:
    """Fan triangulation ``[m - 2, 3, 3]`` of a convex polygon."""
    m = len(poly)
    idx = np.stack([np.zeros(m - 2, int), np.arange(1, m - 1), np.arange(2, m)], axis=1)
    return poly[idx]
