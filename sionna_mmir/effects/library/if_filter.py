"""IF chain filters: two first-order high-pass stages and a Butterworth anti-alias low-pass.

The I and Q branches pass identical real analog filters, so the complex beat
signal sees ``H(f)`` with ``H(-f) = conj(H(f))``; in the range domain::

    X[f, t, r, c, k] <- H(f_k) X[f, t, r, c, k],    x = IDFT(X)
    H(f) = H_hp(f; f_hp) H_hp(f; f_hp2) H_lp(f)
    H_hp(f) = (j f / f_hp) / (1 + j f / f_hp)                      (first order)
    H_hp(f_k) := mean of H_hp over the bin [f_k - f_s/2N, f_k + f_s/2N]
    H_lp(f) = 1 / prod_{i=1..n} (j f / f_lp - p_i),   p_i = exp(j pi (2 i + n - 1) / (2 n))

(``n``-th order Butterworth, ``|H_lp|^2 = 1 / (1 + (f / f_lp)^{2 n})``, with
its phase).  TI's single-chip front ends have two high-pass stages (HPF1
175-700 kHz, HPF2 350 kHz-2.8 MHz); the second corner at its lower bound (a
thousandth of a bin) leaves one.  Each high-pass stage is averaged over each
bin (``1 + j a [ln(a + j u)]`` from ``u = k - 1/2`` to ``k + 1/2``, ``a =
f_hp`` in bins): with the point value the DC bin would be nulled for any
corner, even far below one bin, removing an off-bin tone's leakage there; the
average tends to 1 as ``f_hp -> 0`` and to ``H_hp(f_k)`` for corners of a few
bins.  ``f_k`` is the bin's physical beat frequency in the band ``[band_start
f_s, (band_start + 1) f_s)`` (default ``-0.1``: targets up to ``0.9
max_range`` are positive frequencies, near-DC leakage negative; see
:func:`~._sensor_common.band_frequencies`).  The high-pass suppresses the
Tx-Rx coupling and near-range clutter, the low-pass rolls off far range.

Steady state.  The analog filters run long before the ADC window opens, so
each beat tone leaves them multiplied by ``H`` of its own frequency.  The
DFT-domain product instead treats the window as periodic: an off-bin tone's
end wraps onto its start and the filters' memory (a few samples) sees that
jump, an error of about -20 dB of the signal.  Each fast-time row is
therefore first extended by ``extension`` samples on both sides by linear
prediction (:class:`~._sensor_common.RowExtension`, predictor of order
``prediction_order`` frozen on the model and renewed whenever another effect
joins it: a leakage adopted after the filter brings a tone a predictor
frozen without it continues wrongly), filtered on the longer
grid, and cut back to the window (error about -40 dB in the tests);
``extension=0`` gives the plain DFT-domain product.

Settling.  Where the ADC window opens soon after the beat signal starts
(a short ADC start time; a chirp's leakage and near returns start with the
ramp), the high-pass has not settled.  A first-order high-pass
``y' + w y = u'`` switched on (zero state) at ``t = 0`` passes the step,
``y(0+) = u(0)``, and its output differs from the steady state ``y_ss`` by a
free decay, so ``y = y_ss + (u(0) - y_ss(0)) exp(-w t)``.  Through two stages
(poles ``w_1``, ``w_2``; ``z_ss`` the first stage's steady state)::

    y = y_ss + (1 - a) [(z_ss(0) - y_ss(0)) e^{-w_2 t}
                        + (u(0) - z_ss(0)) (w_2 e^{-w_2 t} - w_1 e^{-w_1 t}) / (w_2 - w_1)]

(the last fraction, symmetric in the two poles, written as ``e^{-w_l t} (1 -
w_h t phi((w_h - w_l) t))`` with ``w_l <= w_h`` the lower and higher pole and
``phi(x) = (1 - e^{-x}) / x``: finite at ``w_1 = w_2`` and free of overflow),
with ``t`` the sample times from the window's first sample and ``a``
(``settled``) the share of the transient already gone: 0 for a filter switched
on at the window, 1 in steady state; ``a = 1 - exp(-w t_s)`` for one stage
switched on ``t_s`` before the window.  The low-pass's own transient (a corner
near ``f_s``) is left out.  A strong tone below the corner (Tx->Rx leakage)
leaves a transient over the first samples of every chirp that carries more
energy than its settled output.

Receiver noise.  Thermal noise of the LNA and mixer passes the same
filters, so a fraction ``rho`` of the white floor ``sigma^2`` (the rest is
added after the filters: ADC quantisation and driver noise) is shaped by
their power gain.  What a bin of the ``N``-sample window sees is the
*expected periodogram* of that shaped noise, its power spectral density
``S(nu) = |H_hp(nu)|^2 |H_lp(nu)|^2`` (``nu`` in bins, one period
``[-N/2, N/2)``) smoothed by the window's Fejer kernel
(:meth:`IFFilter.noise_gain`, :func:`periodogram_matrix`)::

    s_k = rho E|X_k|^2 + (1 - rho),    E|X_k|^2 = int S(nu) F_N(k - nu) dnu
    F_N(u) = sin^2(pi u) / (N sin^2(pi u / N))

evaluated on a grid of ``q = 8`` points per bin (the midpoint rule is exact
for ``F_N``, a trigonometric polynomial of less than one cycle per bin).
The kernel's sidelobes fill the notch: behind two high-pass stages at 2.8
and 8.4 bins the DC bin of a 128-sample window sits 18 dB under the floor,
not the 40 dB of ``S`` averaged over the bin, and a model that predicts the
deeper notch is punished there.  The notch at near-DC bins is the
high-pass's most robust signature: the signal-side response alone is a
smooth complex gain over range that per-object amplitudes absorb when the
scene is a few compact scatterers.

Parameters: ``log_fc`` ``[2]`` = (``log10(f_hp / kHz)``, ``log10(f_lp / kHz)``),
``log_hp2`` ``[1]`` = ``log10(f_hp2 / kHz)`` (``highpass_stages=2``),
``pre_noise`` ``[1]`` = ``rho`` in ``[0, 1]``, ``settled`` ``[1]`` = ``a`` in
``[0, 1]`` (``transient=True``): 5 numbers by default.  Stage 2 (IF).

Initial values: on a grid of corners (one or two high-pass stages, the
low-pass), the filtered (extended, settled) model is fitted to the data up
to one complex gain in closed form; the corners that explain the most
energy, with the settling (0, 1/2 or 1) that explains the most at those
corners, are one start, the corners (with ``rho``) whose noise shape best
explains the residual power spectrum another; the start with the lower
approximate likelihood wins (see :meth:`IFFilter._init`).
"""
from __future__ import annotations

