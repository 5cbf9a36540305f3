"""The boundary (visibility) term of the solver's geometry and pose gradients.

The depth-1 returns the solver estimates are an integral over the directions
``w`` from the array's phase centre ``c`` of the field ``H(w)`` of the first
surface point ``y(w)`` a ray in that direction meets (per steradian; the
Monte Carlo sample of direction ``w`` carries ``H(w) / (N pdf(w))``).
Interaction points are attached to the mesh (fixed triangle and
barycentrics), so automatic differentiation of the samples gives the
*interior* part of the derivative: the change of every sample with its
region of the surface held fixed.  What it misses is the change of the
region itself: where a silhouette edge moves relative to the surface behind
it, a strip of that surface is hidden or revealed.  With ``s(theta)`` the
angular displacement of the edge relative to the far surface along the unit
vector ``n`` pointing to the far side (perpendicular to the ray and to the
edge),

    dI/dtheta = interior - sum_edges int_edge H_far(w(x)) (sin(alpha) / r_e) ds/dtheta dl(x),

    s = n . (e - c) / r_e - n . (y - c) / r_y,

where ``x`` runs along the edge (length element ``dl``), ``e`` is the edge
point, ``r_e = |e - c|``, ``alpha`` the angle between the edge and the ray,
``y`` the far surface point behind ``e`` at ``r_y`` and ``H_far`` the
integrand just beyond the edge (Li et al. 2018, "Differentiable Monte
Carlo ray tracing through edge sampling", eq. 5, in the directional
parameterisation; the relative displacement is the projective form of
Zhang et al. 2023, "Projective sampling for differentiable rendering of
geometry").  ``sin(alpha) dl / r_e`` is the angular length of the edge
element, so the product with ``ds`` is the solid angle that changes sides.

The edge integral is estimated with ``M`` stratified samples on the
silhouette edges seen from ``c`` (:mod:`.silhouette`); each becomes a path
whose amplitude is the far-side sample's amplitude times
``-N sin(alpha) / r_e (s - detach(s)) / (M p_l)``: zero in value (no
rendered quantity changes) and the boundary term in derivative, for every
quantity linear in the path amplitudes -- the ADC and everything computed
from it (range-azimuth maps, the fit loss).  The edges are the silhouettes
seen from the array centre because the solver connects every depth-1
return to the transmitter through that same point: the primary ray and the
connection share one visibility.

The rim of the random rays' cone is a boundary of the same kind, fixed in
the radar frame (:func:`rim_emissions`): when the radar turns or moves, it
sweeps over the scene.

Scope: the coherent (physical-optics) depth-1 field and the radar pose and
vertex positions; deeper chains and the random-phase speckle part (zero
mean in the ADC) get no boundary term.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from ...utils.backend import init_backend
from ..geometry import Tape
from ..transport import coherent
from ..transport.connection import connect
from ..transport.state import Emission, start_state, zeros
from ..transport.surface import at_surface
from .silhouette import SilhouetteEdges

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

#: offset of the near / far probe rays from the edge, relative to its range
PROBE = 2e-4


def _vec(a):
    a = np.asarray(a, dtype=np.float32)
    return mi.Vector3f(mi.Float(a[:, 0]), mi.Float(a[:, 1]), mi.Float(a[:, 2]))


def _frame(ctx):
    """``(c, boresight, cos of the cone)`` of the call, detached NumPy."""
    c = np.array([float(dr.detach(ctx.c_w)[i][0]) for i in range(3)], dtype=np.float64)
    bore = np.array([float(dr.detach(r.x)[0]) for r in ctx.pose.rows], dtype=np.float64)
    return c, bore, math.cos(math.radians(float(ctx.options.cone_angle_deg)))


def _probe(ctx, c, s):
    """Trace the near and far probes of every edge sample (no AD).

    Returns ``(ok, far hit)``: ``ok`` where the edge point is seen from ``c``
    (the near probe meets one of the edge's own faces) and something lies
    behind it; the far hit ``(valid, obj, face, u, v)``.
    """
    geo = ctx.geo
    r_e = np.linalg.norm(s.point - c, axis=1, keepdims=True)
    M = len(s)
    # the centre as an array, not literals: a new pose must not recompile kernels
    origin = dr.zeros(mi.Point3f, M) + dr.detach(ctx.c_w)
    d_near = s.point - PROBE * r_e * s.far - c
    d_far = s.point + PROBE * r_e * s.far - c
    d_near /= np.linalg.norm(d_near, axis=1, keepdims=True)
    d_far /= np.linalg.norm(d_far, axis=1, keepdims=True)
    nv, _, nface, _, _ = geo._trace(origin, _vec(d_near), True)
    nface = np.asarray(nface, dtype=np.int64)
    near_ok = np.asarray(nv, dtype=bool) & ((nface == s.faces[:, 0]) | (nface == s.faces[:, 1]))
    hit = geo._trace(origin, _vec(d_far), mi.Bool(near_ok))
    return mi.Bool(near_ok) & hit[0], hit


def _displacement(ctx, s, c, y):
    """The edges' relative angular displacement ``s(theta)`` of the module
    docstring (AD) at the far points ``y``."""
    geo = ctx.geo
    i0, i1 = mi.UInt32(s.v0.astype(np.uint32)), mi.UInt32(s.v1.astype(np.uint32))
    p0 = mi.Point3f(*(dr.gather(mi.Float, geo.positions, i0 * 3 + k) for k in range(3)))
    p1 = mi.Point3f(*(dr.gather(mi.Float, geo.positions, i1 * 3 + k) for k in range(3)))
    t = mi.Float(s.t.astype(np.float32))
    e = p0 * (1.0 - t) + p1 * t
    n = _vec(s.far)
    r_e = mi.Float(np.linalg.norm(s.point - c, axis=1).astype(np.float32))
    r_y = dr.detach(dr.norm(y - ctx.c_w))
    return dr.dot(n, e - ctx.c_w) / r_e - dr.dot(n, y - ctx.c_w) / r_y


def _paths(ctx, hit, ok, w, displacement):
    """Zero-valued paths at the first hits ``hit`` (directions ``ok``) of
    weight ``w`` (``mi.Float``) times ``displacement(y) - detach(...)``.

    The far-side field is evaluated outside AD: the path's value is zero, so
    the derivative of ``field * kappa`` is ``field * d kappa`` exactly, and
    only the displacement ``kappa`` carries gradients (a small graph)."""
    geo = ctx.geo
    M = dr.width(w)
    bctx = dataclasses.replace(ctx, tape=Tape())
    it = geo.interaction(*hit, bctx.tape)
    disp = displacement(it.p)
    with dr.suspend_grad():
        st = start_state(bctx, it, dr.ones(mi.Float, M), it.tri)  # pdf 1: amplitude H / n_est
        surf = at_surface(bctx, st, 1)
        conn = connect(bctx, st, surf)
        coherent.unfold(st, surf, 1)
        wr, wi, _ = coherent.coherent_field(bctx, st, surf, conn, 1)
        ok &= (surf.cos_in > 0) & (dr.dot(surf.ng, conn.k_t) > 0) & (conn.cos_t > 0)
        wr, wi = dr.select(ok, wr, 0.0), dr.select(ok, wi, 0.0)
        x, x1, rate = dr.detach(surf.x), dr.detach(st.x1), dr.detach(conn.rate)
        dr.eval(wr, wi, ok, x, x1, rate)
    kappa = w * (disp - dr.detach(disp))
    return [Emission(wr * kappa, wi * kappa, x, x1, zeros(M), zeros(M), rate, 1, ok, st.obj1,
                     boundary=True)]


def edge_emissions(ctx, seed: int) -> list:
    """The boundary paths of the silhouette edges (an empty list when no
    silhouette edge lies in the cone), ``seed`` the strata offsets' seed."""
    geo, opts = ctx.geo, ctx.options
    V = np.asarray(dr.detach(geo.positions), dtype=np.float64).reshape(-1, 3)
    F = np.asarray(geo.faces, dtype=np.int64).reshape(-1, 3)
    c, bore, cos_cone = _frame(ctx)
    edges = SilhouetteEdges.cached(geo.scene, F, V)
    s = edges.sample(V, c, int(opts.boundary_samples), seed, bore, cos_cone)
    if s is None:
        return []
    ok, hit = _probe(ctx, c, s)
    ray = s.point - c
    r_e = np.linalg.norm(ray, axis=1)
    ray /= r_e[:, None]
    ok &= mi.Bool(ray @ bore >= cos_cone)
    tang = V[s.v1] - V[s.v0]
    sin_a = np.linalg.norm(np.cross(ray, tang / np.linalg.norm(tang, axis=1)[:, None]), axis=1)
    w = mi.Float((-float(ctx.n_est) * sin_a / r_e * s.inv_density).astype(np.float32))
    return _paths(ctx, hit, ok, w, lambda y: _displacement(ctx, s, c, y))


def rim_emissions(ctx, seed: int) -> list:
    """The boundary paths of the rim of the random rays' cone.

    The cone is fixed in the radar frame, so when the radar turns or moves
    it sweeps over the scene: along the rim (half-angle ``beta``, unit
    outward normal ``n`` on the sphere of directions) the relative
    displacement is ``s = n . w(theta) - n . (y - c) / r_y`` and the region
    inside gains ``sin(beta) dphi ds`` of solid angle (``M`` stratified
    azimuths ``phi``)."""
    opts = ctx.options
    M = max(int(opts.boundary_samples) // 4, 16)
    beta = math.radians(float(opts.cone_angle_deg))
    phi = 2.0 * math.pi * (np.arange(M) + np.random.default_rng(int(seed) + 1).random(M)) / M
    cb, sb = math.cos(beta), math.sin(beta)
    d_loc = np.stack([np.full(M, cb), sb * np.cos(phi), sb * np.sin(phi)], axis=1)
    n_loc = np.stack([np.full(M, -sb), cb * np.cos(phi), cb * np.sin(phi)], axis=1)
    pose = ctx.pose
    w_dir = pose.to_scene(_vec(d_loc))                               # AD (orientation)
    n = dr.detach(pose.to_scene(_vec(n_loc)))
    c = dr.detach(ctx.c_w)
    origin = dr.zeros(mi.Point3f, M) + c
    hit = ctx.geo._trace(origin, dr.detach(w_dir), True)
    ok = mi.Bool(hit[0])
    w = dr.opaque(mi.Float, float(ctx.n_est) * sb * 2.0 * math.pi / M, M)

    def displacement(y):
        r_y = dr.detach(dr.norm(y - ctx.c_w))
        return dr.dot(n, w_dir) - dr.dot(n, y - ctx.c_w) / r_y
    return _paths(ctx, hit, ok, w, displacement)


def boundary_emissions(ctx, seed: int) -> list:
    """The boundary paths of one solver call: silhouette edges and (random
    rays) the cone's rim; ``seed`` seeds the strata offsets."""
    out = edge_emissions(ctx, seed)
    if ctx.options.sampling == "random":
        out += rim_emissions(ctx, seed)
    return out
