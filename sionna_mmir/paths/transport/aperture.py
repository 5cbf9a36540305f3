"""Lit apertures of the facet quadrature's specular chains (the exit aperture).

Under :class:`~sionna_mmir.paths.sampling.FacetQuadrature` every node stands
for a whole cell ``C`` (a sub-facet of its first triangle).  A coherent
chain ``x1 -> .. -> x_l`` integrates the physical-optics field over its last
surface (:mod:`.coherent`), and the node covers there the *footprint* of its
cell: the cell carried through the chain's mirrors onto the last triangle,
less what misses the chain's triangles -- the exit aperture of shooting and
bouncing rays, computed exactly for flat triangles:

* Unfolded (every mirror undone, ``U_j = M_1 .. M_{j-1}`` with ``M_i`` the
  mirror in the plane of triangle ``i``), the rays are straight lines from
  the array centre ``c``; the rays through a clip line ``(a, b)`` of
  triangle ``j`` (:mod:`.clip_lines`) form the plane through ``c``,
  ``U_j(a)`` and ``U_j(b)``, which meets the first triangle's plane in a
  line.  The lit polygon is the cell clipped by those half-planes, in the
  first triangle's barycentric ``(u, v)``.
* The lit polygon is carried onto the last triangle (central projection from
  ``c`` onto the unfolded plane, then ``U^-1``) and handed to the coherent
  stage as triangles with frozen barycentric corners and areas [m^2], over
  which the phase is integrated exactly to first order about each piece's
  centroid (:func:`fan_integral`): a grazing last surface stretches the
  footprint, not the weight.  The cell's lit share scales the chain's
  scattered power.
* A node's ray that misses the next triangle says nothing of the rest of its
  cell (a cell across the rim of a corner reflector, a node on a crease):
  the chain continues from a lit corner of its polygon instead
  (:func:`reaim`), and the next clip keeps the lit part.

Most cells are never cut: their footprint is the cell's projected triangle,
computed for all lanes at once in Dr.Jit (one *main* piece per lane).  The
cells a clip line crosses are clipped in NumPy (:class:`CutPolygons`) and
handed over as extra pieces.  Everything is detached and frozen on the tape,
so a replay of frozen samples skips it and stays exact.
"""
from __future__ import annotations

import numpy as np

from ...utils.backend import init_backend
from ..triangle_po import triangle_phase_average
from .clip_lines import NO_CLIP, OPEN, drjit_tables
from .state import RAY_EPSILON

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

#: floats per footprint piece: three (u, v) corners, area [m^2], share of the cell
PIECE_FIELDS = 8


# ----------------------------------------------------------------- NumPy
def _unit(v):
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-30)


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


def _project(geo1, c, poly, P, A, b):
    """``(uv [n, M, 2], z [n, M, 3])``: polygons ``poly`` (first-triangle
    ``(u, v)``, ``geo1 = (P0, e1, e2)``) carried from ``c`` onto the
    triangles ``P [n, 3, 3]`` through the unfoldings ``U = (A [n, 3, 3], b)``."""
    P0, e1, e2 = geo1
    n = _unit(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]))
    n_u = np.einsum("nij,nj->ni", A, n)
    p_u = np.einsum("nij,nj->ni", A, P[:, 0]) + b
    d = P0[:, None] + poly[..., :1] * e1[:, None] + poly[..., 1:] * e2[:, None] - c
    den = np.sum(n_u[:, None] * d, axis=2)
    t = np.sum(n_u * (p_u - c), axis=1)[:, None] / np.where(np.abs(den) > 1e-30, den, 1e-30)
    w = c + t[..., None] * d - b[:, None]
    z = np.einsum("nij,nmi->nmj", A, w)                                # U^-1 = A^T (. - b)
    E1, E2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    g11, g12, g22 = np.sum(E1 * E1, 1), np.sum(E1 * E2, 1), np.sum(E2 * E2, 1)
    det = g11 * g22 - g12 ** 2
    det = np.where(np.abs(det) > 1e-30, det, 1e-30)[:, None]
    r = z - P[:, None, 0]
    r1, r2 = np.sum(r * E1[:, None], 2), np.sum(r * E2[:, None], 2)
    uv = np.stack([(g22[:, None] * r1 - g12[:, None] * r2) / det,
                   (g11[:, None] * r2 - g12[:, None] * r1) / det], axis=2)
    return uv, z


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


