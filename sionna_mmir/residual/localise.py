"""Where an unexplained residual sits, against the receiver noise it should be.

After the last adoption the residual should be white receiver noise.  What
is left above it -- an effect nobody declared and the library lacks -- is
reported by where it concentrates: range bins (with their beat frequency),
virtual channels, chirp loops (slow time), fast-time samples and transmit
slots (frame, Tx, chirp: a TDM-MIMO transmission), each as the
excess of the residual's power over the receiver noise.

The noise reference is not the white floor the model fitted: that floor is
the mean residual power, so it absorbs the very rest it should expose
(excess 0 dB by construction).  It is the median, over range bins and
transmit slots (frame, Tx, chirp), of the residual power averaged over the
Rx, corrected for the median's bias on Gaussian noise
(:func:`robust_noise_power`): a rest confined to some range bins (a
scatterer), or to some transmissions (an interferer's bursts), leaves the
median to the noise as long as it covers less than half of that grid.
"""
from __future__ import annotations

import numpy as np
from scipy import stats


def robust_noise_power(residual) -> float:
    """Receiver noise power per complex sample of ``residual [F, T, R, C, N]``.

    ``P[f, t, c, k]``, the unitary-DFT power averaged over the ``R`` receivers,
    is ``Gamma(R, sigma^2 / R)`` distributed for white Gaussian noise; its median
    over all (transmit slot, range bin) cells divided by that distribution's
    median (``gamma.median(R) / R``) estimates ``sigma^2``.
    """
    R = np.fft.fft(np.asarray(residual), axis=-1, norm="ortho")
    return _median_noise(R)


def _median_noise(R) -> float:
    """:func:`robust_noise_power` from the residual's range spectrum ``R``."""
    n_rx = R.shape[2]
    P = np.mean(np.abs(R) ** 2, axis=2)
    return float(np.median(P) / (stats.gamma.median(n_rx) / n_rx))


def _top(values, labels, n=5):
    order = np.argsort(values)[::-1][:n]
    return [{**labels(int(i)), "excess_db": round(float(10 * np.log10(max(values[i], 1e-30))), 2)}
            for i in order]


def localise(ctx, residual, noise_power: float | None = None, n_top: int = 5) -> dict:
    """Excess of the residual over the noise floor, by domain.

    Parameters
    ----------
    ctx : EffectContext
        Axes of the capture.
    residual : numpy.ndarray
        Capture minus model ``[F, T, R, C, N]`` (capture units).
    noise_power : float, optional
        Noise power per complex sample (capture units); default
        :func:`robust_noise_power` of the residual.
    n_top : int
        Entries listed per domain.

    Returns
    -------
    dict
        ``excess_db`` (residual power over the noise, whole capture), a flag
        ``significant`` (more than 0.5 dB above the floor), and the top
        range bins, channels, chirps, samples and transmit slots (frame, Tx,
        chirp) with their excess [dB].
    """
    r = np.asarray(residual)
    R = np.fft.fft(r, axis=-1, norm="ortho")
    floor = max(float(_median_noise(R) if noise_power is None else noise_power), 1e-300)
    total = float(np.mean(np.abs(r) ** 2)) / floor
    per_bin = np.mean(np.abs(R) ** 2, axis=(0, 1, 2, 3)) / floor
    per_ch = np.mean(np.abs(r) ** 2, axis=(0, 3, 4)) / floor
    per_chirp = np.mean(np.abs(r) ** 2, axis=(0, 1, 2, 4)) / floor
    per_sample = np.mean(np.abs(r) ** 2, axis=(0, 1, 2, 3)) / floor
    per_slot = np.mean(np.abs(r) ** 2, axis=(2, 4)) / floor             # [F, T, C]
    F, T_, C_ = per_slot.shape
    ranges, freqs = ctx.band_ranges, ctx.band_frequencies()
    T, R_ = per_ch.shape
    return {
        "excess_db": round(float(10 * np.log10(max(total, 1e-30))), 3),
        "significant": bool(total > 10 ** 0.05),
        "range_bins": _top(per_bin, lambda i: {"bin": i, "range_m": round(float(ranges[i]), 3),
                                               "beat_hz": round(float(freqs[i]), 1)}, n_top),
        "channels": _top(per_ch.ravel(), lambda i: {"tx": i // R_, "rx": i % R_}, n_top),
        "chirps": _top(per_chirp, lambda i: {"chirp": i}, n_top),
        "samples": _top(per_sample, lambda i: {"sample": i}, n_top),
        "slots": _top(per_slot.ravel(), lambda i: {"frame": i // (T_ * C_),
                                                    "tx": (i // C_) % T_, "chirp": i % C_}, n_top),
        "spread_db": {
            "range": round(float(10 * np.log10(per_bin.max() / max(np.median(per_bin), 1e-30))), 2),
            "channel": round(float(10 * np.log10(per_ch.max() / max(np.median(per_ch), 1e-30))), 2),
            "chirp": round(float(10 * np.log10(per_chirp.max() / max(np.median(per_chirp),
                                                                       1e-30))), 2),
            "slot": round(float(10 * np.log10(per_slot.max() / max(np.median(per_slot),
                                                                     1e-30))), 2)},
    }