import copy
import typing

import numpy as np

from ...errors import ConfigError
from .. import ops
from ..base import Effect, ParamSpec
from ._sensor_common import (ExtendedRows, LN10, RowExtension, band_frequencies, check_float, const,
                             bin_power, check_int, chirp_deviation, last_axis, noise_bins,
                             scalar, seen_chirp_mean)

dr = ops.dr
KHZ = 1e3


def butterworth_poles(order: int) -> np.ndarray:
    """Left-half-plane poles of the normalised ``order``-th Butterworth low-pass."""
    i = np.arange(1, order + 1)
    return np.exp(1j * np.pi * (2 * i + order - 1) / (2 * order))


def response_numpy(f, f_hp, f_lp, order: int, bin_hz=None, f_hp2=None) -> np.ndarray:
    """``H(f)`` of the high-pass(es) x low-pass chain (NumPy, complex); with
    ``bin_hz`` each high-pass stage is its bin average (what :class:`IFFilter`
    applies); ``f_hp2``: the second stage's corner (None: one stage)."""
    f = np.asarray(f, float)
    h = np.ones(f.shape, complex)
    for fc in (f_hp,) if f_hp2 is None else (f_hp, f_hp2):
        if bin_hz is None:
            h = h * (1j * f / fc / (1 + 1j * f / fc))
        else:
            h = h * highpass_bin_average_numpy(f, fc, bin_hz)
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


#: grid points per bin of the expected periodogram (:func:`periodogram_matrix`)
PERIODOGRAM_OVERSAMPLING = 8


