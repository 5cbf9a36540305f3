"""IF chain filters: first-order high-pass and Butterworth anti-alias low-pass.

The I and Q branches pass identical real analog filters, so the complex beat
signal sees ``H(f)`` with ``H(-f) = conj(H(f))``; in the range domain::

    X[f, t, r, c, k] <- H(f_k) X[f, t, r, c, k],    x = IDFT(X)
    H(f) = H_hp(f) H_lp(f)
    H_hp(f) = (j f / f_hp) / (1 + j f / f_hp)                      (first order)
    H_hp(f_k) := mean of H_hp over the bin [f_k - f_s/2N, f_k + f_s/2N]
    H_lp(f) = 1 / prod_{i=1..n} (j f / f_lp - p_i),   p_i = exp(j pi (2 i + n - 1) / (2 n))

(``n``-th order Butterworth, ``|H_lp|^2 = 1 / (1 + (f / f_lp)^{2 n})``, with its
phase).  The high-pass is averaged over each bin (``1 + j a [ln(a + j u)]``
from ``u = k - 1/2`` to ``k + 1/2``, ``a = f_hp`` in bins): with the point
value the DC bin would be nulled for any corner, even far below one bin,
removing an off-bin tone's leakage there; the average tends to 1 as
``f_hp -> 0`` and to ``H_hp(f_k)`` for corners of a few bins.  ``f_k`` is the
bin's physical beat frequency in the band ``[band_start f_s, (band_start + 1)
f_s)`` (default ``-0.1``: targets up to ``0.9 max_range`` are positive
frequencies, near-DC leakage negative; see
:func:`~._sensor_common.band_frequencies`).  The high-pass suppresses the
Tx-Rx coupling and near-range clutter, the low-pass rolls off far range.

Steady state.  The analog filters run long before the ADC window opens, so
each beat tone leaves them multiplied by ``H`` of its own frequency.  The
DFT-domain product instead treats the window as periodic: an off-bin tone's
end wraps onto its start and the filters' memory (a few samples) sees that
jump, an error of about -20 dB of the signal.  Each fast-time row is
therefore first extended by ``extension`` samples on both sides by linear
prediction (:class:`~._sensor_common.RowExtension`, predictor of order
``prediction_order`` frozen on the initial model), filtered on the longer
grid, and cut back to the window (error about -40 dB in the tests);
``extension=0`` gives the plain DFT-domain product.

Receiver noise.  Thermal noise of the LNA and mixer passes the same
filters, so a fraction ``rho`` of the white floor ``sigma^2`` (the rest is
added after the filters: ADC quantisation and driver noise) is shaped by
their power gain (:meth:`IFFilter.noise_gain`)::

    s_k = rho |H_hp|^2_k |H_lp(f_k)|^2 + (1 - rho)
    |H_hp|^2_k := mean of (f / f_hp)^2 / (1 + (f / f_hp)^2) over the bin
              = 1 - a (atan(u_hi / a) - atan(u_lo / a))      (a = f_hp in bins)

with ``f_k`` the bin's frequency in ``[-f_s / 2, f_s / 2)`` (noise is
symmetric about DC).  The notch this leaves at near-DC bins is the high-pass's
most robust signature: the signal-side response alone is a smooth complex
gain over range that per-object amplitudes absorb when the scene is a few
compact scatterers.

Parameters: ``log_fc`` ``[2]`` = (``log10(f_hp / kHz)``, ``log10(f_lp / kHz)``),
``pre_noise`` ``[1]`` = ``rho`` in ``[0, 1]``.  Stage 2 (IF).

Initial values: on a grid of corner pairs, the filtered (extended) model is
fitted to the data up to one complex gain in closed form; the pair that
explains the most energy is one start, the pair (with ``rho``) whose noise
shape best explains the residual power spectrum another; the start with the
lower approximate likelihood wins (see :meth:`IFFilter._init`).
"""
from __future__ import annotations

import numpy as np