class CutPolygons:
    """The lit polygons of the cells a clip line has cut (NumPy, rows of the
    sorted lanes ``lanes``).

    Parameters
    ----------
    c : np.ndarray
        Array centre ``[3]`` [m].
    V, F : np.ndarray
        Mesh vertices ``[Nv, 3]`` [m] and triangles ``[F, 3]``.
    face1 : np.ndarray
        First triangles of all lanes ``[K]``.
    cells : np.ndarray
        The nodes' cells ``[K, 3, 2]`` (first-triangle ``(u, v)``).
    lines : tuple
        :func:`~.clip_lines.clip_lines` of the mesh.
    """

    def __init__(self, c, V, F, face1, cells, lines):
        self.c, self.V, self.F, self.lines = np.asarray(c, np.float64), V, F, lines
        self.face1, self.cells = face1, cells
        self.lanes = np.zeros(0, np.int64)
        self.poly, self.cnt = np.zeros((0, 3, 2)), np.zeros(0, np.int64)

    def first(self, lanes):
        """``(P0, e1, e2)`` of the first triangles of ``lanes`` [m]."""
        T = self.V[self.F[self.face1[lanes]]]
        return T[:, 0], T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]

    def polygons(self, lanes):
        """``(poly [n, M, 2], cnt [n])`` of ``lanes`` (their cells unless cut)."""
        M = max(self.poly.shape[1], 3)
        cells = self.cells[lanes]
        poly = np.concatenate([cells, np.repeat(cells[:, :1], M - 3, 1)], 1)
        cnt = np.full(len(lanes), 3)
        if len(self.lanes):
            pos = np.minimum(np.searchsorted(self.lanes, lanes), len(self.lanes) - 1)
            hit = self.lanes[pos] == lanes
            poly[hit], cnt[hit] = self.poly[pos[hit]], self.cnt[pos[hit]]
        return poly, cnt

    def clip(self, lanes, face, P, A, b):
        """Clip ``lanes`` (on triangles ``face``, vertices ``P [n, 3, 3]``,
        unfoldings ``(A, b)``) by their triangles' clip lines; returns their
        footprint pieces (:func:`footprint_pieces`)."""
        n = _unit(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]))
        p_u = np.einsum("nij,nj->ni", A, P[:, 0]) + b
        side_in = np.sign(np.sum(np.einsum("nij,nj->ni", A, n) * (self.c - p_u), axis=1))
        code = self.lines[3][face]
        act = (code == OPEN) | ((code != NO_CLIP) & (code != side_in[:, None]))
        geo1 = self.first(lanes)
        self._adopt(lanes[act.any(axis=1)])
        for k in np.flatnonzero(act.any(axis=0)):
            r = np.flatnonzero(act[:, k])
            ends = np.stack([x[face[r], k] for x in self.lines[:3]], axis=1)      # [m, 3, 3]
            ends = np.einsum("nij,nvj->nvi", A[r], ends) + b[r, None] - self.c
            self._clip_line(lanes[r], tuple(g[r] for g in geo1), ends)
        poly, cnt = self.polygons(lanes)
        uv, z = _project(geo1, self.c, poly, P, A, b)
        area0 = _area(self.cells[lanes], np.full(len(lanes), 3))
        return footprint_pieces(lanes, uv, z, poly, cnt, area0)

    def _clip_line(self, lanes, geo1, ends):
        """Clip ``lanes`` by the rays through the unfolded lines ``ends [n, 3,
        3]`` (endpoints and a kept point, relative to the array centre)."""
        P0, e1, e2 = geo1
        N = np.cross(ends[:, 0], ends[:, 1])
        N *= np.where(np.sum(N * ends[:, 2], axis=1) < 0, -1.0, 1.0)[:, None]
        coef = np.stack([np.sum(N * e1, 1), np.sum(N * e2, 1), np.sum(N * (P0 - self.c), 1)],
                        axis=1)
        rows = np.searchsorted(self.lanes, lanes)             # (adopted)
        poly, cnt = self.poly[rows], self.cnt[rows]
        g = coef[:, None, 0] * poly[..., 0] + coef[:, None, 1] * poly[..., 1] + coef[:, None, 2]
        inside = np.arange(poly.shape[1])[None, :] < cnt[:, None]
        cuts = np.any(inside & (g < 0), axis=1) & (cnt > 0)       # the line crosses the polygon
        if not cuts.any():
            return
        rows, coef = rows[cuts], coef[cuts]
        poly, cnt = _clip(self.poly[rows], self.cnt[rows], coef)
        if int(cnt.max(initial=0)) > self.poly.shape[1]:
            self.poly = np.concatenate([self.poly, self.poly[:, :1]], axis=1)
        self.poly[rows], self.cnt[rows] = poly[:, :self.poly.shape[1]], cnt

    def _adopt(self, lanes):
        """Give ``lanes`` rows of their own (their cells first)."""
        new = np.setdiff1d(lanes, self.lanes)
        if not len(new):
            return
        M = max(self.poly.shape[1], 3)
        cells = np.concatenate([self.cells[new], np.repeat(self.cells[new, :1], M - 3, 1)], 1)
        merged = np.concatenate([self.lanes, new])
        order = np.argsort(merged, kind="stable")
        self.lanes = merged[order]
        self.poly = np.concatenate([self.poly, cells])[order]
        self.cnt = np.concatenate([self.cnt, np.full(len(new), 3)])[order]

    def corners(self, lanes, P, A, b, inset):
        """Three spread corners of the lit polygons of ``lanes`` on their
        triangles ``P`` (unfoldings ``(A, b)``), moved ``inset`` of the way to
        the mean vertex: ``(lanes, uv [m, 3, 2], z [m, 3, 3])`` of those left."""
        poly, cnt = self.polygons(lanes)
        keep = cnt >= 3
        lanes, poly, cnt = lanes[keep], poly[keep], cnt[keep]
        uv, z = _project(self.first(lanes), self.c, poly, P[keep], A[keep], b[keep])
        w = (np.arange(poly.shape[1])[None, :] < cnt[:, None])[..., None]
        pick = np.stack([np.zeros_like(cnt), cnt // 3, (2 * cnt) // 3], axis=1)[..., None]
        c_uv, c_z = ((np.take_along_axis(x, pick, 1) * (1 - inset)
                      + inset * (np.sum(x * w, 1) / cnt[:, None])[:, None]) for x in (uv, z))
        return lanes, c_uv, c_z


# ---------------------------------------------------------------- Dr.Jit
def _fetch(vectors, idx):
    """NumPy ``[n, 3]`` float64 of each 3-vector array in ``vectors`` at lanes
    ``idx`` (mi.UInt32), gathered in one kernel."""
    g = [dr.gather(mi.Float, v[c], idx) for v in vectors for c in range(3)]
    dr.eval(*g)
    a = [np.asarray(x, dtype=np.float64) for x in g]
    return [np.stack(a[3 * i:3 * i + 3], axis=-1) for i in range(len(vectors))]


def _mat_apply(cols, v):
    return cols[0] * v.x + cols[1] * v.y + cols[2] * v.z


def _mat_t_apply(cols, v):
    return mi.Vector3f(dr.dot(cols[0], v), dr.dot(cols[1], v), dr.dot(cols[2], v))


def _normal(P):
    return dr.normalize(dr.cross(P[1] - P[0], P[2] - P[0]))


class LitAperture:
    """Lit footprints of the facet quadrature's chains, one lane per node
    (detached Dr.Jit state; the cut cells in :class:`CutPolygons`).

    Parameters
    ----------
    c : np.ndarray
        Array centre ``[3]`` [m].
    face : mi.UInt32
        First triangles ``[K]``.
    tri : tuple
        Their vertices (three ``mi.Point3f``, detached) [m].
    sub : tuple
        The nodes' cells on them (three ``mi.Point3f``, detached) [m].
    sub_uv : list
        The cells' corners' ``(u, v)`` on the first triangles (six ``mi.Float``).
    cut : CutPolygons
        The cut cells' polygons (and the mesh).
    """

    def __init__(self, c, face, tri, sub, sub_uv, cut):
        self.c = mi.Point3f(*(float(x) for x in c))
        self.cut = cut
        self.tables = drjit_tables(cut.lines)
        self.L = cut.lines[3].shape[1]
        K = self.K = dr.width(face)
        self.ray = [p - self.c for p in sub]                  # centre -> cell corners (fixed)
        eye = [mi.Vector3f(1.0, 0.0, 0.0), mi.Vector3f(0.0, 1.0, 0.0), mi.Vector3f(0.0, 0.0, 1.0)]
        #: unfolding of the current triangle (columns, offset) and of the next
        self.U = ([dr.zeros(mi.Vector3f, K) + e for e in eye], dr.zeros(mi.Vector3f, K))
        self.tri, self.U_next = tri, self._fold(self.U, tri)
        #: corners of the uncut footprints on the current triangle: (u, v), points
        self.foot = (list(sub_uv), list(sub))
        self.is_cut = dr.zeros(mi.Bool, K)
        dr.eval(self.U, self.U_next, self.ray, self.foot)

    @staticmethod
    def _fold(U, P):
        """``U M``: the unfolding ``U`` with the mirror in the plane of ``P``."""
        cols, off = U
        n = _normal(P)
        An = _mat_apply(cols, n)
        return ([cols[i] - An * (2.0 * n[i]) for i in range(3)],
                off + An * (2.0 * dr.dot(n, P[0])))

    def _numpy_state(self, idx):
        """``(P [n, 3, 3], A [n, 3, 3], b [n, 3])``: the current triangles and
        unfoldings of lanes ``idx`` in NumPy."""
        f = _fetch(list(self.tri) + list(self.U[0]) + [self.U[1]], idx)
        return np.stack(f[:3], axis=1), np.stack(f[3:6], axis=2), f[6]

    def clip(self, face, valid, P, prev):
        """Footprints on the next triangles ``face`` (``valid``, vertices ``P``,
        the chains' previous points ``prev``; detached): ``(main [8
        mi.Float], lane mi.UInt32, extra mi.Float)``."""
        self.U, self.tri = self.U_next, P
        uv, z, area = self._carry(P)
        touch = valid & (self.is_cut | self._crossed(face, valid, P, prev, z))
        idx = dr.compress(touch)
        simple = valid & ~touch
        main = [dr.select(simple, x, 0.0) for x in uv] + [dr.select(simple, area, 0.0),
                                                          dr.select(simple, 1.0, 0.0)]
        lane, extra = np.zeros(0, np.uint32), np.zeros((PIECE_FIELDS, 0), np.float32)
        if dr.width(idx):
            lanes = np.asarray(idx, dtype=np.int64)
            Pn, A, b = self._numpy_state(idx)
            lane, extra = self.cut.clip(lanes, np.asarray(dr.gather(mi.UInt32, face, idx),
                                                          dtype=np.int64), Pn, A, b)
            mask = np.zeros(self.K, bool)
            mask[self.cut.lanes] = True
            self.is_cut = mi.Bool(mask)
        self.U_next = self._fold(self.U, P)
        dr.eval(self.U_next, self.foot, main)
        return main, mi.UInt32(lane), mi.Float(extra.ravel())

    def _crossed(self, face, valid, P, prev, z):
        """Lanes whose footprint (corners ``z`` on ``P``) a clip line of their
        triangle crosses, for a chain arriving from ``prev``'s side."""
        code_t, eq_t, any_t = self.tables
        side_in = dr.sign(dr.dot(dr.cross(P[1] - P[0], P[2] - P[0]), prev - P[0]))
        may = valid & dr.gather(mi.Bool, any_t, face, valid)
        out = dr.zeros(mi.Bool, self.K)
        for k in range(self.L):
            code = dr.gather(mi.Int32, code_t, face * self.L + k, may)
            act = may & ((code == OPEN) | ((code != NO_CLIP) & (mi.Float(code) != side_in)))
            base = (face * self.L + k) * 4
            m = mi.Vector3f(*(dr.gather(mi.Float, eq_t, base + i, act) for i in range(3)))
            d = dr.gather(mi.Float, eq_t, base + 3, act)
            out |= act & ((dr.dot(m, z[0]) < d) | (dr.dot(m, z[1]) < d) | (dr.dot(m, z[2]) < d))
        return out

    def _carry(self, P):
        """The cells' triangles carried onto the triangles ``P``: corners'
        ``(u, v)`` there (six ``mi.Float``), points and area [m^2]; keeps
        ``(u, v)`` and points as :attr:`foot`."""
        cols, off = self.U
        n_u = _mat_apply(cols, _normal(P))
        h = dr.dot(n_u, _mat_apply(cols, P[0]) + off - self.c)
        E1, E2 = P[1] - P[0], P[2] - P[0]
        g11, g12, g22 = dr.dot(E1, E1), dr.dot(E1, E2), dr.dot(E2, E2)
        det = g11 * g22 - g12 * g12
        det = dr.select(dr.abs(det) > 1e-30, det, 1e-30)
        z, uv = [], []
        for r in self.ray:
            den = dr.dot(n_u, r)
            t = h / dr.select(dr.abs(den) > 1e-30, den, 1e-30)
            zk = mi.Point3f(_mat_t_apply(cols, self.c + r * t - off))   # U^-1 = A^T (. - b)
            d = zk - P[0]
            r1, r2 = dr.dot(d, E1), dr.dot(d, E2)
            z.append(zk)
            uv += [(g22 * r1 - g12 * r2) / det, (g11 * r2 - g12 * r1) / det]
        self.foot = (uv, z)
        return uv, z, 0.5 * dr.norm(dr.cross(z[1] - z[0], z[2] - z[0]))

    def corner_rays(self, lost, inset: float = 0.05):
        """Three rays per ``lost`` lane from corners of its lit polygon on the
        current triangle, moved ``inset`` of the way to the mean vertex,
        leaving as the chain's reflected rays: ``[(origin, direction, u, v)]``
        (Dr.Jit, one tuple per corner; inactive where not ``lost``)."""
        uv, z = self.foot
        mean = (z[0] + z[1] + z[2]) / 3.0
        m_u, m_v = (uv[0] + uv[2] + uv[4]) / 3.0, (uv[1] + uv[3] + uv[5]) / 3.0
        corners = [[uv[2 * k] + (m_u - uv[2 * k]) * inset, uv[2 * k + 1] + (m_v - uv[2 * k + 1])
                    * inset, z[k] + (mean - z[k]) * inset] for k in range(3)]
        idx = dr.compress(lost & self.is_cut)
        if dr.width(idx):                    # cut cells: corners of their polygons
            lanes, c_uv, c_z = self.cut.corners(np.asarray(idx, dtype=np.int64),
                                                *self._numpy_state(idx), inset)
            at = mi.UInt32(lanes.astype(np.uint32))
            for k in range(3):
                dr.scatter(corners[k][0], mi.Float(c_uv[:, k, 0].astype(np.float32)), at)
                dr.scatter(corners[k][1], mi.Float(c_uv[:, k, 1].astype(np.float32)), at)
                dr.scatter(corners[k][2], mi.Point3f(*(mi.Float(c_z[:, k, i].astype(np.float32))
                                                       for i in range(3))), at)
        # the reflected ray leaves the source's image in the folded mirrors
        cols, off = self.U_next
        src = _mat_t_apply(cols, self.c - off)
        n = _normal(self.tri)
        out = []
        for u, v, p in corners:
            d = dr.normalize(p - src)
            o = p + n * (dr.sign(dr.dot(d, n)) * RAY_EPSILON)
            out.append((o, d, u, v))
        return out


# ------------------------------------------------------- the solver's hooks
def clip(ctx, st, depth: int) -> None:
    """Clip the lanes' lit polygons by the triangles hit at ``depth`` and set
    ``st.fan`` (the footprint pieces) and ``st.lit`` (the cells' lit shares);
    no-op without an aperture or at depth 1."""
    if st.aperture is None or depth == 1:
        return
    tape = ctx.tape
    if tape.replaying:
        main = [tape.freeze(None) for _ in range(PIECE_FIELDS)]
        lane, extra = tape.freeze(None), tape.freeze(None)
    else:
        P = tuple(dr.detach(v) for v in st.it.tri)
        main, lane, extra = st.aperture.clip(st.it.face, dr.detach(st.it.valid), P,
                                             dr.detach(st.prev_p))
        main = [tape.freeze(x) for x in main]
        lane, extra = tape.freeze(lane), tape.freeze(extra)
    st.fan = (main, lane, extra)
    lit = mi.Float(main[7])
    if dr.width(lane):
        dr.scatter_add(lit, _piece_value(extra, dr.width(lane), 7), lane)
    st.lit = lit


def _piece_value(vals, E, j):
    return dr.gather(mi.Float, vals, dr.arange(mi.UInt32, E) + j * E)


def _gather3(v, idx):
    return type(v)(*(dr.gather(mi.Float, v[c], idx) for c in range(3)))


def _piece_integral(k_wave, g, tri, U, c_w, L_x):
    """``area exp(-j k (L(y) - L(x_l))) F`` of pieces ``g`` (7 values) on the
    triangles ``tri``, ``F`` the linear-phase average about the centroid ``y``."""
    P0, P1, P2 = tri
    e1, e2 = P1 - P0, P2 - P0
    corners = [P0 + e1 * g[2 * c] + e2 * g[2 * c + 1] for c in range(3)]
    y = (corners[0] + corners[1] + corners[2]) / 3.0
    cols, off = U
    to_rx = _mat_apply(cols, y) + off - c_w
    to_tx = y - c_w
    d_rx, d_tx = dr.norm(to_rx), dr.norm(to_tx)
    q = k_wave * (_mat_t_apply(cols, to_rx / d_rx) + to_tx / d_tx)
    ph = -k_wave * ((d_rx + d_tx) - L_x)
    ar, ai = triangle_phase_average(q, *corners, y)
    cr, ci = dr.cos(ph), dr.sin(ph)
    return g[6] * (ar * cr - ai * ci), g[6] * (ar * ci + ai * cr)


def fan_integral(k_wave, st, surf, average: bool):
    """``(re, im)`` [m^2]: ``int exp(-j k (L(y) - L(x_l))) dA(y)`` over the lit
    footprint, ``L(y) = |U(y) - c| + |y - c|`` (the footprint's area where
    ``average`` is off), at the triangle's area at sampling time
    (``area_ratio`` scales it).  Each piece takes the exact phase and its
    gradient at its centroid and the linear phase across it (AD)."""
    main, lane, extra = st.fan
    E = dr.width(lane)
    if not average:
        fr = dr.zeros(mi.Float, st.width)
        if E:
            dr.scatter_add(fr, _piece_value(extra, E, 6), lane)
        return fr + main[6], dr.zeros(mi.Float, st.width)
    if E:        # (the extras gather these: evaluated once, not in a kernel of their own)
        dr.eval(st.U, st.x_star, surf.x, st.it.tri)
    L_x = dr.norm(st.x_star - st.cw_k) + dr.norm(surf.x - st.cw_k)
    fr, fi = _piece_integral(k_wave, main, st.it.tri, st.U, st.cw_k, L_x)
    if E:
        g = [_piece_value(extra, E, j) for j in range(7)]
        U = ([_gather3(c, lane) for c in st.U[0]], _gather3(st.U[1], lane))
        er, ei = _piece_integral(k_wave, g, tuple(_gather3(v, lane) for v in st.it.tri), U,
                                 _gather3(st.cw_k, lane), dr.gather(mi.Float, L_x, lane))
        xr, xi = dr.zeros(mi.Float, st.width), dr.zeros(mi.Float, st.width)
        dr.scatter_add(xr, er, lane)
        dr.scatter_add(xi, ei, lane)
        fr, fi = fr + xr, fi + xi
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
        out = [tape.freeze(v) for v in _reaim_rays(ctx, st.aperture, hit, dr.detach(lost))]
    moved, ou, ov = out[5:]
    P0, P1, P2 = st.it.tri
    origin = dr.select(moved, P0 + (P1 - P0) * ou + (P2 - P0) * ov, surf.x)
    return tuple(out[:5]), origin


def _reaim_rays(ctx, ap, hit, lost):
    """Trace the corner rays of the ``lost`` lanes (outside AD): the hits with
    the first hitting corner's, the moved lanes and their corners' ``(u, v)``."""
    valid, obj, face, u, v = hit
    moved = dr.zeros(mi.Bool, dr.width(lost))
    ou, ov = dr.zeros(mi.Float, dr.width(lost)), dr.zeros(mi.Float, dr.width(lost))
    if not dr.any(lost):
        return valid, obj, face, u, v, moved, ou, ov
    for o, d, cu, cv in ap.corner_rays(lost):
        r = ctx.geo._trace(o, d, lost & ~moved)
        take = r[0] & ~moved
        valid = valid | take
        obj, face = dr.select(take, r[1], obj), dr.select(take, r[2], face)
        u, v = dr.select(take, r[3], u), dr.select(take, r[4], v)
        ou, ov = dr.select(take, cu, ou), dr.select(take, cv, ov)
        moved = moved | take
    dr.eval(valid, obj, face, u, v, moved, ou, ov)
    return valid, obj, face, u, v, moved, ou, ov
