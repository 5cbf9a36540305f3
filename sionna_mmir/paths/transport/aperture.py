"""Lit apertures of the facet quadrature's specular chains (the exit aperture).

Under :class:`~sionna_mmir.paths.sampling.FacetQuadrature` every node stands
for a whole cell ``C`` (a sub-facet of its first triangle).  A coherent
chain ``x1 -> .. -> x_l`` integrates the physical-optics field over its last
surface (:mod:`.coherent`), and the node covers there the *footprint* of its
cell: the cell carried through the chain's mirrors onto the last triangle,
less what misses the chain's triangles -- the exit aperture of shooting and
bouncing rays, computed exactly for flat triangles:

* Unfolded (every mirror undone, ``U_j = M_1 .. M_{j-1}``), the rays are
  straight lines from the array centre ``c``; the rays through a clip line
  ``(a, b)`` of triangle ``j`` (:mod:`.clip_lines`) form the plane through
  ``c``, ``U_j(a)`` and ``U_j(b)``, which meets the first triangle's plane in
  a line.  The lit polygon is the cell clipped by those half-planes, in the
  first triangle's barycentric ``(u, v)``.
* The lit polygon is carried onto the last triangle (central projection from
  ``c`` onto the unfolded plane, then ``U^-1``) and handed to the coherent
  stage as triangles with frozen barycentric corners and areas [m^2]
  (:func:`footprint_pieces`), over which the phase is integrated exactly to
  first order about each piece's centroid (:func:`fan_integral`); a grazing
  last surface stretches the footprint, not the weight.  The lit share of
  the cell scales the chain's scattered power.
* A node's ray that misses the next triangle says nothing of the rest of its
  cell (a cell across the rim of a corner reflector, a node on a crease):
  the chain continues from a lit corner of its polygon instead
  (:func:`reaim`), and the next clip keeps the lit part.

Everything here is detached NumPy, frozen on the tape: a replay of frozen
samples skips it and stays exact.
"""
from __future__ import annotations

import numpy as np

from ...utils.backend import init_backend
from ..triangle_po import triangle_phase_average
from .clip_lines import NO_CLIP, OPEN
from .state import RAY_EPSILON

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

#: floats per footprint piece: three (u, v) corners, area [m^2], share of the cell
PIECE_FIELDS = 8


def _unit(v):
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-30)


def _apply(A, b, x):
    """``A x + b`` for ``A [n, 3, 3]``, ``b [n, 3]`` and ``x [n, m, 3]``."""
    return np.matmul(x, np.swapaxes(A, 1, 2)) + b[:, None, :]


def _area(poly, cnt):
    """Signed shoelace areas ``[n]`` of the polygons ``[n, M, 2]`` (``cnt`` vertices)."""
    M = poly.shape[1]
    idx = np.arange(M)[None, :]
    pn = np.take_along_axis(poly, np.where(idx + 1 < cnt[:, None], idx + 1, 0)[..., None], 1)
    cr = poly[..., 0] * pn[..., 1] - poly[..., 1] * pn[..., 0]
    return 0.5 * np.sum(np.where(idx < cnt[:, None], cr, 0.0), axis=1)


def _clip(poly, cnt, coef):
    """Clip convex polygons ``poly [n, M, 2]`` (``cnt`` vertices) to ``a u +
    b v + d >= 0`` (``coef [n, 3]``): ``(poly [n, M + 1, 2], cnt)``."""
    n, M, _ = poly.shape
    g = coef[:, 0:1] * poly[..., 0] + coef[:, 1:2] * poly[..., 1] + coef[:, 2:3]
    idx = np.arange(M)[None, :]
    nxt = np.where(idx + 1 < cnt[:, None], idx + 1, 0)
    gn = np.take_along_axis(g, nxt, 1)
    pn = np.take_along_axis(poly, nxt[..., None], 1)
    valid = idx < cnt[:, None]
    keep = valid & (g >= 0)
    cross = valid & ((g >= 0) != (gn >= 0))
    t = g / np.where(cross, g - gn, 1.0)
    out = np.stack([poly, poly + t[..., None] * (pn - poly)], axis=2).reshape(n, 2 * M, 2)
    flag = np.stack([keep, cross], axis=2).reshape(n, 2 * M)
    order = np.argsort(~flag, axis=1, kind="stable")[:, :M + 1]
    return np.take_along_axis(out, order[..., None], 1), np.sum(flag, axis=1)


