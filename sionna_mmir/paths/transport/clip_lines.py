"""Clip lines of every triangle: where a lit aperture ends (NumPy, mesh topology).

A facet-quadrature chain keeps the part of its cell whose rays land inside
the later triangles (:mod:`.aperture`).  A triangle's edge ends the lit
region only where the surface ends there:

open edge
    no neighbour (the rim of a plate): clips
convex crease
    the neighbour bends away by more than :data:`CREASE_DEG` (seen from the
    side the chain arrives from): clips
flat edge
    the neighbour continues the plane (within :data:`CREASE_DEG`) or the edge
    is non-manifold: no clip
concave crease
    the neighbour bends towards the incoming rays (a corner seen from
    inside): no clip -- the rays beyond go on in another ordering of the same
    corner, which for a right-angled corner carries the same field (the
    ray-tube assignment of shooting and bouncing rays)

A footprint may reach past a flat edge onto a neighbour and over that
neighbour's rim, so each triangle also carries the clipping edges of its
coplanar neighbours sharing a vertex whose half-plane holds the whole
triangle (the rim of a plate meshed finely).  The mesh is welded by
position (objects meshed separately, faces not sharing vertices), and the
result is cached for the last geometry seen.
"""
from __future__ import annotations

import numpy as np

from ...utils.backend import init_backend

init_backend()

import mitsuba as mi  # noqa: E402

#: creases flatter than this [deg] continue the surface (no clipping)
CREASE_DEG = 20.0
#: edge codes: no clip, open (always clips); +-1: side of the neighbour
NO_CLIP, OPEN = 0, 2
#: vertices closer than this [m] are the same vertex when welding
WELD_TOL = 1e-6
#: clip lines per triangle: its three edges and at most this many more
MAX_EXTRA = 6

_CACHE: dict = {}


def clip_lines(V, F):
    """``(a, b, inner, code)`` of the clip lines of every triangle (cached).

    Parameters
    ----------
    V : np.ndarray
        Vertex positions ``[Nv, 3]`` [m] (float64).
    F : np.ndarray
        Triangles ``[F, 3]`` (vertex indices).

    Returns
    -------
    a, b : np.ndarray
        Line endpoints ``[F, L, 3]`` [m] (``L = 3 + MAX_EXTRA``; padding
        repeats the triangle's first edge with code ``NO_CLIP``).
    inner : np.ndarray
        ``[F, L, 3]``: a point on the kept side of each line [m].
    code : np.ndarray
        ``[F, L]`` int8: ``OPEN``, ``NO_CLIP`` or ``+-1``, the side (along
        the triangle's ``n_g = (P1 - P0) x (P2 - P0)``) of the neighbour
        beyond a crease: the line clips a chain arriving from the other side.
    """
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    topo_key = (V.shape, F.shape, hash(F.tobytes()))
    if _CACHE.get("topo_key") != topo_key:       # welding and adjacency: once per mesh
        _CACHE.clear()
        _CACHE.update(topo_key=topo_key, topo=_topology(V, F))
    key = hash(V.tobytes())
    if _CACHE.get("key") != key:                 # codes and lines: once per geometry
        _CACHE.update(key=key, value=_build(V, F, _CACHE["topo"]))
    return _CACHE["value"]


def drjit_tables(lines):
    """The clip lines as flat Dr.Jit tables (cached with the lines):
    ``(code mi.Int32 [F L], eq mi.Float [F L 4], any mi.Bool [F])`` -- ``eq``
    the line ``m . x = d`` of line ``(f, k)`` at ``(f L + k) 4`` (``m`` the
    unit in-plane normal towards the kept side, then ``d``), ``any`` the
    triangles with a line that can clip."""
    if _CACHE.get("tables_of") is not lines:
        a, b, inner, code = lines
        F, L = code.shape
        n = np.cross(a[:, 0] - inner[:, 0], b[:, 0] - inner[:, 0])        # the triangle's plane
        m = np.cross(n[:, None], b - a)
        m /= np.maximum(np.linalg.norm(m, axis=2, keepdims=True), 1e-30)
        m *= np.where(np.sum(m * (inner - a), axis=2, keepdims=True) < 0, -1.0, 1.0)
        eq = np.concatenate([m, np.sum(m * a, axis=2, keepdims=True)], axis=2)
        _CACHE["tables_of"] = lines
        _CACHE["tables"] = (mi.Int32(code.astype(np.int32).ravel()),
                            mi.Float(eq.astype(np.float32).ravel()),
                            mi.Bool(np.any(code != NO_CLIP, axis=1)))
    return _CACHE["tables"]


def _topology(V, F):
    """Welded vertex ids ``[F, 3]``, the edge pairing of :func:`edge_codes`
    and the vertex-sharing pairs of triangles."""
    W = np.unique(np.round(V / WELD_TOL).astype(np.int64), axis=0,
                  return_inverse=True)[1].reshape(-1)[F]
    return W, _edge_pairs(W), _vertex_neighbours(W)


def _build(V, F, topo):
    W, pairs, neighbours = topo
    P = V[F]                                                   # [F, 3, 3]
    n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1), 1e-30)[:, None]
    codes = edge_codes(P, n, pairs)
    nf, L = len(F), 3 + MAX_EXTRA
    a = np.repeat(P[:, :1], L, axis=1)
    b = np.repeat(P[:, 1:2], L, axis=1)
    inner = np.repeat(P[:, 2:3], L, axis=1)
    code = np.zeros((nf, L), np.int8)
    for k in range(3):
        a[:, k], b[:, k], inner[:, k] = P[:, k], P[:, (k + 1) % 3], P[:, (k + 2) % 3]
    code[:, :3] = codes
    f, la, lb, li, lc = _neighbour_lines(P, n, neighbours, codes)
    if len(f):
        rank = np.arange(len(f)) - np.searchsorted(f, f)      # f sorted: index within f
        ok = rank < MAX_EXTRA
        f, rank = f[ok], rank[ok] + 3
        a[f, rank], b[f, rank], inner[f, rank], code[f, rank] = la[ok], lb[ok], li[ok], lc[ok]
    return a, b, inner, code


