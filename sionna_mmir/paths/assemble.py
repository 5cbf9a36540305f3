"""Assembly: per-path terms and per-element legs as factorised :class:`RadarPaths`.

MIMO ray reuse (Schuessler et al. 2021): the bounce topology is found once
from the array centre; only the first leg ``rx_j -> x_1`` and the last leg
``x_l -> tx_i`` (distances, directions, element gains) are evaluated per Tx
and Rx element, so every pair gets its own exact delay and phase, and the
amplitudes factor as ``a[i, j, p] = C[p] g_t[i, p] g_r[j, p]``.

Convention: the transport stages compute channel coefficients in the
``exp(+j w t)`` / ``exp(-j k r)`` convention of ITU-R P.2040 and Sionna RT
(``h(f) = sum a_s exp(-j 2 pi f tau)``); the FMCW beat signal is
``sum conj(a_s) exp(+j 2 pi f_k tau)``, so :class:`RadarPaths` holds
``a = conj(a_s)`` -- the convention of the Sionna RT baseline too.
"""
from __future__ import annotations

import numpy as np

from ..radio_materials.fresnel import SPEED_OF_LIGHT
from ..utils.backend import init_backend
from .radar_paths import PathFactors, PathGeometry, RadarPaths

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402


def gather3(v, idx):
    """``mi.Point3f`` of ``v`` (three component arrays) at ``idx``."""
    return mi.Point3f(*(dr.gather(mi.Float, v[c], idx) for c in range(3)))


def empty_paths(T: int, R: int, N: int) -> RadarPaths:
    """No paths (``shape (T, R, 0)``) from ``N`` candidates."""
    z = dr.zeros(mi.Float, 0)
    return RadarPaths(a_re=z, a_im=z, tau=z, tau_rate=None, shape=(T, R, 0),
                      depth=np.zeros(0, dtype=np.int32), num_candidates=N, info={"hits": 0})


def element_legs(elements, X, chain, pattern, pose, n, P):
    """``(sqrt(G) / length, length)`` [n * P] of the element <-> ``X`` legs.

    ``length = |X - element| + chain`` (the unfolded length on that side);
    the gain is the element's pattern towards ``X`` in the radar frame.
    """
    i = dr.arange(mi.UInt32, n * P)
    Pv = dr.opaque(mi.UInt32, P)          # a literal P would recompile per path count
    e_idx = i // Pv
    p_idx = i - e_idx * Pv
    e = gather3(elements, e_idx)
    xp = gather3(X, p_idx)
    d = dr.maximum(dr.norm(xp - e), 1e-6)
    length = d + dr.gather(mi.Float, chain, p_idx)
    return dr.sqrt(pattern.gain(pose.to_radar((xp - e) / d), e_idx)) / length, length


def _compress(emissions):
    """Keep the contributing lanes of every emission: ``[(fields, depth, n)]``.

    Dead rays, failed shadow rays and empty reciprocal twins are dropped
    before the per-element legs are formed (the masks are detached and
    frozen, so a replay is identical).  Every field is evaluated in one pass:
    compress and gather would otherwise evaluate each (and the shared
    upstream work) in a kernel of its own.
    """
    dr.eval(*(f for e in emissions for f in e.fields()), *(e.mask for e in emissions))
    kept = []
    for e in emissions:
        idx = dr.compress(dr.detach(e.mask))
        if dr.width(idx) == 0:
            continue
        g = [gather3(f, idx) if i in (2, 3) else dr.gather(mi.Float, f, idx)
             for i, f in enumerate(e.fields())]
        g.append(dr.gather(mi.UInt32, e.obj, idx))
        kept.append((g, e.depth, dr.width(idx), e.boundary))
    return kept


def _concat(kept, depth0=None):
    """Concatenate the kept groups: eight fields (the seven of an emission and
    the first-hit object), depth per path and ``P`` (``depth0``: the depths
    of the first group, when they are not all the same)."""
    def cat(i):
        return dr.concat([k[0][i] for k in kept]) if len(kept) > 1 else kept[0][0][i]

    def cat3(i):
        return mi.Point3f(*(dr.concat([k[0][i][c] for k in kept]) if len(kept) > 1
                            else kept[0][0][i][c] for c in range(3)))

    fields = [cat3(i) if i in (2, 3) else cat(i) for i in range(8)]
    depth = np.concatenate([depth0 if (i == 0 and depth0 is not None) else
                            np.full(k[2], k[1], dtype=np.int32) for i, k in enumerate(kept)])
    return fields, depth, sum(k[2] for k in kept)


