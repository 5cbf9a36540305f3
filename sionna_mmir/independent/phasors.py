"""Unit phasors ``exp(j phase)`` of large float64 phase arrays.

The phase is formed in float64 and reduced exactly to ``[-pi, pi]``
(``phase - 2 pi rint(phase / 2 pi)``, error ~1e-12 rad for phases below
1e5 rad); the sine and cosine of the reduced angle are then evaluated in
float32 (SIMD), accurate to ~1e-7 rad.
"""
from __future__ import annotations

import numpy as np

_TWO_PI = 2.0 * np.pi


def cis(phase, dtype=np.complex128) -> np.ndarray:
    """``exp(j phase)`` (module docstring).

    Parameters
    ----------
    phase : numpy.ndarray
        Any shape, float64 [rad].
    dtype : numpy.dtype
        ``complex128`` or ``complex64``.

    Returns
    -------
    numpy.ndarray
        Same shape, ``dtype``.
    """
    phase = np.asarray(phase, dtype=np.float64)
    r = (phase - np.rint(phase * (1.0 / _TWO_PI)) * _TWO_PI).astype(np.float32)
    out = np.empty(phase.shape, dtype)
    out.real = np.cos(r)
    out.imag = np.sin(r)
    return out
