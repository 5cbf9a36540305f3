"""Doppler FFT over slow time (the chirp-loop axis).

Sign convention, derived from the forward model
``s = sum_p a_p exp(+j 2 pi (f0 + S t_k) tau_p(t))``: a target receding at
radial velocity ``v`` has ``tau(t) = tau_0 + (2 v / c) t``, so from one loop to
the next (``t = l T_loop``) the phase advances by ``+2 pi f (2 v / c) T_loop``.
Across loops the signal is the tone ``exp(+j 2 pi f_D l T_loop)`` with
``f_D = 2 v f / c = 2 v / lambda > 0``.  ``np.fft.fft`` over the chirp axis
puts it at the positive frequency ``f_D``, and the velocity axis is::

    v = f_D * lambda / 2,   f_D = k / (n_fft * T_loop),  k = -n_fft/2 .. n_fft/2 - 1

(``fftshift`` order, ``lambda = radar.wavelength`` at the centre frequency,
``T_loop = radar.loop_period``).  **Positive velocity = target moving away**
(delay increasing); approaching targets have negative velocity.
"""
from __future__ import annotations

import numpy as np

from ..errors import InputValueError
from ..radar.config import RadarConfig
from .windows import get_window


def doppler_bins_hz(radar: RadarConfig, n_fft: int | None = None) -> np.ndarray:
    """Doppler frequency of every (fftshifted) bin, ``[n_fft]`` [Hz], ``k / (n_fft T_loop)``."""
    n_fft = radar.num_chirps if n_fft is None else int(n_fft)
    k = np.arange(n_fft) - n_fft // 2
    return k / (n_fft * radar.loop_period)


def doppler_velocities_m_s(radar: RadarConfig, n_fft: int | None = None) -> np.ndarray:
    """Radial velocity of every (fftshifted) bin, ``[n_fft]`` [m/s], positive = receding."""
    return doppler_bins_hz(radar, n_fft) * radar.wavelength / 2.0


def doppler_fft(rfft, radar: RadarConfig, window="hann", n_fft: int | None = None):
    """Windowed, fftshifted FFT over the chirp axis (axis -2).

    Parameters
    ----------
    rfft : array_like
        Complex ``[..., chirp, range]``, e.g. the range spectrum ``[tx, rx,
        chirp, range]`` (any leading axes).
    radar : RadarConfig
        The waveform.
    window : str or None, optional
        Window name (unit coherent gain), ``None`` for none.
    n_fft : int, optional
        FFT length (zero padding), default ``num_chirps``.

    Returns
    -------
    spectrum : numpy.ndarray
        Complex ``[..., n_fft, range]`` in fftshift order (bin ``n_fft // 2``
        is zero Doppler).
    velocities_m_s : numpy.ndarray
        float64 ``[n_fft]`` [m/s], positive for targets moving away.
    """
    x = np.asarray(rfft)
    if x.ndim < 2 or x.shape[-2] != radar.num_chirps:
        raise InputValueError(f"doppler_fft: rfft must be [..., chirp={radar.num_chirps}, range], "
                              f"got shape {x.shape}")
    n_fft = radar.num_chirps if n_fft is None else int(n_fft)
    if n_fft < radar.num_chirps:
        raise InputValueError(f"doppler_fft: n_fft ({n_fft}) must be >= num_chirps "
                              f"({radar.num_chirps})")
    if not np.iscomplexobj(x):
        x = x.astype(np.complex64)
    w = get_window(window, radar.num_chirps).astype(x.real.dtype)
    spec = np.fft.fft(x * w[:, None], n_fft, axis=-2)
    spec = np.fft.fftshift(spec, axes=-2)
    return spec, doppler_velocities_m_s(radar, n_fft)
