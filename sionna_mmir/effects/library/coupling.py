"""Tx -> Rx leakage (antenna coupling, on-chip leakage) as short-delay paths.

Every transmitter leaks into every receiver over a few very short paths
(package / board coupling between the antennas, on-chip LO leakage): tones at
ranges of a few centimetres that are the same in every chirp and frame (TI's
"antenna coupling" calibration, ColoRadar's ``coupling_calib.txt``)::

    x[f, t, r, c, k] += sum_m A_m u_t w_r B[chip_t, chip_r] exp(j 2 pi (f0 + S t_k) tau_m,tr)
    tau_m,tr = tau_m + kappa_m d_tr / c

with ``K`` (default 2) delays ``tau_m`` shared by all channels (equivalent
ranges ``c tau / 2`` of 0.02 - 0.5 m, i.e. ``tau`` ~ 0.1 - 3.5 ns) and, per
path, the share ``kappa_m`` in [0, 1] of the Tx-Rx antenna separation
``d_tr = |p_t - p_r|`` in its length: a space wave from one antenna to the
other (``kappa = 1``) is longer for antennas further apart, by several
carrier cycles across an array (0-8 mm, 0-4 pi rad on an AWR1843), which no
per-Tx and per-Rx factor can express; a leak common to all pairs (on-chip LO
leakage, a bounce off a radome parallel to the array) has ``kappa = 0``.
Each ``kappa_m`` starts at 0 or 1, whichever explains more of the residual
(:func:`_greedy_delays`), since the likelihood in ``kappa`` wraps with the
carrier phase.  Complex
amplitudes ``A_m``, separable per-Tx and per-Rx complex factors ``u_t`` /
``w_r`` and, for a multi-chip radar, a complex factor ``B`` per (Tx chip, Rx
chip) block (``ctx.tx_chip`` / ``ctx.rx_chip``).  There is no free
parameter per virtual (tx, rx) channel, so a held-out channel is predicted
from the others.

A real unit's leakage is not separable: each channel's own leakage deviates
from the shared pattern (its direct path's length follows its antenna pair,
package and board tolerances differ; the MMWCAS corner captures' leakage has
no separable structure beyond a per-chip-pair mean).  With ``spread=True``
the effect says so: that deviation, of RMS ``rho`` times the pattern, enters the
variance as ``rho^2 |DFT(leak_tr)[k]|^2`` per channel and range bin
(:meth:`Coupling.spread`), so the bins the leakage dominates carry the
uncertainty of a prediction from the other channels instead of a misfit no
other effect can mend.

The stored amplitudes are referred to the centre frequency ``f_c``:
``a_m = A_m exp(j 2 pi f_c tau_m)``, so the model computes
``a_m exp(j 2 pi S (t_k - t_c) tau_m)`` and a change of ``tau_m`` moves the
tone without rotating it (no ``1 / f_c`` ripple of the loss in ``tau``).
``A_m`` is reported by :meth:`Coupling.summary`; the product
``A_m u_t w_r B`` is invariant to the (unconstrained) scale / phase gauge
between the factors.

Parameters: ``delay`` ``[K]`` [ns], ``separation`` ``[K]`` (``kappa``),
``amp`` ``[K, 2]``, ``tx`` ``[T, 2]``, ``rx`` ``[R, 2]`` (re, im; normalised
units), with more than one chip ``chip`` ``[n_chips^2, 2]``, and with
``spread`` ``log_spread`` ``[1]`` (``ln rho``): ``4 K + 2 (T + R)`` (+ ``2
n_chips^2``) (+ 1) numbers.  Values without ``separation`` (fitted before
it existed) mean ``kappa = 0``.
"""
from __future__ import annotations

import itertools

import numpy as np

from ...errors import ConfigError
from ...processing.range_fft import range_fft
from ...radar.config import SPEED_OF_LIGHT
from .. import ops
from ..base import Effect, ParamSpec
from .scatterer import single_blas, static_view

dr, mi = ops.dr, ops.mi
NS = 1e-9
#: largest factor by which :meth:`Coupling.behind` raises a path's amplitude
MAX_BEHIND = 1e3


def _centre_time(radar) -> float:
    return (radar.center_frequency - radar.start_frequency) / radar.slope


