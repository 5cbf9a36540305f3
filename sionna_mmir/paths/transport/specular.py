"""The SMS stage: specular manifold sampling as the specular connection on curved meshes.

On a curved object tessellated finely (or coarsely, with interpolated
vertex normals) the mirror direction at the point a ray happened to hit
leaves the hit triangle: the reflection towards the transmitter happens at a
point of another triangle, and on a smooth-shaded mesh no flat facet holds
it at all.  With ``SolverOptions.sms`` every interaction of a coherent chain
on a *curved* triangle (its three vertex normals differ) seeds the Newton
walk of :func:`sionna_mmir.paths.sms.solve_specular` (Zeltner, Georgiev &
Jakob, "Specular manifold sampling for rendering high-frequency caustics and
glints", ACM TOG 39(4), 2020), which moves on the mesh, re-projecting onto
it after every step, until the half-vector of ``a -> x -> c`` is the
interpolated normal; ``c`` is the array centre and ``a = U^-1(c)`` the
array seen through the chain's earlier mirrors (``c`` itself at depth 1:
monostatic).  The specular point ``x`` radiates the stationary-phase value
of the physical-optics integral
(:func:`sionna_mmir.paths.sms.stationary_phase`)::

    C = j / (4 pi) (e_t . E_refl) cos_i sqrt(eta_b) A_sp(x) W / N,

``A_sp = 2 pi / (k sqrt|det H|) exp(-j pi sig(H) / 4)``, ``E_refl`` the
chain's Jones vector reflected at ``x`` and ``W`` the
estimate of ``1 / p(x)``, ``p(x)`` the probability that a seed converges to
``x``.  ``W`` follows Zeltner et al.'s Bernoulli-trial estimator: trials draw
seeds from the same ``N`` candidates, a trial succeeds when its walk ends at
``x`` (within ``match``), so the trial count until the first success is
geometric with success probability ``c(x) / N`` (``c`` the candidates whose
walk ends there) and is drawn as such; ``E[W] = N / c(x)`` makes the sum
over the seeds an unbiased estimate of the sum over the specular points the
walks find (``c(x) - 1`` is binomial, so the expectation over the candidates
is the sum over all specular points, each times ``1 - (1 - p(x))^N``: the
bias is the chance that no seed reaches a point, as for Zeltner et al.'s
capped trials).  Under the deterministic facet quadrature ``W = N / c(x)``.
The seeds that reached one specular point are merged into one path carrying
their summed ``W`` (:func:`merge_walks`).
Multi-bounce chains (:func:`sms_stage`): the radar is monostatic, so a chain
and its reversal are the same field; a chain whose last vertex is curved and
first is flat is emitted for both, and the chains that start on a curved
triangle (which the mirror continuation carries with the tangent-plane
mirror of a curved surface, the image method's error) are dropped.
These lanes' own physical-optics term is dropped (the stationary-phase value
replaces the integral over the curved surface they sample).

Gradients: the specular point moves by the implicit function theorem
(:func:`sionna_mmir.paths.sms.specular_point_ad`), and the amplitude and
the per-element legs follow it; the walk, the trial counts and the
visibility are detached and frozen on the tape (a replay re-uses them).

Limits: stationary phase needs the first Fresnel zone about ``x`` to lie on
the curved surface (no truncation by its rim) and a non-degenerate ``H``;
the earlier vertices of a chain are taken as plane mirrors (exact for flat
ones; a curved vertex in the middle of a chain keeps its tangent-plane
mirror); chains that start and end on curved triangles are dropped; the
segment from ``x`` back to the chain's previous vertex is not traced for
visibility; the two orders of a chain share one set of per-element legs.
"""
from __future__ import annotations

import math

import numpy as np

from ...radio_materials.fresnel import complex_permittivity, slab_coefficients
from ...radio_materials.fresnel import SPEED_OF_LIGHT
from ...utils.backend import init_backend
from ..polarization import Field, reflect_field, transverse
from ..sms import SpecularSolution, solve_specular, stationary_phase
from .motion import vertex_rate
from .state import Emission, zeros

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

