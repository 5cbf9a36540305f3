r"""Coherent free-space diffraction (FSD): edge-attached diffracted rays with phase.

A connection ``x -> c`` that a thin screen blocks still receives the field
diffracted by the screen's boundary edges.  In Kirchhoff's theory the field
behind an opaque screen is the Huygens integral over the open part ``A`` of
the screen's plane (``exp(+j w t)``, unit point source at ``x``)

.. math::

    U(c) = \frac{j}{\lambda} \int_A \chi \frac{e^{-j k (s + r)}}{s\, r}\, dA,
    \qquad s = |y - x|,\; r = |c - y|,

``chi = (cos_in + cos_out) / 2`` the obliquity.  Following the
generalised-ray view of wave-optical transport (Steinberg et al., "A
generalized ray formulation for wave-optics rendering", 2024), where a
diffracted ray is *attached* to the edge that diffracts it and a Gaussian
footprint bounds the region it stands for, ``A`` is parameterised from the
edge: ``y = e(tau) + p m``, ``e(tau)`` on the edge, ``m`` the unit vector in
the screen's plane perpendicular to the edge pointing into the open side,
``p >= 0``.  With the path length expanded to second order in ``p``,
``phi = phi_e(tau) + g p + h p^2 / 2`` (``g = m . (k_in - k_out)``, ``h =
(1 - (m . k_in)^2) / s + (1 - (m . k_out)^2) / r``), the ``p`` integral is a
Fresnel integral:

.. math::

    \int_0^\infty e^{-j k \phi} dp = e^{-j k \phi_e} e^{j k g^2 / (2 h)}
    \sqrt{\pi / (k h)}\; T(w),\qquad w = g \sqrt{k / (\pi h)},
    \qquad T(w) = \int_w^\infty e^{-j \pi t^2 / 2} dt.

The geometric-optics part of the lit side (``w < 0``: ``T -> 1 - j``) is
the direct connection the solver already has, so the diffracted ray keeps
the boundary-diffraction-wave part ``T_d(w) = sign(w) T(|w|)`` (Miyamoto &
Wolf, JOSA 52, 1962: Kirchhoff = geometric field + edge wave); ``T`` is
evaluated with the rational auxiliary functions of Abramowitz & Stegun
(7.3.32-33, error below 2e-3).  The remaining integral along the edge is
sampled: ``NODES`` stratified, jittered nodes in a Gaussian footprint of
width ``sigma = 1.5 sqrt(lambda / h_tau)`` (``h_tau`` the path length's
curvature along the edge at its stationary point, i.e. 1.5 Fresnel zones),
the footprint's bias on a quadratic phase removed in closed form.  Each node
is a diffracted ray ``x -> e(tau) -> c`` whose two segments are traced for
visibility (detached, frozen on the tape).

Only boundary edges (one adjacent face: thin screens, plates, LiDAR mesh
borders) diffract; the open side is the one away from the adjacent face.
A connection takes the edges whose Fresnel parameter seen from it is below
:data:`SELECT` (:func:`_select`), at most :data:`MAX_EDGES`.

Output: the ratio ``D = U_d(c) / (e^{-j k |c - x|} / |c - x|)`` -- the
diffracted field relative to the unobstructed one -- so that the solver's
per-element legs stay those of the direct connection; a path's Jones vector
is projected on the arrival direction's transmitter polarisation
(:func:`fsd_emission`).  Everything but the node positions along the edge
(detached samples, carried by the differentiable edge vertices) is inside
the AD graph: ``D`` follows the edge vertices and ``x`` (and the pose).
"""
from __future__ import annotations

import math

import numpy as np

from ...utils.backend import init_backend
from ..polarization import transverse
from .state import Connection

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

#: nodes per (connection, edge) along the edge
NODES = 256
#: footprint width in Fresnel zones along the edge, and its extent in widths
FOOTPRINT = 1.5
EXTENT = 3.5
#: edges whose Fresnel parameter seen from the segment x -> c exceeds this are skipped
SELECT = 8.0
#: most edges per connection
MAX_EDGES = 4


