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

Parameters: ``L0`` [dBc per bin at ``df_ref``] and ``beta`` [1] (2 in all);
``df_ref`` is a constructor argument (default one bin).  Kind "variance".

Initial values: for ``beta`` on a grid, the level and the white floor follow
from least squares of ``|residual_k|^2`` on ``(1, (|X|^2 * K_beta)_k)``; the
``beta`` with the best exponential likelihood wins, unless white noise alone
explains the residual as well (then ``L0 = -120`` dB: no skirt).
"""
from __future__ import annotations

import numpy as np

from .. import ops
from ..base import Effect, ParamSpec
from ._sensor_common import LN10, check_float, last_axis, scalar

dr, mi = ops.dr, ops.mi

L0_BOUNDS = (-160.0, 0.0)
BETA_BOUNDS = (0.0, 6.0)
BETA_GRID = np.arange(0.0, 4.01, 0.5)
NO_SKIRT_DB = -120.0


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
                "beta": ParamSpec([beta], lower=BETA_BOUNDS[0], upper=BETA_BOUNDS[1], unit="1")}

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
        return {"L0_dbc_per_bin": round(L0, 3), "beta": round(beta, 4),
                "ref_offset_khz": self.ref_hz(ctx) / 1e3,
                "psd_dbc_per_hz_at_ref": round(float(L0 - bin_db), 3)}