def _edge_pairs(W):
    """``(multi, me, other)``: edge slots ``f 3 + k`` shared by more than two
    triangles, and the slot pairs of edges shared by exactly two."""
    e0, e1 = W, np.roll(W, -1, axis=1)
    key = (np.minimum(e0, e1) * (int(W.max(initial=0)) + 1) + np.maximum(e0, e1)).ravel()
    order = np.argsort(key, kind="stable")
    ks = key[order]
    start = np.r_[True, ks[1:] != ks[:-1]] if len(ks) else np.zeros(0, bool)
    group = np.cumsum(start) - 1
    count = np.bincount(group)[group] if len(ks) else np.zeros(0, np.int64)
    first = np.flatnonzero(start & (count == 2))
    return order[count > 2], order[first], order[first + 1]


def edge_codes(P, n, pairs, crease_deg: float = CREASE_DEG) -> np.ndarray:
    """``[F, 3]`` int8 code of each edge ``(k, k + 1)`` of the triangles
    ``P [F, 3, 3]`` (unit normals ``n``, edge pairing ``pairs`` of
    :func:`_edge_pairs`)."""
    codes = np.full((len(P), 3), OPEN, dtype=np.int8)
    multi, one, two = pairs
    codes.ravel()[multi] = NO_CLIP
    sin_c = np.sin(np.radians(crease_deg))
    for me, other in ((one, two), (two, one)):
        f, k, g, kg = me // 3, me % 3, other // 3, other % 3
        ea, eb = P[f, k], P[f, (k + 1) % 3]
        off = P[g, (kg + 2) % 3] - ea                 # the neighbour's vertex off the edge
        t = (eb - ea) / np.maximum(np.linalg.norm(eb - ea, axis=1), 1e-30)[:, None]
        off -= np.sum(off * t, axis=1)[:, None] * t
        h = np.sum(off * n[f], axis=1)
        sin_a = h / np.maximum(np.linalg.norm(off, axis=1), 1e-30)
        codes.ravel()[me] = np.where(np.abs(sin_a) < sin_c, NO_CLIP, np.sign(h)).astype(np.int8)
    return codes


def _neighbour_lines(P, n, neighbours, codes):
    """Clip lines that coplanar vertex-sharing neighbours lend each triangle:
    ``(face [m] sorted, a, b, inner [m, 3], code [m])``, nearest first."""
    f, g = neighbours
    lends = np.any(codes != NO_CLIP, axis=1)
    f, g = f[lends[g]], g[lends[g]]
    cen = P.mean(axis=1)
    size = np.linalg.norm(P[:, 1] - P[:, 0], axis=1) + np.linalg.norm(P[:, 2] - P[:, 0], axis=1)
    dot = np.sum(n[f] * n[g], axis=1)
    flat = (np.abs(dot) >= np.cos(np.radians(CREASE_DEG))) & (
        np.abs(np.sum((cen[g] - cen[f]) * n[f], axis=1)) < 1e-3 * size[f] + 1e-9)
    f, g, sgn = f[flat], g[flat], np.sign(dot[flat]).astype(np.int8)
    out = []
    for k in range(3):
        c = codes[g, k]
        m = c != NO_CLIP
        ff, gg = f[m], g[m]
        la, lb, li = P[gg, k], P[gg, (k + 1) % 3], P[gg, (k + 2) % 3]
        lc = np.where(c[m] == OPEN, OPEN, c[m] * sgn[m]).astype(np.int8)
        # keep a line only if its kept side holds the whole triangle
        s_in = np.sum(np.cross(lb - la, li - la) * n[ff], axis=1)
        s_v = np.stack([np.sum(np.cross(lb - la, P[ff, v] - la) * n[ff], axis=1)
                        for v in range(3)], axis=1)
        tol = 1e-9 * np.abs(s_in)[:, None]
        ok = np.all(s_v * np.sign(s_in)[:, None] >= -tol - 1e-18, axis=1) & (np.abs(s_in) > 0)
        d = np.linalg.norm(0.5 * (la + lb) - cen[ff], axis=1)
        out.append((ff[ok], la[ok], lb[ok], li[ok], lc[ok], d[ok]))
    f, la, lb, li, lc, d = (np.concatenate([o[i] for o in out]) for i in range(6))
    order = np.lexsort((d, f))
    return f[order], la[order], lb[order], li[order], lc[order]


def _vertex_neighbours(W):
    """Pairs ``(f, g)``, ``f != g``, of triangles sharing a welded vertex."""
    nf = len(W)
    vid = W.ravel()
    face = np.repeat(np.arange(nf), 3)
    order = np.argsort(vid, kind="stable")
    vid, face = vid[order], face[order]
    start = np.r_[0, np.flatnonzero(vid[1:] != vid[:-1]) + 1]
    size = np.diff(np.r_[start, len(vid)])
    grp = np.repeat(np.arange(len(start)), size)              # group of each entry
    reps = size[grp]
    first = np.repeat(start[grp], reps)
    partner = first + (np.arange(reps.sum()) - np.repeat(np.cumsum(reps) - reps, reps))
    f = np.repeat(face, reps)
    g = face[partner]
    key = np.unique(f[f != g] * nf + g[f != g])
    return key // nf, key % nf