def periodogram_matrix(n: int, q: int = PERIODOGRAM_OVERSAMPLING) -> tuple:
    """``(nu [q n], M [n, q n])``: the expected periodogram of an ``n``-sample
    window, ``E|X_k|^2 = sum_j M[k, j] S(nu_j)`` for a stationary process of
    power spectral density ``S`` (unitary DFT, ``k`` the DFT index, ``nu_j``
    the bin midpoints of a ``q``-fold finer grid over ``[-n/2, n/2)``).

    ``M[k, j]`` is the Fejer kernel ``sin^2(pi u) / (n sin^2(pi u / n))`` at
    ``u = k - nu_j`` over ``q``, each row normalised to sum to 1 (a white
    ``S = 1`` stays 1 in every bin).  Cached per ``(n, q)``; read-only."""
    key = (int(n), int(q))
    if key not in _PERIODOGRAM:
        nu = -n / 2 + (np.arange(q * n) + 0.5) / q
        u = np.arange(n)[:, None] - nu[None]
        M = np.sin(np.pi * u) ** 2 / np.sin(np.pi * u / n) ** 2    # u never a multiple of n
        M /= M.sum(axis=1, keepdims=True)
        M.setflags(write=False)
        nu.setflags(write=False)
        _PERIODOGRAM[key] = (nu, M)
    return _PERIODOGRAM[key]


_PERIODOGRAM: dict = {}
_PERIODOGRAM_TENSOR: dict = {}


def _periodogram_tensor(n: int):
    """:func:`periodogram_matrix`'s ``M`` as a Dr.Jit tensor, made once per ``n``
    (it enters every evaluation of :meth:`IFFilter.noise_gain`)."""
    if n not in _PERIODOGRAM_TENSOR:
        M = periodogram_matrix(n)[1]
        _PERIODOGRAM_TENSOR[n] = const(M, M.shape)
    return _PERIODOGRAM_TENSOR[n]


def noise_psd_numpy(nu, f_hp, f_lp, order: int, bin_hz, f_hp2=None) -> np.ndarray:
    """``S(nu) = prod |H_hp|^2 |H_lp|^2`` at ``nu`` [bins] (NumPy)."""
    f = np.abs(np.asarray(nu, float)) * bin_hz
    s = 1.0 / (1.0 + (f / f_lp) ** (2 * order))
    for fc in (f_hp,) if f_hp2 is None else (f_hp, f_hp2):
        s = s * (f * f) / (f * f + fc * fc)
    return s


def noise_gain_numpy(f, f_hp, f_lp, order: int, bin_hz, rho, f_hp2=None) -> np.ndarray:
    """``s_k`` of the module docstring at the window's ``N`` DFT bin
    frequencies ``f`` [Hz] (``k bin_hz`` modulo ``f_s``, any order; NumPy):
    the expected periodogram of the filtered share ``rho`` of the floor plus
    the white rest.  ``f_hp2``: the second high-pass stage (None: one)."""
    f = np.asarray(f, float)
    n = f.size
    nu, M = periodogram_matrix(n)
    k = np.rint(f / bin_hz).astype(np.int64) % n
    e = M[k] @ noise_psd_numpy(nu, f_hp, f_lp, order, bin_hz, f_hp2)
    return rho * e + (1.0 - rho)


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