def tone_phase(ctx, tau) -> np.ndarray:
    """Referred phase ``2 pi S (t_k - t_c) tau`` ``[..., N]`` for delays ``tau [...]`` [s]."""
    radar = ctx.radar
    tk = ctx.fast_time - _centre_time(radar)
    return 2 * np.pi * radar.slope * np.asarray(tau, np.float64)[..., None] * tk


def antenna_separation(ctx) -> np.ndarray:
    """``d_tr = |p_t - p_r|`` ``[T, R]`` [m], the physical Tx-Rx antenna distances."""
    radar = ctx.radar
    tx = np.asarray(radar.tx_positions, np.float64)
    rx = np.asarray(radar.rx_positions, np.float64)
    return np.linalg.norm(tx[:, None] - rx[None], axis=-1)


def pair_phase(ctx, kappa) -> np.ndarray:
    """Phase ``[K, T, R, N]`` of the separation part of each path's delay,
    ``2 pi (f_c + S (t_k - t_c)) kappa_m d_tr / c`` (the carrier part
    referred to ``f_c`` as the stored amplitudes are)."""
    dt = np.asarray(kappa, np.float64)[:, None, None] * antenna_separation(ctx)[None] \
        / SPEED_OF_LIGHT                                                        # [K, T, R]
    return 2 * np.pi * ctx.radar.center_frequency * dt[..., None] + tone_phase(ctx, dt)


def _kappa(values) -> np.ndarray:
    """``kappa [K]`` of parameter values (0 where the values predate it)."""
    k = values.get("separation")
    return np.zeros(len(np.atleast_1d(values["delay"]))) if k is None \
        else np.asarray(k, np.float64).reshape(-1)


def _chip_pair(ctx) -> np.ndarray:
    """Block index ``chip_t * n_chips + chip_r`` ``[T, R]``."""
    return ctx.tx_chip[:, None] * ctx.num_chips + ctx.rx_chip[None, :]


def _cplx(a) -> np.ndarray:
    a = np.asarray(a, np.float64)
    return a[..., 0] + 1j * a[..., 1]


def _pairs(z) -> np.ndarray:
    z = np.asarray(z)
    return np.stack([z.real, z.imag], axis=-1)


def channel_factor(values: dict, ctx) -> np.ndarray:
    """``u_t w_r B[chip_t, chip_r]`` ``[T, R]`` complex from parameter values."""
    g = _cplx(values["tx"])[:, None] * _cplx(values["rx"])[None, :]
    if "chip" in values:
        g = g * _cplx(values["chip"])[_chip_pair(ctx)]
    return g


def coupling_signal(values: dict, ctx) -> np.ndarray:
    """Fitted leakage in the time domain, complex ``[T, R, N]`` (normalised units)."""
    tau = np.asarray(values["delay"], np.float64) * NS
    tones = _cplx(values["amp"])[:, None] * np.exp(1j * tone_phase(ctx, tau))   # [K, N]
    tones = tones[:, None, None, :] * np.exp(1j * pair_phase(ctx, _kappa(values)))
    return channel_factor(values, ctx)[..., None] * tones.sum(axis=0)


def coupling_profile(comp_values: dict, ctx, scale: float = 1.0, n_bins: int | None = None):
    """Fitted coupling per (tx, rx) in the range-FFT domain, complex ``[T, R, n_bins]``.

    The convention of ColoRadar's ``coupling_calib.txt`` (as read by
    :func:`sionna_mmir.captures.coloradar_calib.read_coupling_calib` and
    subtracted by :func:`sionna_mmir.processing.calibration.subtract_coupling`):
    the first ``n_bins`` bins (default all) of the unwindowed, unnormalised
    ``num_samples``-point range FFT of one chirp.  ``comp_values`` are a
    component's values (``EffectModel.components[i].values``) and ``scale``
    converts normalised units to capture units (``EffectModel.scale``).
    """
    spec, _ = range_fft(coupling_signal(comp_values, ctx) * scale, ctx.radar, window="rect")
    n = spec.shape[-1] if n_bins is None else int(n_bins)
    if n < 1 or n > spec.shape[-1]:
        raise ConfigError(f"coupling_profile: n_bins must be in 1..{spec.shape[-1]}, got {n_bins}")
    return spec[..., :n]