#: two walks that end closer than this [m] found the same specular point
MATCH = 1e-4


def curved_faces(geo) -> np.ndarray:
    """``bool [F]``: triangles whose three vertex normals are not parallel."""
    nrm = np.asarray(dr.detach(geo.normals), dtype=np.float64).reshape(-1, 3)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-30)
    f = np.asarray(geo.faces, dtype=np.int64).reshape(-1, 3)
    n0, n1, n2 = nrm[f[:, 0]], nrm[f[:, 1]], nrm[f[:, 2]]
    dots = np.minimum(np.minimum(np.sum(n0 * n1, 1), np.sum(n0 * n2, 1)), np.sum(n1 * n2, 1))
    return dots < 1.0 - 1e-7


def sms_stage(ctx, st, m, depth: int):
    """``(mask, emission)``: the physical-optics mask ``m`` of the chains
    ending here without the ones SMS replaces, and the SMS paths (or ``None``).

    Depth 1: every interaction on a curved triangle is replaced.  Deeper
    chains (monostatic, so reciprocal): a chain whose *last* vertex is
    curved and first is not gives its specular point twice (itself and its
    reversed twin), and chains that *start* on a curved triangle -- the
    reversed twins, which the mirror continuation would carry with the
    tangent-plane mirror of a curved surface -- are dropped.
    """
    curved, lanes = sms_lanes(ctx, st)
    if depth == 1:
        st.curved1 = curved
        return m & ~curved, sms_emission(ctx, st, lanes, depth)
    first = st.curved1 if st.curved1 is not None else dr.zeros(mi.Bool, st.width)
    lanes = dr.compress(curved & ~first)
    return m & ~curved & ~first, sms_emission(ctx, st, lanes, depth, twins=2.0)


def sms_lanes(ctx, st):
    """``(mask, indices)`` of the coherent chains' interactions on curved
    triangles."""
    curved = ctx.tape.freeze_call(_curved_lanes, ctx, st)
    return curved, dr.compress(curved)


def _curved_lanes(ctx, st):
    table = mi.Bool(curved_faces(ctx.geo))
    return st.it.valid & st.coh & dr.gather(mi.Bool, table, st.it.face, st.it.valid)


def trial_weights(pos, obj, valid, n_seeds: int, rng, deterministic: bool) -> np.ndarray:
    """``W`` of each walk: the Bernoulli-trial estimate of ``1 / p(x)``.

    Parameters
    ----------
    pos : ndarray, shape (M, 3)
        End points of the walks [m].
    obj : ndarray, shape (M,)
        Their objects.
    valid : ndarray of bool, shape (M,)
        Walks that found a specular point.
    n_seeds : int
        Seeds a trial draws from (the candidates ``N``; 1 under the facet
        quadrature, whose estimate is not divided by ``N``).
    rng : numpy.random.Generator
        Source of the trial counts.
    deterministic : bool
        Return the expectation ``N / c`` instead of a geometric draw.

    Returns
    -------
    ndarray, shape (M,)
        ``W`` (0 on invalid walks).
    """
    W = np.zeros(len(pos))
    idx = np.flatnonzero(valid)
    if idx.size == 0:
        return W
    counts = _match_counts(pos[idx], obj[idx])
    if deterministic:
        W[idx] = float(n_seeds) / counts
    else:
        W[idx] = rng.geometric(np.clip(counts / float(n_seeds), 1e-12, 1.0)).astype(np.float64)
    return W


def _cells(pos, obj):
    """Integer cells of side :data:`MATCH` and a hash key of (cell, object)."""
    cell = np.floor(pos / MATCH).astype(np.int64)
    primes = np.array([73856093, 19349663, 83492791], dtype=np.int64)

    def key(cl):
        return (cl * primes).sum(axis=1) ^ (obj.astype(np.int64) * 2654435761)

    return cell, key


