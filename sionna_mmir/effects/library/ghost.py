"""Multipath ghost of a strong scatterer via a flat surface (floor, wall).

A point target ``p`` next to a flat surface (plane through ``q`` with unit
normal ``n``, radar frame) is also reached over the surface.  With the image
``p' = p - 2 ((p - q) . n) n`` of the target across the plane (method of
images; exact per (tx, rx) pair)::

    tau_d   = (|p  - tx_t| + |p  - rx_r|) / c     direct (already in the model)
    tau_1a  = (|p' - tx_t| + |p  - rx_r|) / c     Tx -> surface -> target -> Rx
    tau_1b  = (|p  - tx_t| + |p' - rx_r|) / c     Tx -> target -> surface -> Rx
    tau_2   = (|p' - tx_t| + |p' - rx_r|) / c     Tx -> surface -> target -> surface -> Rx

    x += a [Gamma beta (e^{j2pi(f0+S t_k) tau_1a} + e^{j2pi(f0+S t_k) tau_1b})
            + Gamma^2 e^{j2pi(f0+S t_k) tau_2}]

(the classic "multipath ghost" of automotive radar: a ghost at the mean of
the direct and mirrored ranges from the mixed paths and one at the mirrored
range from the double bounce).  ``Gamma`` is the surface's complex
reflection coefficient (spreading-loss differences are folded into it).
``beta`` is the target's bistatic-to-monostatic amplitude ratio
``sqrt(sigma_bi / sigma_mono)`` at the bistatic angle of the mixed paths:
1 for an isotropic point, near 0 for a retro-reflector (a trihedral returns
the double bounce, which it sees monostatically from the image radar, and
little of the mixed paths).

The surface is searched among the scene's large flat objects (floors,
walls: :attr:`~sionna_mmir.effects.scene_basis.SceneBasis.planes`), or
without a scene among floors, ceilings and side walls at a range of
distances.  The target ``p`` is one of the model's strongest points (range-azimuth
peaks of the model ADC, refined, :func:`~.scatterer.strongest_points`): the
one whose ghost removes the most residual energy, found once in
:meth:`MultipathGhost.param_specs`.  Its complex amplitude ``a`` is the LS
amplitude of that point in the model signal the effect is applied to (so the
ghost follows the model's gain).

Parameters: ``offset`` ``[1]`` [m], a shift of the plane along its normal
(``q -> q + offset n``), ``gamma`` ``[2]`` (re, im) and ``mixed`` ``[1]``
(``beta``, 0 .. 1.5) -- 4 numbers.  ``gamma`` is referred to the carrier
phase of the extra path length at the centre frequency: ``gamma = Gamma
exp(j 2 pi f_c (|p'| - |p|) / c)`` so the plane offset moves the ghost
without rotating it; then the double bounce has exactly ``gamma^2`` (see
:func:`ghost_signal_np`).  The summary reports the physical ``Gamma``.
"""
from __future__ import annotations

import numpy as np

from ...errors import ConfigError
from .. import ops
from ..base import Effect, ParamSpec
from .scatterer import (C0, DrGeometry, _freq_terms, carrier_phase, dr_ref_phase, excess_np,
                        has_elevation_aperture, ref_phase_np, single_blas, static_view,
                        strongest_point, strongest_points, unit_vectors)

dr, mi = ops.dr, ops.mi

#: candidate surface families for the default search: (name, unit normal, sign of
#: the plane's offset from the origin along -n); the plane is ``q = -d n``.
FAMILIES = (("floor", (0.0, 0.0, 1.0)), ("ceiling", (0.0, 0.0, -1.0)),
            ("left_wall", (0.0, -1.0, 0.0)), ("right_wall", (0.0, 1.0, 0.0)))


def check_plane(plane):
    """``(q [3], n [3] unit)`` from ``(point, normal)``; ConfigError naming ``plane``."""
    try:
        q, n = (np.asarray(v, np.float64).reshape(3) for v in plane)
    except (TypeError, ValueError):
        raise ConfigError(f"MultipathGhost: plane must be (point [3], normal [3]) in metres, "
                          f"got {plane!r}") from None
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(n))) or np.linalg.norm(n) < 1e-9:
        raise ConfigError(f"MultipathGhost: plane needs a finite point and a non-zero normal, "
                          f"got {plane!r}")
    return q, n / np.linalg.norm(n)


