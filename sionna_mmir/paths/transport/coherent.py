"""The coherent stage: the physical-optics (Kirchhoff) field of specular chains.

A ray that reached ``x_l`` through specular reflections only (a
geometric-optics chain from the receiver, Jones-transported) radiates towards
the transmitter with

    a_po = j / (4 pi) (e_t . E_refl) c_po sqrt(eta_b) / (N p_A)    (times the legs)

``c_po = (cos_in + cos_t) / 2`` the Kirchhoff obliquity,
``eta_b = exp(-(k sigma_h (cos_in + cos_t))^2)`` the bistatic coherent loss,
``E_refl`` the field reflected with the complex P.2040 slab coefficients and
``p_A`` the area density of the sample.  Summed coherently this is an
unbiased estimate of the physical-optics integral (shooting and bouncing
rays); it reproduces the plate ``4 pi A^2 / lambda^2`` and trihedral RCS.

Chains deeper than one are integrated over the *first* surface by image
theory: the Tx leg of ``x1 -> x2 .. x_l -> Tx`` is ``|M(x1) - Tx|`` with
``M`` the chain's mirrors, so each depth is a separate path with its Tx leg
from the unfolded image ``x_img = M(x1)``.  With ``triangle_average`` the
linear phase ``k (k0 + L_m^T u_img) . (y - x1)`` is integrated exactly over
the first triangle (:mod:`sionna_mmir.paths.triangle_po`) where the
quadratic (Fresnel) term ``k D^2 / R`` stays below one radian.
"""
from __future__ import annotations

import math

from ...utils.backend import init_backend
from ..polarization import reflect_field
from ..triangle_po import triangle_phase_average
from .state import Emission, zeros

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402


def unfold(st, surf, depth: int) -> None:
    """Mirror the image of ``x1`` (and the map's linear part) in this
    interaction's plane (depth > 1)."""
    if depth > 1:
        n = surf.n
        st.x_img = st.x_img - n * (2.0 * dr.dot(st.x_img - surf.x, n))
        st.Lm = [c - n * (2.0 * dr.dot(c, n)) for c in st.Lm]


def coherent_field(ctx, st, surf, conn):
    """``(re, im, mask)`` of the physical-optics field of the chain ending
    here, radiated towards the Tx."""
    k_wave = ctx.k_wave
    E_ref = reflect_field(st.E, surf.k_in, surf.n, surf.sc_in.r_s, surf.sc_in.r_p)
    pr, pi_ = E_ref.dot(conn.e_t)
    eta_b = dr.exp(-dr.square(k_wave * surf.sigma_h * (surf.cos_in + conn.cos_t)))
    scale = (0.5 * (surf.cos_in + conn.cos_t) * dr.sqrt(eta_b) * st.inv_p * st.it.area_ratio
             / (4.0 * math.pi * dr.maximum(st.p_area, 1e-30) * ctx.n_est))
    m = conn.ok & st.coh
    wr, wi = -pi_ * scale, pr * scale            # j * (pr + j pi)
    if ctx.options.triangle_average:
        fr, fi = _first_surface_average(ctx, st)
        wr, wi = wr * fr - wi * fi, wr * fi + wi * fr
    return wr, wi, m


def _first_surface_average(ctx, st):
    """Exact average of the chain's linear phase over the first triangle,
    ``(1, 0)`` where the quadratic term is too large."""
    k_wave = ctx.k_wave
    # Tx-side distance of the unfolded chain and the phase gradient on the
    # first surface: grad_y (|y - c| + |M(y) - c|) at x1
    to_img = st.x_img - st.cw_k
    d_img = dr.norm(to_img)
    u_img = to_img / dr.maximum(d_img, 1e-9)
    g_img = mi.Vector3f(*(dr.dot(c, u_img) for c in st.Lm))     # Lm^T u
    fr, fi = triangle_phase_average(k_wave * (st.k0 + g_img), *st.tri1, st.x1)
    # only where the phase is linear across the triangle: the quadratic
    # (Fresnel) term k D^2 / R must stay below ~1 rad
    P0, P1, P2 = (dr.detach(v) for v in st.tri1)
    D2 = dr.maximum(dr.maximum(dr.squared_norm(P1 - P0), dr.squared_norm(P2 - P0)),
                    dr.squared_norm(P2 - P1))
    near = dr.minimum(dr.detach(d_img), st.L0_det)
    lin = ctx.tape.freeze(k_wave * D2 / dr.maximum(near, 1e-3) < 1.0)
    return dr.select(lin, fr, 1.0), dr.select(lin, fi, 0.0)


def coherent_emission(st, wr, wi, m, rate, depth: int) -> Emission:
    """The chain of ``depth > 1`` as a path of its own: Tx leg from the
    unfolded image of ``x1``, Rx leg to ``x1``, no chain lengths."""
    zero = zeros(st.width)
    return Emission(dr.select(m, wr, 0.0), dr.select(m, wi, 0.0), st.x_img, st.x1, zero, zero,
                    rate, depth, m, st.obj1)
