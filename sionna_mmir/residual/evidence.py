"""Independent evidence for what the diagnosis adopts on real captures.

* :func:`peak_evidence`: per-channel peak phase, amplitude and position of a
  model against TI's own ``PeakValMat`` / ``RangeMat`` of the capture (TI's
  estimator: 5x zero-padded, Hann-windowed range FFT peak per channel).
* :func:`coupling_evidence`: fitted Tx->Rx coupling against ColoRadar's
  measured ``coupling_calib.txt`` (same sensor family, other unit and
  waveform: compared by range profile and by the spread across channels)
  and against the capture's own near-range energy.
* :func:`track_evidence`: a fitted per-frame mover range against a model-free
  track (per-frame peak of the static-removed range profile).
"""
from __future__ import annotations

import os

import numpy as np

from ..captures.ti_mat import calibration_window
from ..radar.config import SPEED_OF_LIGHT

INTERP = 5


def _ti_spectrum(adc_trn):
    """TI's per-channel spectrum: ``fft(x * w / rms(w), 5N)``, ``[T, R, 5N]``."""
    n = adc_trn.shape[-1]
    return np.fft.fft(adc_trn * calibration_window(n), INTERP * n, axis=-1)


def _circ_rms_deg(d) -> float:
    d = np.angle(np.exp(1j * (d - np.angle(np.mean(np.exp(1j * d))))))
    return float(np.degrees(np.sqrt(np.mean(d ** 2))))


def peak_evidence(model_adc, extras) -> dict:
    """Model vs ``PeakValMat`` (phase, amplitude) and ``RangeMat`` (peak bin), per channel.

    ``model_adc`` complex ``[T, R, N]`` (chirp-averaged).  Returns the circular
    RMS phase difference [deg] after removing one common phase, the RMS of the
    dB amplitude difference after removing the mean, and the RMS difference of
    the peak positions in TI's fine bins (1/5 range bin) after removing the mean.
    """
    pv = np.asarray(extras["PeakValMat"])
    rm = np.asarray(extras["RangeMat"]).astype(float) - 1.0          # 0-based fine bins
    spec = _ti_spectrum(model_adc)
    idx = rm.round().astype(int)
    at = np.take_along_axis(spec, idx[..., None], axis=-1)[..., 0]
    lo = max(int(rm.min()) - 10, 0)
    hi = int(rm.max()) + 10
    peak = lo + np.argmax(np.abs(spec[..., lo:hi]), axis=-1)
    dphi = np.angle(at) - np.angle(pv)
    da = 20 * np.log10(np.abs(at) / np.abs(pv))
    dpos = peak - rm
    return {"phase_rms_deg": round(_circ_rms_deg(dphi), 2),
            "amplitude_rms_db": round(float(np.std(da)), 3),
            "peak_position_rms_fine_bins": round(float(np.std(dpos)), 3),
            "ti_peak_spread_fine_bins": int(rm.max() - rm.min()),
            "ti_amplitude_spread_db": round(float(np.ptp(20 * np.log10(np.abs(pv)))), 2)}


def coupling_evidence(profile, radar, measured_adc, coloradar_dir=None,
                      max_range_m: float = 1.0) -> dict:
    """Fitted coupling ``profile`` ``[T, R, n]`` (range-FFT domain, unwindowed, capture units)
    against ColoRadar's measured coupling and the capture's own near range.

    Profiles are compared as mean magnitude over channels versus range [m]
    up to ``max_range_m``, each normalised to its peak: the peak range and
    the correlation of the two profiles on ColoRadar's bins; and the spread
    of the per-channel magnitude at the peak (dB std over channels).
    """
    n = radar.num_samples
    bin_m = SPEED_OF_LIGHT * radar.sample_rate / (2 * radar.slope * n)
    fit_r = np.arange(profile.shape[-1]) * bin_m
    fit_mag = np.mean(np.abs(profile), axis=(0, 1))
    meas = np.fft.fft(np.asarray(measured_adc).mean(axis=2), axis=-1)    # [T, R, N]
    near = fit_r < max_range_m
    k = int(np.argmax(fit_mag[near]))
    out = {"fit_peak_range_m": round(float(fit_r[k]), 3),
           "fit_channel_spread_db": round(float(np.std(20 * np.log10(
               np.abs(profile[..., k]) + 1e-30))), 2),
           "capture_near_range_energy_db": round(float(10 * np.log10(
               np.sum(np.abs(meas[..., :near.sum()]) ** 2))), 2),
           "fit_near_range_energy_db": round(float(10 * np.log10(
               np.sum(np.abs(profile[..., :near.sum()]) ** 2) + 1e-30)), 2)}
    if coloradar_dir is None:
        return out
    from ..captures.coloradar_calib import read_coupling_calib, read_heatmap_cfg

    cc = read_coupling_calib(os.path.join(coloradar_dir, "coupling_calib.txt"))
    width = float(read_heatmap_cfg(os.path.join(coloradar_dir, "heatmap_cfg.txt"))
                  ["range_bin_width"])
    cr = np.arange(cc.shape[-1]) * width
    c_near = cr < max_range_m
    c_mag = np.mean(np.abs(cc), axis=(0, 1))[c_near]
    kc = int(np.argmax(c_mag))
    fit_on_c = np.interp(cr[c_near], fit_r, fit_mag)
    corr = np.corrcoef(c_mag / c_mag.max(), fit_on_c / max(fit_on_c.max(), 1e-30))[0, 1]
    out.update({"coloradar_peak_range_m": round(float(cr[kc]), 3),
                "coloradar_channel_spread_db": round(float(np.std(20 * np.log10(
                    np.abs(cc[..., kc]) + 1e-30))), 2),
                "profile_correlation": round(float(corr), 3)})
    return out


