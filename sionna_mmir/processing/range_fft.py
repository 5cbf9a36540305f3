"""Range FFT over fast time (the ADC sample axis).

Forward model (see :mod:`sionna_mmir.fmcw`)::

    s[..., k] = sum_p a_p exp(+j 2 pi (f0 + S t_k) tau_p),  t_k = t_adc + k / f_s

A path of round-trip delay ``tau`` (range ``R = c tau / 2``) is a complex tone
of beat frequency ``+S tau`` [Hz].  ``np.fft.fft`` over ``n_fft`` points puts
it in bin ``n = S tau n_fft / f_s``.  Samples are complex, so every bin
``0 .. n_fft - 1`` is a distinct *positive* beat frequency ``0 .. f_s`` and
hence a range::

    ranges_m[n] = n * c * f_s / (2 * S * n_fft)        0 <= ranges < max_range

``max_range = f_s c / (2 S)`` and the bin width is ``c / (2 B)`` with
``B = S N / f_s`` when ``n_fft == N``.

With ``full=False`` only the first half of the bins (beat frequencies
``0 .. f_s / 2``, ranges below ``max_range / 2``) is returned.  The upper
half holds what a real-IF receiver would call *negative* beat frequencies
(``-f_s / 2 .. 0``: I/Q-imbalance images, DC-offset leakage); it can be taken
apart with :func:`split_range_halves`.  In the complex-baseband model of this
package those bins are genuine ranges ``max_range / 2 .. max_range``, which
is why the default (and every RA map) keeps all bins.

A negative chirp slope reverses the tone direction (beat ``S tau < 0``); the
bins are re-ordered so that ``ranges_m`` still increases from 0.
"""
from __future__ import annotations

import numpy as np
import scipy.fft

from ..errors import InputValueError
from ..radar.config import SPEED_OF_LIGHT, RadarConfig
from .windows import get_window


def _complex_dtype(x: np.ndarray):
    return np.complex128 if x.dtype in (np.complex128, np.float64) else np.complex64


def range_bins_m(radar: RadarConfig, n_fft: int | None = None) -> np.ndarray:
    """Range of every range-FFT bin, ``[n_fft]`` [m]: ``n c f_s / (2 |S| n_fft)``."""
    n_fft = radar.num_samples if n_fft is None else int(n_fft)
    return np.arange(n_fft) * SPEED_OF_LIGHT * radar.sample_rate / (2.0 * abs(radar.slope) * n_fft)


def range_fft(adc, radar: RadarConfig, window="hann", n_fft: int | None = None,
              full: bool = True):
    """Windowed FFT over the last (sample) axis.

    A unit-amplitude tone on a bin has magnitude ``num_samples``.

    Parameters
    ----------
    adc : array_like
        Complex ``[..., num_samples]`` (any leading axes, e.g. ``[tx, rx,
        chirp, sample]`` or with a frame axis).
    radar : RadarConfig
        The waveform.
    window : str or None, optional
        Window name (:func:`~.windows.get_window`), unit coherent gain;
        ``None`` / ``'rect'`` for none.
    n_fft : int, optional
        FFT length (zero padding), default ``num_samples``.
    full : bool, optional
        ``True``: all ``n_fft`` bins (ranges ``0 .. max_range``); ``False``:
        the first ``n_fft // 2`` bins only.

    Returns
    -------
    spectrum : numpy.ndarray
        Complex ``[..., n_fft]`` (or ``[..., n_fft // 2]``; complex64 for
        complex64 input).
    ranges_m : numpy.ndarray
        float64 bin ranges [m].
    """
    x = np.asarray(adc)
    if x.ndim < 1 or x.shape[-1] != radar.num_samples:
        raise InputValueError(f"range_fft: adc must be [..., num_samples={radar.num_samples}], "
                              f"got shape {x.shape}")
    n_fft = radar.num_samples if n_fft is None else int(n_fft)
    if n_fft < radar.num_samples:
        raise InputValueError(f"range_fft: n_fft ({n_fft}) must be >= num_samples "
                              f"({radar.num_samples})")
    dtype = _complex_dtype(x)
    x = x.astype(dtype, copy=False)
    w = get_window(window, radar.num_samples).astype(x.real.dtype)
    spec = scipy.fft.fft(x * w, n_fft, axis=-1, workers=-1)    # multi-threaded, same precision
    if radar.slope < 0:
        spec = spec[..., (-np.arange(n_fft)) % n_fft]
    ranges = range_bins_m(radar, n_fft)
    if not full:
        half = n_fft // 2
        spec, ranges = spec[..., :half], ranges[:half]
    return spec, ranges


def split_range_halves(spectrum):
    """Split a full range spectrum ``[..., n]`` into its two frequency halves.

    Returns ``(positive, negative)``: ``positive = spectrum[..., :n//2]``
    (beat frequencies ``0 .. f_s/2``) and ``negative = spectrum[..., n//2:]``
    (``-f_s/2 .. 0``, i.e. bins ``n//2 .. n-1``, in increasing frequency).
    """
    s = np.asarray(spectrum)
    half = s.shape[-1] // 2
    return s[..., :half], s[..., half:]
