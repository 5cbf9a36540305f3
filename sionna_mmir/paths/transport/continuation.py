"""The continuation stage: mirror or BSDF sample, roulette, the next segment.

At each interaction a coherent chain continues along the mirror direction of
the shading normal with probability ``eta`` (field scaled by
``sqrt(eta) R / eta``: unbiased), otherwise along a direction sampled from the
mmIR BSDF (lobe sampling with the balance-heuristic mixture pdf); a path that
scattered (or diffracted) once continues as a power-only (incoherent) path.
Russian roulette ends paths from ``rr_depth`` on.  Under the facet
quadrature coherent chains always continue and are never rouletted: a random
choice would thin the quadrature's integral at random (variance ~ the sum of
``|terms|^2``, which dwarfs the stationary-phase sum); the scattered energy
still reaches the Tx by next-event estimation at every interaction, and
scatter-then-scatter chains are left out.

The next segment is traced outside AD and rebuilt in AD; the area density of
the next point of a coherent chain is ``p_A = pdf cos / L_unf^2`` (unfolded
length).  A facet chain whose node's ray misses continues from a lit corner of
its cell (:func:`.aperture.reaim`).
"""
from __future__ import annotations

from ...bsdf import mmwave
from ...utils.backend import init_backend
from ..polarization import mirror, polarization_fractions, reflect_field
from . import aperture
from .diffraction import diffract, gate_fsd
from .motion import vertex_rate
from .state import RAY_EPSILON

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402


def continue_paths(ctx, st, surf, depth: int) -> None:
    """Choose each lane's next direction, apply roulette, trace and rebuild
    the next interaction into ``st``."""
    opts = ctx.options
    eta_in = dr.exp(-dr.square(2.0 * ctx.k_wave * surf.sigma_h * surf.cos_in))
    p_spec = _specular_probability(ctx, eta_in, st.width)
    u_ev = ctx.rng.next_float32()
    live, diff, k_diff = st.it.valid, None, None
    if opts.diffraction:
        diff, k_diff = diffract(ctx, surf.x, surf.k_in,
                                gate_fsd(st.E, surf.k_in, surf.n, surf.sc_in), st.it.valid)
        live = st.it.valid & ~diff
    spec = live & (u_ev < p_spec)
    scat = live & ~spec & opts.scattering
    E_new = reflect_field(st.E, surf.k_in, surf.n, surf.sc_in.r_s,
                          surf.sc_in.r_p).scale(dr.sqrt(eta_in))
    pol_pow = E_new.power() / dr.maximum(st.E.power(), 1e-30)
    k_sc, ok_s, pdf_s, params_in, wi_loc = _sample_bsdf(ctx, st, surf, scat)
    _to_incoherent(ctx, st, surf, spec, scat, diff, pol_pow, p_spec)
    st.pending = ((1.0 - eta_in) / dr.maximum(1.0 - p_spec, 1e-6),
                  surf.n, (params_in, 1.0), wi_loc, dr.detach(pdf_s), ok_s)
    st.inv_p = dr.select(spec & st.coh, st.inv_p / dr.maximum(p_spec, 1e-6), st.inv_p)
    st.E = E_new.select(spec, st.E)
    st.coh = st.coh & spec
    alive = spec | ok_s
    if diff is not None:
        alive |= diff
    alive = _roulette(ctx, st, alive, pol_pow, depth)
    k_next = dr.select(spec, mirror(surf.k_in, surf.n), k_sc)
    if diff is not None:
        st.coh = st.coh & ~diff
        k_next = dr.select(diff, k_diff, k_next)
    _next_interaction(ctx, st, surf, k_next, alive, diff)


def _specular_probability(ctx, eta_in, K):
    opts = ctx.options
    p_spec = ctx.tape.freeze(eta_in) if opts.scattering else dr.ones(mi.Float, K)
    if ctx.sampler.deterministic_chains:
        p_spec = dr.ones(mi.Float, K)
    if not opts.coherent:
        p_spec = dr.zeros(mi.Float, K)
    return p_spec


