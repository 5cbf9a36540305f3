"""The residual (measured minus model) seen in every domain where an effect leaves a fingerprint.

All energies are sums of ``|.|^2`` in the unitary-DFT range domain (equal to
the time-domain energy, Parseval) and are reported relative to the measured
capture's energy, in dB, or as fractions of the residual energy.

What each domain shows:

``range_profile``
    residual / measured energy per range bin ``[N]``
    (``np.fft`` order, ranges in ``bin_ranges``: the
    complex IF band ``[-0.1, 0.9) f_s`` of
    :meth:`EffectContext.band_frequencies`)
``negative_frequency_half``
    share in bins ``N/2 .. N-1`` (a real IF's negative
    frequencies: I/Q images of targets below half
    the maximum range, and those beyond it)
``dc``
    share in bin 0 (DC offset)
``near_range``
    share below ``near_range_m`` (coupling / leakage)
``channels``
    share per virtual channel ``[T, R]`` and per chip
    pair (gains, delays, per-chip offsets)
``chirps`` / ``doppler``
    share per chirp loop ``[C]`` and per Doppler bin
    (motion, phase noise)
``frames``
    share per frame ``[F]`` (movers, drift)
``samples``
    share per fast-time sample ``[N]`` (clipping,
    chirp non-linearity at the ramp ends)
``peaks``
    strongest residual range bins with their range
    [m] and share of the residual (missing scatterers)
"""
from __future__ import annotations

import numpy as np

from ..errors import InputValueError
from ..effects.context import EffectContext


def _db(x) -> float:
    return float(10 * np.log10(max(float(x), 1e-30)))


def residual_domains(ctx: EffectContext, measured, model, near_range_m: float = 0.5,
                     n_peaks: int = 5) -> dict:
    """Where the residual energy sits; arrays for plotting under ``"arrays"``.

    ``measured`` and ``model`` are complex ``[F, T, R, C, N]`` in the same
    units.  Returns a JSON-able summary plus NumPy arrays.
    """
    y = ctx.check(measured, "measured ADC")
    m = ctx.check(model, "model ADC")
    r = y - m
    e_meas = float(np.sum(np.abs(y) ** 2))
    e_res = float(np.sum(np.abs(r) ** 2))
    if e_meas <= 0:
        raise InputValueError("residual: the measured capture is all zeros")
    if e_res <= 0:
        raise InputValueError("residual: the model equals the measurement exactly "
                              "(empty residual); nothing to analyse")
    R = np.fft.fft(r, axis=-1, norm="ortho")
    Y = np.fft.fft(y, axis=-1, norm="ortho")
    per_bin = np.sum(np.abs(R) ** 2, axis=(0, 1, 2, 3))
    per_bin_meas = np.sum(np.abs(Y) ** 2, axis=(0, 1, 2, 3))
    freqs = ctx.band_frequencies()
    ranges = ctx.band_ranges
    neg = ctx.beat_frequencies < 0
    near = (ranges >= 0) & (ranges < near_range_m)
    per_ch = np.sum(np.abs(r) ** 2, axis=(0, 3, 4))                     # [T, R]
    chips = ctx.num_chips
    chip_pairs = np.zeros((chips, chips))
    np.add.at(chip_pairs, (ctx.tx_chip[:, None].repeat(per_ch.shape[1], 1),
                           ctx.rx_chip[None, :].repeat(per_ch.shape[0], 0)), per_ch)
    per_chirp = np.sum(np.abs(r) ** 2, axis=(0, 1, 2, 4))
    dop = np.sum(np.abs(np.fft.fft(r, axis=3, norm="ortho")) ** 2, axis=(0, 1, 2, 4))
    per_frame = np.sum(np.abs(r) ** 2, axis=(1, 2, 3, 4))
    per_sample = np.sum(np.abs(r) ** 2, axis=(0, 1, 2, 3))
    order = np.argsort(per_bin)[::-1]
    peaks, used = [], np.zeros(per_bin.size, bool)
    for k in order:
        if len(peaks) >= n_peaks:
            break
        if used[max(0, k - 2):k + 3].any():
            continue
        win = np.arange(k - 2, k + 3) % per_bin.size
        used[win] = True
        peaks.append({"bin": int(k), "range_m": round(float(ranges[k]), 4),
                      "beat_hz": float(freqs[k]),
                      "share": round(float(per_bin[win].sum() / e_res), 4)})
    return {
        "residual_energy_db": _db(e_res / e_meas),
        "measured_energy": e_meas,
        "shares": {
            "negative_frequency_half": round(float(per_bin[neg].sum() / e_res), 4),
            "dc_bin": round(float(per_bin[0] / e_res), 4),
            "near_range": round(float(per_bin[near].sum() / e_res), 4),
            "strongest_channel": round(float(per_ch.max() / e_res), 4),
            "strongest_chip_pair": round(float(chip_pairs.max() / e_res), 4),
            "strongest_frame": round(float(per_frame.max() / e_res), 4),
            "nonzero_doppler": round(float(1 - dop[0] / max(dop.sum(), 1e-300)), 4),
            "ramp_ends_10pct": round(float(_ends(per_sample) / e_res), 4),
        },
        "peaks": peaks,
        "channel_spread_db": _db(per_ch.max() / max(per_ch.min(), 1e-300)),
        "arrays": {"range_profile": per_bin / e_meas, "range_profile_measured": per_bin_meas / e_meas,
                   "bin_ranges": ranges, "channels": per_ch / e_res, "chip_pairs": chip_pairs / e_res,
                   "chirps": per_chirp / e_res, "doppler": dop / e_res, "frames": per_frame / e_res,
                   "samples": per_sample / e_res},
    }


def _ends(per_sample) -> float:
    n = per_sample.size
    k = max(1, n // 20)
    return float(per_sample[:k].sum() + per_sample[-k:].sum())


def json_view(domains: dict) -> dict:
    """``residual_domains`` without the NumPy arrays (for JSON)."""
    return {k: v for k, v in domains.items() if k != "arrays"}
