"""Image-theory chains over planar pieces: the lit regions of double / triple bounces.

A chain ``(P_1, ..., P_n)`` (Tx side first) reflects specularly on
``P_1 .. P_{n-1}`` and is integrated by physical optics over the last piece
``P_n``.  With ``M_k`` the mirror in the plane of ``P_k`` and ``c`` the
array centre, the images are ``s_0 = c``, ``s_k = M_k(s_{k-1})``; a point
``x`` of ``P_n`` is lit through the chain when the straight line
``s_{n-1} -> x`` crosses ``P_{n-1}`` at ``p_{n-1}``, the line
``s_{n-2} -> p_{n-1}`` crosses ``P_{n-2}``, and so on (geometric optics on
the mirrors).  The lit region is built exactly, by beam tracing with convex
polygons (Heckbert & Hanrahan, SIGGRAPH 1984): the region on ``P_k`` is
clipped to ``0 < f(y) < f(s_{k-1})`` (``f`` the signed distance to the next
plane, oriented towards ``s_{k-1}``), projected from ``s_{k-1}`` onto the
next plane and intersected with that piece's triangles.  Occlusion by other
objects is tested later per sub-facet, on the real (folded) segments.
Every ordered chain is enumerated, so both orders of a pair of pieces (and
all six of a corner's three) appear once each.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import polygons as pg
from .planes import Piece

_MARGIN = 1e-9        # [m] keeps projected corners off the source / plane


@dataclass
class Chain:
    """Lit region of one chain.

    Attributes
    ----------
    pieces : tuple of int
        Piece indices, Tx side first; the last is integrated.
    regions : list of tuple
        ``(polygon [m, 3], faces)`` on the last piece; ``faces`` are the
        scene faces (one per piece) the polygon's rays cross.
    """

    pieces: tuple
    regions: list


def mirror_map(piece: Piece):
    """``(L [3, 3], o [3])`` with ``M(y) = L y + o``, the mirror in ``piece``'s plane."""
    return piece.reflection(), 2.0 * piece.offset * piece.normal


def compose(outer, inner):
    """Affine map ``outer o inner`` as ``(L, o)``."""
    return outer[0] @ inner[0], outer[0] @ inner[1] + outer[1]


def image_sources(pieces: list, seq, c: np.ndarray) -> list:
    """``[s_0 = c, s_1, ..., s_n]`` for the chain ``seq``."""
    out = [np.asarray(c, dtype=np.float64)]
    for p in seq:
        out.append(pieces[p].mirror(out[-1]))
    return out


def _extend(regions, src, piece: Piece):
    """Regions on the next ``piece`` lit from ``src`` through ``regions``."""
    f_src = src @ piece.normal - piece.offset
    if abs(f_src) < 1e-9:
        return []
    n = np.sign(f_src) * piece.normal
    d = np.sign(f_src) * piece.offset
    out = []
    for poly, faces in regions:
        poly = pg.clip(poly, n, d + _MARGIN)
        poly = pg.clip(poly, -n, -(n @ src) + _MARGIN)
        if len(poly) == 0:
            continue
        proj = pg.project(poly, src, piece.normal, piece.offset)
        plo, phi = proj.min(axis=0) - 1e-9, proj.max(axis=0) + 1e-9
        if np.any(phi < piece.lo) or np.any(plo > piece.hi):
            continue
        near = np.flatnonzero(np.all(piece.tri_hi >= plo, axis=1) & np.all(piece.tri_lo <= phi, axis=1))
        for t in near:
            q = pg.clip_to_triangle(proj, piece.triangles[t])
            if len(q) and pg.area(q) > pg.MIN_POLY_AREA:
                out.append((q, faces + (int(piece.faces[t]),)))
    return out


def _feasible(regions, src, pieces: list, exclude: int) -> np.ndarray:
    """Pieces that some region corner could reach from ``src`` (a cheap pre-test)."""
    corners = np.concatenate([p for p, _ in regions])
    nrm = np.array([p.normal for p in pieces])
    off = np.array([p.offset for p in pieces])
    f_src = nrm @ src - off
    f_v = corners @ nrm.T - off                                   # [m, N]
    s = np.sign(f_src)
    ok = np.any((s * f_v > _MARGIN) & (s * (f_src - f_v) > _MARGIN), axis=0)
    ok[exclude] = False
    return np.flatnonzero(ok)


def chains(pieces: list, c: np.ndarray, max_depth: int) -> list[Chain]:
    """All chains of 2..``max_depth`` pieces with a non-empty lit region.

    Parameters
    ----------
    pieces : list of Piece
        Planar pieces of the scene.
    c : numpy.ndarray
        ``[3]`` array centre [m] (source and receiver of the masks).
    max_depth : int
        Longest chain (number of interactions).

    Returns
    -------
    list of Chain
        Only chains whose last piece has the receiver on its lit side.
    """
    out = []
    frontier = [((i,), [(t, (int(f),)) for t, f in zip(p.triangles, p.faces)])
                for i, p in enumerate(pieces)]
    for _ in range(2, int(max_depth) + 1):
        nxt = []
        for seq, regions in frontier:
            src = image_sources(pieces, seq, c)[-1]
            for q in _feasible(regions, src, pieces, seq[-1]):
                reg = _extend(regions, src, pieces[q])
                if not reg:
                    continue
                nxt.append((seq + (int(q),), reg))
                side = (src @ pieces[q].normal - pieces[q].offset) \
                    * (c @ pieces[q].normal - pieces[q].offset)
                if side > 0:
                    out.append(Chain(seq + (int(q),), reg))
        frontier = nxt
    return out