def fresnel_tail(w):
    """``(re, im)`` of ``T(w) = int_w^inf exp(-j pi t^2 / 2) dt`` for real ``w``
    (Abramowitz & Stegun 7.3.9-10 with the rational 7.3.32-33; Dr.Jit, AD)."""
    a = dr.abs(w)
    f = (1.0 + 0.926 * a) / (2.0 + 1.792 * a + 3.104 * a * a)
    g = 1.0 / (2.0 + 4.142 * a + 3.492 * a * a + 6.670 * a * a * a)
    ph = 0.5 * math.pi * a * a
    sn, cs = dr.sin(ph), dr.cos(ph)
    re = g * cs - f * sn                # 1/2 - C(|w|)
    im = -(f * cs + g * sn)             # -(1/2 - S(|w|))
    neg = w < 0
    return dr.select(neg, 1.0 - re, re), dr.select(neg, -1.0 - im, im)


def boundary_edges(geo) -> dict | None:
    """Boundary edges of the scene: vertex ids ``v0, v1`` and the apex ``a``
    of the adjacent face (numpy), an :class:`~sionna_mmir.scene.edges.EdgeIndex`."""
    from ...scene.edges import WELD_TOL, EdgeIndex, find_diffracting_edges

    verts = np.asarray(dr.detach(geo.positions), dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(geo.faces, dtype=np.int64).reshape(-1, 3)
    es = find_diffracting_edges(verts, faces, weld_tol=WELD_TOL)   # seams are not edges
    keep = np.flatnonzero(np.asarray(es.kind) == 0) if len(es) else np.zeros(0, np.int64)
    if keep.size == 0:
        return None
    sub = type(es)(**{f: getattr(es, f)[keep] for f in es.__dataclass_fields__})
    return {"v0": es.v0[keep], "v1": es.v1[keep], "a": es.a0[keep], "index": EdgeIndex(sub)}


def _select(edges, x, c, wavelength):
    """``(query, edge)`` pairs: up to :data:`MAX_EDGES` boundary edges whose
    Fresnel parameter ``nu = delta sqrt(2 / (lambda d f (1 - f)))`` seen from
    the segment ``x [Q, 3] -> c [3]`` is below :data:`SELECT` (``delta`` the
    distance between the edge and the segment, reached at the fraction ``f``
    of its length ``d``: the edges of the surface holding ``x`` itself have
    ``f -> 0`` and drop out), smallest first (numpy, detached)."""
    d = np.linalg.norm(c[None] - x, axis=1)
    radius = SELECT * np.sqrt(wavelength * np.maximum(d, 1e-3) / 8.0)   # nu < SELECT at f = 1/2
    qs, es = [], []
    rows = np.arange(len(x))
    for f in np.linspace(0.05, 0.95, 10):
        idx, ok, dist = edges["index"].query(x + f * (c[None] - x), float(radius.max()),
                                             max_edges=4 * MAX_EDGES, return_distance=True)
        ok &= dist < radius[:, None]
        qs.append(np.broadcast_to(rows[:, None], idx.shape)[ok])
        es.append(idx[ok])
    q, e = np.concatenate(qs), np.concatenate(es)
    n_e = int(e.max()) + 1 if e.size else 1
    key = np.unique(q * n_e + e)
    q, e = key // n_e, key % n_e
    src = edges["index"].edges
    delta, frac = _segment_distance(x[q], np.broadcast_to(c, x[q].shape), src.p0[e], src.p1[e])
    nu = delta * np.sqrt(2.0 / (wavelength * d[q] * np.maximum(frac * (1.0 - frac), 1e-12)))
    good = nu < SELECT
    q, e, nu = q[good], e[good], nu[good]
    order = np.lexsort((nu, q))
    q, e = q[order], e[order]
    rank = np.arange(len(q)) - np.searchsorted(q, q)      # position within its query
    keep = rank < MAX_EDGES
    return q[keep], e[keep]


def _segment_distance(a0, a1, b0, b1):
    """``(distance, s)`` between segments ``a0 a1`` and ``b0 b1`` (rows), ``s``
    the fraction along ``a`` of the closest point (Ericson, *Real-Time
    Collision Detection*, 5.1.9)."""
    d1, d2, r = a1 - a0, b1 - b0, a0 - b0
    a, e, f = (d1 * d1).sum(1), (d2 * d2).sum(1), (d2 * r).sum(1)
    c_, b = (d1 * r).sum(1), (d1 * d2).sum(1)
    den = np.maximum(a * e - b * b, 1e-30)
    s = np.clip((b * f - c_ * e) / den, 0.0, 1.0)
    t = (b * s + f) / np.maximum(e, 1e-30)
    s = np.where(t < 0, np.clip(-c_ / np.maximum(a, 1e-30), 0, 1), s)
    s = np.where(t > 1, np.clip((b - c_) / np.maximum(a, 1e-30), 0, 1), s)
    t = np.clip(t, 0.0, 1.0)
    return np.linalg.norm(a0 + d1 * s[:, None] - (b0 + d2 * t[:, None]), axis=1), s


def edge_field(geo, edges, x, c, wavelength: float, tape, seed: int = 0, check_visible=True):
    """``(D_re, D_im, k_arr)``: diffracted-to-direct field ratio at ``c`` of a
    unit source at ``x`` and the arrival direction at ``c`` (module docstring).

    Parameters
    ----------
    geo : SceneGeometry
        The scene's differentiable mesh arrays (the edge vertices carry AD).
    edges : dict
        :func:`boundary_edges` of ``geo``.
    x : mi.Point3f
        Sources [m] (width ``Q``, AD).
    c : mi.Point3f
        Receiver [m] (width 1 or ``Q``, AD).
    wavelength : float
        [m].
    tape : Tape
        Freezes the edge choice, the nodes and the visibility.
    seed : int
        Seed of the node jitter.
    check_visible : bool
        Trace the two segments of every diffracted ray.

    Returns
    -------
    D_re, D_im : mi.Float
        ``U_d / U_direct`` (width ``Q``).
    k_arr : mi.Vector3f
        Unit arrival direction at ``c`` (``c - e``, ``e`` the strongest edge
        point; the direct one where no edge diffracts).
    """
    Q = dr.width(x)
    c = mi.Point3f(*(dr.zeros(mi.Float, Q) + c[i] for i in range(3)))
    k = 2.0 * math.pi / wavelength
    sel = tape.freeze_call(_pairs, edges, x, c, wavelength, seed, NODES)
    qi, vi0, vi1, vai, frac = sel
    ok_pair = dr.width(qi) > 0
    k_dir = dr.normalize(c - x)
    if not ok_pair:
        return dr.zeros(mi.Float, Q), dr.zeros(mi.Float, Q), k_dir
    X, Cc = _gather3(x, qi), _gather3(c, qi)
    P0, P1, A = (_vertex(geo, v) for v in (vi0, vi1, vai))
    t = dr.normalize(P1 - P0)
    L = dr.norm(P1 - P0)
    ap = A - P0
    m = -dr.normalize(ap - t * dr.dot(t, ap))              # in the plane, away from the face
    nf = dr.cross(t, m)
    tau_s, sig, lo, hi = _footprint(X, Cc, P0, t, L, wavelength)
    tau = lo + frac * (hi - lo)                             # frac: frozen jittered strata
    y = P0 + t * tau
    s_v, r_v = y - X, Cc - y
    s, r = dr.norm(s_v), dr.norm(r_v)
    kin, kout = s_v / s, r_v / r
    g = dr.dot(m, kin - kout)
    h = (1.0 - dr.square(dr.dot(m, kin))) / s + (1.0 - dr.square(dr.dot(m, kout))) / r
    w = g * dr.sqrt(k / (math.pi * h))
    t_re, t_im = fresnel_tail(w)
    t_re = dr.select(w < 0, t_re - 1.0, t_re)               # edge wave only: T - (1 - j)
    t_im = dr.select(w < 0, t_im + 1.0, t_im)
    chi = 0.5 * (dr.abs(dr.dot(nf, kin)) + dr.abs(dr.dot(nf, kout)))
    d_dir = dr.norm(Cc - X)
    phase = -k * (s + r - d_dir) + k * dr.square(g) / (2.0 * h)
    taper = dr.exp(-dr.square(tau - tau_s) / (2.0 * dr.square(sig)))
    mag = (chi / (s * r) * dr.sqrt(math.pi / (k * h)) * d_dir / wavelength * taper
           * (hi - lo) / NODES)
    cr, ci = mag * dr.cos(phase), mag * dr.sin(phase)
    z_re, z_im = cr * t_re - ci * t_im, cr * t_im + ci * t_re  # times T_d
    z_re, z_im = -z_im, z_re                                     # times j
    vis = tape.freeze_call(_visible, geo, X, y, Cc, m, check_visible)
    z_re, z_im = dr.select(vis, z_re, 0.0), dr.select(vis, z_im, 0.0)
    # remove the footprint's bias on a quadratic phase: sqrt(1 - j / (k h_tau sig^2))
    z_re, z_im = _times_sqrt_bias(z_re, z_im, k, sig, X, Cc, P0, t, tau_s)
    D_re, D_im = dr.zeros(mi.Float, Q), dr.zeros(mi.Float, Q)
    dr.scatter_reduce(dr.ReduceOp.Add, D_re, z_re, qi)
    dr.scatter_reduce(dr.ReduceOp.Add, D_im, z_im, qi)
    # arrival direction: from the node of largest weight of each connection
    wt = dr.detach(dr.sqrt(dr.square(z_re) + dr.square(z_im)))
    best = dr.zeros(mi.Float, Q)
    dr.scatter_reduce(dr.ReduceOp.Max, best, wt, qi)
    is_best = wt >= dr.gather(mi.Float, best, qi)
    k_arr = _scatter3(k_dir, dr.normalize(r_v), qi, is_best & (wt > 0))
    return D_re, D_im, dr.normalize(k_arr)


def _scatter3(base, value, index, active=True):
    """``base`` (a 3-vector) with ``value`` written at ``index``."""
    comps = [mi.Float(base[i]) for i in range(3)]
    for i in range(3):
        dr.scatter(comps[i], value[i], index, active)
    return mi.Vector3f(*comps)


def _gather3(v, idx):
    return mi.Point3f(*(dr.gather(mi.Float, v[i], idx) for i in range(3)))


def _vertex(geo, vid):
    return mi.Point3f(*(dr.gather(mi.Float, geo.positions, vid * 3 + i) for i in range(3)))


def _footprint(X, Cc, P0, t, L, wavelength):
    """Detached ``(tau*, sigma, lo, hi)``: the stationary point of the path
    length on the edge's line (Newton), the Gaussian footprint width and the
    sampled interval (footprint extent clipped to the edge)."""
    with dr.suspend_grad():
        X, Cc, P0, t, L = (dr.detach(v) for v in (X, Cc, P0, t, L))
        tau = dr.dot(t, 0.5 * (X + Cc) - P0)
        h_t = dr.ones(mi.Float, dr.width(tau))
        for _ in range(8):
            y = P0 + t * tau
            a, b = y - X, Cc - y
            la, lb = dr.norm(a), dr.norm(b)
            ka, kb = a / la, b / lb
            f = dr.dot(t, ka - kb)
            h_t = (1.0 - dr.square(dr.dot(t, ka))) / la + (1.0 - dr.square(dr.dot(t, kb))) / lb
            tau = tau - f / dr.maximum(h_t, 1e-9)
        sig = FOOTPRINT * dr.sqrt(wavelength / dr.maximum(h_t, 1e-9))
        lo = dr.clip(tau - EXTENT * sig, 0.0, L)
        hi = dr.clip(tau + EXTENT * sig, 0.0, L)
    return tau, sig, lo, hi


def _times_sqrt_bias(z_re, z_im, k, sig, X, Cc, P0, t, tau_s):
    with dr.suspend_grad():
        y = dr.detach(P0 + t * tau_s)
        a, b = y - dr.detach(X), dr.detach(Cc) - y
        la, lb = dr.norm(a), dr.norm(b)
        tt = dr.detach(t)
        h_t = ((1.0 - dr.square(dr.dot(tt, a / la))) / la
               + (1.0 - dr.square(dr.dot(tt, b / lb))) / lb)
        eps = 1.0 / (k * h_t * dr.square(sig))
        # sqrt(1 - j eps) in polar form
        mod = dr.sqrt(dr.sqrt(1.0 + eps * eps))
        arg = -0.5 * dr.atan2(eps, 1.0)
        b_re, b_im = mod * dr.cos(arg), mod * dr.sin(arg)
    return z_re * b_re - z_im * b_im, z_re * b_im + z_im * b_re


def _pairs(edges, x, c, wavelength, seed, nodes):
    """Frozen ``(query, v0, v1, apex, frac)`` of every node (detached)."""
    xs = np.stack([np.asarray(dr.detach(x)[i], dtype=np.float64) for i in range(3)], 1)
    cs = np.stack([np.asarray(dr.detach(c)[i], dtype=np.float64) for i in range(3)], 1)
    qs, es = _select(edges, xs, cs[0], wavelength) if len(xs) else (np.zeros(0, np.int64),) * 2
    rng = np.random.default_rng(int(seed) + 0xD1FF)
    n = len(qs)
    frac = ((np.arange(nodes)[None, :] + rng.random((n, nodes))) / nodes).ravel()
    rep = np.repeat(np.arange(n), nodes)
    u32 = lambda a: mi.UInt32(np.asarray(a, dtype=np.uint32))   # noqa: E731
    return (u32(qs[rep]), u32(edges["v0"][es][rep]), u32(edges["v1"][es][rep]),
            u32(edges["a"][es][rep]), mi.Float(frac.astype(np.float32)))


def _visible(geo, X, y, Cc, m, check):
    """Both segments of each diffracted ray unobstructed (node lifted 1 mm
    into the open side, off the screen's own faces)."""
    if not check:
        return dr.full(mi.Bool, True, dr.width(X))
    yl = dr.detach(y + m * 1e-3)
    return geo.visible(dr.detach(X), yl) & geo.visible(yl, dr.detach(Cc))


def fsd_emission(ctx, st, surf, conn, depth: int):
    """The coherent chain ending at ``x_l`` connected to the array through
    the edges that block its direct connection: ``(wr, wi, mask)`` of width
    ``K`` (the chain's physical-optics field times ``D``, the Tx
    polarisation taken along the arrival direction), or ``None``."""
    from . import coherent

    geo_ok = st.it.valid & (dr.dot(surf.n, conn.k_t) > 0) & (dr.dot(surf.ng, conn.k_t) > 0) \
        & (surf.cos_in > 0)
    blocked = ctx.tape.freeze(geo_ok & ~conn.ok & st.coh)
    lanes = dr.compress(blocked)
    if dr.width(lanes) == 0 or ctx.fsd_edges is None:
        return None
    x = _gather3(surf.x, lanes)
    D_re, D_im, k_arr = edge_field(ctx.geo, ctx.fsd_edges, x, ctx.c_w, ctx.wavelength, ctx.tape,
                                   seed=int(ctx.options.seed) + depth)
    K = st.width
    Dr_, Di_ = dr.zeros(mi.Float, K), dr.zeros(mi.Float, K)
    dr.scatter(Dr_, D_re, lanes)
    dr.scatter(Di_, D_im, lanes)
    ka = _scatter3(conn.k_t, k_arr, lanes)
    pose = ctx.pose
    e_t = transverse(pose.to_scene(ctx.ptx.polarization(pose.to_radar(-ka))), ka)
    via = Connection(k_t=ka, cos_t=conn.cos_t, ok=blocked, e_t=e_t, rate=conn.rate)
    wr, wi, m = coherent.coherent_field(ctx, st, surf, via, depth)
    return wr * Dr_ - wi * Di_, wr * Di_ + wi * Dr_, m