# ----------------------------------------------------------------- init
def _pair_tones(ctx, taus, kappas) -> np.ndarray:
    """Unit tones ``[len(taus), T * R, N]`` of paths with delays ``taus`` [s]
    and separation shares ``kappas`` (:func:`pair_phase`)."""
    ph = tone_phase(ctx, taus)[:, None, None, :] + pair_phase(ctx, kappas)
    return np.exp(1j * ph).reshape(len(taus), -1, ph.shape[-1])


def _project_pairs(z, tones):
    """LS amplitudes ``[C, K]`` of per-channel tones ``[K, C, N]`` in ``z [C, N]``
    (the normal equations per channel, batched; a tiny ridge keeps two
    coinciding tones solvable)."""
    t = np.transpose(tones, (1, 2, 0))                                       # [C, N, K]
    gram = np.conj(np.swapaxes(t, 1, 2)) @ t                                 # [C, K, K]
    gram = gram + 1e-9 * np.trace(gram, axis1=1, axis2=2)[:, None, None] * np.eye(t.shape[2])
    rhs = np.einsum("cnk,cn->ck", np.conj(t), z)
    return np.linalg.solve(gram, rhs[..., None])[..., 0]


def _separable_error(z, ctx, tau, kappa, seen) -> float:
    """Residual energy of ``z [C, N]`` after the separable leakage
    (:func:`factorise`) with paths ``tau``, ``kappa``, amplitudes from a
    per-channel LS fit."""
    T, R = ctx.radar.num_tx, ctx.radar.num_rx
    tones = _pair_tones(ctx, tau, kappa)
    h = _project_pairs(z, tones).reshape(T, R, -1)
    A, u, w, B = factorise(h, ctx, seen, n_iter=10)
    g = (u[:, None] * w[None, :] * B[_chip_pair(ctx)])[..., None] * A        # [T, R, K]
    return float(np.sum(np.abs(z - np.einsum("ck,kcn->cn", g.reshape(T * R, -1), tones)) ** 2))


def _descend(z, ctx, t_k, kappa, err, grid, seen, passes: int, window=None):
    """Coordinate descent of the delays ``t_k`` over ``grid`` (within
    ``window`` [s] of the current value when given), ``kappa`` held;
    returns ``(error, delays)``."""
    for _ in range(passes):
        moved = False
        for m in range(len(t_k)):
            near = grid if window is None else grid[np.abs(grid - t_k[m]) <= window]
            for t in near:
                trial = t_k.copy()
                trial[m] = t
                e = _separable_error(z, ctx, trial, kappa, seen)
                if e < err:
                    err, t_k, moved = e, trial, True
        if not moved:
            break
    return err, t_k


def _refine_paths(z, ctx, tau, taus, seen, passes: int = 2, stride: int = 4):
    """The paths' separation shares (every assignment of 0 or 1) and delays
    (coordinate descent from the greedy ``tau``, on every ``stride``-th
    point of the grid ``taus``, then on the full grid near the result),
    scored by the residual the *separable* pattern leaves
    (:func:`_separable_error`).  The greedy choice fits every channel freely,
    where a space wave's per-pair carrier phase costs nothing and two tones
    within a range bin trade places; the pattern is what the effect fits.
    Returns ``(tau, kappa)`` sorted by delay."""
    best = (np.inf, None, None)
    step = float(taus[1] - taus[0]) if len(taus) > 1 else 0.0
    for kappa in itertools.product((0.0, 1.0), repeat=len(tau)):
        kappa, t_k = np.array(kappa), np.array(tau, float)
        err = _separable_error(z, ctx, t_k, kappa, seen)
        err, t_k = _descend(z, ctx, t_k, kappa, err, taus[::stride], seen, passes)
        err, t_k = _descend(z, ctx, t_k, kappa, err, taus, seen, 1, window=stride * step)
        if err < best[0]:
            best = (err, t_k, kappa)
    order = np.argsort(best[1])
    return best[1][order], best[2][order]