def near_range_evidence(residual_adc, radar, coloradar_dir=None,
                        max_range_m: float = 0.5) -> dict:
    """Where the near-range residual lives and whether a low-parameter coupling
    model could predict it: the residual ``[F, T, R, C, N]`` (capture units)
    in the range-FFT domain (Hann window) below ``max_range_m``.

    * ``near_share``: share of the residual energy in those bins;
    * ``rank1_share`` / ``rank3_share``: share of the per-channel complex
      ``[T, R]`` pattern (at the strongest near bin) captured by its best
      rank-1 / rank-3 approximation (a separable per-Tx x per-Rx model
      reaches at most the rank-1 share);
    * ``channel_spread_db``: dB std of the per-channel magnitude there;
    * with ``coloradar_dir``: ``coloradar_pattern_correlation``, the
      correlation of the per-channel dB magnitudes with ColoRadar's measured
      coupling at its peak bin (same sensor family, another unit: a stable
      board property would correlate).
    """
    r = np.asarray(residual_adc)
    n = r.shape[-1]
    w = np.hanning(n)
    spec = np.fft.fft(r * w, axis=-1)                                       # [F, T, R, C, N]
    bin_m = SPEED_OF_LIGHT * radar.sample_rate / (2 * abs(radar.slope) * n)
    near = np.arange(n) * bin_m < max_range_m
    e = np.sum(np.abs(spec) ** 2, axis=(0, 1, 2, 3))
    k = int(np.argmax(np.where(near, e, -1.0)))
    pat = spec[..., k].mean(axis=(0, 3))                                    # [T, R]
    s = np.linalg.svd(pat, compute_uv=False) ** 2
    mag_db = 20 * np.log10(np.abs(pat) + 1e-30)
    out = {"near_share": round(float(e[near].sum() / e.sum()), 4),
           "strongest_near_bin_m": round(float(k * bin_m), 3),
           "rank1_share": round(float(s[0] / s.sum()), 3),
           "rank3_share": round(float(s[:3].sum() / s.sum()), 3),
           "channel_spread_db": round(float(np.std(mag_db)), 2)}
    if coloradar_dir is None:
        return out
    from ..captures.coloradar_calib import read_coupling_calib

    cc = read_coupling_calib(os.path.join(coloradar_dir, "coupling_calib.txt"))
    if cc.shape[:2] != pat.shape:
        out["coloradar_pattern_correlation"] = None
        return out
    kc = int(np.argmax(np.sum(np.abs(cc), axis=(0, 1))))
    c_db = 20 * np.log10(np.abs(cc[..., kc]) + 1e-30)
    out["coloradar_pattern_correlation"] = round(float(np.corrcoef(c_db.ravel(),
                                                                   mag_db.ravel())[0, 1]), 3)
    return out


def near_range_similarity(adc_a, adc_b, radar, max_range_m: float = 0.5) -> dict:
    """Near-range per-channel pattern of two captures of the same unit, ``[F, T, R, C, N]``
    each: is the leakage a stable property of the board?

    At the strongest near bin (Hann window, mean over frames and chirps):
    ``db_correlation`` of the per-channel magnitudes [dB], ``coherence``
    ``|<a, b>| / (|a| |b|)`` of the complex patterns, and ``explained``, the
    share of ``b``'s pattern energy one complex gain on ``a`` explains.
    """
    pats = []
    for adc in (adc_a, adc_b):
        x = np.asarray(adc)
        n = x.shape[-1]
        spec = np.fft.fft(x * np.hanning(n), axis=-1).mean(axis=(0, 3))     # [T, R, N]
        bin_m = SPEED_OF_LIGHT * radar.sample_rate / (2 * abs(radar.slope) * n)
        near = np.arange(n) * bin_m < max_range_m
        e = np.sum(np.abs(spec) ** 2, axis=(0, 1))
        pats.append(spec[..., int(np.argmax(np.where(near, e, -1.0)))])
    a, b = pats
    coh = abs(np.vdot(a, b)) / (np.linalg.norm(a) * np.linalg.norm(b))
    db = [20 * np.log10(np.abs(p) + 1e-30).ravel() for p in pats]
    return {"db_correlation": round(float(np.corrcoef(*db)[0, 1]), 3),
            "coherence": round(float(coh), 3), "explained": round(float(coh ** 2), 3)}


def track_evidence(fitted_range_m, frames, radar, min_range: float = 0.3) -> dict:
    """Fitted per-frame ranges ``[F]`` [m] vs the per-frame peak of the static-removed
    range profile (Hann window, 4x zero padding, summed over channels)."""
    y = np.asarray(frames)
    y = y - y.mean(axis=0, keepdims=True)
    n = y.shape[-1]
    w = np.hanning(n)
    spec = np.fft.fft(y * w, 4 * n, axis=-1)
    p = np.sum(np.abs(spec) ** 2, axis=(1, 2, 3))                      # [F, 4N]
    r = np.fft.fftfreq(4 * n, 1 / radar.sample_rate) * SPEED_OF_LIGHT / (2 * radar.slope)
    ok = r >= min_range
    track = r[ok][np.argmax(p[:, ok], axis=1)]
    d = np.asarray(fitted_range_m, float) - track
    return {"median_abs_diff_m": round(float(np.median(np.abs(d))), 4),
            "p90_abs_diff_m": round(float(np.percentile(np.abs(d), 90)), 4),
            "fitted_span_m": [round(float(np.min(fitted_range_m)), 3),
                              round(float(np.max(fitted_range_m)), 3)],
            "peak_track_span_m": [round(float(track.min()), 3), round(float(track.max()), 3)]}
