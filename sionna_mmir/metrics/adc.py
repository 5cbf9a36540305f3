"""ADC-level magnitude metrics (paper Table 2, "ADC Log-Mag MSE" / "ADC MM-Mag MSE").

Both compare two complex ADC arrays of the same shape (any shape, e.g.
``[tx, rx, chirp, sample]``) by magnitude only: absolute phase carries no
reliable supervision (LO phase, oscillator drift).  Shape mismatch, NaN or
Inf raise :class:`~sionna_mmir.errors.InputValueError`.
"""
from __future__ import annotations

import numpy as np

from ..errors import InputValueError

#: Floor added to peak-normalised magnitudes before the log: 1e-6 = -120 dB.
LOG_EPS = 1e-6


def _mags(a, b, where):
    out = []
    for name, v in (("a", a), ("b", b)):
        arr = np.asarray(v)
        try:
            mag = np.abs(arr).astype(np.float64)
        except TypeError:
            raise InputValueError(f"{where}: '{name}' is not numeric (dtype {arr.dtype})") from None
        if mag.size == 0:
            raise InputValueError(f"{where}: '{name}' is empty")
        if not np.all(np.isfinite(mag)):
            raise InputValueError(f"{where}: '{name}' holds NaN or Inf")
        out.append(mag)
    if out[0].shape != out[1].shape:
        raise InputValueError(f"{where}: shapes differ, a {out[0].shape} vs b {out[1].shape}")
    return out


def _peak_norm(m):
    peak = float(m.max())
    return m / peak if peak > 0 else np.zeros_like(m)


def _minmax(m):
    lo, hi = float(m.min()), float(m.max())
    return (m - lo) / (hi - lo) if hi > lo else np.zeros_like(m)


def adc_log_magnitude_mse(a, b, eps: float = LOG_EPS) -> float:
    """Log-magnitude MSE [dB^2]::

        mean_n ( 20 log10(|a_n| / max|a| + eps) - 20 log10(|b_n| / max|b| + eps) )^2

    over all samples ``n``, ``eps = 1e-6`` (a -120 dB floor).  Each array is
    normalised by its own peak, so only the relative magnitude pattern counts;
    an all-zero array is taken as all at the floor.
    """
    ma, mb = _mags(a, b, "adc_log_magnitude_mse")
    la = 20.0 * np.log10(_peak_norm(ma) + eps)
    lb = 20.0 * np.log10(_peak_norm(mb) + eps)
    return float(np.mean((la - lb) ** 2))


def adc_minmax_magnitude_mse(a, b) -> float:
    """Min-max magnitude MSE: ``mean_n (|a|~_n - |b|~_n)^2`` with
    ``|x|~ = (|x| - min|x|) / (max|x| - min|x|)`` (a constant magnitude -> 0).
    """
    ma, mb = _mags(a, b, "adc_minmax_magnitude_mse")
    return float(np.mean((_minmax(ma) - _minmax(mb)) ** 2))