def _greedy_delays(z, ctx, K, taus):
    """Greedy (orthogonal matching pursuit) choice of ``K`` paths from a grid
    of delays and separation shares (0 and 1).

    ``z [C, N]`` channels (``C = T R``), ``taus [G]`` candidate delays [s];
    at each step the candidate with the largest energy (summed over
    channels) in the current residual is picked, then all amplitudes are
    re-fitted jointly, per channel.  Returns ``(tau [K], kappa [K])`` sorted
    by delay."""
    grid = [(t, k) for k in (0.0, 1.0) for t in taus]
    atoms = np.concatenate([_pair_tones(ctx, taus, np.full(len(taus), k)) for k in (0.0, 1.0)])
    norm = np.sum(np.abs(atoms[:, 0]) ** 2, axis=-1)                             # [2G]
    gtau = np.array([g[0] for g in grid])
    chosen = []
    resid = z
    for _ in range(K):
        score = np.sum(np.abs(np.einsum("gcn,cn->gc", np.conj(atoms), resid)) ** 2,
                       axis=1) / norm
        for j in chosen:          # keep picks half a range bin apart
            score[np.abs(gtau - gtau[j]) < 0.5 / ctx.radar.bandwidth] = -1.0
        chosen.append(int(np.argmax(score)))
        tones = atoms[chosen]
        h = _project_pairs(z, tones)
        resid = z - np.einsum("ck,kcn->cn", h, tones)
    order = sorted(chosen, key=lambda j: gtau[j])
    return gtau[order], np.array([grid[j][1] for j in order])


def factorise(h, ctx, weight=None, n_iter: int = 50):
    """ALS split of ``h [T, R, K]`` into ``A_m u_t w_r B[chip_t, chip_r]``.

    ``weight [T, R]`` (0/1) leaves unobserved channels out.  Returns ``(A
    [K], u [T], w [R], B [n_chips^2])`` with ``u`` and ``w`` of unit RMS and
    ``u_0``, ``w_0`` real positive (``B[0]`` = 1 with several chips).
    """
    T, R, K = h.shape
    W = np.ones((T, R, 1)) if weight is None else np.asarray(weight, np.float64)[..., None]
    pair = _chip_pair(ctx)
    nb = ctx.num_chips ** 2
    u, w, B = np.ones(T, complex), np.ones(R, complex), np.ones(nb, complex)
    A = (h * W).sum(axis=(0, 1)) / max(W.sum(), 1.0)

    def ls(model, axes):
        num = (W * np.conj(model) * h).sum(axis=axes)
        den = (W * np.abs(model) ** 2 + 0 * h.real).sum(axis=axes)
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), 1.0)

    def ls_block(model):
        num = (W * np.conj(model) * h).sum(axis=-1).ravel()
        den = (W * np.abs(model) ** 2 + 0 * h.real).sum(axis=-1).ravel()
        idx = pair.ravel()
        nu = np.bincount(idx, num.real, nb) + 1j * np.bincount(idx, num.imag, nb)
        de = np.bincount(idx, den, nb)
        return np.where(de > 0, nu / np.where(de > 0, de, 1.0), 1.0)

    for _ in range(n_iter):
        g = B[pair][..., None]
        u = ls(A * w[None, :, None] * g, (1, 2))
        w = ls(A * u[:, None, None] * g, (0, 2))
        if nb > 1:
            B = ls_block(A * (u[:, None] * w[None, :])[..., None])
        A = ls((u[:, None] * w[None, :] * B[pair])[..., None], (0, 1))
    su = np.sqrt(np.mean(np.abs(u) ** 2)) * np.exp(1j * np.angle(u[0]))
    sw = np.sqrt(np.mean(np.abs(w) ** 2)) * np.exp(1j * np.angle(w[0]))
    sb = B[0] if nb > 1 and abs(B[0]) > 0 else 1.0
    return A * su * sw * sb, u / su, w / sw, B / sb


def _deviation(h, A, u, w, B, ctx, seen) -> float:
    """RMS of the per-channel tone amplitudes ``h [T, R, K]`` about the
    separable pattern ``A u w B``, relative to the pattern (observed channels)."""
    model = (u[:, None] * w[None, :] * B[_chip_pair(ctx)])[..., None] * A
    sel = np.asarray(seen, bool)
    den = float(np.sum(np.abs(model[sel]) ** 2))
    return float(np.sqrt(np.sum(np.abs(h[sel] - model[sel]) ** 2) / den)) if den > 0 else 1.0


