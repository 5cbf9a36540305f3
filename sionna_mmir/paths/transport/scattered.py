"""The scattered stage: the BSDF-scattered part as a speckle field.

The remaining ``1 - eta`` of the energy, distributed by the mmIR BSDF ``f``
(paper eqs. 5-7, :mod:`sionna_mmir.bsdf.mmwave`, energy gate from the P.2040
slab and the path's s/p power fractions), is rendered with power::

    P_sc = (lambda / 4 pi)^2 (1 - eta) f c_t |E|^2 c_in / (L0^2 ...) / (N p_A)

(the bistatic radar equation with ``sigma^0 = 4 pi f c_t c_in``; element
gains and leg lengths come with the legs) and a uniform random phase per
path, so the expected power of the coherent sum is the Monte Carlo estimate
of the scattered power for any ``N``.  Chains that already scattered carry
their throughput ``beta``.

Reciprocal twins: a path whose receiver-side events are all specular and
whose last event scatters has a physical twin with the order reversed
(scatter first, then the specular chain to the Tx) that receiver-side
sampling cannot produce; it is added with the Tx and Rx legs swapped.
"""
from __future__ import annotations

import math

from ...bsdf import mmwave
from ...radio_materials.fresnel import slab_coefficients
from ...utils.backend import init_backend
from ..polarization import polarization_fractions
from .state import Emission, zeros

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402


def scattered_field(ctx, st, surf, conn):
    """``(re, im)`` of the speckle field scattered towards the Tx (one random
    phase per lane, drawn from ``ctx.rng``)."""
    wavelength = ctx.wavelength
    fs, fp = polarization_fractions(st.E, surf.k_in, surf.n)
    sc_t = slab_coefficients(conn.cos_t, surf.eps, surf.thick, ctx.frequency, backend="drjit")
    gate = fs * dr.squared_norm(sc_t.r_s) + fp * dr.squared_norm(sc_t.r_p)
    params = mmwave.MMWaveParams(surf.sigma_h, surf.l_c, surf.tau_b, wavelength, gate)
    frame = mi.Frame3f(surf.n)
    wi_t, wo_r = frame.to_local(conn.k_t), frame.to_local(-surf.k_in)
    eta_t = params.eta(dr.maximum(conn.cos_t, 0.0))
    f_sc = (1.0 - eta_t) * mmwave.eval(wi_t, wo_r, params)
    base_coh = (st.E.power() * st.inv_p * surf.cos_in * st.it.area_ratio
                / (dr.maximum(st.p_area, 1e-30) * ctx.n_est))
    if st.lit is not None:          # the lit part of a facet node's footprint
        base_coh = base_coh * st.lit
    base = dr.select(st.coh, base_coh, st.beta)
    P = dr.square(wavelength / (4.0 * math.pi)) * f_sc * conn.cos_t * base
    amp = dr.select(conn.ok, dr.sqrt(dr.maximum(P, 1e-36)), 0.0)
    phase = 2.0 * math.pi * ctx.rng.next_float32()
    return amp * dr.cos(phase), amp * dr.sin(phase)


def reciprocal_emission(st, surf, conn, sc_re, sc_im, depth: int) -> Emission:
    """The reversed twin (scatter at ``x`` first, then the specular chain to
    the Tx), added by reciprocity: legs swapped."""
    m = st.coh & conn.ok
    return Emission(dr.select(m, sc_re, 0.0), dr.select(m, sc_im, 0.0), st.x1, surf.x,
                    st.chain, zeros(st.width), conn.rate, depth, m, st.obj1)