from .. import ops
from ..base import Effect, ParamSpec
from ._sensor_common import (LN10, RowExtension, band_frequencies, check_float, check_int,
                             chirp_deviation, last_axis, scalar, seen_chirp_mean)

dr = ops.dr
KHZ = 1e3


def _bin_power(residual: np.ndarray) -> np.ndarray:
    """Mean power per range bin (unitary DFT) over the cells that are not all zero, ``[N]``."""
    R = np.fft.fft(residual.reshape(-1, residual.shape[-1]), axis=-1, norm="ortho")
    P = np.abs(R) ** 2
    keep = P.sum(axis=-1) > 0
    return np.maximum(P[keep].mean(axis=0) if keep.any() else P.mean(axis=0), 1e-300)


def butterworth_poles(order: int) -> np.ndarray:
    """Left-half-plane poles of the normalised ``order``-th Butterworth low-pass."""
    i = np.arange(1, order + 1)
    return np.exp(1j * np.pi * (2 * i + order - 1) / (2 * order))


def response_numpy(f, f_hp, f_lp, order: int, bin_hz=None) -> np.ndarray:
    """``H(f)`` of the high-pass x low-pass chain (NumPy, complex); with ``bin_hz``
    the high-pass is the bin average (what :class:`IFFilter` applies)."""
    f = np.asarray(f, float)
    if bin_hz is None:
        h = 1j * f / f_hp / (1 + 1j * f / f_hp)
    else:
        h = highpass_bin_average_numpy(f, f_hp, bin_hz)
    s = 1j * f / f_lp
    for pole in butterworth_poles(order):
        h = h / (s - pole)
    return h


def highpass_bin_average_numpy(f, f_hp, bin_hz) -> np.ndarray:
    """Mean of ``H_hp`` over ``[f - bin/2, f + bin/2]`` (closed form, NumPy)."""
    a, up, lo = f_hp / bin_hz, f / bin_hz + 0.5, f / bin_hz - 0.5
    d = (0.5 * np.log((a * a + up * up) / (a * a + lo * lo))
         + 1j * (np.arctan2(up, a) - np.arctan2(lo, a)))
    return 1 + 1j * a * d


def noise_gain_numpy(f, f_hp, f_lp, order: int, bin_hz, rho) -> np.ndarray:
    """``s_k`` of the module docstring at frequencies ``f`` [Hz] (NumPy)."""
    a, u = f_hp / bin_hz, np.abs(np.asarray(f, float)) / bin_hz
    hp = 1.0 - a * (np.arctan((u + 0.5) / a) - np.arctan((u - 0.5) / a))
    lp = 1.0 / (1.0 + (np.abs(f) / f_lp) ** (2 * order))
    return rho * hp * lp + (1.0 - rho)


def _highpass_bin_average(a, up, lo):
    """Dr.Jit version of :func:`highpass_bin_average_numpy` (``a``, ``up``, ``lo`` in bins)."""
    d_re = 0.5 * dr.log((a * a + up * up) / (a * a + lo * lo))
    d_im = dr.atan2(up, a) - dr.atan2(lo, a)
    return (1.0 - a * d_im, a * d_re)


def corner_bounds(ctx):
    """``((lo, hi) high-pass, (lo, hi) low-pass)`` in ``log10(kHz)``.

    The outer ends (a thousandth of a bin, a thousand times ``f_s``) make the
    filter's magnitude *and* phase negligible across the band.
    """
    fs_k = ctx.radar.sample_rate / KHZ
    bin_k = fs_k / ctx.radar.num_samples
    return ((np.log10(bin_k / 1000), np.log10(fs_k / 2)),
            (np.log10(fs_k / 20), np.log10(fs_k * 1000)))


