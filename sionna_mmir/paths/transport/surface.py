"""The surface stage: local geometry, deferred BSDF weight and materials at ``x_l``.

At every interaction the shading and geometric normals are turned to face
the incident ray, the first interaction's area density is frozen
(``p_A = pdf |k . n_g| / L_0^2``), and the weight of a BSDF-sampled direction
that led here is applied in area measure (``f cos_o |k . n_g| / seg^2`` over
its frozen density), which keeps vertex motion exact.  Materials are the six
barycentrically interpolated per-vertex ITU-R P.2040 parameters.
"""
from __future__ import annotations

from ...bsdf import mmwave
from ...radio_materials.fresnel import complex_permittivity, slab_coefficients
from ...utils.backend import init_backend
from .state import Surface

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402


def at_surface(ctx, st, depth: int) -> Surface:
    """Local quantities at the current interaction; updates ``st.chain``,
    ``st.p_area`` (depth 1) and ``st.beta`` (deferred BSDF weight)."""
    it, tape = st.it, ctx.tape
    # dead lanes get a harmless dummy point 1 m ahead (no NaN anywhere)
    x = dr.select(it.valid, it.p, st.prev_p + mi.Vector3f(1.0, 0.0, 0.0))
    n_sh = dr.select(it.valid, it.n, mi.Vector3f(-1.0, 0.0, 0.0))
    it.ng = dr.select(it.valid, it.ng, mi.Vector3f(-1.0, 0.0, 0.0))
    k_in = dr.normalize(x - st.prev_p)
    seg = dr.maximum(dr.norm(x - st.prev_p), 1e-6)
    if depth > 1:
        st.chain = st.chain + seg
    n = dr.select(dr.dot(k_in, n_sh) > 0, -n_sh, n_sh)
    cos_in = dr.maximum(-dr.dot(k_in, n), 0.0)
    front = dr.dot(k_in, it.ng) < 0
    ng = dr.select(front, it.ng, -it.ng)
    if depth == 1:
        st.p_area = tape.freeze(st.first_pdf * dr.abs(dr.dot(k_in, ng)) / dr.square(st.L0_det))
    if st.pending is not None:
        _apply_pending(st, tape, k_in, ng, seg)
    eps = complex_permittivity(it.mat[0], it.mat[1], backend="drjit")
    sc_in = slab_coefficients(cos_in, eps, it.mat[5], ctx.frequency, backend="drjit")
    return Surface(x=x, n=n, ng=ng, k_in=k_in, seg=seg, cos_in=cos_in, eps=eps,
                   sigma_h=it.mat[2], l_c=it.mat[3], tau_b=it.mat[4], thick=it.mat[5],
                   sc_in=sc_in)


def _apply_pending(st, tape, k_in, ng, seg) -> None:
    """Weight of the BSDF-sampled direction that led here, in area measure."""
    pw, pf_n, pf_params, pf_wi, pf_pdf, pf_mask = st.pending
    wo_prev = mi.Frame3f(pf_n).to_local(k_in)
    f_prev = pf_params[1] * mmwave.eval(pf_wi, wo_prev, pf_params[0])
    g_ad = dr.maximum(wo_prev.z, 0.0) * dr.abs(dr.dot(k_in, ng)) / dr.square(seg)
    g_det = tape.freeze(pf_pdf * dr.abs(dr.dot(k_in, ng)) / dr.square(seg))
    w = f_prev * g_ad / dr.maximum(g_det, 1e-30) * st.it.area_ratio * pw
    st.beta = dr.select(pf_mask, st.beta * w, st.beta)