def image_point(p, q, n, offset=0.0) -> np.ndarray:
    """Mirror image of ``p [..., 3]`` across the plane through ``q + offset n``, normal ``n``."""
    d = np.sum((np.asarray(p) - q) * n, axis=-1) - np.asarray(offset)
    return np.asarray(p) - 2.0 * d[..., None] * n


def ghost_delays(radar, p, q, n, offset=0.0) -> np.ndarray:
    """Exact delays ``[4, T, R]`` [s]: direct, Tx-side bounce, Rx-side bounce, double."""
    pi = image_point(p, q, n, offset)
    dt = np.linalg.norm(p - radar.tx_positions, axis=1)[:, None]
    dr_ = np.linalg.norm(p - radar.rx_positions, axis=1)[None, :]
    it = np.linalg.norm(pi - radar.tx_positions, axis=1)[:, None]
    ir = np.linalg.norm(pi - radar.rx_positions, axis=1)[None, :]
    return np.stack([dt + dr_, it + dr_, dt + ir, it + ir]) / C0


def ghost_templates(ctx, p, img):
    """Referred unit-amplitude signals of the single and double bounces, ``[..., T, R, N]`` each.

    ``img [..., 3]`` image points; ``p [3]`` the target.
    """
    pb = np.broadcast_to(p, np.shape(img))
    single = np.exp(1j * ref_phase_np(ctx, img, pb)) + np.exp(1j * ref_phase_np(ctx, pb, img))
    double = np.exp(1j * ref_phase_np(ctx, img, img))
    return single, double


def ghost_signal_np(ctx, p, a_ref, q, n, offset, gamma_ref, mixed=1.0) -> np.ndarray:
    """The ghost ``[T, R, N]`` (NumPy reference of :meth:`MultipathGhost.apply`)."""
    single, double = ghost_templates(ctx, p, image_point(p, q, n, offset))
    return a_ref * (gamma_ref * mixed * single + gamma_ref ** 2 * double)


def gamma_and_mixed(coef, single, double, z, a):
    """``(gamma_ref, beta)`` of the ghost closest to the free least-squares
    coefficients ``coef = (c_single, c_double)`` of the templates ``single``,
    ``double [T, R, N]`` on ``z`` (target amplitude ``a``): either the double
    bounce kept (``gamma = sqrt(c_double)``, ``beta = Re(c_single / gamma)``) or
    the mixed paths kept (``gamma = c_single``, ``beta = 1``), whichever leaves
    less of ``z``."""
    c1, c2 = complex(coef[0]), complex(coef[1])
    g = np.sqrt(c2)
    if (c1 * np.conj(g)).real < 0:
        g = -g
    options = [(c1, 1.0)]
    if abs(g) > 1e-12:
        options.append((g, float(np.clip((c1 / g).real, 0.0, 1.5))))

    def left(opt):
        gm, b = opt
        return np.sum(np.abs(z - a * (gm * b * single + gm ** 2 * double)) ** 2)

    return min(options, key=left)


#: a ghost is searched only where its double bounce's template shares at
#: most this normalised inner product with its target's own (direct) signal
#: (:func:`target_coherence`): more than half of its energy is then
#: something the target's amplitude cannot take
MAX_TARGET_COHERENCE = 2 ** -0.5


def _element_terms(ctx, pts):
    """The Tx and Rx factors of the referred phase of paths through ``pts
    [..., 3]`` (:func:`ref_phase_np`): ``(U [..., T, N], V [..., R, N])``."""
    fk = _freq_terms(ctx)[0]
    return tuple(np.exp(1j * fk * excess_np(pts, el)[..., None])
                 for el in (ctx.radar.tx_positions, ctx.radar.rx_positions))