class IFFilter(ExtendedRows, Effect):
    """One or two first-order high-pass stages + a Butterworth low-pass (corners in
    log10 kHz), the share ``rho`` of the white floor they filter and the share
    ``a`` of the pre-window input the high-pass has settled on (5 parameters by
    default, 3 with ``highpass_stages=1, transient=False``).

    Parameters
    ----------
    lowpass_order : int
        Butterworth order of the anti-alias low-pass (1-12, default 4).
    band_start : float
        Lower edge of the beat band as a fraction of ``f_s`` (default -0.1).
    extension, prediction_order : int
        Samples predicted on each side of a row, and the predictor's order.
    highpass_stages : {1, 2}
        First-order high-pass stages (default 2, as TI's HPF1 and HPF2).
    transient : bool
        Fit how far the high-pass has settled when the window opens
        (default True; False: steady state).
    """

    name = "if_filter"
    kind = "mean"
    stage = 2
    per_unit = True
    shapes_noise = True
    #: a Tx->Rx leakage adopted before it was fitted to what the high-pass
    #: leaves of it (its tones 20-40 dB down): left out of the filter's start,
    #: and refitted from zero beside it when it is scored
    may_replace = ("coupling",)
    #: the base fit's per-object gains took its attenuation and phase at the
    #: nearest targets (a corner 1.2 times above the high-pass corner): held
    #: fixed, the filter would count them twice
    refit_beside = ("object_gain",)
    description = "IF high-pass (1st order) and anti-alias low-pass (Butterworth)"

    def __init__(self, lowpass_order: int = 4, band_start: float = -0.1, extension: int = 32,
                 prediction_order: int = 32, highpass_stages: int = 2, transient: bool = True):
        owner = type(self).__name__
        self.lowpass_order = check_int(owner, "lowpass_order", lowpass_order, 1, 12)
        self.highpass_stages = check_int(owner, "highpass_stages", highpass_stages, 1, 2)
        if not isinstance(transient, (bool, np.bool_)):
            raise ConfigError(f"{owner}: transient must be True or False, got {transient!r}")
        self.transient = bool(transient)
        self.band_start = check_float(owner, "band_start", band_start, -1.0, 0.0)
        self.extension = RowExtension(
            check_int(owner, "extension", extension, 0, 4096),
            check_int(owner, "prediction_order", prediction_order, 1, 256))

    # ------------------------------------------------------------------ init
    def param_specs(self, ctx, model, residual):
        self.extension.fit(model)
        (hl, hh), (ll, lh) = corner_bounds(ctx)
        st = self._init(ctx, model, model + residual, (hl, hh), (ll, lh))
        specs = {"log_fc": ParamSpec([st.hp, st.lp], lower=[hl, ll], upper=[hh, lh],
                                     unit="log10 kHz")}
        if self.highpass_stages == 2:
            specs["log_hp2"] = ParamSpec([st.hp2], lower=hl, upper=hh, unit="log10 kHz")
        specs["pre_noise"] = ParamSpec([st.rho], lower=0.0, upper=1.0, unit="share of the floor")
        if self.transient:
            specs["settled"] = ParamSpec([st.settled], lower=0.0, upper=1.0,
                                         unit="share of the pre-window input")
        return specs

    def _init(self, ctx, model, data, hb, lb) -> "_Start":
        """The starting values: the better (by the approximate profiled
        likelihood of :meth:`_start_nll`) of the signal start
        (:meth:`_signal_init`, ``rho`` by a 1-D search) and the noise start
        (:meth:`_noise_init`, with the signal start's settling)."""
        sig = self._signal_init(ctx, model, data, hb, lb)
        noise = chirp_deviation(data - model)
        noise = data - model if noise is None else noise
        hps, lps = np.linspace(hb[0], hb[1], 16), np.linspace(lb[0], lb[1], 12)
        shaped = self._noise_init(ctx, noise, self._hp_pairs(hps, hb[0]), lps)
        starts = [sig._replace(rho=self._noise_init(ctx, noise, [(sig.hp, sig.hp2)],
                                                    [sig.lp]).rho),
                  shaped._replace(settled=sig.settled)]
        absorbed = ctx.basis is not None
        nll = [self._start_nll(ctx, model, data, st, absorbed) for st in starts]
        return starts[int(np.argmin(nll))]

    def _hp_pairs(self, hps, off) -> list:
        """High-pass corner pairs of the init grids: one stage (the second at
        ``off``, its lower bound) or two with ``f_hp <= f_hp2``."""
        if self.highpass_stages == 1:
            return [(float(h), float(off)) for h in hps]
        return [(float(h), float(off)) for h in hps] + [
            (float(h), float(g)) for i, h in enumerate(hps) for g in hps[i:]]

    def _corners(self, st) -> dict:
        """Corner frequencies [Hz] of a start for the NumPy responses."""
        return {"f_hp": 10 ** st.hp * KHZ, "f_lp": 10 ** st.lp * KHZ,
                "f_hp2": 10 ** st.hp2 * KHZ if self.highpass_stages == 2 else None}

    def _filtered_numpy(self, ctx, model, st) -> np.ndarray:
        """``y`` of the module docstring (settling included) in NumPy."""
        N = ctx.radar.num_samples
        ext = self.extension
        E = ext.matrix if ext.n == N else None
        Xe = np.fft.fft(ext.extend_numpy(model, E), axis=-1)
        n = Xe.shape[-1]
        c = self._corners(st)
        f, bin_hz = band_frequencies(ctx, self.band_start, n), ctx.radar.sample_rate / n
        H = response_numpy(f, c["f_hp"], c["f_lp"], self.lowpass_order, bin_hz, c["f_hp2"])
        y = ext.crop_numpy(np.fft.ifft(Xe * H, axis=-1), E)
        if not self.transient or st.settled >= 1.0:
            return y
        t = np.arange(N) / ctx.radar.sample_rate
        w1 = 2 * np.pi * c["f_hp"]
        u0, y0 = model[..., :1], y[..., :1]
        if c["f_hp2"] is None:
            return y + (1.0 - st.settled) * (u0 - y0) * np.exp(-w1 * t)
        H1 = highpass_bin_average_numpy(f, c["f_hp"], bin_hz)
        z0 = ext.crop_numpy(np.fft.ifft(Xe * H1, axis=-1), E)[..., :1]
        w2 = 2 * np.pi * c["f_hp2"]
        lo, hi = min(w1, w2), max(w1, w2)
        x = (hi - lo) * t
        phi = np.where(x < 1e-4, 1 - x / 2 + x * x / 6, -np.expm1(-x) / np.where(x == 0, 1.0, x))
        both = np.exp(-lo * t) * (1.0 - hi * t * phi)
        return y + (1.0 - st.settled) * ((z0 - y0) * np.exp(-w2 * t) + (u0 - z0) * both)

    def _noise_shape(self, ctx, st) -> np.ndarray:
        r = ctx.radar
        c = self._corners(st)
        return noise_gain_numpy(band_frequencies(ctx, -0.5), c["f_hp"], c["f_lp"],
                                self.lowpass_order, r.sample_rate / r.num_samples, st.rho,
                                c["f_hp2"])

    def _start_nll(self, ctx, model, data, st, absorbed: bool = False) -> float:
        """Mean NLL per sample of ``data`` under ``g filter(model)`` (``g`` least
        squares) and the white floor shaped by ``s`` (profiled), cells that are
        all zero (held out) left out.

        ``absorbed``: the model's per-object gains are refitted beside the
        filter (:attr:`refit_beside`) and can take its response at the objects
        back, so the mean part of a start is never worse than the model left
        unfiltered.  Without it a noise start (a notch at near-DC bins, where
        the receiver noise passes the high-pass) loses to no filter at all
        whenever the base fit's object gains took the filter's attenuation of
        the nearest targets: filtered once more, the model counts it twice.

        With ``C >= 2`` chirp loops it is split as the model's likelihood is
        (:meth:`~sionna_mmir.effects.model.EffectModel.split_likelihood`):
        the chirp mean of the residual (one sample in ``C``, what the scene
        leaves unexplained plus the averaged noise) under its own profiled
        white floor, and its deviation from that mean (``C - 1`` in ``C``,
        receiver noise only) under the profiled shaped floor, so the noise
        shape is judged where noise is all there is."""
        xf = self._filtered_numpy(ctx, model, st)
        e = np.vdot(xf, xf).real
        g = np.vdot(xf, data) / e if e > 0 else 0.0
        r = data - g * xf
        dev = chirp_deviation(r)
        if dev is None:
            return self._shape_nll(ctx, r, st)
        C = r.shape[3]
        mean = self._white_nll(seen_chirp_mean(r))
        if absorbed:
            mean = min(mean, self._white_nll(seen_chirp_mean(data - model)))
        return (mean + (C - 1) * self._shape_nll(ctx, dev, st)) / C

    @staticmethod
    def _white_nll(residual) -> float:
        """Mean NLL per sample under a profiled white floor (cells that are all
        zero left out): the chirp mean's share of the split likelihood
        (:meth:`~sionna_mmir.effects.model.EffectModel.split_likelihood`)."""
        return float(np.log(max(float(np.mean(bin_power(residual))), 1e-300)) + 1.0)

    def _shape_nll(self, ctx, residual, st) -> float:
        """Mean NLL per sample of the chirp-to-chirp scatter ``residual`` under
        the profiled shaped floor, on the bins of receiver noise alone
        (:func:`~._sensor_common.noise_bins`)."""
        P = bin_power(residual)
        keep = noise_bins(P)
        P, s = P[keep], self._noise_shape(ctx, st)[keep]
        s2 = max(float(np.mean(P / s)), 1e-300)
        return float(np.log(s2) + 1.0 + np.mean(np.log(s)))

    def _noise_init(self, ctx, residual, hp_pairs, lps) -> "_Start":
        """Best corners and ``rho`` for the residual's power spectrum over the
        given high-pass pairs ``(log f_hp, log f_hp2)``, low-pass corners and
        ``rho`` in 0, 0.05, ..., 1 (settled), on the bins of receiver noise
        alone (:func:`~._sensor_common.noise_bins`)."""
        P = bin_power(residual)
        keep = noise_bins(P)
        P = P[keep]
        r = ctx.radar
        f, bin_hz = band_frequencies(ctx, -0.5), r.sample_rate / r.num_samples
        rho = np.linspace(0.0, 1.0, 21)[:, None]
        hp0, hp20 = hp_pairs[0]
        best = (np.inf, _Start(float(hp0), float(hp20), float(lps[-1]), 0.0, 1.0))
        for hp, hp2 in hp_pairs:
            for lp in lps:
                st = _Start(float(hp), float(hp2), float(lp), 1.0, 1.0)
                c = self._corners(st)
                shaped = noise_gain_numpy(f, c["f_hp"], c["f_lp"], self.lowpass_order, bin_hz,
                                          1.0, c["f_hp2"])[keep]
                s = rho * shaped[None] + (1.0 - rho)                        # [rho, N]
                nll = (np.log(np.maximum(np.mean(P / s, axis=1), 1e-300))
                       + np.mean(np.log(s), axis=1))
                j = int(np.argmin(nll))
                if nll[j] < best[0]:
                    best = (float(nll[j]), st._replace(rho=float(rho[j, 0])))
        return best[1]

    def _signal_init(self, ctx, model, data, hb, lb) -> "_Start":
        """Best corners and settling on a grid (16 high-pass corners as one
        stage or as pairs, 12 low-pass corners; settled), by the
        least-squares fit of ``g * y(model)`` to ``data`` (one complex gain ``g``
        per grid point, in closed form); then the settling among 0, 1/2 and 1
        that explains the most at those corners.

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
        off = _Start(float(hb[0]), float(hb[0]), float(lb[1]), 0.0, 1.0)
        xe = ext.extend_numpy(model, E).reshape(-1, ext.length if E is not None else N)
        n = xe.shape[-1]
        m = ext.margin if E is not None else 0
        ye = np.zeros_like(xe)
        ye[:, m:m + N] = data.reshape(-1, N)
        Ye = np.fft.fft(ye, axis=-1)
        f = band_frequencies(ctx, self.band_start, n)
        bin_hz = ctx.radar.sample_rate / n
        lps = np.linspace(lb[0], lb[1], 12)
        grid = [(hp, hp2, lp) for hp, hp2 in self._hp_pairs(np.linspace(hb[0], hb[1], 16), hb[0])
                for lp in lps]
        H = np.stack([response_numpy(f, 10 ** hp * KHZ, 10 ** lp * KHZ, self.lowpass_order,
                                     bin_hz, 10 ** hp2 * KHZ if self.highpass_stages == 2
                                     else None) for hp, hp2, lp in grid])   # [grid, n]
        win = np.exp(2j * np.pi * np.arange(n) * m / n) * np.fft.fft(
            (np.arange(n) < N).astype(float)).conj() / n ** 2      # D_kl / n^2 = win[l - k]
        dk = (np.arange(n)[None, :] - np.arange(n)[:, None]) % n
        Xe = np.fft.fft(xe, axis=-1)
        if not np.any(Xe != 0):
            return off
        v = np.sum(np.conj(Xe) * Ye, axis=0) / n
        G = (np.conj(Xe).T @ Xe) * win[dk]
        den = np.real(np.sum(np.conj(H) * (H @ G.T), axis=1))
        num = np.abs(np.conj(H) @ v) ** 2
        gain = np.where(den > 0, num / np.where(den > 0, den, 1.0), -np.inf)
        hp, hp2, lp = grid[int(np.argmax(gain))]
        start = _Start(float(hp), float(hp2), float(lp), 0.0, 1.0)
        if not self.transient:
            return start

        def explained(a):
            xf = self._filtered_numpy(ctx, model, start._replace(settled=a))
            e = np.vdot(xf, xf).real
            return np.abs(np.vdot(xf, data)) ** 2 / e if e > 0 else -np.inf

        return start._replace(settled=max((1.0, 0.5, 0.0), key=explained))

    # --------------------------------------------------------------- forward
    def response(self, p, ctx, n: int | None = None):
        """Response on the ``n``-point DFT grid (default ``N``) as a complex pair of
        ``(1, 1, 1, 1, n)`` tensors (AD in ``p``)."""
        r = ctx.radar
        n = n or r.num_samples
        bin_hz = r.sample_rate / n
        nu = band_frequencies(ctx, self.band_start, n) / bin_hz             # bins
        up, lo = last_axis(nu + 0.5), last_axis(nu - 0.5)
        h = None
        for corner in self._highpass_corners(p):
            a = dr.exp(LN10 * corner) * (KHZ / bin_hz)                       # f_hp [bins]
            stage = _highpass_bin_average(a, up, lo)
            h = stage if h is None else ops.cmul(h, stage)
        w = last_axis(nu * bin_hz / KHZ) * dr.exp(-LN10 * scalar(p["log_fc"], 1))
        for pole in butterworth_poles(self.lowpass_order):
            re, im = -float(pole.real), w - float(pole.imag)                # s - p_i (Python
            # floats: a NumPy scalar on the left of a tensor would detach it from AD)
            mag = re * re + im * im
            h = ops.cmul(h, (re / mag, -im / mag))
        return h

    def tone_gains(self, values, ctx, freqs):
        """Least-squares gain of :meth:`apply` (settling and all) on a unit
        tone at each beat frequency ``freqs`` [Hz], complex ``[K]``, its rows
        extended by a predictor of those tones (the steady state)."""
        r = ctx.radar
        f = np.atleast_1d(np.asarray(freqs, np.float64))
        tones = np.exp(2j * np.pi * f[:, None] * np.arange(r.num_samples) / r.sample_rate)
        x = tones[None, None, None]
        probe = copy.deepcopy(self)
        probe.extension.fit(x)
        p = {k: ops.tensor(np.asarray(v, np.float64)) for k, v in values.items()}
        with dr.suspend_grad(), ops.single_thread():
            y = ops.to_numpy(probe.apply(ops.tensor(x), p, ctx))[0, 0, 0]
        return np.sum(np.conj(tones) * y, axis=-1) / r.num_samples

    def _highpass_corners(self, p) -> list:
        """``log10(f / kHz)`` of the high-pass stages in ``p`` (Dr.Jit scalars)."""
        corners = [scalar(p["log_fc"], 0)]
        if self.highpass_stages == 2 and "log_hp2" in p:
            corners.append(scalar(p["log_hp2"], 0))
        return corners

    def noise_gain(self, p, ctx):
        """``s_k`` of the module docstring, ``(1, 1, 1, 1, N)`` in the order of the
        DFT indices (AD in ``p``)."""
        r = ctx.radar
        N = r.num_samples
        bin_hz = r.sample_rate / N
        nu, M = periodogram_matrix(N)
        L = nu.size
        f = const(np.abs(nu) * bin_hz / KHZ, (1, L))                        # |f| [kHz]
        psd = 1.0 / (1.0 + (f * dr.exp(-LN10 * scalar(p["log_fc"], 1))) ** (2 * self.lowpass_order))
        for corner in self._highpass_corners(p):
            fc = dr.exp(LN10 * corner)
            psd = psd * (f * f) / (f * f + fc * fc)
        e = dr.sum(_periodogram_tensor(N) * psd, axis=1)                    # [N]
        rho = scalar(p["pre_noise"], 0)
        return ops.view(rho * e + (1.0 - rho), (1, 1, 1, 1, N))

    def apply(self, x, p, ctx):
        ext = self.extension
        N = ctx.radar.num_samples
        E = ext.current(lambda: ops.to_numpy(x), N)
        n = N if E is None else E.shape[0]
        H = self.response(p, ctx, n)
        if not (self.transient and "settled" in p):
            return ext.filter(x, E, [H])[0]
        corners = self._highpass_corners(p)
        if len(corners) == 1:
            y = ext.filter(x, E, [H])[0]
            return self._transient(x, y, None, p, ctx)
        bin_hz = ctx.radar.sample_rate / n
        nu = band_frequencies(ctx, self.band_start, n) / bin_hz
        a1 = dr.exp(LN10 * corners[0]) * (KHZ / bin_hz)
        H1 = _highpass_bin_average(a1, last_axis(nu + 0.5), last_axis(nu - 0.5))
        y, z0 = ext.filter(x, E, [H, H1], first=(False, True))
        return self._transient(x, y, z0, p, ctx)

    def _transient(self, x, y, z0, p, ctx):
        """``y`` plus the unsettled high-pass's free decay (module docstring; AD);
        ``z0``: the first window sample after the first stage alone (two stages)."""
        r = ctx.radar
        t = last_axis(np.arange(r.num_samples) / r.sample_rate)
        unseen = 1.0 - scalar(p["settled"], 0)
        corners = self._highpass_corners(p)
        w1 = dr.exp(LN10 * corners[0]) * (2 * np.pi * KHZ)
        u0, y0 = first_sample(x), first_sample(y)
        d1 = dr.exp(-w1 * t)
        if z0 is None:
            return ops.cadd(y, _scaled(_minus(u0, y0), unseen, d1))
        w2 = dr.exp(LN10 * corners[1]) * (2 * np.pi * KHZ)
        lo, hi = dr.minimum(w1, w2), dr.maximum(w1, w2)        # symmetric in the poles
        xw = (hi - lo) * t                                      # >= 0: no overflow
        phi = dr.select(xw < 1e-4, 1.0 - xw * 0.5 + xw * xw * (1.0 / 6.0),
                        (1.0 - dr.exp(-xw)) / dr.select(xw == 0.0, 1.0, xw))
        both = dr.exp(-lo * t) * (1.0 - hi * t * phi)
        out = ops.cadd(y, _scaled(_minus(z0, y0), unseen, dr.exp(-w2 * t)))
        return ops.cadd(out, _scaled(_minus(u0, z0), unseen, both))

    def summary(self, p, ctx):
        hp, lp = (float(v) for v in np.ravel(p["log_fc"])[:2])
        hp2 = float(np.ravel(p["log_hp2"])[0]) if "log_hp2" in p else None
        f = np.abs(band_frequencies(ctx, self.band_start))
        H = response_numpy(f, 10 ** hp * KHZ, 10 ** lp * KHZ, self.lowpass_order,
                           f_hp2=None if hp2 is None else 10 ** hp2 * KHZ)
        out = {"highpass_corner_khz": round(10 ** hp, 4), "lowpass_corner_khz": round(10 ** lp, 4),
               "lowpass_order": self.lowpass_order,
               "filtered_noise_share": round(float(np.ravel(p["pre_noise"])[0]), 4),
               "min_gain_db_in_band": float(20 * np.log10(np.abs(H[1:]).min()))}
        if hp2 is not None:
            out["second_highpass_corner_khz"] = round(10 ** hp2, 4)
        if "settled" in p:
            out["settled_share"] = round(float(np.ravel(p["settled"])[0]), 4)
        return out


def _scaled(z, k, d):
    """``k d z`` for a complex pair ``z [..., 1]``, a real scalar ``k`` and a real
    decay ``d [..., N]``."""
    return (z[0] * (k * d), z[1] * (k * d))


def _minus(a, b):
    return (a[0] - b[0], a[1] - b[1])


def first_sample(z):
    """``z[..., :1]`` of a complex pair (AD)."""
    return (z[0][..., 0:1], z[1][..., 0:1])


class _Start(typing.NamedTuple):
    """Starting values of :class:`IFFilter` (corners in log10 kHz)."""

    hp: float
    hp2: float
    lp: float
    rho: float
    settled: float