def _match_counts(pos, obj) -> np.ndarray:
    """For each end point, the end points on its object within about
    :data:`MATCH` (a cell grid of that size and its 26 neighbours; distinct
    specular points lie much further apart)."""
    cell, key = _cells(pos, obj)
    uniq, cnt = np.unique(key(cell), return_counts=True)
    out = np.zeros(len(pos))
    for off in np.stack(np.meshgrid(*([np.arange(-1, 2)] * 3), indexing="ij"), -1).reshape(-1, 3):
        k = key(cell + off)
        j = np.clip(np.searchsorted(uniq, k), 0, len(uniq) - 1)
        out += np.where(uniq[j] == k, cnt[j], 0)
    return out


def merge_walks(pos, obj, W) -> np.ndarray:
    """Walks that ended in the same cell are one specular point: the first
    carries their summed ``W`` (the estimate is unchanged, one path is
    emitted instead of one per seed), the others get 0."""
    out = np.zeros_like(W)
    idx = np.flatnonzero(W > 0)
    if idx.size == 0:
        return out
    cell, key = _cells(pos[idx], obj[idx])
    _, first, inv = np.unique(key(cell), return_index=True, return_inverse=True)
    np.add.at(out, idx[first], np.bincount(inv.ravel(), weights=W[idx]))
    return out


def _image(st, lanes, c):
    """``U^-1(c)``: the array centre seen through the chain's mirrors (the
    walk's virtual source; ``c`` itself at depth 1) and ``U`` at ``lanes``."""
    cols = [mi.Vector3f(*(_take(col[i], lanes) for i in range(3))) for col in st.U[0]]
    off = mi.Vector3f(*(_take(st.U[1][i], lanes) for i in range(3)))
    d = c - off                                       # U is orthogonal: U^-1 = A^T (y - off)
    return mi.Point3f(*(dr.dot(col, d) for col in cols)), (cols, off)


def _take(arr, idx):
    """``arr[idx]``; a width-1 ``arr`` (the identity ``U`` of depth 1) broadcast."""
    if dr.width(arr) == 1:
        return dr.zeros(mi.Float, dr.width(idx)) + arr
    return dr.gather(mi.Float, arr, idx)


def _solve(ctx, st, lanes, depth):
    """Frozen ``(valid, obj, prim, u, v, W, lane)`` of the specular points
    found from ``lanes`` (``lane``: the chain that carries each)."""
    tape, geo = ctx.tape, ctx.geo
    if tape.replaying:
        return [tape.freeze(None) for _ in range(7)]
    with dr.suspend_grad():
        c = dr.detach(ctx.c_w)
        a, _ = _image(st, lanes, c)
        seed = mi.Point3f(*(dr.gather(mi.Float, dr.detach(st.it.p[i]), lanes) for i in range(3)))
        sol = solve_specular(geo.scene, dr.detach(a), c, seed, max_iter=40, tol=1e-6,
                             trace_a=depth == 1)
    x = np.stack([np.asarray(sol.position[i], dtype=np.float64) for i in range(3)], axis=1)
    rng = np.random.default_rng(int(ctx.options.seed) + 0x5EED + depth)
    obj = np.asarray(sol.object_id, dtype=np.int64)
    W = trial_weights(x, obj, np.asarray(sol.valid, dtype=bool), int(ctx.n_est), rng,
                      ctx.sampler.deterministic_chains)
    W = merge_walks(x, obj, W)
    keep = mi.UInt32(np.flatnonzero(W > 0).astype(np.uint32))
    out = (mi.Bool(True) & dr.gather(mi.Bool, sol.valid, keep),
           dr.gather(mi.UInt32, sol.object_id, keep), dr.gather(mi.UInt32, sol.prim_index, keep),
           dr.gather(mi.Float, sol.bary.x, keep), dr.gather(mi.Float, sol.bary.y, keep),
           mi.Float(W[W > 0].astype(np.float32)), dr.gather(mi.UInt32, lanes, keep))
    return [tape.freeze(v) for v in out]


