"""The coherent stage: the physical-optics (Kirchhoff) field of specular chains.

A ray that reached ``x_l`` through specular reflections only (a
geometric-optics chain from the receiver, Jones-transported) radiates towards
the transmitter with

    a_po = j / (4 pi) (e_t . E_refl) c_po sqrt(eta_b) / (N p_A)    (times the legs)

``c_po = (cos_in + cos_t) / 2`` the Kirchhoff obliquity at ``x_l``,
``eta_b = exp(-(k sigma_h (cos_in + cos_t))^2)`` the bistatic coherent loss,
``E_refl`` the field reflected with the complex P.2040 slab coefficients and
``p_A`` the area density of ``x_l``.  Summed coherently this is an unbiased
estimate of the physical-optics integral over the chain's *last* surface,
lit by the geometric-optics field the chain carries from the receiver (the
exit aperture of shooting and bouncing rays): the lit region is the one the
receiver's rays reach -- the region ``p_A`` samples -- and the receiver
seen through the chain's mirrors is its image, so the Rx leg is
``|U(x_l) - rx|`` with ``U = M_1 .. M_{l-1}`` the mirrors before ``x_l``
(:attr:`PathState.x_star`) and the Tx leg ``|x_l - tx|``; each depth is a
path of its own.  It reproduces the plate ``4 pi A^2 / lambda^2``, the
dihedral ``8 pi a^2 b^2 / lambda^2`` and the trihedral ``4 pi a^4 / (3
lambda^2)``, and in the near field a brute-force physical-optics sum
(for a monostatic radar the model is its own reciprocal: the transmitter's
rays and the first surface give the same integral).

With ``triangle_average`` the linear phase ``k (U^T u_rx + u_tx) . (y -
x_l)`` (``u_rx``, ``u_tx`` the unit vectors from the array centre to
``U(x_l)`` and ``x_l``) is integrated exactly over the last triangle -- the
first (sub-)triangle at depth 1 -- (:mod:`sionna_mmir.paths.triangle_po`)
where the quadratic (Fresnel) term ``k D^2 / R`` stays below one radian.
Under the facet quadrature a chain integrates instead over the lit
footprint of its node's cell on the last triangle, ``sum_t A_t F_t`` over
the footprint's fan triangles (:mod:`.aperture`), which replaces ``1 / p_A``.
"""
from __future__ import annotations

import math

from ...utils.backend import init_backend
from ..polarization import reflect_field
from ..triangle_po import triangle_phase_average
from . import aperture
from .state import Emission, zeros

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402


def unfold(st, surf, depth: int) -> None:
    """Fold the previous interaction's mirror into ``st.U`` (depth > 1), set
    ``st.x_star = U(x_l)`` and remember this interaction's plane."""
    if depth > 1:
        n, p = st.plane
        cols, off = st.U
        An = cols[0] * n.x + cols[1] * n.y + cols[2] * n.z
        cols = [cols[0] - An * (2.0 * n.x), cols[1] - An * (2.0 * n.y),
                cols[2] - An * (2.0 * n.z)]
        st.U = (cols, off + An * (2.0 * dr.dot(n, p)))
        x = surf.x
        st.x_star = mi.Point3f(cols[0] * x.x + cols[1] * x.y + cols[2] * x.z + st.U[1])
    st.plane = (surf.n, surf.x)


def coherent_field(ctx, st, surf, conn, depth: int):
    """``(re, im, mask)`` of the physical-optics field of the chain ending
    here, radiated towards the Tx."""
    k_wave = ctx.k_wave
    E_ref = reflect_field(st.E, surf.k_in, surf.n, surf.sc_in.r_s, surf.sc_in.r_p)
    pr, pi_ = E_ref.dot(conn.e_t)
    eta_b = dr.exp(-dr.square(k_wave * surf.sigma_h * (surf.cos_in + conn.cos_t)))
    scale = (0.5 * (surf.cos_in + conn.cos_t) * dr.sqrt(eta_b) * st.inv_p * st.it.area_ratio
             / (4.0 * math.pi * ctx.n_est))
    m = conn.ok & st.coh
    wr, wi = -pi_ * scale, pr * scale            # j * (pr + j pi)
    fr, fi = _aperture_integral(ctx, st, surf, depth)
    return wr * fr - wi * fi, wr * fi + wi * fr, m


def _aperture_integral(ctx, st, surf, depth: int):
    """``(re, im)`` [m^2] of ``int exp(-j q . (y - x_l)) dA(y)`` over the
    region the sample stands for: ``F / p_A`` (``F`` the triangle average,
    1 where the phase is not linear across it), or the facet footprint's
    ``sum_t A_t F_t``."""
    use_avg = bool(ctx.options.triangle_average)
    if st.fan is not None:
        return aperture.fan_integral(ctx.k_wave, st, surf, use_avg)
    inv_pa = 1.0 / dr.maximum(st.p_area, 1e-30)
    if not use_avg:
        return inv_pa, 0.0
    tri = st.tri1 if depth == 1 else st.it.tri
    fr, fi = triangle_phase_average(_phase_gradient(ctx, st, surf), *tri, surf.x)
    # only where the phase is linear across the triangle: the quadratic
    # (Fresnel) term k D^2 / R must stay below ~1 rad
    P0, P1, P2 = (dr.detach(v) for v in tri)
    D2 = dr.maximum(dr.maximum(dr.squared_norm(P1 - P0), dr.squared_norm(P2 - P0)),
                    dr.squared_norm(P2 - P1))
    near = dr.detach(dr.minimum(dr.norm(st.x_star - st.cw_k), dr.norm(surf.x - st.cw_k)))
    lin = ctx.tape.freeze(ctx.k_wave * D2 / dr.maximum(near, 1e-3) < 1.0)
    return dr.select(lin, fr, 1.0) * inv_pa, dr.select(lin, fi, 0.0) * inv_pa


def _phase_gradient(ctx, st, surf):
    """``q = k grad_y (|U(y) - c| + |y - c|)`` at ``x_l`` [rad/m]."""
    to_rx = st.x_star - st.cw_k
    u_rx = to_rx / dr.maximum(dr.norm(to_rx), 1e-9)
    to_tx = surf.x - st.cw_k
    u_tx = to_tx / dr.maximum(dr.norm(to_tx), 1e-9)
    g_rx = mi.Vector3f(*(dr.dot(c, u_rx) for c in st.U[0]))     # U^T u_rx
    return ctx.k_wave * (g_rx + u_tx)


def coherent_emission(st, surf, wr, wi, m, rate, depth: int) -> Emission:
    """The chain of ``depth > 1`` as a path of its own: Tx leg to ``x_l``,
    Rx leg from the receiver's image of it (``x_star``), no chain lengths."""
    zero = zeros(st.width)
    return Emission(dr.select(m, wr, 0.0), dr.select(m, wi, 0.0), surf.x, st.x_star, zero, zero,
                    rate, depth, m, st.obj1)