class IFFilter(Effect):
    """First-order high-pass + Butterworth low-pass (2 corners, log10 kHz) and the
    share ``rho`` of the white floor they filter (3 parameters)."""

    name = "if_filter"
    kind = "mean"
    stage = 2
    per_unit = True
    shapes_noise = True
    description = "IF high-pass (1st order) and anti-alias low-pass (Butterworth)"

    def __init__(self, lowpass_order: int = 4, band_start: float = -0.1, extension: int = 32,
                 prediction_order: int = 32):
        owner = type(self).__name__
        self.lowpass_order = check_int(owner, "lowpass_order", lowpass_order, 1, 12)
        self.band_start = check_float(owner, "band_start", band_start, -1.0, 0.0)
        self.extension = RowExtension(
            check_int(owner, "extension", extension, 0, 4096),
            check_int(owner, "prediction_order", prediction_order, 1, 256))

    # ------------------------------------------------------------------ init
    def param_specs(self, ctx, model, residual):
        self.extension.fit(model)
        (hl, hh), (ll, lh) = corner_bounds(ctx)
        hp, lp, rho = self._init(ctx, model, model + residual, (hl, hh), (ll, lh))
        return {"log_fc": ParamSpec([hp, lp], lower=[hl, ll], upper=[hh, lh], unit="log10 kHz"),
                "pre_noise": ParamSpec([rho], lower=0.0, upper=1.0, unit="share of the floor")}

    def _init(self, ctx, model, data, hb, lb):
        """Starting ``(log f_hp, log f_lp, rho)``: the better (by the approximate
        profiled likelihood of :meth:`_start_nll`) of the signal start
        (:meth:`_signal_init`, ``rho`` by a 1-D search) and the noise start
        (:meth:`_noise_init`)."""
        hp, lp = self._signal_init(ctx, model, data, hb, lb)
        noise = chirp_deviation(data - model)
        noise = data - model if noise is None else noise
        starts = [(hp, lp, self._noise_init(ctx, noise, [hp], [lp])[2]),
                  self._noise_init(ctx, noise, np.linspace(hb[0], hb[1], 32),
                                   np.linspace(lb[0], lb[1], 16))]
        nll = [self._start_nll(ctx, model, data, *st) for st in starts]
        return starts[int(np.argmin(nll))]

    def _filtered_numpy(self, ctx, model, hp, lp) -> np.ndarray:
        """``crop(IDFT(H DFT(extend(model))))`` in NumPy."""
        N = ctx.radar.num_samples
        ext = self.extension
        E = ext.matrix if ext.n == N else None
        xe = ext.extend_numpy(model, E)
        n = xe.shape[-1]
        H = response_numpy(band_frequencies(ctx, self.band_start, n), 10 ** hp * KHZ,
                           10 ** lp * KHZ, self.lowpass_order, ctx.radar.sample_rate / n)
        return ext.crop_numpy(np.fft.ifft(np.fft.fft(xe, axis=-1) * H, axis=-1), E)

    def _noise_shape(self, ctx, hp, lp, rho) -> np.ndarray:
        r = ctx.radar
        f = band_frequencies(ctx, -0.5)
        return noise_gain_numpy(f, 10 ** hp * KHZ, 10 ** lp * KHZ, self.lowpass_order,
                                r.sample_rate / r.num_samples, rho)

    def _start_nll(self, ctx, model, data, hp, lp, rho) -> float:
        """Mean NLL per sample of ``data`` under ``g filter(model)`` (``g`` least
        squares) and the white floor shaped by ``s`` (profiled), cells that are
        all zero (held out) left out.

        With ``C >= 2`` chirp loops it is split as the Gaussian likelihood
        splits: the chirp mean of the residual (one sample in ``C``, what the
        scene leaves unexplained plus the averaged noise) and its deviation
        from that mean (``C - 1`` in ``C``, receiver noise only), each with its
        own profiled floor, so the noise shape is judged where noise is all
        there is."""
        xf = self._filtered_numpy(ctx, model, hp, lp)
        e = np.vdot(xf, xf).real
        g = np.vdot(xf, data) / e if e > 0 else 0.0
        r = data - g * xf
        dev = chirp_deviation(r)
        if dev is None:
            return self._shape_nll(ctx, r, hp, lp, rho)
        C = r.shape[3]
        mean = seen_chirp_mean(r)
        return (self._shape_nll(ctx, mean, hp, lp, rho)
                + (C - 1) * self._shape_nll(ctx, dev, hp, lp, rho)) / C

    def _shape_nll(self, ctx, residual, hp, lp, rho) -> float:
        P = _bin_power(residual)
        s = self._noise_shape(ctx, hp, lp, rho)
        s2 = max(float(np.mean(P / s)), 1e-300)
        return float(np.log(s2) + 1.0 + np.mean(np.log(s)))

    def _noise_init(self, ctx, residual, hps, lps):
        """Best ``(log f_hp, log f_lp, rho)`` for the residual's power spectrum
        over the given corner grids and ``rho`` in 0, 0.05, ..., 1."""
        P = _bin_power(residual)
        r = ctx.radar
        f, bin_hz = band_frequencies(ctx, -0.5), r.sample_rate / r.num_samples
        rho = np.linspace(0.0, 1.0, 21)[:, None]
        best = (np.inf, float(hps[0]), float(lps[-1]), 0.0)
        for hp in hps:
            for lp in lps:
                shaped = noise_gain_numpy(f, 10 ** hp * KHZ, 10 ** lp * KHZ, self.lowpass_order,
                                          bin_hz, 1.0)
                s = rho * shaped[None] + (1.0 - rho)                        # [rho, N]
                nll = (np.log(np.maximum(np.mean(P / s, axis=1), 1e-300))
                       + np.mean(np.log(s), axis=1))
                j = int(np.argmin(nll))
                if nll[j] < best[0]:
                    best = (float(nll[j]), float(hp), float(lp), float(rho[j, 0]))
        return best[1:]

    def _signal_init(self, ctx, model, data, hb, lb):
        """Best ``(log f_hp, log f_lp)`` on a 32 x 32 grid, by the least-squares
        fit of ``g * crop(IDFT(H DFT(extend(model))))`` to ``data`` (one complex
        gain ``g`` per grid point, in closed form).

        The filtered model is linear in the response samples ``H_k`` on the
        extended grid: ``crop(IDFT(H Xe)) = sum_k H_k B_k`` with
        ``<B_k, B_l> = sum_rows conj(Xe_k) Xe_l D_kl / n^2`` (``D`` the window's
        Dirichlet kernel) and ``<B_k, y> = sum_rows conj(Xe_k) Ye_k / n`` (``Ye``
        the DFT of the data placed in the window), so each grid point costs
        one ``n x n`` quadratic form: the explained energy
        ``|H^H v|^2 / H^H G H``.  With the same row extension as the forward
        model, off-bin tones are filtered in steady state here too (a plain
        per-bin ratio of DFTs confuses the high-pass's phase with a low-pass
        delay).
        """
        N = ctx.radar.num_samples
        ext = self.extension
        E = ext.matrix if ext.n == N else None
        xe = ext.extend_numpy(model, E).reshape(-1, ext.length if E is not None else N)
        n = xe.shape[-1]
        m = ext.margin if E is not None else 0
        ye = np.zeros_like(xe)
        ye[:, m:m + N] = data.reshape(-1, N)
        Xe, Ye = np.fft.fft(xe, axis=-1), np.fft.fft(ye, axis=-1)
        if not np.any(Xe != 0):
            return hb[0], lb[1]
        v = np.sum(np.conj(Xe) * Ye, axis=0) / n
        win = np.exp(2j * np.pi * np.arange(n) * m / n) * np.fft.fft(
            (np.arange(n) < N).astype(float)).conj() / n ** 2      # D_kl / n^2 = win[l - k]
        dk = (np.arange(n)[None, :] - np.arange(n)[:, None]) % n
        G = (np.conj(Xe).T @ Xe) * win[dk]
        f = band_frequencies(ctx, self.band_start, n)
        bin_hz = ctx.radar.sample_rate / n
        grid = [(hp, lp) for hp in np.linspace(hb[0], hb[1], 32)
                for lp in np.linspace(lb[0], lb[1], 32)]
        H = np.stack([response_numpy(f, 10 ** hp * KHZ, 10 ** lp * KHZ, self.lowpass_order,
                                     bin_hz) for hp, lp in grid])            # [grid, n]
        den = np.real(np.sum(np.conj(H) * (H @ G.T), axis=1))
        num = np.abs(np.conj(H) @ v) ** 2
        gain = np.where(den > 0, num / np.where(den > 0, den, 1.0), -np.inf)
        hp, lp = grid[int(np.argmax(gain))]
        return float(hp), float(lp)

    # --------------------------------------------------------------- forward
    def response(self, p, ctx, n: int | None = None):
        """Response on the ``n``-point DFT grid (default ``N``) as a complex pair of
        ``(1, 1, 1, 1, n)`` tensors (AD in ``p``)."""
        r = ctx.radar
        n = n or r.num_samples
        bin_hz = r.sample_rate / n
        nu = band_frequencies(ctx, self.band_start, n) / bin_hz             # bins
        a = dr.exp(LN10 * scalar(p["log_fc"], 0)) * (KHZ / bin_hz)          # f_hp [bins]
        h = _highpass_bin_average(a, last_axis(nu + 0.5), last_axis(nu - 0.5))
        w = last_axis(nu * bin_hz / KHZ) * dr.exp(-LN10 * scalar(p["log_fc"], 1))
        for pole in butterworth_poles(self.lowpass_order):
            re, im = -float(pole.real), w - float(pole.imag)                # s - p_i (Python
            # floats: a NumPy scalar on the left of a tensor would detach it from AD)
            mag = re * re + im * im
            h = ops.cmul(h, (re / mag, -im / mag))
        return h

    def noise_gain(self, p, ctx):
        """``s_k`` of the module docstring, ``(1, 1, 1, 1, N)`` (AD in ``p``)."""
        r = ctx.radar
        bin_hz = r.sample_rate / r.num_samples
        nu = np.abs(band_frequencies(ctx, -0.5)) / bin_hz                  # |f| [bins]
        a = dr.exp(LN10 * scalar(p["log_fc"], 0)) * (KHZ / bin_hz)
        hp = 1.0 - a * (dr.atan2(last_axis(nu + 0.5), a) - dr.atan2(last_axis(nu - 0.5), a))
        w = last_axis(nu * bin_hz / KHZ) * dr.exp(-LN10 * scalar(p["log_fc"], 1))
        lp = 1.0 / (1.0 + w ** (2 * self.lowpass_order))
        rho = scalar(p["pre_noise"], 0)
        return rho * hp * lp + (1.0 - rho)

    def apply(self, x, p, ctx):
        ext = self.extension
        E = ext.current(lambda: ops.to_numpy(x), ctx.radar.num_samples)
        xe = ext.extend(x, E)
        ye = ops.idft(ops.cmul(ops.dft(xe), self.response(p, ctx, int(xe[0].shape[-1]))))
        return ext.crop(ye, E)

    def summary(self, p, ctx):
        hp, lp = (float(v) for v in np.ravel(p["log_fc"])[:2])
        f = np.abs(band_frequencies(ctx, self.band_start))
        H = response_numpy(f, 10 ** hp * KHZ, 10 ** lp * KHZ, self.lowpass_order)
        return {"highpass_corner_khz": round(10 ** hp, 4), "lowpass_corner_khz": round(10 ** lp, 4),
                "lowpass_order": self.lowpass_order,
                "filtered_noise_share": round(float(np.ravel(p["pre_noise"])[0]), 4),
                "min_gain_db_in_band": float(20 * np.log10(np.abs(H[1:]).min()))}