def sms_emission(ctx, st, lanes, depth: int = 1, twins: float = 1.0) -> Emission | None:
    """The specular points found from ``lanes`` as paths of ``depth``
    interactions (see the module docstring), ``twins`` times; ``None`` when
    there are none."""
    if dr.width(lanes) == 0:
        return None
    valid, obj, prim, u0, v0, W, lane = _solve(ctx, st, lanes, depth)
    M = dr.width(valid)
    if M == 0:
        return None
    sol = SpecularSolution(valid=valid, shape=None, object_id=obj, prim_index=prim,
                           bary=mi.Point2f(u0, v0), position=None, normal=None,
                           iterations=None, error=None)
    c = mi.Point3f(*(dr.zeros(mi.Float, M) + ctx.c_w[i] for i in range(3)))
    a, (cols, off) = _image(st, lane, c)
    x, u, v, ar, ai = stationary_phase(ctx.geo.scene, sol, a, c, ctx.k_wave)
    face = dr.gather(mi.UInt32, ctx.geo._face_offset, dr.select(valid, obj, 0)) + prim
    it = ctx.geo.interaction(valid, obj, face, u, v)
    k_in, k_t = dr.normalize(x - a), dr.normalize(c - x)
    n = dr.select(dr.dot(it.n, k_in) > 0, -it.n, it.n)
    cos_i = dr.maximum(-dr.dot(k_in, n), 0.0)
    sc = slab_coefficients(cos_i, complex_permittivity(it.mat[0], it.mat[1], backend="drjit"),
                           it.mat[5], ctx.frequency, backend="drjit")
    pose = ctx.pose
    E = reflect_field(_incident(ctx, st, lane, k_in, depth), k_in, n, sc.r_s, sc.r_p)
    e_t = transverse(pose.to_scene(ctx.ptx.polarization(pose.to_radar(-k_t))), k_t)
    pr, pi_ = E.dot(e_t)
    eta_b = dr.exp(-dr.square(ctx.k_wave * it.mat[2] * 2.0 * cos_i))
    scale = twins * cos_i * dr.sqrt(eta_b) * W / (4.0 * math.pi * ctx.n_est)
    wr, wi = -pi_ * scale, pr * scale            # j (pr + j pi)
    m = valid & (W > 0) & (cos_i > 0)
    k0 = k_in if depth == 1 else dr.gather(mi.Vector3f, st.k0, lane)
    rate = dr.gather(mi.Float, st.rate_chain, lane) + vertex_rate(ctx.velocities, obj, k_in, k_t)
    rate = (rate - dr.detach(dr.dot(ctx.v_radar, k0) + dr.dot(ctx.v_radar, -k_t))) \
        / SPEED_OF_LIGHT
    x_rx = mi.Point3f(cols[0] * x.x + cols[1] * x.y + cols[2] * x.z + off)     # U(x)
    obj1 = obj if depth == 1 else dr.gather(mi.UInt32, st.obj1, lane)
    return Emission(dr.select(m, wr * ar - wi * ai, 0.0), dr.select(m, wr * ai + wi * ar, 0.0),
                    x, x_rx, zeros(M), zeros(M), rate, depth, m, obj1)


def _incident(ctx, st, lane, k_in, depth: int) -> Field:
    """The field arriving at the specular point along ``k_in``: the receiver
    element's polarisation at depth 1, else the chain's Jones vector made
    transverse to ``k_in``."""
    if depth == 1:
        pose = ctx.pose
        return Field(transverse(pose.to_scene(ctx.prx.polarization(pose.to_radar(k_in))), k_in))
    re = mi.Vector3f(*(dr.gather(mi.Float, st.E.re[i], lane) for i in range(3)))
    im = mi.Vector3f(*(dr.gather(mi.Float, st.E.im[i], lane) for i in range(3)))
    return Field(re - k_in * dr.dot(re, k_in), im - k_in * dr.dot(im, k_in))
