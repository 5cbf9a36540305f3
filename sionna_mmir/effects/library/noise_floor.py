"""Coloured receiver noise: per-Rx level times a 1/f-knee and anti-alias spectral shape.

Beyond the white floor ``sigma^2`` of the model (ADC quantisation, always
fitted), each receiver adds noise of power per range bin (unitary DFT)::

    v[r, k] = exp(l_r) (1 + (f_knee / |f_k|)^gamma) / (1 + (|f_k| / f_lp)^{2 n})

a white level ``exp(l_r)`` in the pass band, a flicker (1/f) rise towards DC
below the knee ``f_knee`` (mixer / baseband amplifier flicker noise; the
exponent ``gamma`` is a constructor argument, default 1, not fitted: fitted
together with the knee it trades off against the white level) and the
``n``-th order anti-alias roll-off with corner ``f_lp``.  ``f_k`` is the
bin's beat frequency in the band ``[band_start f_s, (band_start + 1) f_s)``
(default ``-0.5``: ``np.fft.fftfreq``, noise is symmetric about DC); the DC
bin uses ``|f| = f_s / (2 N)``.

Parameters: ``level`` ``[R]`` (``l_r``, ln of normalised power per bin) and
``shape`` ``[2]`` = (``log10(f_knee / kHz)``, ``log10(f_lp / kHz)``), ``R + 2``
in all.  Kind "variance", stage 2.

Initial values: grid search over the two shape parameters; for each, the
per-Rx levels are the closed-form maximum-likelihood values of the residual's
mean power per (Rx, bin); the best exponential likelihood wins.
"""
from __future__ import annotations

import itertools

import numpy as np

from .. import ops
from ..base import Effect, ParamSpec
from ._sensor_common import LN10, band_frequencies, check_float, check_int, last_axis, scalar

dr = ops.dr
KHZ = 1e3
LEVEL_BOUNDS = (-40.0, 15.0)


class NoiseFloor(Effect):
    """Per-Rx coloured noise level, shared 1/f knee and roll-off (``R + 2`` parameters)."""

    name = "noise_floor"
    chirp_static = False
    kind = "variance"
    stage = 2
    description = "coloured receiver noise: per-Rx level, 1/f knee, anti-alias roll-off"

    def __init__(self, lowpass_order: int = 4, band_start: float = -0.5, gamma: float = 1.0):
        owner = type(self).__name__
        self.gamma = check_float(owner, "gamma", gamma, 0.0, 4.0, lo_open=True)
        self.lowpass_order = check_int(owner, "lowpass_order", lowpass_order, 1, 12)
        self.band_start = check_float(owner, "band_start", band_start, -1.0, 0.0)

    # ------------------------------------------------------------- helpers
    def log_abs_freq(self, ctx) -> np.ndarray:
        """``ln(|f_k| / kHz)`` with the DC bin at half a bin, ``[N]``."""
        r = ctx.radar
        f = np.abs(band_frequencies(ctx, self.band_start))
        f = np.maximum(f, 0.5 * r.sample_rate / r.num_samples)
        return np.log(f / KHZ)

    def bounds(self, ctx):
        fs_k = ctx.radar.sample_rate / KHZ
        bin_k = fs_k / ctx.radar.num_samples
        lo = [np.log10(bin_k / 10), np.log10(fs_k / 20)]
        hi = [np.log10(fs_k / 2), np.log10(fs_k * 1000)]
        return lo, hi

    def shape_numpy(self, ctx, knee, lp) -> np.ndarray:
        """Spectral shape ``[N]`` for the (log10 kHz, log10 kHz) shape parameters."""
        lf = self.log_abs_freq(ctx)
        flick = 1.0 + np.exp(self.gamma * (LN10 * knee - lf))
        return flick / (1.0 + np.exp(2 * self.lowpass_order * (lf - LN10 * lp)))

    # ------------------------------------------------------------------ init
    def param_specs(self, ctx, model, residual):
        F, T, R, C, N = residual.shape
        P = np.mean(np.abs(np.fft.fft(residual, axis=-1, norm="ortho")) ** 2, axis=(0, 1, 3))
        lo, hi = self.bounds(ctx)
        best = (np.inf, None, None)
        grids = (np.linspace(lo[0], hi[0], 13), np.linspace(lo[1], hi[1], 13))
        for shp in itertools.product(*grids):
            s = self.shape_numpy(ctx, *shp)
            lvl = np.log(np.maximum(np.mean(P / s[None], axis=1), 1e-30))      # [R]
            v = np.exp(lvl)[:, None] * s[None]
            nll = np.sum(P / v + np.log(v))
            if nll < best[0]:
                best = (nll, lvl, np.asarray(shp, float))
        lvl = np.clip(best[1], *LEVEL_BOUNDS)
        return {"level": ParamSpec(lvl, lower=LEVEL_BOUNDS[0], upper=LEVEL_BOUNDS[1],
                                   unit="ln(normalised power per bin)"),
                "shape": ParamSpec(best[2], lower=lo, upper=hi, unit="log10 kHz")}

    # -------------------------------------------------------------- variance
    def variance(self, x, X, p, ctx):
        R = ctx.radar.num_rx
        lf = last_axis(self.log_abs_freq(ctx))
        knee, lp = scalar(p["shape"], 0), scalar(p["shape"], 1)
        flick = 1.0 + dr.exp(self.gamma * (LN10 * knee - lf))
        roll = 1.0 + dr.exp((2.0 * self.lowpass_order) * (lf - LN10 * lp))
        level = dr.exp(ops.view(p["level"], (1, 1, R, 1, 1)))
        return level * (flick / roll)

    def summary(self, p, ctx):
        lvl = np.asarray(p["level"], float)
        knee, lp = (float(v) for v in np.ravel(p["shape"])[:2])
        return {"level_db": (10 / np.log(10) * lvl).round(3).tolist(),
                "knee_khz": round(10 ** knee, 4), "gamma": self.gamma,
                "lowpass_corner_khz": round(10 ** lp, 4), "lowpass_order": self.lowpass_order}