class LitAperture:
    """Lit polygons of the facet quadrature's chains (one per lane, NumPy).

    A lane's polygon is its cell until a clip line cuts it; the cut lanes
    (few) keep their polygons in ``poly`` / ``cnt`` (rows ``cut``, sorted).

    Parameters
    ----------
    c : np.ndarray
        Array centre ``[3]`` [m].
    face1 : np.ndarray
        First triangles ``[K]`` (indices into ``F``).
    cells : np.ndarray
        The nodes' cells ``[K, 3, 2]`` in the first triangle's barycentric
        ``(u, v)``.
    V, F : np.ndarray
        Mesh vertices ``[Nv, 3]`` [m] and triangles ``[F, 3]``.
    lines : tuple
        :func:`~.clip_lines.clip_lines` of the mesh.
    """

    def __init__(self, c, face1, cells, V, F, lines):
        self.c, self.V, self.F, self.lines = np.asarray(c, np.float64), V, F, lines
        tri1 = V[F[face1]]
        self.P0 = tri1[:, 0]
        self.e1, self.e2 = tri1[:, 1] - self.P0, tri1[:, 2] - self.P0
        self.cells = np.asarray(cells, np.float64)
        self.area0 = _area(self.cells, np.full(len(cells), 3))
        n1 = _unit(np.cross(self.e1, self.e2))
        self.A = np.eye(3)[None] - 2.0 * n1[:, :, None] * n1[:, None, :]    # U_2 = M_1
        self.b = 2.0 * np.sum(n1 * self.P0, axis=1)[:, None] * n1
        #: the current triangles and their planes (normal, point)
        self.face, self.plane = np.asarray(face1, np.int64).copy(), (n1, self.P0.copy())
        self.cut = np.zeros(0, np.int64)
        self.poly, self.cnt = np.zeros((0, 3, 2)), np.zeros(0, np.int64)

    def _polygons(self, lanes):
        """``(poly [n, M, 2], cnt [n])`` of ``lanes`` (cells unless cut)."""
        M = max(self.poly.shape[1], 3)
        poly = np.concatenate([self.cells[lanes], np.repeat(self.cells[lanes, :1], M - 3, 1)], 1)
        cnt = np.full(len(lanes), 3)
        pos = np.searchsorted(self.cut, lanes)
        hit = pos < len(self.cut)
        hit[hit] = self.cut[pos[hit]] == lanes[hit]
        poly[hit], cnt[hit] = self.poly[pos[hit]], self.cnt[pos[hit]]
        return poly, cnt

    def clip(self, face, valid):
        """Clip the lanes ``valid [K]`` by the clip lines of their next
        triangles ``face [K]``, carry their lit polygons onto those triangles
        and fold the triangles' mirrors into the unfolding; returns
        :func:`footprint_pieces`."""
        idx = np.flatnonzero(valid)
        P = self.V[self.F[face[idx]]]                                  # [n, 3, 3]
        n = _unit(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]))
        A, b = self.A[idx], self.b[idx]
        p_u = np.matmul(A, P[:, 0, :, None])[..., 0] + b
        n_u = np.matmul(A, n[..., None])[..., 0]                       # (A orthogonal)
        side_in = np.sign(np.sum(n_u * (self.c - p_u), axis=1))
        code = self.lines[3][face[idx]]
        act = (code == OPEN) | ((code != NO_CLIP) & (code != side_in[:, None]))
        rows, cols = np.nonzero(act)
        for k in np.unique(cols):
            r = rows[cols == k]
            f = face[idx[r]]
            ends = np.stack([x[f, k] for x in self.lines[:3]], axis=1)           # [m, 3, 3]
            self._clip_line(idx[r], _apply(A[r], b[r], ends) - self.c)
        pieces = self._footprint(idx, P, n_u, p_u, A, b)
        self.plane[0][idx], self.plane[1][idx], self.face[idx] = n, P[:, 0], face[idx]
        self.b[idx] = np.matmul(A, (2.0 * np.sum(n * P[:, 0], axis=1)[:, None] * n)[
            ..., None])[..., 0] + b                                    # U_{j+1} = U_j M_j
        self.A[idx] = A - 2.0 * np.matmul(A, n[..., None]) * n[:, None, :]
        return pieces

    def _cut_lanes(self, lanes):
        """Give ``lanes`` rows of their own in ``poly`` (their cells first)."""
        new = np.setdiff1d(lanes, self.cut, assume_unique=True)
        if not len(new):
            return
        M = max(self.poly.shape[1], 3)
        cells = np.concatenate([self.cells[new], np.repeat(self.cells[new, :1], M - 3, 1)], 1)
        cut = np.concatenate([self.cut, new])
        order = np.argsort(cut, kind="stable")
        self.cut = cut[order]
        self.poly = np.concatenate([self.poly, cells])[order]
        self.cnt = np.concatenate([self.cnt, np.full(len(new), 3)])[order]

    def _clip_line(self, lanes, ends):
        """Clip ``lanes`` by the rays through the unfolded lines ``ends [n, 3,
        3]`` (endpoints and a kept point, relative to the array centre)."""
        N = np.cross(ends[:, 0], ends[:, 1])
        N *= np.where(np.sum(N * ends[:, 2], axis=1) < 0, -1.0, 1.0)[:, None]
        coef = np.stack([np.sum(N * self.e1[lanes], 1), np.sum(N * self.e2[lanes], 1),
                         np.sum(N * (self.P0[lanes] - self.c), 1)], axis=1)
        poly, cnt = self._polygons(lanes)
        g = coef[:, None, 0] * poly[..., 0] + coef[:, None, 1] * poly[..., 1] + coef[:, None, 2]
        inside = np.arange(poly.shape[1])[None, :] < cnt[:, None]
        cuts = np.any(inside & (g < 0), axis=1) & (cnt > 0)     # the line crosses the polygon
        if not cuts.any():
            return
        lanes, coef = lanes[cuts], coef[cuts]
        self._cut_lanes(lanes)
        rows = np.searchsorted(self.cut, lanes)
        poly, cnt = _clip(self.poly[rows], self.cnt[rows], coef)
        M = self.poly.shape[1]
        if int(cnt.max(initial=0)) > M:
            self.poly = np.concatenate([self.poly, self.poly[:, :1]], axis=1)
            M += 1
        self.poly[rows], self.cnt[rows] = poly[:, :M], cnt

    def _project(self, lanes, poly, P, n_u, p_u, A, b):
        """``(uv [n, M, 2], z [n, M, 3])``: the polygons (first-triangle
        ``(u, v)``) carried onto the triangles ``P`` through ``U = (A, b)``."""
        d = (self.P0[lanes, None] + poly[..., :1] * self.e1[lanes, None]
             + poly[..., 1:] * self.e2[lanes, None]) - self.c           # rays [n, M, 3]
        den = np.sum(n_u[:, None] * d, axis=2)
        t = np.sum(n_u * (p_u - self.c), axis=1)[:, None] / np.where(
            np.abs(den) > 1e-30, den, 1e-30)
        z = np.matmul(self.c + t[..., None] * d - b[:, None], A)        # U^-1 = A^T (. - b)
        E1, E2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
        g11, g12, g22 = np.sum(E1 * E1, 1), np.sum(E1 * E2, 1), np.sum(E2 * E2, 1)
        det = g11 * g22 - g12 ** 2
        det = np.where(np.abs(det) > 1e-30, det, 1e-30)[:, None]
        r = z - P[:, None, 0]
        r1, r2 = np.sum(r * E1[:, None], 2), np.sum(r * E2[:, None], 2)
        uv = np.stack([(g22[:, None] * r1 - g12[:, None] * r2) / det,
                       (g11[:, None] * r2 - g12[:, None] * r1) / det], axis=2)
        return uv, z

    def _footprint(self, idx, P, n_u, p_u, A, b):
        """:func:`footprint_pieces` of the lanes ``idx`` (cells, then cut lanes)."""
        is_cut = np.isin(idx, self.cut, assume_unique=True)
        out = []
        for sel in (~is_cut, is_cut):
            lanes = idx[sel]
            poly, cnt = self._polygons(lanes) if sel is is_cut else (self.cells[lanes],
                                                                      np.full(len(lanes), 3))
            uv, z = self._project(lanes, poly, P[sel], n_u[sel], p_u[sel], A[sel], b[sel])
            out.append(footprint_pieces(lanes, uv, z, poly, cnt, self.area0[lanes]))
        return (np.concatenate([o[0] for o in out]),
                np.concatenate([o[1] for o in out], axis=1))

    def corner_rays(self, lanes, inset: float = 0.05):
        """Rays from corners of the lit polygons of ``lanes`` on their
        current triangles: ``(lane, corner (u, v) [m, 2], origin [m, 3],
        direction [m, 3])``, three spread corners per lane moved ``inset`` of
        the way to the mean vertex, leaving as the chain's reflected rays."""
        poly, cnt = self._polygons(lanes)
        lanes, poly, cnt = lanes[cnt >= 3], poly[cnt >= 3], cnt[cnt >= 3]
        n, p = self.plane[0][lanes], self.plane[1][lanes]
        A1, b1 = self.A[lanes], self.b[lanes]                  # U_{j+1}; U_j = U_{j+1} M_j
        A = A1 - 2.0 * np.matmul(A1, n[..., None]) * n[:, None, :]
        b = np.matmul(A1, (2.0 * np.sum(n * p, axis=1)[:, None] * n)[..., None])[..., 0] + b1
        P = self.V[self.F[self.face[lanes]]]
        uv, z = self._project(lanes, poly, P, np.matmul(A, n[..., None])[..., 0],
                              np.matmul(A, p[..., None])[..., 0] + b, A, b)
        w = (np.arange(poly.shape[1])[None, :] < cnt[:, None])[..., None]
        pick = np.stack([np.zeros_like(cnt), cnt // 3, (2 * cnt) // 3], axis=1)[..., None]
        out = []
        for arr in (uv, z):
            mean = np.sum(arr * w, 1) / cnt[:, None]
            corner = np.take_along_axis(arr, pick, 1)
            out.append(corner + inset * (mean[:, None] - corner))
        c_uv, c_z = out
        # the reflected ray leaves the source's image in the folded mirrors
        d = _unit(c_z - np.matmul((self.c - b1)[:, None], A1))
        o = c_z + n[:, None] * np.sign(np.sum(d * n[:, None], axis=2, keepdims=True)) * RAY_EPSILON
        return np.repeat(lanes, 3), c_uv.reshape(-1, 2), o.reshape(-1, 3), d.reshape(-1, 3)


def footprint_pieces(lanes, uv, z, poly, cnt, area0):
    """The lit footprints of ``lanes`` as triangles: ``(lane [E] uint32,
    values [8, E] float32)``.

    Parameters
    ----------
    lanes : np.ndarray
        ``[n]`` lane indices.
    uv, z : np.ndarray
        The polygons' vertices on the last triangles: barycentric ``[n, M,
        2]`` and points ``[n, M, 3]`` [m].
    poly, cnt, area0 : np.ndarray
        The polygons on the first triangles ``[n, M, 2]``, their vertex
        counts ``[n]`` and their cells' areas ``[n]`` (both in ``(u, v)``).

    Returns
    -------
    lane : np.ndarray
        Lane of each piece (the fans ``(0, i, i + 1)`` of the polygons).
    values : np.ndarray
        Three ``(u, v)`` corners on the last triangle, area [m^2] and share
        of the node's cell.
    """
    out_l, out_v = [np.zeros(0, np.uint32)], [np.zeros((PIECE_FIELDS, 0), np.float32)]
    for t in range(max(int(cnt.max(initial=0)) - 2, 0)):
        on = np.flatnonzero(t + 2 < cnt)
        i = t + 1
        tri = np.stack([uv[on, 0], uv[on, i], uv[on, i + 1]], axis=1).reshape(-1, 6)
        area = 0.5 * np.linalg.norm(np.cross(z[on, i] - z[on, 0], z[on, i + 1] - z[on, 0]),
                                    axis=1)
        d1, d2 = poly[on, i] - poly[on, 0], poly[on, i + 1] - poly[on, 0]
        share = (0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
                 / np.where(area0[on] != 0, area0[on], 1.0))
        out_l.append(lanes[on].astype(np.uint32))
        out_v.append(np.concatenate([tri.T, area[None], np.maximum(share, 0.0)[None]]
                                    ).astype(np.float32))
    return np.concatenate(out_l), np.concatenate(out_v, axis=1)


def clip(ctx, st, depth: int) -> None:
    """Clip the lanes' lit polygons by the triangles hit at ``depth`` and set
    ``st.fan`` (the footprint pieces) and ``st.lit`` (the cells' lit shares);
    no-op without an aperture or at depth 1."""
    if st.aperture is None or depth == 1:
        return
    if ctx.tape.replaying:
        lane, vals = ctx.tape.freeze(None), ctx.tape.freeze(None)
    else:
        valid = np.asarray(st.it.valid, dtype=bool)
        face = np.where(valid, np.asarray(st.it.face, dtype=np.int64), 0)
        lane, vals = st.aperture.clip(face, valid)
        lane = ctx.tape.freeze(mi.UInt32(lane))
        vals = ctx.tape.freeze(mi.Float(vals.ravel()))
    st.fan = (lane, vals)
    lit = dr.zeros(mi.Float, st.width)
    if dr.width(lane):
        dr.scatter_add(lit, _piece_value(vals, dr.width(lane), 7), lane)
    st.lit = lit


def _piece_value(vals, E, j):
    return dr.gather(mi.Float, vals, dr.arange(mi.UInt32, E) + j * E)


def _gather3(v, idx):
    return type(v)(*(dr.gather(mi.Float, v[c], idx) for c in range(3)))


def fan_integral(k_wave, st, surf, average: bool):
    """``(re, im)`` [m^2]: ``int exp(-j k (L(y) - L(x_l))) dA(y)`` over the lit
    footprint, ``L(y) = |U(y) - c| + |y - c|`` (the footprint's area where
    ``average`` is off), at the triangle's area at sampling time
    (``area_ratio`` scales it).  Each piece takes the exact phase and its
    gradient at its centroid and the linear phase across it (AD)."""
    lane, vals = st.fan
    K, E = st.width, dr.width(lane)
    fr, fi = dr.zeros(mi.Float, K), dr.zeros(mi.Float, K)
    if E == 0:
        return fr, fi
    g = [_piece_value(vals, E, j) for j in range(7)]
    if not average:
        dr.scatter_add(fr, g[6], lane)
        return fr, fi
    P0, P1, P2 = (_gather3(v, lane) for v in st.it.tri)
    e1, e2 = P1 - P0, P2 - P0
    corners = [P0 + e1 * g[2 * c] + e2 * g[2 * c + 1] for c in range(3)]
    y = (corners[0] + corners[1] + corners[2]) / 3.0
    cols = [_gather3(c, lane) for c in st.U[0]]
    c_w = _gather3(st.cw_k, lane)
    to_rx = cols[0] * y.x + cols[1] * y.y + cols[2] * y.z + _gather3(st.U[1], lane) - c_w
    to_tx = y - c_w
    d_rx, d_tx = dr.norm(to_rx), dr.norm(to_tx)
    q = k_wave * (mi.Vector3f(*(dr.dot(col, to_rx / d_rx) for col in cols)) + to_tx / d_tx)
    L_x = dr.norm(_gather3(st.x_star, lane) - c_w) + dr.norm(_gather3(surf.x, lane) - c_w)
    ph = -k_wave * ((d_rx + d_tx) - L_x)
    ar, ai = triangle_phase_average(q, *corners, y)
    cr, ci = dr.cos(ph), dr.sin(ph)
    dr.scatter_add(fr, g[6] * (ar * cr - ai * ci), lane)
    dr.scatter_add(fi, g[6] * (ar * ci + ai * cr), lane)
    return fr, fi


def reaim(ctx, st, surf, hit, lost):
    """Continue the chains whose node's ray ``lost`` the next triangle from
    a lit corner of their polygon (see the module docstring).

    Parameters
    ----------
    ctx, st, surf
        Context, path state and the current surface.
    hit : tuple
        ``(valid, obj, face, u, v)`` of the nodes' next segments.
    lost : mi.Bool
        Coherent lanes whose next segment missed.

    Returns
    -------
    hit : tuple
        The hits, with those of the re-aimed lanes' corners (frozen).
    origin : mi.Point3f
        Where each lane's next segment starts: ``surf.x`` or its corner (AD,
        barycentric on the current triangle).
    """
    if st.aperture is None:
        return hit, surf.x
    tape = ctx.tape
    if tape.replaying:
        out = [tape.freeze(None) for _ in range(8)]
    else:
        out = [tape.freeze(v) for v in _reaim_np(ctx, st, hit, np.asarray(lost, dtype=bool))]
    moved, ou, ov = out[5:]
    P0, P1, P2 = st.it.tri
    origin = dr.select(moved, P0 + (P1 - P0) * ou + (P2 - P0) * ov, surf.x)
    return tuple(out[:5]), origin


def _reaim_np(ctx, st, hit, lost):
    """The hits with the re-aimed lanes', the moved lanes and their corners."""
    valid, obj, face, u, v = (np.array(a) for a in hit)
    K = len(valid)
    moved, ou, ov = np.zeros(K, bool), np.zeros(K, np.float32), np.zeros(K, np.float32)
    lane, c_uv, o, d = st.aperture.corner_rays(np.flatnonzero(lost))
    if len(lane):
        o32, d32 = o.astype(np.float32), d.astype(np.float32)
        r = ctx.geo._trace(mi.Point3f(*(mi.Float(o32[:, c]) for c in range(3))),
                           mi.Vector3f(*(mi.Float(d32[:, c]) for c in range(3))), True)
        rv, ro, rf, ru, rvv = (np.asarray(a) for a in r)
        hits = np.flatnonzero(rv)                      # the first corner of a lane that hits
        first = hits[np.r_[True, lane[hits][1:] != lane[hits][:-1]]] if len(hits) else hits
        k = lane[first]
        valid[k], obj[k], face[k], u[k], v[k] = True, ro[first], rf[first], ru[first], rvv[first]
        moved[k], ou[k], ov[k] = True, c_uv[first, 0], c_uv[first, 1]
    return (mi.Bool(valid), mi.UInt32(obj), mi.UInt32(face), mi.Float(u), mi.Float(v),
            mi.Bool(moved), mi.Float(ou), mi.Float(ov))
