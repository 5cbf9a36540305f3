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


def fsd_setup(geo, wavelength, width):
    """Diffracting edges of the scene, their index and the lobe width [m]."""
    from ...scene.edges import EdgeIndex, find_diffracting_edges

    verts = np.asarray(dr.detach(geo.positions), dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(geo.faces, dtype=np.int64).reshape(-1, 3)
    es = find_diffracting_edges(verts, faces)
    s = float(width) if width is not None else 3.0 * wavelength
    return {"edges": es, "index": EdgeIndex(es) if len(es) else None, "s": s,
            "radius": 3.0 * s}


def diffract(ctx, x, k_in, opacity, valid):
    """``(mask, direction)`` of lanes diffracted by nearby edges (detached)."""
    from ...bsdf import fsd

    state, rng, tape, wavelength = ctx.fsd, ctx.rng, ctx.tape, ctx.wavelength
    n = dr.width(valid)
    u_d, u1, u2, u3 = (rng.next_float32() for _ in range(4))
    if state["index"] is None:
        return tape.freeze(dr.zeros(mi.Bool, n)), dr.zeros(mi.Vector3f, n)
    xs = np.column_stack([np.asarray(dr.detach(x[c]), dtype=np.float64) for c in range(3)])
    idx, ok = state["index"].query(xs, state["radius"], max_edges=4)
    ok &= np.asarray(valid, dtype=bool)[:, None]
    es = state["edges"]
    sel = [getattr(es, name)[idx.ravel()].reshape(idx.shape + (3,))
           for name in ("p0", "p1", "apex0", "apex1")]
    edges = fsd.FsdEdges.from_numpy(*sel, valid=ok)
    with dr.suspend_grad():
        d, xd = dr.detach(k_in), dr.detach(x)
        p_d = tape.freeze(fsd.beta(d, xd, edges, wavelength, state["s"],
                                   opacity=dr.detach(opacity), check=False))
        wo, pdf = fsd.sample(d, xd, edges, wavelength, state["s"], u1, mi.Point2f(u2, u3),
                             check=False)
        mask = tape.freeze(valid & (u_d < p_d) & (pdf > 0))
    return mask, wo