def _sample_bsdf(ctx, st, surf, scat):
    """Sample the BSDF in the local frame around the mirror (detached)."""
    frame = mi.Frame3f(surf.n)
    wi_loc = frame.to_local(-surf.k_in)
    fs, fp = polarization_fractions(st.E, surf.k_in, surf.n)
    gate_in = fs * dr.squared_norm(surf.sc_in.r_s) + fp * dr.squared_norm(surf.sc_in.r_p)
    params_in = mmwave.MMWaveParams(surf.sigma_h, surf.l_c, surf.tau_b, ctx.wavelength, gate_in)
    rng, tape = ctx.rng, ctx.tape
    with dr.suspend_grad():
        wo_s, pdf_s = mmwave.sample(dr.detach(wi_loc), rng.next_float32(),
                                    mi.Point2f(rng.next_float32(), rng.next_float32()),
                                    params_in)
        k_sc = frame.to_world(wo_s)
        ok_s = tape.freeze(scat & (wo_s.z > 1e-4) & (pdf_s > 0))
        pdf_s = tape.freeze(pdf_s)
    return k_sc, ok_s, pdf_s, params_in, wi_loc


def _to_incoherent(ctx, st, surf, spec, scat, diff, pol_pow, p_spec) -> None:
    """Fold a coherent chain's power into ``beta`` where it scatters or
    diffracts; specular steps of incoherent paths carry their power on."""
    base_coh = (st.E.power() * st.inv_p * surf.cos_in * st.it.area_ratio
                / (dr.maximum(st.p_area, 1e-30) * ctx.n_est))
    if st.lit is not None:          # the lit part of a facet node's footprint
        base_coh = base_coh * st.lit
    st.beta = dr.select(scat & st.coh, base_coh, st.beta)
    if diff is not None:
        # diffracted lanes carry their power on (eval / (pdf * beta) = 1)
        st.beta = dr.select(diff & st.coh, base_coh, st.beta)
    st.beta = dr.select(spec & ~st.coh, st.beta * pol_pow / dr.maximum(p_spec, 1e-6), st.beta)


def _roulette(ctx, st, alive, pol_pow, depth: int):
    """Russian roulette on the power-carrying paths from ``rr_depth`` on."""
    if depth + 1 <= ctx.options.rr_depth:
        return alive
    q = ctx.tape.freeze(dr.clip(dr.select(st.coh, pol_pow, 0.5), 0.1, 1.0))
    if ctx.sampler.deterministic_chains:
        q = dr.select(st.coh, 1.0, q)     # no roulette on the quadrature's chains
    survive = ctx.rng.next_float32() < q
    st.inv_p = dr.select(st.coh, st.inv_p / q, st.inv_p)
    st.beta = dr.select(~st.coh, st.beta / q, st.beta)
    return alive & survive


def _next_interaction(ctx, st, surf, k_next, alive, diff) -> None:
    """Trace the next segment (detached; a facet chain whose node's ray
    misses continues from a lit corner, :func:`.aperture.reaim`), rebuild it
    in AD, update the coherent area density and the chain's motion."""
    geo, tape = ctx.geo, ctx.tape
    x = surf.x
    with dr.suspend_grad():
        side = dr.select(dr.dot(dr.detach(k_next), dr.detach(surf.ng)) > 0, 1.0, -1.0)
        o2 = dr.detach(x) + dr.detach(surf.ng) * (RAY_EPSILON * side)
        if diff is not None:       # free-space diffraction passes the surface
            o2 = dr.select(diff, dr.detach(x) + dr.detach(k_next) * 1e-3, o2)
        hit = geo.trace(o2, dr.detach(k_next), alive)
    (v2, ob2, fa2, uu, vv), x = aperture.reaim(ctx, st, surf, hit, alive & st.coh & ~hit[0])
    # motion along the chain: vertex x moving with v contributes v.(u_in + u_out)
    st.rate_chain = st.rate_chain + vertex_rate(ctx.velocities, st.it.obj, surf.k_in, -k_next)
    st.prev_p = x
    st.it = geo.interaction(v2, ob2, fa2, uu, vv, tape)
    L_unf = tape.freeze(st.L0_det + st.chain + dr.norm(st.it.p - x))
    cos_next = tape.freeze(dr.select(v2, dr.abs(dr.dot(dr.normalize(st.it.p - x), st.it.ng)),
                                     0.0))
    st.p_area = dr.select(st.coh, st.first_pdf * cos_next / dr.square(L_unf), st.p_area)
    st.it.valid = st.it.valid & v2
