"""``synthesize_adc``: per-path amplitudes and delays -> raw FMCW ADC.

NumPy input runs the exact batched-matrix-product engine
(:mod:`sionna_mmir.fmcw.engine`) and returns complex64; Dr.Jit input returns
:class:`~sionna_mmir.fmcw.engine.DrAdc` tensors inside the AD graph via a
``dr.CustomOp`` (:mod:`sionna_mmir.fmcw.drjit_op`).
"""
from __future__ import annotations

import numpy as np

from ..radar.config import RadarConfig
from .drjit_op import is_drjit, synthesize_adc_drjit
from .engine import DrAdc, Prepared

__all__ = ["DrAdc", "synthesize_adc"]


def synthesize_adc(radar: RadarConfig, a, tau, tau_rate=None):
    """Raw complex baseband FMCW ADC from per-path amplitudes and delays.

    ``s[tx, rx, chirp, k] = sum_p a exp(j 2 pi (f_0 + S t_k) tau)`` (paper eq. 4),
    with optional motion through ``tau_rate`` (see :mod:`sionna_mmir.fmcw.model`).

    Parameters
    ----------
    radar : RadarConfig
        Waveform and layout.
    a : array_like
        Complex amplitudes ``[tx, rx, P]`` or ``[P]`` (broadcast); NumPy, or
        Dr.Jit: ``mi.Complex2f`` / ``(re, im)`` pair of ``mi.TensorXf`` /
        ``mi.Float``.
    tau : array_like
        Delays [s], same shapes.
    tau_rate : array_like, optional
        ``d tau / dt`` [s/s] (``2 v / c`` receding at ``v``).

    Returns
    -------
    numpy.ndarray or DrAdc
        Complex64 ``[n_tx, n_rx, num_chirps, num_samples]`` for NumPy input,
        or :class:`DrAdc` (``real``, ``imag`` ``mi.TensorXf``) inside the
        Dr.Jit AD graph when any input is a Dr.Jit array (gradients flow to
        ``a``, ``tau`` and ``tau_rate``).

    Raises
    ------
    InputValueError
        NaN / Inf or mismatched shapes.
    """
    if is_drjit(a) or is_drjit(tau) or is_drjit(tau_rate):
        return synthesize_adc_drjit(radar, a, tau, tau_rate)
    prep = Prepared(radar, a, tau, tau_rate)
    return np.ascontiguousarray(prep.forward())
