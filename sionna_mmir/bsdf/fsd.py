r"""Free-space diffraction (FSD) lobe: closed-form Fraunhofer diffraction by nearby edges.

After Steinberg et al., "A Free-Space Diffraction BSDF" (ACM TOG 43(4),
SIGGRAPH 2024): at a ray hit ``x`` the nearby geometry is projected onto a
virtual screen perpendicular to the propagation direction ``d``, its boundary
(silhouette) edges are found, and the far-field (Fraunhofer) diffraction of
those edges, within a Gaussian beam footprint centred at ``x``, is evaluated
in closed form.  A fraction ``beta`` of the energy is redirected into the
resulting importance-sampleable lobes.  The mmIR additions (paper, "Free-space
diffraction BSDF") are an **edge opacity** (``opacity``, e.g. the Fresnel
energy gate ``A`` of :func:`sionna_mmir.radio_materials.fresnel.energy_gate`
from the learnable permittivity) and the LiDAR **edge suppression** filter
(:func:`sionna_mmir.scene.edges.find_diffracting_edges`).
This module is written from the physics below (scalar, paraxial Fraunhofer
optics); it is not a port of any reference implementation.

Everything is in **world coordinates**: ``d`` is the unit propagation
direction of the incident ray, ``x`` the hit point, ``wo`` an outgoing unit
direction.  The lobe lives on the forward hemisphere ``wo . d > 0``.

1. Screen and beam
------------------
The screen is the plane through ``x`` perpendicular to ``d`` with the
orthonormal basis ``(u, v) = (Frame3f(d).s, Frame3f(d).t)``; ``r = (a, b)`` are
screen coordinates relative to ``x`` and ``q = (wo.u, wo.v)`` the transverse
direction cosines of ``wo`` (``cos theta = wo.d = sqrt(1 - |q|^2)``,
``dOmega = d^2q / cos theta``).  The incident field is a Gaussian beam of
footprint width ``s`` (default ``3 lambda``)::

    w(r) = exp(-|r|^2 / (2 s^2)),        P_b = int |w|^2 d^2r = pi s^2.

For a screen transmission ``T(r)`` the Fraunhofer far field and its power are::

    U(q) = (k/2pi) int w T exp(-j k q.r) d^2r,    dP/d^2q = |U|^2,
    dP/dOmega = |U|^2 cos theta,

normalised by Parseval (``int |U|^2 d^2q = int |w T|^2 d^2r``), ``k = 2pi/lambda``.

2. One projected edge
---------------------
An edge ``p0 p1`` projects to the 2-D segment ``P0 P1`` of length ``L`` and unit
direction ``e``; ``n`` is its unit normal pointing into the **opaque side**, the
side on which the projected apexes of its adjacent faces lie (``apex0``,
``apex1``).  If the two apexes project onto opposite sides the edge is interior
to the projected geometry (not a silhouette) and does not diffract.  With
``p = -n.r`` (perpendicular coordinate) and ``tau = e.r`` (along the edge,
``tau = 0`` at the foot of the perpendicular from ``x``)::

    delta = -n.P0   signed distance of x from the edge line (> 0: x on the
                    opaque side, the usual case for a hit point),
    tau0 = e.P0,  tau1 = e.P1,

and the free half-plane next to the edge is ``p > delta``.  The Gaussian window
separates, ``w = exp(-p^2/2s^2) exp(-tau^2/2s^2)``, so ``U`` factorises into a
perpendicular and an along-edge spectrum (``kappa = k q``).

*Perpendicular* (Gaussian-windowed half plane)::

    F_perp(kappa) = int_delta^inf exp(-p^2/(2 s^2)) exp(-j kappa p) dp.

For ``delta = 0`` this is exactly
``s sqrt(pi/2) exp(-kappa^2 s^2/2) - j sqrt(2) s Daw(kappa s/sqrt2)``
(``Daw`` the Dawson function), with ``|F(0)|^2 = pi s^2 / 2`` and
``|F|^2 -> 1/kappa^2`` for ``kappa s >> 1``.  For any ``delta``,
``|F(0)|^2 = (pi/2) s^2 erfc(xi)^2`` with ``xi = delta/(sqrt2 s)``, and
integration by parts gives the edge wave ``|F|^2 -> exp(-delta^2/s^2)/kappa^2``.
The model is the Lorentzian that matches both limits::

    |F_perp|^2 ~= exp(-2 xi^2) / (kappa^2 + kappa0^2),
    q0 = kappa0 / k = 1 / (k s sqrt(pi/2) erfcx(xi))       (= sqrt(2/pi)/(k s) at delta = 0),

``erfcx(z) = exp(z^2) erfc(z)`` (``xi`` clamped to ``[-4, 4]``, where the weight
is < 1e-13).  Its energy ``pi s sqrt(pi/2) exp(-xi^2) erfc(xi)`` equals the exact
``2 pi int_delta^inf exp(-p^2/s^2) dp`` for ``delta >> s`` and is ``1/sqrt2`` of
it at ``delta = 0``.  Pointwise it is exact at ``q = 0``, within 3 % of the
exact ``|F|^2`` for ``k s q >= 11`` (``1/q^2`` tail), and low by up to ~50 %
in the shoulder ``q ~ q0 .. 3 q0`` (the exact spectrum is flatter-topped).

*Along the edge*: ``G(kappa) = int_tau0^tau1 exp(-tau^2/2s^2) exp(-j kappa tau) dtau``
is modelled as a uniform segment of **visible length** ``l``,
``|G|^2 ~= l^2 sinc^2(kappa l / 2)`` (``sinc x = sin x / x``: zeros at
``q_par = 2 pi n / (k l)``), with ``l`` fixed by energy conservation
(``int |G|^2 dkappa = 2 pi int exp(-tau^2/s^2) dtau = 2 pi l``)::

    l = (sqrt(pi) s / 2) [erf(tau1/s) - erf(tau0/s)],

i.e. the segment clipped by the beam: ``l = L`` for a short segment at the foot
of the perpendicular, ``l = sqrt(pi) s`` for an edge crossing the whole beam.

*Per-edge intensity* (fraction of the beam power per ``d^2q``)::

    I_e(q) = |U|^2 / P_b
           = exp(-2 xi^2) l^2 sinc^2(k q_par l / 2) / (4 pi^3 s^2 (q_perp^2 + q0^2)),

``q_par = q.e``, ``q_perp = q.n``.  Over the whole ``q`` plane it integrates to

    w_full = exp(-xi^2) erfc(xi) (l/s) / (2 sqrt(2 pi))
           (0.354 for an edge through x crossing the beam;
            ~ exp(-delta^2/s^2) l / (2 pi delta) for delta >> s).

``w_full`` counts the beam spread ``q <~ q0 ~ 1/(k s)``; the power diffracted
beyond an angle ``theta >> q0`` is ``~ w_full (2/pi) q0/theta``, i.e.
``~ (l/s) / (k s theta)``: the familiar edge cross-section of order ``lambda``
per unit length.

3. Normalised lobe ``D_e`` and weights ``w_e``
-----------------------------------------------
``I_e`` is truncated to the square ``|q_perp| < 1, |q_par| < 1`` (``|t| < t_max``)::

    p_perp(q_perp) = q0 / (pi (q_perp^2 + q0^2)) / M_perp,   M_perp = (2/pi) atan(1/q0)
    p_par(q_par)   = (k l / 2pi) sinc^2(t) / M_par,          t = k l q_par / 2,
                     M_par = 2 G(t_max),  t_max = min(k l / 2, T_TAB),
                     G(t) = int_0^t sinc^2/pi = (Si(2t) - sin^2(t)/t) / pi
    D_e(wo) = p_perp p_par cos theta   for wo.d > 0,  0 otherwise   [1/sr]
    w_e     = w_full M_perp M_par,

so that ``w_e D_e = I_e cos theta`` is exactly the Fraunhofer ``dP/dOmega / P_b``.
The corners of the square outside the unit disc ``|q| < 1`` correspond to no
direction: ``int_{S^2} D_e dOmega = 1 - eps_e`` with ``eps_e`` the corner mass
(typically ~1e-3).  :func:`sample` returns those draws with ``pdf = 0``; eval,
pdf and sample are mutually consistent.

4. Mixture, ``beta``, opacity
-----------------------------
Only valid silhouette edges with ``L > 1e-6 s`` count.  With ``W = sum_e w_e``::

    beta = min(beta_max, W) * opacity                         (beta_max = 0.5)
    eval = beta * sum_e (w_e / W) D_e(wo)     [1/sr, no cosine]
    pdf  =        sum_e (w_e / W) D_e(wo)

For ``W <= beta_max`` and ``opacity = 1`` the lobe is the incoherent sum of
the edge intensities.  ``opacity`` (float or ``mi.Float``) scales ``beta``.

Sampling: ``u1`` picks edge ``e`` with probability ``w_e / W``; ``q_perp``
from the truncated Lorentzian by inversion,
``q_perp = q0 tan((2 u - 1) atan(1/q0))``; ``t`` from the truncated
``sinc^2`` with the universal CDF ``G`` tabulated once (SciPy ``sici``, step
1/64 on ``[0, T_TAB = 256]``), inverted by binary search and linear
interpolation; ``q = q_perp n + q_par e`` and
``wo = q_u u + q_v v + sqrt(1 - |q|^2) d``.

Limitations: scalar (no polarisation), Fraunhofer / paraxial (no obliquity
factor), edges add incoherently (no inter-edge interference; two edges meeting
at a corner both count near it), forward lobe only.  ``eval`` and ``pdf`` are
differentiable w.r.t. the edge endpoints and apexes (hence mesh vertices, see
:meth:`FsdEdges.from_vertices`), ``x``, ``d``, ``wo``, ``s``, ``lambda`` and
``opacity``; :func:`sample` is not meant for gradients (its ``t`` is detached).

Edge layout (:class:`FsdEdges`)
-------------------------------
Up to ``K`` edges per query point, flattened row-major: entry ``n*K + j`` is
edge ``j`` of point ``n`` (``N`` rows of ``K``).  ``N == 1`` rows broadcast
over all query points.  Invalid slots have ``valid == False``.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..errors import InputValueError
from ._common import as_float, dr, mi

__all__ = ["FsdEdges", "eval", "pdf", "sample", "beta", "edge_parameters",
           "BEAM_WIDTH_WAVELENGTHS", "BETA_MAX", "T_TAB"]

#: default beam footprint width ``s = 3 lambda``
BEAM_WIDTH_WAVELENGTHS = 3.0
#: default cap of the diffracted fraction ``beta``
BETA_MAX = 0.5
#: end and step of the ``sinc^2`` CDF table (in ``t = k l q_par / 2``)
T_TAB = 256.0
TAB_STEP = 1.0 / 64.0
#: ``xi = delta / (sqrt2 s)`` is clamped to ``[-XI_CLAMP, XI_CLAMP]`` inside ``erfcx``
XI_CLAMP = 4.0

_SQRT_PI = math.sqrt(math.pi)
_INV_PI = 1.0 / math.pi


class FsdEdges(NamedTuple):
    """Edges near each query point (world coordinates, metres).

    Parameters
    ----------
    p0, p1 : mi.Point3f
        edge endpoints, width ``N*K`` (or ``K``)
    apex0 : mi.Point3f
        a point on the opaque side: the vertex opposite
        the edge in its first adjacent face
    apex1 : mi.Point3f
        same for the second face (``= apex0`` for a
        boundary edge); apexes on opposite sides of the projected edge
        mark it as a non-silhouette (no diffraction)
    valid : mi.Bool
        slot mask
    k : int
        edges per query point ``K``
    """

    p0: object
    p1: object
    apex0: object
    apex1: object
    valid: object
    k: int

    @classmethod
    def from_numpy(cls, p0, p1, apex0, apex1=None, valid=None) -> "FsdEdges":
        """From arrays ``[K, 3]`` (one row, broadcast) or ``[N, K, 3]``; ``valid [.., K]``."""
        arrs = [np.asarray(a, dtype=np.float64) for a in
                (p0, p1, apex0, apex0 if apex1 is None else apex1)]
        shape = arrs[0].shape
        if arrs[0].ndim not in (2, 3) or shape[-1] != 3 or 0 in shape:
            raise InputValueError(f"FsdEdges: p0 must have shape (K, 3) or (N, K, 3) with "
                                  f"K, N >= 1, got {shape}")
        for name, a in zip(("p1", "apex0", "apex1"), arrs[1:]):
            if a.shape != shape:
                raise InputValueError(f"FsdEdges: {name} has shape {a.shape}, p0 has {shape}")
        for name, a in zip(("p0", "p1", "apex0", "apex1"), arrs):
            if not np.all(np.isfinite(a)):
                raise InputValueError(f"FsdEdges: {name} contains NaN or Inf")
        k = shape[-2]
        v = np.ones(shape[:-1], dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
        if v.shape != shape[:-1]:
            raise InputValueError(f"FsdEdges: valid has shape {v.shape}, expected {shape[:-1]}")
        pts = [mi.Point3f(*(mi.Float(a.reshape(-1, 3)[:, c].astype(np.float32))
                            for c in range(3))) for a in arrs]
        return cls(*pts, mi.Bool(v.reshape(-1)), int(k))

    @classmethod
    def from_vertices(cls, vertices, edge_set, idx, valid) -> "FsdEdges":
        """Gather endpoints and apexes from a (differentiable) vertex buffer.

        Parameters
        ----------
        vertices : mi.Point3f or mi.Float
            ``mi.Point3f`` of width ``Nv`` or a flat ``mi.Float``
            ``[3 Nv]`` (Mitsuba's ``vertex_positions`` buffer);
            gradients of :func:`eval` flow back into it
        edge_set : EdgeSet
            :class:`sionna_mmir.scene.edges.EdgeSet` of that mesh
        idx, valid : numpy.ndarray
            ``[N, K]`` from :meth:`sionna_mmir.scene.edges.EdgeIndex.query`

        Returns
        -------
        FsdEdges
        """
        idx = np.asarray(idx, dtype=np.int64)
        valid = np.asarray(valid, dtype=bool)
        if idx.ndim != 2 or idx.shape != valid.shape or 0 in idx.shape:
            raise InputValueError(f"FsdEdges: idx / valid must be matching (N, K) arrays with "
                                  f"N, K >= 1, got {idx.shape} / {valid.shape}")
        if len(edge_set) == 0:
            idx = np.zeros_like(idx)
            valid = np.zeros_like(valid)
            ids = [np.zeros(idx.size, dtype=np.uint32)] * 4
        else:
            if idx.min() < 0 or idx.max() >= len(edge_set):
                raise InputValueError(f"FsdEdges: edge ids out of range [0, {len(edge_set)})")
            ids = [np.asarray(getattr(edge_set, n))[idx].reshape(-1).astype(np.uint32)
                   for n in ("v0", "v1", "a0", "a1")]
        pts = [dr.gather(mi.Point3f, vertices, mi.UInt32(i)) for i in ids]
        return cls(*pts, mi.Bool(valid.reshape(-1)), int(idx.shape[1]))


# ------------------------------------------------------------------ numerics
def _erfcx_pos(z):
    """``exp(z^2) erfc(z)`` for ``z >= 0``.

    ``z < 2``: ``exp(z^2) (1 - erf(z))`` with Dr.Jit's ``erf`` (``erfc(2) =
    4.7e-3``, so float32 cancellation costs < 3e-5 relative).  ``z >= 2``:
    Laplace's continued fraction (Abramowitz & Stegun 7.1.14)
    ``sqrt(pi) erfcx(z) = 1 / (z + (1/2) / (z + 1 / (z + (3/2) / (z + ...))))``
    evaluated bottom-up with 12 levels (relative error < 1e-7 for ``z >= 2``).
    """
    zc = dr.maximum(z, 2.0)
    frac = zc
    for n in range(12, 0, -1):
        frac = zc + (0.5 * n) / frac
    cf = 1.0 / (dr.sqrt(dr.pi) * frac)
    zs = dr.minimum(z, 2.0)
    small = dr.exp(zs * zs) * (1.0 - dr.erf(zs))
    return dr.select(z < 2.0, small, cf)


def _erfcx(z):
    """``exp(z^2) erfc(z)`` for any ``z`` (``2 exp(z^2) - erfcx(-z)`` for z < 0)."""
    a = dr.abs(z)
    e = _erfcx_pos(a)
    return dr.select(z >= 0, e, 2.0 * dr.exp(z * z) - e)


def _erfc_pos(z):
    """``erfc(z)`` for ``z >= 0`` without cancellation."""
    return dr.exp(-z * z) * _erfcx_pos(z)


def _erf_diff(a, b):
    """``erf(b) - erf(a)`` for ``a <= b``, accurate in both tails (NaN-free branches)."""
    pos = _erfc_pos(dr.maximum(a, 0.0)) - _erfc_pos(dr.maximum(b, 0.0))
    neg = _erfc_pos(dr.maximum(-b, 0.0)) - _erfc_pos(dr.maximum(-a, 0.0))
    mid = dr.erf(b) - dr.erf(a)
    return dr.select(a >= 0, pos, dr.select(b <= 0, neg, mid))


def _sinc2(t):
    small = dr.abs(t) < 1e-3
    ts = dr.select(small, 1.0, t)
    s = dr.sin(ts) / ts
    return dr.select(small, 1.0 - t * t / 3.0, s * s)


_TABLE = {}


def _table():
    """``G(t) = int_0^t sinc^2 / pi`` on ``t = i * TAB_STEP``, ``0 <= t <= T_TAB``."""
    if "G" not in _TABLE:
        from scipy.special import sici

        t = np.arange(int(round(T_TAB / TAB_STEP)) + 1) * TAB_STEP
        si, _ = sici(2.0 * t)
        with np.errstate(divide="ignore", invalid="ignore"):
            g = np.where(t > 0, (si - np.sin(t) ** 2 / np.where(t > 0, t, 1.0)) / np.pi, 0.0)
        g = np.maximum.accumulate(g)
        _TABLE["G"] = mi.Float(g.astype(np.float32))
        _TABLE["n"] = len(g)
    return _TABLE["G"], _TABLE["n"]


def _g_of_t(t):
    """Linear interpolation of ``G`` at ``0 <= t <= T_TAB`` (differentiable in ``t``)."""
    g, n = _table()
    pos = dr.clip(t, 0.0, T_TAB) / TAB_STEP
    i = mi.UInt32(dr.clip(dr.floor(dr.detach(pos)), 0, n - 2))
    f = pos - mi.Float(i)
    return (1.0 - f) * dr.gather(mi.Float, g, i) + f * dr.gather(mi.Float, g, i + 1)


def _t_of_g(v):
    """Inverse of :func:`_g_of_t` for ``0 <= v <= G(T_TAB)`` (binary search, detached)."""
    g, n = _table()
    v = dr.detach(v)
    j = dr.binary_search(0, n - 1, lambda idx: dr.gather(mi.Float, g, idx) <= v)
    i = mi.UInt32(dr.clip(mi.Int32(j) - 1, 0, n - 2))
    g0 = dr.gather(mi.Float, g, i)
    g1 = dr.gather(mi.Float, g, i + 1)
    den = g1 - g0
    f = dr.select(den > 0, (v - g0) / dr.select(den > 0, den, 1.0), 0.5)
    return dr.clip((mi.Float(i) + dr.clip(f, 0.0, 1.0)) * TAB_STEP, 0.0, T_TAB)


# ------------------------------------------------------------------ geometry per edge
def _check(d, x, edges, lam, s, extra=()):
    if not isinstance(edges, FsdEdges):
        raise InputValueError(f"edges must be an FsdEdges, got {type(edges).__name__}")
    k = int(edges.k)
    width = dr.width(edges.p0)
    if k < 1 or width == 0:
        raise InputValueError("edges: empty edge input (K = 0 or no entries); pass at least "
                              "one (possibly invalid) edge slot per query point")
    if width % k:
        raise InputValueError(f"edges: width {width} is not a multiple of K = {k}")
    for name in ("p1", "apex0", "apex1", "valid"):
        if dr.width(getattr(edges, name)) != width:
            raise InputValueError(f"edges: {name} has width {dr.width(getattr(edges, name))}, "
                                  f"p0 has {width}")
    for name in ("p0", "p1", "apex0", "apex1"):
        a = getattr(edges, name)
        if not all(np.all(np.isfinite(np.array(c))) for c in (a.x, a.y, a.z)):
            raise InputValueError(f"edges: {name} contains NaN or Inf")
    for name, val in (("d", d), ("x", x)) + tuple(extra):
        comps = [val[i] for i in range(len(val))] if dr.depth_v(val) > 1 else (val,)
        if not all(np.all(np.isfinite(np.array(c))) for c in comps):
            raise InputValueError(f"{name} contains NaN or Inf")
    for name, val in (("lam", lam), ("s", s)):
        if val is None and name == "s":
            continue
        arr = np.array(val, dtype=np.float64)
        if arr.size == 0 or not np.all(np.isfinite(arr)) or np.any(arr <= 0):
            raise InputValueError(f"{name} must be finite and > 0, got {val!r}")
    rows = width // k
    n = max(dr.width(d), dr.width(x))
    if rows not in (1, n) and n != 1:
        raise InputValueError(f"edges: {rows} rows of K = {k} edges do not match {n} query points")


def _columns(edges, n):
    """Per-slot ``(p0, p1, apex0, apex1, valid)`` gathered for each of the K columns.

    A single row is gathered at the full query width ``n`` (not broadcast from
    width 1): broadcasting a width-1 AD variable makes every backward pass
    reduce (and launch a kernel) per variable."""
    k = int(edges.k)
    rows = dr.width(edges.p0) // k
    out = []
    for j in range(k):
        idx = dr.full(mi.UInt32, j, n) if rows == 1 else dr.arange(mi.UInt32, rows) * k + j
        out.append(tuple(dr.gather(type(a), a, idx) for a in
                         (edges.p0, edges.p1, edges.apex0, edges.apex1))
                   + (dr.gather(mi.Bool, edges.valid, idx),))
    return out


def _edge_terms(frame, x, col, k, s):
    """Screen-projected edge quantities of Sec. 2-3 of the module docstring."""
    pa, pb, qa, qb, valid = col
    fs, ft = frame.s, frame.t

    def proj(p):
        r = p - x
        return dr.dot(r, fs), dr.dot(r, ft)

    p0x, p0y = proj(pa)
    p1x, p1y = proj(pb)
    a0x, a0y = proj(qa)
    a1x, a1y = proj(qb)
    ex, ey = p1x - p0x, p1y - p0y
    length = dr.sqrt(ex * ex + ey * ey)
    ok_len = length > 1e-6 * s
    inv = 1.0 / dr.maximum(length, 1e-30)
    ex, ey = ex * inv, ey * inv
    nx, ny = -ey, ex
    eps = 1e-6 * s
    sa = nx * (a0x - p0x) + ny * (a0y - p0y)
    sb = nx * (a1x - p0x) + ny * (a1y - p0y)
    sa = dr.select(dr.abs(sa) < eps, 0.0, sa)
    sb = dr.select(dr.abs(sb) < eps, 0.0, sb)
    silhouette = (sa * sb >= 0) & ((dr.abs(sa) + dr.abs(sb)) > 0)
    side = dr.select(sa + sb >= 0, 1.0, -1.0)
    nx, ny = side * nx, side * ny                       # into the opaque side
    delta = -(nx * p0x + ny * p0y)
    tau0 = ex * p0x + ey * p0y
    tau1 = ex * p1x + ey * p1y
    l_vis = (0.5 * _SQRT_PI) * s * _erf_diff(tau0 / s, tau1 / s)
    xi = delta / (math.sqrt(2.0) * s)
    ecx = _erfcx(dr.clip(xi, -XI_CLAMP, XI_CLAMP))
    q0 = 1.0 / (k * s * math.sqrt(0.5 * math.pi) * ecx)
    w_full = dr.exp(-2.0 * xi * xi) * ecx * (l_vis / s) / (2.0 * math.sqrt(2.0 * math.pi))
    m_perp = (2.0 * _INV_PI) * dr.atan(1.0 / q0)
    half_kl = 0.5 * k * l_vis
    t_max = dr.minimum(half_kl, T_TAB)
    m_par = 2.0 * _g_of_t(t_max)
    ok = valid & ok_len & silhouette & (l_vis > 0) & (m_par > 0)
    w = dr.select(ok, w_full * m_perp * m_par, 0.0)
    return dict(ex=ex, ey=ey, nx=nx, ny=ny, delta=delta, length=l_vis, proj_length=length,
                q0=q0, half_kl=half_kl, t_max=t_max, m_perp=m_perp, m_par=m_par,
                w_full=dr.select(ok, w_full, 0.0), w=w, ok=ok, silhouette=silhouette)


def _density(frame, d, wo, e):
    """Normalised lobe ``D_e(wo)`` [1/sr] of one edge (Sec. 3)."""
    qx, qy, c = dr.dot(wo, frame.s), dr.dot(wo, frame.t), dr.dot(wo, d)
    q_par = qx * e["ex"] + qy * e["ey"]
    q_perp = qx * e["nx"] + qy * e["ny"]
    t = e["half_kl"] * q_par
    q0 = e["q0"]
    lor = q0 * _INV_PI / (q_perp * q_perp + q0 * q0)
    par = e["half_kl"] * _INV_PI * _sinc2(t)
    norm = e["m_perp"] * dr.maximum(e["m_par"], 1e-30)
    inside = e["ok"] & (c > 0) & (dr.abs(q_perp) < 1.0) & (dr.abs(t) < e["t_max"])
    return dr.select(inside, lor * par * c / norm, 0.0)


def _setup(d, x, edges, lam, s, check, extra=()):
    n = max([dr.width(d), dr.width(x)] + [dr.width(v) for _, v in extra])
    if check:
        _check(d, x, edges, lam, s, extra)
    lam = as_float(lam)
    s = BEAM_WIDTH_WAVELENGTHS * lam if s is None else as_float(s)
    k = 2.0 * dr.pi / lam
    frame = mi.Frame3f(d)
    terms = [_edge_terms(frame, x, col, k, s) for col in _columns(edges, n)]
    total = mi.Float(0.0)
    for e in terms:
        total += e["w"]
    return frame, terms, total


def _mixture(frame, d, wo, terms, total):
    acc = mi.Float(0.0)
    for e in terms:
        acc += e["w"] * _density(frame, d, wo, e)
    return dr.select(total > 0, acc / dr.select(total > 0, total, 1.0), 0.0)


# ------------------------------------------------------------------ public API
def edge_parameters(d, x, edges, lam, s=None, check=True):
    """Per-edge quantities (list of K dicts of ``mi.Float`` / ``mi.Bool``) for diagnostics.

    Keys: ``delta`` (signed distance of ``x`` from the projected edge line,
    > 0 on the opaque side), ``length`` (visible length ``l``), ``proj_length``
    (``L``), ``q0``, ``w`` (energy weight ``w_e``), ``w_full`` (untruncated),
    ``m_perp``, ``m_par``, ``t_max``, ``ok`` (counts), ``silhouette``, the
    screen-frame edge direction ``ex, ey`` and opaque-side normal ``nx, ny``.
    """
    _, terms, _ = _setup(d, x, edges, lam, s, check)
    return terms


def beta(d, x, edges, lam, s=None, opacity=1.0, beta_max=BETA_MAX, check=True):
    """Diffracted fraction ``beta = min(beta_max, sum_e w_e) * opacity`` (``mi.Float``)."""
    _, _, total = _setup(d, x, edges, lam, s, check)
    return dr.minimum(as_float(beta_max), total) * as_float(opacity)


def eval(d, wo, x, edges, lam, s=None, opacity=1.0, beta_max=BETA_MAX, check=True):  # noqa: A001
    """FSD lobe value ``beta * sum_e (w_e/W) D_e(wo)`` [1/sr, no cosine].

    Parameters
    ----------
    d : mi.Vector3f
        unit propagation direction of the incident ray
    wo : mi.Vector3f
        unit outgoing direction (world)
    x : mi.Point3f
        hit point (screen origin)
    edges : FsdEdges
        ``N*K`` or ``K`` slots
    lam : float
        wavelength [m]
    s : float, optional
        Gaussian beam footprint width [m] (default ``3 lam``)
    opacity : float, optional
        edge opacity in ``[0, 1]`` (e.g. the Fresnel energy gate)
    beta_max : float, optional
        cap of the diffracted fraction
    check : bool, optional
        validate inputs (raises ``InputValueError`` for NaN / empty)

    Returns
    -------
    mi.Float
    """
    frame, terms, total = _setup(d, x, edges, lam, s, check, (("wo", wo),))
    b = dr.minimum(as_float(beta_max), total) * as_float(opacity)
    return b * _mixture(frame, d, wo, terms, total)


def pdf(d, wo, x, edges, lam, s=None, check=True):
    """Solid-angle pdf of :func:`sample`: ``sum_e (w_e/W) D_e(wo)`` (0 if ``W = 0``)."""
    frame, terms, total = _setup(d, x, edges, lam, s, check, (("wo", wo),))
    return _mixture(frame, d, wo, terms, total)


def sample(d, x, edges, lam, s, u1, u2, check=True):
    """Importance-sample the FSD lobe (``s=None``: ``3 lam``).

    Parameters
    ----------
    d, x, edges, lam, s
        as in :func:`eval`
    u1 : mi.Float
        in ``[0, 1)``: picks edge ``e`` w.p. ``w_e / W``
    u2 : mi.Point2f
        in ``[0, 1)^2``: ``q_perp`` (x) and ``q_par`` (y)

    check : bool, optional
        validate inputs

    Returns
    -------
    wo : mi.Vector3f
        sampled direction (``wo == d`` where ``pdf == 0``)
    pdf : mi.Float
        its pdf; 0 where no edge diffracts or the draw fell outside the
        unit disc of directions
    """
    u1 = as_float(u1)
    frame, terms, total = _setup(d, x, edges, lam, s, check, (("u1", u1), ("u2", u2.x)))
    target = u1 * total
    chosen = dict(terms[0])
    cdf = terms[0]["w"]
    keys = ("ex", "ey", "nx", "ny", "q0", "half_kl", "t_max", "m_par")
    for e in terms[1:]:
        take = (target >= cdf) & (e["w"] > 0)
        for key in keys:
            chosen[key] = dr.select(take, e[key], chosen[key])
        cdf = cdf + e["w"]
    q0 = chosen["q0"]
    q_perp = q0 * dr.tan((2.0 * u2.x - 1.0) * dr.atan(1.0 / q0))
    v = (2.0 * u2.y - 1.0) * (0.5 * chosen["m_par"])
    t = dr.minimum(_t_of_g(dr.abs(v)), chosen["t_max"])
    t = dr.select(v < 0, -t, t)
    q_par = t / dr.maximum(chosen["half_kl"], 1e-30)
    qx = q_perp * chosen["nx"] + q_par * chosen["ex"]
    qy = q_perp * chosen["ny"] + q_par * chosen["ey"]
    r2 = qx * qx + qy * qy
    ok = (total > 0) & (r2 < 1.0)
    wo = qx * frame.s + qy * frame.t + dr.safe_sqrt(1.0 - r2) * frame.n
    wo = dr.select(ok, wo, mi.Vector3f(d))
    p = _mixture(frame, d, wo, terms, total)
    return wo, dr.select(ok, p, 0.0)
