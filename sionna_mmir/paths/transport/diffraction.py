"""Free-space diffraction (FSD, Steinberg et al. 2024) as a continuation event.

At interactions near boundary or crease edges
(:func:`sionna_mmir.scene.edges.find_diffracting_edges`) a ray is diffracted
with probability ``beta`` -- the FSD diffracted fraction
(:func:`sionna_mmir.bsdf.fsd.beta`) scaled by the Fresnel energy gate of the
surface as edge opacity -- into a forward direction sampled from the FSD
lobe, and continues as a power (incoherent) path.  The event is detached:
diffraction redirects power but passes no gradient.  The coherent,
differentiable counterpart (``SolverOptions.fsd_coherent``) is
:mod:`.fsd_coherent`.
"""
from __future__ import annotations

import numpy as np

from ...utils.backend import init_backend
from ..polarization import polarization_fractions

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402


def gate_fsd(E, k_in, n, sc):
    """Edge opacity of the FSD lobe: the Fresnel energy gate of the surface."""
    fs, fp = polarization_fractions(E, k_in, n)
    return fs * dr.squared_norm(sc.r_s) + fp * dr.squared_norm(sc.r_p)


#: the last scene's FSD state (edges, index, query memo), by geometry and lobe width
_SETUP: dict = {}
#: edge queries remembered per scene (the facet quadrature's hit points repeat
#: from call to call: a fit renders the same first hits every iteration)
QUERY_MEMO = 8


def fsd_setup(geo, wavelength, width):
    """Diffracting edges of the scene, their index and the lobe width [m]
    (cached for the last geometry)."""
    from ...scene.edges import WELD_TOL, EdgeIndex, find_diffracting_edges

    verts = np.asarray(dr.detach(geo.positions), dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(geo.faces, dtype=np.int64).reshape(-1, 3)
    s = float(width) if width is not None else 3.0 * wavelength
    key = (verts.shape, faces.shape, hash(verts.tobytes()), hash(faces.tobytes()), s)
    if _SETUP.get("key") != key:
        es = find_diffracting_edges(verts, faces, weld_tol=WELD_TOL)   # seams are not edges
        _SETUP.clear()
        _SETUP.update(key=key, state={"edges": es, "index": EdgeIndex(es) if len(es) else None,
                                      "s": s, "radius": 3.0 * s, "memo": {}})
    return _SETUP["state"]


def _near_edges(state, xs):
    """``(idx, ok)`` ``[N, 4]``: the edges within the lobe's search radius of
    the points ``xs`` (remembered for the last :data:`QUERY_MEMO` point sets)."""
    memo = state["memo"]
    key = (xs.shape, hash(xs.tobytes()))
    if key not in memo:
        if len(memo) >= QUERY_MEMO:
            memo.pop(next(iter(memo)))
        memo[key] = state["index"].query(xs, state["radius"], max_edges=4)
    return memo[key]


def diffract(ctx, x, k_in, opacity, valid):
    """``(mask, direction)`` of lanes diffracted by nearby edges (detached).

    The FSD lobe is evaluated on the lanes with an edge within the search
    radius only (elsewhere ``beta = 0``), and its sampled directions are
    stored (frozen) rather than left as an expression that every later
    kernel of the path -- forward and backward -- would recompute.
    """
    state, rng, tape = ctx.fsd, ctx.rng, ctx.tape
    n = dr.width(valid)
    u = [rng.next_float32() for _ in range(4)]          # u_d, u1, u2, u3 of every lane
    if state["index"] is None:
        return tape.freeze(dr.zeros(mi.Bool, n)), dr.zeros(mi.Vector3f, n)
    xs = np.column_stack([np.asarray(dr.detach(x[c]), dtype=np.float64) for c in range(3)])
    idx, ok = _near_edges(state, xs)
    ok = ok & np.asarray(valid, dtype=bool)[:, None]
    near = np.flatnonzero(ok.any(axis=1))
    mask, wo = dr.zeros(mi.Bool, n), dr.zeros(mi.Vector3f, n)
    if near.size:
        m_near, wo_near = _diffract_near(ctx, near, idx[near], ok[near], x, k_in, opacity, u)
        rows = mi.UInt32(near.astype(np.uint32))
        dr.scatter(mask, m_near, rows)
        dr.scatter(wo, wo_near, rows)
    return tape.freeze(mask), tape.freeze(wo)


def _diffract_near(ctx, near, idx, ok, x, k_in, opacity, u):
    """``(mask, direction)`` of the lanes ``near`` (numpy ids) with their edges
    ``idx`` / ``ok`` ``[len(near), 4]``: diffracted with probability ``beta``."""
    from ...bsdf import fsd

    state, wavelength = ctx.fsd, ctx.wavelength
    es = state["edges"]
    sel = [getattr(es, name)[idx.ravel()].reshape(idx.shape + (3,))
           for name in ("p0", "p1", "apex0", "apex1")]
    edges = fsd.FsdEdges.from_numpy(*sel, valid=ok)
    rows = mi.UInt32(near.astype(np.uint32))
    with dr.suspend_grad():
        d = mi.Vector3f(*(dr.gather(mi.Float, dr.detach(k_in[c]), rows) for c in range(3)))
        xd = mi.Point3f(*(dr.gather(mi.Float, dr.detach(x[c]), rows) for c in range(3)))
        op = dr.gather(mi.Float, dr.detach(opacity), rows)
        u_d, u1, u2, u3 = (dr.gather(mi.Float, v, rows) for v in u)
        p_d = fsd.beta(d, xd, edges, wavelength, state["s"], opacity=op, check=False)
        wo, pdf = fsd.sample(d, xd, edges, wavelength, state["s"], u1, mi.Point2f(u2, u3),
                             check=False)
        return (u_d < p_d) & (pdf > 0), wo