# --------------------------------------------------------------- effect
class Coupling(Effect):
    """Tx -> Rx leakage: ``K`` short-delay paths, separable channel factors.

    Parameters
    ----------
    num_paths : int, optional
        ``K``, number of leakage delays (default 2)
    min_range : float, optional
        smallest equivalent range ``c tau / 2`` [m] (0.02)
    max_range : float, optional
        largest equivalent range [m] (0.5)
    spread : bool, optional
        model each channel's deviation from the separable pattern as
        variance (default False; see the module docstring)
    """

    name = "coupling"
    kind = "mean"
    stage = 1
    per_unit = True
    description = "Tx->Rx antenna / on-chip leakage (short-delay paths)"

    #: bounds of ``rho``, the RMS deviation of a channel's leakage from the pattern
    SPREAD_BOUNDS = (1e-3, 3.0)

    def __init__(self, num_paths: int = 2, min_range: float = 0.02, max_range: float = 0.5,
                 spread: bool = False):
        if isinstance(num_paths, bool) or int(num_paths) != num_paths or num_paths < 1:
            raise ConfigError(f"Coupling: num_paths must be a positive integer, got {num_paths!r}")
        if not np.isfinite(min_range) or min_range < 0:
            raise ConfigError(f"Coupling: min_range must be >= 0 m, got {min_range}")
        if not np.isfinite(max_range) or max_range <= min_range:
            raise ConfigError(f"Coupling: max_range must be > min_range ({min_range} m), "
                              f"got {max_range}")
        self.num_paths = int(num_paths)
        self.min_range = float(min_range)
        self.max_range = float(max_range)
        self.has_spread = bool(spread)

    def _delay_bounds(self):
        return 2 * self.min_range / SPEED_OF_LIGHT, 2 * self.max_range / SPEED_OF_LIGHT

    @single_blas
    def param_specs(self, ctx, model, residual):
        radar = ctx.radar
        T, R, N = radar.num_tx, radar.num_rx, radar.num_samples
        lo, hi = self._delay_bounds()
        taus = np.linspace(lo, hi, max(8, int(np.ceil((hi - lo) * radar.bandwidth * 16)) + 1))
        z = static_view(residual)                                   # static: frame/chirp mean
        seen = np.any(z != 0, axis=-1)                              # observed channels
        z = z.reshape(T * R, N)
        tau, kappa = _greedy_delays(z, ctx, self.num_paths, taus)
        tau, kappa = _refine_paths(z, ctx, tau, taus, seen.reshape(T, R))
        h = _project_pairs(z, _pair_tones(ctx, tau, kappa)).reshape(T, R, -1)
        A, u, w, B = factorise(h, ctx, seen)
        specs = {"delay": ParamSpec(tau / NS, lower=lo / NS, upper=hi / NS, unit="ns"),
                 "separation": ParamSpec(kappa, lower=0.0, upper=1.0,
                                         unit="share of the Tx-Rx antenna distance"),
                 "amp": ParamSpec(_pairs(A), unit="normalised (referred to f_c)"),
                 "tx": ParamSpec(_pairs(u), unit="complex factor"),
                 "rx": ParamSpec(_pairs(w), unit="complex factor")}
        if ctx.num_chips > 1:
            specs["chip"] = ParamSpec(_pairs(B), unit="complex factor")
        if self.has_spread:
            lo, hi = self.SPREAD_BOUNDS
            rho = np.clip(_deviation(h, A, u, w, B, ctx, seen), lo, hi)
            specs["log_spread"] = ParamSpec([np.log(rho)], lower=np.log(lo), upper=np.log(hi),
                                            unit="ln(RMS deviation / pattern)")
        return specs

    def apply(self, x, p, ctx):
        return ops.cadd(x, self._leak(p, ctx))

    def spread(self, p, ctx):
        """``rho^2 |DFT(leak_tr)|^2`` ``[1, T, R, 1, N]``: the expected power of a
        channel's deviation from the separable leakage pattern."""
        rho2 = dr.exp(2.0 * ops.view(p["log_spread"], (1, 1, 1, 1, 1)))
        return ops.abs2(ops.dft(self._leak(p, ctx))) * rho2

    def _leak(self, p, ctx):
        """The leakage ``u_t w_r B sum_m A_m tone_m,tr`` ``[1, T, R, 1, N]`` (re, im)."""
        radar = ctx.radar
        T, R, N = radar.num_tx, radar.num_rx, radar.num_samples
        K = self.num_paths
        tk = ops.tensor((2 * np.pi * radar.slope * NS
                         * (ctx.fast_time - _centre_time(radar))).reshape(1, 1, 1, N))
        dw = ops.tensor(pair_phase(ctx, [1.0]))                                # [1, T, R, N]
        kappa = p.get("separation")
        phase = ops.view(p["delay"], (K, 1, 1, 1)) * tk                         # [K, 1, 1, N]
        if kappa is not None:
            phase = phase + ops.view(kappa, (K, 1, 1, 1)) * dw                  # [K, T, R, N]
        tone = ops.cmul(ops.cis(phase), (ops.column(p["amp"], 0, (K, 1, 1, 1)),
                                         ops.column(p["amp"], 1, (K, 1, 1, 1))))
        n_tr = (T, R) if kappa is not None else (1, 1)
        tone = (dr.sum(tone[0], axis=0), dr.sum(tone[1], axis=0))             # [T, R, N]
        tone = (ops.view(tone[0], (1,) + n_tr + (1, N)),
                ops.view(tone[1], (1,) + n_tr + (1, N)))
        st, sr = (1, T, 1, 1, 1), (1, 1, R, 1, 1)
        g = ops.cmul((ops.column(p["tx"], 0, st), ops.column(p["tx"], 1, st)),
                     (ops.column(p["rx"], 0, sr), ops.column(p["rx"], 1, sr)))
        if "chip" in p:
            idx = mi.UInt32(_chip_pair(ctx).ravel().astype(np.uint32))
            shape = (1, T, R, 1, 1)
            b = tuple(ops.mi.TensorXf(dr.gather(mi.Float, p["chip"].array, idx * 2 + j), shape)
                      for j in range(2))
            g = ops.cmul(g, b)
        return ops.cmul(g, tone)

    def silenced(self, values):
        """The leakage with zero amplitude (its delays and channel factors kept)."""
        return {**values, "amp": np.zeros_like(np.asarray(values["amp"]))}

    def behind(self, values, ctx, gains):
        """The leakage restarted behind a filter: each path's amplitude divided
        by the filter's gain at its beat frequency ``S tau_m`` (the growth
        capped at :data:`MAX_BEHIND`, where the filter's notch would make
        it unbounded)."""
        tau = np.asarray(values["delay"], np.float64) * NS
        g = gains(ctx.radar.slope * tau)
        if g is None:
            return None
        g = np.asarray(g, complex)
        small = np.abs(g) < 1.0 / MAX_BEHIND
        g = np.where(small, g / np.maximum(np.abs(g), 1e-300) / MAX_BEHIND, g)
        return {**values, "amp": _pairs(_cplx(values["amp"]) / g)}

    def summary(self, p, ctx):
        tau = np.asarray(p["delay"], np.float64) * NS
        A = _cplx(p["amp"]) * np.exp(-2j * np.pi * ctx.radar.center_frequency * tau)
        g = channel_factor(p, ctx)
        lvl = np.abs(g)[..., None] * np.abs(A)
        out = {"delay_ns": (tau / NS).round(4).tolist(),
                "range_m": (tau * SPEED_OF_LIGHT / 2).round(4).tolist(),
                "amplitude_abs": np.abs(A).round(6).tolist(),
                "amplitude_phase_deg": np.degrees(np.angle(A)).round(2).tolist(),
                "channel_level_db_range": [
                    round(float(20 * np.log10(max(lvl.min(), 1e-30))), 2),
                    round(float(20 * np.log10(max(lvl.max(), 1e-30))), 2)]}
        out["separation_share"] = _kappa(p).round(4).tolist()
        if "log_spread" in p:
            out["channel_deviation_rms"] = round(float(np.exp(np.asarray(p["log_spread"])[0])), 4)
        return out
