"""LO phase noise: a noise skirt around every strong beat tone.

A random LO phase ``phi(t)`` (small, two-sided PSD ``S_phi(f)`` [rad^2/Hz],
equal to the single-sideband ``L(f)`` in dBc/Hz) multiplies the beat signal:
``x e^{j phi} ~ x (1 + j phi)``.  For a tone of range-domain (unitary DFT)
power ``|X_p|^2`` the term ``j phi x`` puts the power
``|X_p|^2 S_phi(f_k - f_p) f_s / N`` into bin ``k``; summed over all bins of
the mean model this is a circular convolution of the range power profile::

    v[f, t, r, c, k] = sum_p |X_p|^2 K(|f_k - f_p|)
    K(df) = 10^(L0 / 10) (df / df_ref)^(-beta)   (df != 0),   K(0) = 0

``df`` is the circular bin distance in Hz (``f_s / N`` per bin).  ``K`` is
in dBc *per bin*: ``L(f) [dBc/Hz] = L0 - 10 log10(f_s / N)`` at ``f = df_ref``.
The LO's range correlation (the beat sees ``phi(t) - phi(t - tau)``, which
scales the skirt by ``2 (1 - cos(2 pi df tau))``) is not modelled separately:
for one dominant range it only changes ``L0`` and ``beta`` (by about -2 at
short range), which are fitted.

**The common frequency error.**  The skirt is the noise's power; where the
paths are short its PSD is nearly flat, the same as the thermal floor's, and
power alone cannot tell them apart.  What can is that one LO serves every
receiver: every Rx of one transmit slot (frame, Tx, chirp) sees the same
realisation.  To first order in the range correlation,
``phi(t) - phi(t - tau) ~ 2 pi tau e(t)`` with ``e = phi' / 2 pi`` the LO's
frequency error [Hz], and since a path's beat tone has
``dx_p / dt = j 2 pi S tau_p x_p``, the noise in channel ``r`` is::

    n_r(t) = (e(t) / S) dx_r/dt = e(t) g_r(t),      g_r = IDFT(j 2 pi f_k DFT(x_r)) / S

with ``e`` *real* and shared by the slot's Rx (the chirp non-linearity's
time warp, drawn anew in every slot; ``f_k`` the bins' beat frequencies,
:meth:`~sionna_mmir.effects.context.EffectContext.band_frequencies`).  The
effect treats ``e`` as a random effect, white in fast time with variance
``lambda`` [Hz^2] (white frequency noise: the PSD of a PLL's phase noise
above its loop bandwidth, ``S_phi ~ f^-2``), and predicts each cell's
chirp-to-chirp deviation ``d_r`` from the *other* Rx of its slot by the
posterior mean of ``e`` (leave one out, weights ``1 / sigma_r^2``)::

    e_-r = Re sum_{q != r} conj(g_q) d_q / sigma_q^2
           / (sum_{q != r} |g_q|^2 / sigma_q^2 + 1 / (2 lambda)),    d_r ~ e_-r g_r

(:func:`common_prediction`).  The deviation, not the residual: a static
misfit repeats in every chirp and would be taken for a frequency error.
The real ``e`` matters: an amplitude change shared by the Rx (a transmit
droop) lies along ``x_r``, at right angles to ``j tau x_r``.  The held-out
score (:meth:`~sionna_mmir.effects.model.EffectModel.nll_profiled` with
``deviation``) and the scatter the skirt is fitted to
(:meth:`~sionna_mmir.effects.model.EffectModel.on_chirp_deviation`) are
what the prediction leaves.  ``lambda`` is fitted by maximum likelihood
of the deviation along ``g`` on the fitting cells (:func:`fit_common`); in a white-FM
PLL it is ``S_e f_s``, ``S_e = f^2 L(f)`` above the loop bandwidth, which
:meth:`PhaseNoise.summary` reports as the equivalent ``L(1 MHz)``.
Limits: first order in ``tau e`` (``2 pi tau e_rms`` of ~0.01 rad at 5 m);
``e`` white (a loop bandwidth near ``f_s / 2`` would colour it); the Dr.Jit
variance (the mean fits' likelihood) holds the skirt only.

Parameters: ``L0`` [dBc per bin at ``df_ref``], ``beta`` [1] and
``common_db`` [dB re 1 Hz^2] (``10 log10 lambda``; 3 in all); ``df_ref`` is a
constructor argument (default one bin).  Kind "variance".

Initial values: for ``beta`` on a grid, the level and the white floor follow
from least squares of ``|residual_k|^2`` on ``(1, (|X|^2 * K_beta)_k)``; the
``beta`` with the best exponential likelihood wins, unless white noise alone
explains the residual as well (then ``L0 = -120`` dB: no skirt).
``common_db`` from :func:`fit_common` on the residual's chirp deviation (its
lower bound with one chirp loop: nothing to predict).
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar

from .. import ops
from ..base import Effect, ParamSpec
from ._sensor_common import LN10, check_float, chirp_deviation, last_axis, scalar

dr, mi = ops.dr, ops.mi

L0_BOUNDS = (-160.0, 0.0)
BETA_BOUNDS = (0.0, 6.0)
BETA_GRID = np.arange(0.0, 4.01, 0.5)
NO_SKIRT_DB = -120.0
#: bounds of ``common_db`` = ``10 log10 lambda`` [dB re 1 Hz^2]: an rms
#: frequency error of 1 Hz (nothing) to 10 MHz
COMMON_BOUNDS = (0.0, 140.0)


def slope_derivative(x: np.ndarray, ctx) -> np.ndarray:
    """``g = (1 / S) dx/dt`` of the beat signal ``x [..., N]`` (time domain): its
    change per hertz of LO frequency error, spectral (``j 2 pi f_k`` on the
    bins' beat frequencies in the IF band)."""
    f = ctx.band_frequencies()
    X = np.fft.fft(x, axis=-1)
    return np.fft.ifft(2j * np.pi * f * X, axis=-1) / ctx.radar.slope


def _loo_terms(g, d, w, use):
    """Leave-one-Rx-out sums of ``Re conj(g) d w`` and ``|g|^2 w`` over the
    predictor cells ``use`` of each slot (the Rx axis is 2)."""
    num = np.real(np.conj(g) * d) * (w * use)
    den = (np.abs(g) ** 2) * (w * use)
    return num.sum(axis=2, keepdims=True) - num, den.sum(axis=2, keepdims=True) - den


def along_common(g, d, w, use=1.0):
    """Per slot and sample: ``a^2`` (the whitened deviation's real part along
    ``g``, squared), ``G = sum |g|^2 w`` and the rest's energy and real
    dimensions, over the cells ``use``; ``[F, T, C, N]`` each (the rest's
    dimensions ``[F, T, C, 1]``)."""
    root = np.sqrt(w * use)
    gw, dw = g * root, d * root
    G = np.sum(np.abs(gw) ** 2, axis=2)
    a2 = np.real(np.sum(np.conj(gw) * dw, axis=2)) ** 2 / np.maximum(G, 1e-300)
    n = np.sum(np.broadcast_to(use, g.shape[:4] + (1,)), axis=2)
    return a2, G, np.sum(np.abs(dw) ** 2, axis=2) - a2, 2.0 * n - 1.0


def floor_scale(g, d, w, use=1.0) -> float:
    """``s``: the white floor of the deviation ``d`` in units of ``1 / w``,
    from what lies off the common error's direction (``2 R - 1`` real
    dimensions per slot and sample, each of variance ``s / 2``); a floor
    fitted to the whole residual (the static misfit with it) or to the whole
    scatter (the common error's power with it) overstates it, and with it
    the shrinkage of the prediction."""
    a2, G, rest, dims = along_common(g, d, w, use)
    ok = (G > 0) & (dims >= 1)
    if not ok.any():
        return 1.0
    return max(float(np.sum(rest[ok]) / (0.5 * np.sum(np.broadcast_to(dims, ok.shape)[ok]))),
               1e-300)


def common_prediction(g, d, w, lam: float, use=None) -> np.ndarray:
    """Each cell's chirp deviation predicted from the other Rx of its slot (module docstring).

    ``g`` ``[F, T, R, C, N]`` (:func:`slope_derivative` of the model), ``d`` the
    deviation (time domain, same shape), ``w`` ``1 / sigma^2`` per cell up to
    a common scale (broadcastable; the scale is :func:`floor_scale`'s), ``lam``
    the variance of ``e`` [Hz^2], ``use`` the predictor cells (bool
    ``[F, T, R, C]``; None: all).  Returns ``e_-r g_r``."""
    use = 1.0 if use is None else np.asarray(use, np.float64)[..., None]
    w = w / floor_scale(g, d, w, use)
    num, den = _loo_terms(g, d, w, use)
    return num / (den + 0.5 / max(lam, 1e-300)) * g


def fit_common(g, d, w, use=None) -> float:
    """``common_db`` by maximum likelihood of the deviation ``d`` on the cells
    ``use`` (None: all), bounded by :data:`COMMON_BOUNDS`.

    Whitened by ``w`` (``1 / sigma^2`` per cell up to a common scale), each
    slot and sample's deviation splits into its real part along ``g``,
    ``a = Re(g^H d) / |g| ~ N(0, lambda |g|^2 + s / 2)``, and the rest, white
    with ``2 R - 1`` real dimensions of variance ``s / 2`` each; ``s``
    (:func:`floor_scale`) comes from the rest, then ``lambda`` from ``a``.
    Returns the lower bound where the error is not there."""
    use = 1.0 if use is None else np.asarray(use, np.float64)[..., None]
    a2, G, rest, dims = along_common(g, d, w, use)
    ok = (G > 0) & (dims >= 1)
    if not ok.any():
        return COMMON_BOUNDS[0]
    s = floor_scale(g, d, w, use)
    a2, G = a2[ok], G[ok]

    def nll(db):
        tot = 10 ** (db / 10.0) * G + 0.5 * s
        return float(np.sum(a2 / tot + np.log(tot)))

    out = minimize_scalar(nll, bounds=COMMON_BOUNDS, method="bounded", options={"xatol": 0.02})
    lo = COMMON_BOUNDS[0]
    return float(out.x) if out.fun < nll(lo) else lo


def cell_weights(v: np.ndarray) -> np.ndarray:
    """``1 / sigma^2`` per cell ``[F, T, R, C, 1]`` from a per-bin variance ``v``
    (unitary DFT: the time-domain variance per sample is the mean over bins)."""
    return 1.0 / np.maximum(np.mean(v, axis=-1, keepdims=True), 1e-300)


def log_offsets(ctx, ref_hz: float):
    """``(ln(df_k / df_ref), mask)``: circular bin offsets from bin 0, ``[N]`` (mask 0 at DC)."""
    df = np.abs(ctx.beat_frequencies)
    mask = (df > 0).astype(np.float64)
    return np.log(np.where(df > 0, df, ref_hz) / ref_hz), mask


def kernel_numpy(ctx, ref_hz, L0, beta) -> np.ndarray:
    """``K(df_k)`` in linear units per bin, ``[N]`` (NumPy)."""
    lg, mask = log_offsets(ctx, ref_hz)
    return mask * 10 ** (L0 / 10.0) * np.exp(-beta * lg)


def skirt_numpy(power: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Circular convolution along the last axis of ``power`` with ``kernel`` (NumPy)."""
    return np.real(np.fft.ifft(np.fft.fft(power, axis=-1) * np.fft.fft(kernel), axis=-1))


class PhaseNoise(Effect):
    """Phase-noise skirt ``|X|^2 (*) K`` with a power-law kernel (2 parameters: dB, 1)."""

    name = "phase_noise"
    chirp_static = False
    kind = "variance"
    stage = 1
    description = "LO phase-noise skirt around strong tones (power-law PSD)"

    def __init__(self, ref_offset_hz: float | None = None):
        self.ref_offset_hz = None if ref_offset_hz is None else check_float(
            type(self).__name__, "ref_offset_hz", ref_offset_hz, 0.0, 1e10, lo_open=True)

    def ref_hz(self, ctx) -> float:
        r = ctx.radar
        return self.ref_offset_hz or r.sample_rate / r.num_samples

    # ------------------------------------------------------------------ init
    def param_specs(self, ctx, model, residual):
        power = np.abs(np.fft.fft(model, axis=-1, norm="ortho")) ** 2
        r2 = np.abs(np.fft.fft(residual, axis=-1, norm="ortho")) ** 2
        L0, beta = self._init(ctx, power, r2)
        return {"L0": ParamSpec([L0], lower=L0_BOUNDS[0], upper=L0_BOUNDS[1], unit="dBc/bin"),
                "beta": ParamSpec([beta], lower=BETA_BOUNDS[0], upper=BETA_BOUNDS[1], unit="1"),
                "common_db": ParamSpec([self._init_common(ctx, model, residual)],
                                       lower=COMMON_BOUNDS[0], upper=COMMON_BOUNDS[1],
                                       unit="dB re 1 Hz^2")}

    @staticmethod
    def _init_common(ctx, model, residual) -> float:
        """:func:`fit_common` on the chirp deviation of ``residual``, the white
        floor from its median power (exponential: ``median = s^2 ln 2``)."""
        d = chirp_deviation(np.asarray(residual))
        if d is None or ctx.shape[2] < 2:
            return COMMON_BOUNDS[0]
        seen = np.abs(d) > 0                         # cells outside a fold are zeroed
        if not seen.any():
            return COMMON_BOUNDS[0]
        s2 = max(float(np.median(np.abs(d[seen]) ** 2)) / np.log(2.0), 1e-300)
        return fit_common(slope_derivative(np.asarray(model), ctx), d, 1.0 / s2)

    def _init(self, ctx, power, r2):
        y = r2.ravel()
        white = np.mean(y)
        best = (1.0 + np.log(white) - 1e-3, NO_SKIRT_DB, 2.0)      # a skirt must beat white noise
        for beta in BETA_GRID:
            s = skirt_numpy(power, kernel_numpy(ctx, self.ref_hz(ctx), 0.0, beta)).ravel()
            A = np.stack([np.ones_like(s), s], axis=1)
            w2, a = np.linalg.lstsq(A, y, rcond=None)[0]
            w2 = max(w2, 1e-3 * y.mean() + 1e-30)
            a = max(a, 1e-16)
            v = w2 + a * s
            nll = np.mean(y / v + np.log(v))
            if nll < best[0]:
                best = (nll, 10 * np.log10(a), beta)
        return float(np.clip(best[1], *L0_BOUNDS)), float(best[2])

    # ------------------------------------------------- common frequency error
    predicts_deviation = True

    def deviation_prediction(self, x, d, values, ctx, v, use=None) -> np.ndarray:
        """The deviation ``d`` (time domain ``[F, T, R, C, N]``) that the common
        frequency error explains in each cell, from the other Rx of its slot
        (:func:`common_prediction`; ``x`` the mean model, ``v`` its per-bin
        variance, ``use`` the predictor cells, None: all)."""
        lam = 10 ** (float(np.ravel(values["common_db"])[0]) / 10.0)
        if lam <= 10 ** (COMMON_BOUNDS[0] / 10.0) or ctx.shape[2] < 2:
            return np.zeros_like(d)
        return common_prediction(slope_derivative(x, ctx), d, cell_weights(v), lam, use)

    def fit_deviation(self, x, d, values, ctx, v, use=None) -> dict:
        """``values`` with ``common_db`` fitted to the deviation ``d`` on the
        cells ``use`` (:func:`fit_common`)."""
        if ctx.shape[2] < 2:
            return dict(values)
        db = fit_common(slope_derivative(x, ctx), d, cell_weights(v), use)
        return {**values, "common_db": np.array([db])}

    def fitted_gain_floor(self, model, values) -> float:
        """Not acceptable (an infinite floor) where the common frequency error
        is identifiable (two or more Rx and chirp loops) and fitted at its
        lower bound: one LO serves every Rx, so phase noise that is really
        there shows in the error they share; a skirt alone is then some other
        chirp-to-chirp scatter near the strong tones (a transmit droop)."""
        F, T, R, C, N = model.ctx.shape
        common = float(np.ravel(values.get("common_db", [COMMON_BOUNDS[1]]))[0])
        if R >= 2 and C >= 2 and common <= COMMON_BOUNDS[0]:
            return float("inf")
        return self.gain_floor(model.ctx)

    # -------------------------------------------------------------- variance
    def variance(self, x, X, p, ctx):
        N = ctx.radar.num_samples
        lg, mask = log_offsets(ctx, self.ref_hz(ctx))
        k = dr.exp(scalar(p["L0"]) * (LN10 / 10.0) - scalar(p["beta"]) * last_axis(lg))
        k = k * last_axis(mask)
        power = ops.abs2(X)
        zero = dr.zeros(mi.TensorXf, power.shape)
        kz = dr.zeros(mi.TensorXf, k.shape)
        conv = ops.idft(ops.cmul(ops.dft((power, zero)), ops.dft((k, kz))))
        return dr.maximum(conv[0] * float(np.sqrt(N)), 0.0)

    def summary(self, p, ctx):
        L0, beta = float(np.ravel(p["L0"])[0]), float(np.ravel(p["beta"])[0])
        r = ctx.radar
        bin_db = 10 * np.log10(r.sample_rate / r.num_samples)
        out = {"L0_dbc_per_bin": round(L0, 3), "beta": round(beta, 4),
               "ref_offset_khz": self.ref_hz(ctx) / 1e3,
               "psd_dbc_per_hz_at_ref": round(float(L0 - bin_db), 3)}
        if "common_db" in p:
            db = float(np.ravel(p["common_db"])[0])
            out["common_error_khz_rms"] = round(10 ** (db / 20.0) / 1e3, 3)
            # white FM: lambda = S_e f_s, S_e = f^2 L(f)  ->  L(1 MHz) = lambda / (f_s 1e12)
            out["white_fm_dbc_hz_at_1mhz"] = round(db - 10 * np.log10(r.sample_rate) - 120.0, 2)
        return out
