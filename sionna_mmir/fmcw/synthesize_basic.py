"""Reference twin of :mod:`sionna_mmir.fmcw.synthesize`: the model written out.

Evaluates :mod:`sionna_mmir.fmcw.model` literally, one (tx, rx) pair at a
time, with a dense ``exp`` over ``[chirp, sample, path]``.  Slow and simple on
purpose; the tests compare the fast synthesiser against it.
"""
from __future__ import annotations

import numpy as np

from ..radar.config import RadarConfig
from .model import broadcast_paths


def synthesize_adc_basic(radar: RadarConfig, a, tau, tau_rate=None) -> np.ndarray:
    """Direct evaluation of the beat-signal model.

    Returns complex128 ``[n_tx, n_rx, num_chirps, num_samples]``.
    """
    a, tau, rho, (T, R, P) = broadcast_paths(radar, a, tau, tau_rate)
    f0, S = radar.start_frequency, radar.slope
    tk = radar.sample_times()                      # [K]
    Tl = radar.chirp_start_times()                 # [T, L]
    out = np.zeros(radar.adc_shape, dtype=np.complex128)
    for i in range(T):
        for j in range(R):
            if rho is None:   # static: every chirp is the same, evaluate one
                delay = tau[i, j][None, None, :]
                doppler = 0.0
            else:
                delay = (tau[i, j][None, None, :]
                         + rho[i, j][None, None, :] * Tl[i][:, None, None])   # [L, 1, P]
                doppler = f0 * rho[i, j][None, None, :] * tk[None, :, None]
            phase = (f0 + S * tk)[None, :, None] * delay + doppler           # [L, K, P]
            out[i, j] = np.sum(a[i, j][None, None, :] * np.exp(2j * np.pi * phase), axis=-1)
    return out