def strongest(ctx, fields, P, min_rel_power) -> np.ndarray:
    """Indices (sorted) of the paths whose power at the first Tx-Rx pair,
    ``|C|^2 g_t0^2 g_r0^2``, exceeds ``min_rel_power`` x the strongest's.

    The proxy costs two ``[P]`` legs instead of the ``[T, P] + [R, P]`` the
    paths need; for an array a few cm wide at >= 1 m, element gains and leg
    lengths differ from the first element's by a small fraction of a dB,
    which only moves paths within that of the threshold
    (:meth:`PathFactors.pruned` uses the mean over all pairs).
    """
    C_re, C_im, X, X1, chain_t, chain = fields[:6]
    with dr.suspend_grad():
        g_t, _ = element_legs(ctx.tx_w, dr.detach(X), dr.detach(chain_t), ctx.ptx, ctx.pose, 1, P)
        g_r, _ = element_legs(ctx.rx_w, dr.detach(X1), dr.detach(chain), ctx.prx, ctx.pose, 1, P)
        pw = (dr.square(dr.detach(C_re)) + dr.square(dr.detach(C_im))) \
            * dr.square(g_t) * dr.square(g_r)
        dr.eval(pw)
    pw = np.asarray(pw, dtype=np.float64)
    return np.flatnonzero(pw > min_rel_power * pw.max())


def _select(fields, keep):
    idx = mi.UInt32(keep.astype(np.uint32))
    return [gather3(f, idx) if i in (2, 3) else
            dr.gather(mi.UInt32 if i == 7 else mi.Float, f, idx) for i, f in enumerate(fields)]


def assemble(ctx, emissions, num_candidates: int, num_hits: int, moving: bool,
             object_names=()) -> RadarPaths:
    """Factorised :class:`RadarPaths` of the emitted paths.

    With ``options.min_rel_power > 0`` the paths weaker than that x the
    strongest at the first Tx-Rx pair (:func:`strongest`) are dropped
    *before* the per-element legs (``[T, P]``, ``[R, P]``) are formed.
    """
    T, R = ctx.num_tx, ctx.num_rx
    every = _compress(emissions)
    kept = [k for k in every if not k[3]]
    if not kept:
        return empty_paths(T, R, num_candidates)
    fields, depth, P = _concat(kept)
    min_rel_power = float(ctx.options.min_rel_power)
    if min_rel_power > 0.0:
        keep = strongest(ctx, fields, P, min_rel_power)
        if keep.size < P:
            fields, depth, P = _select(fields, keep), depth[keep], int(keep.size)
    extra = [k for k in every if k[3]]       # boundary paths: zero-valued, never pruned
    if extra:
        fields, depth, P = _concat([(fields, 0, P, False)] + extra, depth)
    C_re, C_im, X, X1, chain_t, chain, rate, obj = fields
    # per-Tx leg [T, P] and per-Rx leg [R, P]: sqrt(gain) / leg length, and lengths
    g_t, dt = element_legs(ctx.tx_w, X, chain_t, ctx.ptx, ctx.pose, T, P)
    g_r, L = element_legs(ctx.rx_w, X1, chain, ctx.prx, ctx.pose, R, P)
    # factorised [T, R, P]: a = conj(C) g_t g_r (FMCW beat convention, see
    # fmcw.model), tau = (dt + L) / c; expanded only on demand (RadarPaths)
    factors = PathFactors(c_re=C_re, c_im=-C_im, g_t=g_t, tau_t=dt / SPEED_OF_LIGHT,
                          g_r=g_r, tau_r=L / SPEED_OF_LIGHT, rate=rate if moving else None,
                          shape=(T, R, P))
    geometry = PathGeometry(X, X1, chain_t, chain, obj, list(object_names), ctx.tx_w, ctx.rx_w)
    return RadarPaths.from_factors(factors, depth=depth, num_candidates=num_candidates,
                                   info={"hits": num_hits}, geometry=geometry)