def target_coherence(ctx, p, img) -> np.ndarray:
    """``|<s_p, s_i>| / (|s_p| |s_i|)`` of the direct signal of the target
    ``p [3]`` and the double bounce via each image point ``img [B, 3]``
    (:func:`ref_phase_np`), ``[B]``: how much of the ghost its target could
    mimic.  Range and angle separate them, so a range margin alone (say
    1.5 range bins) would miss the floor ghost of a corner 13.6 m away in
    a 25 m hall, 0.47 bins beyond it on a 0.31 m AWR1843 waveform but 8 deg
    below it (coherence 0.66), and one in a room at 1.14 bins (0.10).  By
    the separable phase: ``sum_n
    conj(w_p) w_i (sum_t conj(U_p) U_i) (sum_r conj(V_p) V_i) / (T R N)``.
    """
    sk = _freq_terms(ctx)[1]
    img = np.atleast_2d(img)
    (up, vp), (ui, vi) = _element_terms(ctx, p), _element_terms(ctx, img)
    w = np.exp(1j * sk * 2 * (np.linalg.norm(img, axis=1)[:, None] - np.linalg.norm(p)))
    inner = np.sum(w * np.einsum("tn,btn->bn", up.conj(), ui)
                   * np.einsum("rn,brn->bn", vp.conj(), vi), axis=1)
    return np.abs(inner) / up.shape[0] / vp.shape[0] / up.shape[1]


def ghost_scores(ctx, z, p, a, img):
    """Energy removed from ``z [T, R, N]`` by a least-squares fit of the ghost of ``p``
    (amplitude ``a``) at each image point ``img [B, 3]``, and the fitted
    coefficients of the single- and double-bounce templates: ``(gain [B],
    coef [B, 2])`` (free coefficients: an upper bound on the ghost's gain).

    The referred phase is separable, ``exp(j phase) = U_t[n] V_r[n] w[n]``
    (:func:`ref_phase_np`: a Tx term, an Rx term and an origin term), so the
    projections of the two templates (single bounce ``a1 + a2``, double bounce
    ``s2``) onto ``z`` and their Gram matrix reduce to sums over Tx or Rx
    only, except ``<s2, z>`` (one ``T R N`` contraction per image point):
    the same numbers as building the ``[B, T, R, N]`` templates, without them.
    """
    sk = _freq_terms(ctx)[1]
    T, R, N = z.shape
    (Up, Vp), (Ui, Vi) = _element_terms(ctx, p), _element_terms(ctx, img)
    n_p, n_i = np.linalg.norm(p), np.linalg.norm(img, axis=1)
    w1 = np.exp(1j * sk * (n_p + n_i)[:, None])           # single bounce [B, N]
    w2 = np.exp(1j * sk * (2 * n_i)[:, None])              # double bounce [B, N]
    Zp = np.einsum("rn,trn->tn", Vp.conj(), z)             # z seen by the target's Rx term
    Zq = np.einsum("tn,trn->rn", Up.conj(), z)             # ... by its Tx term
    Zi = np.einsum("brn,trn->btn", Vi.conj(), z)           # ... by each image's Rx term
    rhs = np.stack([np.einsum("btn,bn,tn->b", Ui.conj(), w1.conj(), Zp)
                    + np.einsum("brn,bn,rn->b", Vi.conj(), w1.conj(), Zq),
                    np.einsum("btn,bn,btn->b", Ui.conj(), w2.conj(), Zi)], axis=-1)
    cu = np.einsum("btn,tn->bn", Ui.conj(), Up)            # sum_t conj(U_i) U_p
    cv = np.einsum("rn,brn->bn", Vp.conj(), Vi)            # sum_r conj(V_p) V_i
    trn = float(T * R * N)
    G = np.empty((len(img), 2, 2), complex)
    G[:, 0, 0] = 2 * trn + 2 * np.sum(cu * cv, axis=1).real
    G[:, 0, 1] = np.sum(w1.conj() * w2 * (T * cv + R * cu.conj()), axis=1)
    G[:, 1, 0] = G[:, 0, 1].conj()
    G[:, 1, 1] = trn
    G, rhs = G * abs(a) ** 2, rhs * np.conj(a)
    coef = np.linalg.solve(G + 1e-9 * np.eye(2), rhs[..., None])[..., 0]
    gain = np.einsum("bi,bi->b", np.conj(coef), rhs).real
    return gain, coef


def target_amplitude(x, ctx, p):
    """LS amplitude (referred, :func:`ref_phase_np`) of the static point ``p`` in ``x`` (Dr.Jit).

    ``<s, x> / <s, s>`` over all frames, chirps and channels, as a pair of
    width-1 ``mi.Float``: the ghost follows the model's target (and its gain).
    """
    T, R, N = ctx.radar.num_tx, ctx.radar.num_rx, ctx.radar.num_samples
    s = np.exp(-1j * ref_phase_np(ctx, p, p)).reshape(1, T, R, 1, N) / float(np.prod(x[0].shape))
    prod = ops.cmul(x, ops.tensor(s))
    one = (1, 1, 1, 1, 1)
    return tuple(ops.view(dr.sum(c, axis=None), one) for c in prod)


#: how far the model's point may lie from the mirrored residual peak, in
#: direction, to be a ghost's target (:meth:`MultipathGhost._mirrored_targets`) [deg]
MIRROR_TOLERANCE_DEG = 10.0


class MultipathGhost(Effect):
    """Multipath ghost of one of the model's strongest scatterers via a flat surface
    (4 parameters).

    The target and (default) the plane chosen at init are kept on the
    instance (``target_``, ``plane_``), so use one instance per model.

    Parameters
    ----------
    plane : tuple, optional
        ``(point [3], normal [3])`` [m] in the radar frame, e.g.
        ``((0, 0, -h), (0, 0, 1))`` for a floor ``h`` below; None:
        search the scene's flat objects (``ctx.basis.planes``,
        +- ``max_offset``) in init, or without any, floors, ceilings and
        side walls at ``distances``
    distances : tuple, optional
        ``(min, max)`` plane distances from the radar searched
        when ``plane`` is None and the scene has no flat object [m]
    max_offset : float, optional
        bound of the plane offset refinement [m]
    min_range : float, optional
        smallest target range considered [m]
    targets : int, optional
        how many of the model's strongest points are tried as the target
    """

    name = "multipath_ghost"
    kind = "mean"
    stage = 0
    description = "multipath ghost of a strong scatterer via a flat surface"

    def __init__(self, plane=None, distances=(0.2, 4.0), max_offset: float = 0.25,
                 min_range: float = 0.3, targets: int = 3):
        self.plane = None if plane is None else check_plane(plane)
        try:
            lo, hi = (float(v) for v in distances)
        except (TypeError, ValueError):
            raise ConfigError(f"MultipathGhost: distances must be (min, max) in metres, "
                              f"got {distances!r}") from None
        if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo < hi):
            raise ConfigError(f"MultipathGhost: distances must satisfy 0 < min < max, "
                              f"got {distances!r}")
        if not np.isfinite(max_offset) or max_offset <= 0:
            raise ConfigError(f"MultipathGhost: max_offset must be > 0 m, got {max_offset}")
        if not np.isfinite(min_range) or min_range < 0:
            raise ConfigError(f"MultipathGhost: min_range must be >= 0 m, got {min_range}")
        if int(targets) != targets or targets < 1:
            raise ConfigError(f"MultipathGhost: targets must be a whole number >= 1, "
                              f"got {targets}")
        self.targets = int(targets)
        self.distances = (lo, hi)
        self.max_offset = float(max_offset)
        self.min_range = float(min_range)
        self.plane_ = self.plane
        self.target_ = None

    # ---------------------------------------------------------- init
    def _targets(self, ctx, model):
        """``[(p [3] m, A_ref)]``: the model's strongest points, strongest first."""
        radar = ctx.radar
        found = strongest_points(static_view(model), ctx, self.min_range, 0.95 * radar.max_range,
                                 has_elevation_aperture(radar), self.targets)
        return [(r * unit_vectors(az, el), a) for r, az, el, a in found]

    def _mirrored_targets(self, ctx, model, z):
        """``[(p [3] m, A_ref)]``: the model's points whose image via one of
        the scene's flat objects lies at the residual's strongest point.

        The model's few strongest points miss the target of a strong ghost
        when that target is a corner reflector further out than brighter
        clutter near the radar (the suite's AWR1843 room of seed 2: a corner
        at 5.8 m, its floor image 1.1 m under the floor adopted as a missing
        scatterer).  The residual's peak is mirrored through every flat
        object it lies behind, and the model's strongest point within a
        range bin of the mirror is taken when it lies within
        :data:`MIRROR_TOLERANCE_DEG` of the mirror's direction."""
        planes = getattr(ctx.basis, "planes", None) or []
        if not planes:
            return []
        radar = ctx.radar
        fit_el = has_elevation_aperture(radar)
        rmax = 0.95 * radar.max_range
        r, az, el, _ = strongest_point(z, ctx, self.min_range, rmax, fit_el)
        peak = r * unit_vectors(az, el)
        res, out = radar.range_resolution, []
        for _, q, n in planes:
            depth = np.dot(peak - np.asarray(q, float), n)
            if depth > -0.05:                         # the peak is not behind this plane
                continue
            mirror = peak - 2.0 * depth * np.asarray(n, float)
            rm = float(np.linalg.norm(mirror))
            if not self.min_range + res <= rm <= rmax - res:
                continue
            (rt, azt, elt, a), = strongest_points(static_view(model), ctx, rm - res, rm + res,
                                                  fit_el, 1)
            p = rt * unit_vectors(azt, elt)
            cos = np.dot(p, mirror) / (np.linalg.norm(p) * rm)
            if cos >= np.cos(np.radians(MIRROR_TOLERANCE_DEG)):
                out.append((p, a))
        return out

    def _candidates(self, ctx, p, step):
        """``[(q, n, offsets)]`` to score: the given plane +- max_offset; else the
        scene's flat objects (:attr:`~..scene_basis.SceneBasis.planes`) +-
        max_offset, those the target lies in front of; else the families.

        The mesh's planes come first because range alone cannot tell the
        mixed paths via one plane from the double bounce via a nearer one (a
        radar with little elevation aperture sees both as one range)."""
        offs = np.arange(-self.max_offset, self.max_offset + 1e-12, step)
        if self.plane is not None:
            q, n = self.plane
            return [(q, n, offs)]
        planes = getattr(ctx.basis, "planes", None) or []
        mesh = [(np.asarray(q, float), np.asarray(n, float), offs) for _, q, n in planes
                if np.dot(p - np.asarray(q, float), n) > 0.05]
        if mesh:
            return mesh
        out = []
        lo, hi = self.distances
        for _, n in FAMILIES:
            n = np.asarray(n)
            d = np.arange(lo, hi + 1e-12, step)
            d = d[d > -np.dot(p, n) + 0.05]            # target on the radar's side, 5 cm clear
            if d.size:
                out.append((np.zeros(3), n, -d))      # plane through -d n: offsets of q = 0
        return out

    @staticmethod
    def _scan(ctx, z, p, a, q, n, offs):
        """Best ``(gain, offset, coef [2])`` of one plane over ``offs`` (None: none resolvable)."""
        img = image_point(p, q, n, offs)                                    # [B, 3]
        extra = np.linalg.norm(img, axis=1) - np.linalg.norm(p)
        keep = (extra > 0) & (target_coherence(ctx, p, img) <= MAX_TARGET_COHERENCE)
        offs, img = offs[keep], img[keep]
        if not len(offs):
            return None
        gain, g1 = ghost_scores(ctx, z, p, a, img)
        j = int(np.argmax(gain))
        return gain[j], offs[j], g1[j]

    def _search(self, ctx, z, p, a):
        """Best ``(gain, q, n, offset, coef [2])`` by LS energy reduction (None: no
        resolvable ghost): a grid of two thirds of a range bin over the candidates
        (the score's peak is a range bin wide), then a sixth of that about the best."""
        coarse = ctx.radar.range_resolution / 1.5
        best = None
        for q, n, offs in self._candidates(ctx, p, coarse):
            found = self._scan(ctx, z, p, a, q, n, offs)
            if found is not None and (best is None or found[0] > best[0][0]):
                best = (found, q, n)
        if best is None:
            return None
        (gain, off, c), q, n = best
        fine = off + np.linspace(-coarse, coarse, 13)
        if self.plane is not None:
            fine = np.clip(fine, -self.max_offset, self.max_offset)
        found = self._scan(ctx, z, p, a, q, n, fine)
        if found is not None:
            gain, off, c = found
        return gain, q, n, off, c

    @single_blas
    def param_specs(self, ctx, model, residual):
        z = static_view(residual)
        best = None
        for p, a in self._targets(ctx, model) + self._mirrored_targets(ctx, model, z):
            found = self._search(ctx, z, p, a)
            if found is not None and (best is None or found[0] > best[0][0]):
                best = (found, p, a)
        if best is None:
            raise ConfigError("MultipathGhost: no candidate plane gives a resolvable ghost "
                              f"(distances={self.distances})")
        (_, q, n, off, c), p, a = best
        single, double = ghost_templates(ctx, p, image_point(p, q, n, off))
        g, beta = gamma_and_mixed(c, single, double, z, a)
        if self.plane is None:               # re-centre the found plane: offset starts at 0
            q, off = q + off * n, 0.0
        self.plane_ = (q, n)
        self.target_ = (p, a)
        if abs(g) > 1.5:
            g = 1.5 * g / abs(g)
        return {"offset": ParamSpec([off], lower=-self.max_offset, upper=self.max_offset,
                                    unit="m"),
                "gamma": ParamSpec([g.real, g.imag], lower=-2.0, upper=2.0,
                                   unit="complex (referred to f_c, |p'| - |p|)"),
                "mixed": ParamSpec([beta], lower=0.0, upper=1.5,
                                   unit="sqrt(sigma_bistatic / sigma_mono)")}

    # --------------------------------------------------------- forward
    def apply(self, x, p, ctx):
        if self.target_ is None:
            raise ConfigError("MultipathGhost: apply() before param_specs() (no target)")
        tgt, _ = self.target_
        q, n = self.plane_
        one = (1, 1, 1, 1, 1)
        geo = DrGeometry(ctx)
        a = target_amplitude(x, ctx, tgt)
        img0 = image_point(tgt, q, n, 0.0)
        off = ops.view(p["offset"], one)
        P = [ops.opaque(tgt[i]) for i in range(3)]
        I = [ops.opaque(img0[i]) + ops.opaque(2.0 * n[i]) * off for i in range(3)]
        nP = ops.opaque(np.linalg.norm(tgt))
        nI = dr.sqrt(dr.square(I[0]) + dr.square(I[1]) + dr.square(I[2]))
        s1 = ops.cadd(ops.cis(dr_ref_phase(geo, I, P, nI, nP)),
                      ops.cis(dr_ref_phase(geo, P, I, nP, nI)))
        s2 = ops.cis(dr_ref_phase(geo, I, I, nI, nI))
        g = (ops.column(ops.view(p["gamma"], (1, 2)), 0, one),
             ops.column(ops.view(p["gamma"], (1, 2)), 1, one))
        beta = ops.view(p["mixed"], one)
        ghost = ops.cadd(ops.cmul(s1, (g[0] * beta, g[1] * beta)), ops.cmul(s2, ops.cmul(g, g)))
        return ops.cadd(x, ops.cmul(ghost, a))

    def summary(self, p, ctx):
        off = float(p["offset"][0])
        g_ref = complex(p["gamma"][0], p["gamma"][1])
        out = {"offset_m": round(off, 5), "gamma_abs": round(abs(g_ref), 5),
               "mixed": round(float(p["mixed"][0]), 5)}
        if self.target_ is not None:
            tgt, a = self.target_
            q, n = self.plane_
            img = image_point(tgt, q, n, off)
            extra = np.linalg.norm(img) - np.linalg.norm(tgt)
            g = g_ref * np.exp(-1j * carrier_phase(ctx, extra))
            out.update({"gamma_phase_deg": round(float(np.degrees(np.angle(g))), 2),
                        "plane_point_m": (q + off * n).round(4).tolist(),
                        "plane_normal": n.round(4).tolist(),
                        "target_m": tgt.round(4).tolist(),
                        "image_m": img.round(4).tolist(),
                        "ghost_ranges_m": [round(float(np.linalg.norm(tgt) + extra / 2), 4),
                                           round(float(np.linalg.norm(img)), 4)]})
        return out
