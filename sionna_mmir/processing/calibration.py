"""ColoRadar / TI-style channel calibration: phase, frequency and coupling.

Each (tx, rx) channel of a real cascade has its own complex gain
``g_i = |g_i| exp(j phi_i)`` and a small extra delay ``dtau_i`` (board
traces, LO distribution), so channel ``i`` sees::

    s_i[n] = g_i exp(j 2 pi (f0 + S t_n) (tau + dtau_i)),   t_n = t_adc + n / f_s

Calibration captures a corner reflector and stores, per channel, the peak bin
``b_i`` of an ``interp_factor * N_cal``-point range FFT (zero-padded,
``interp_factor`` x interpolated) and the complex peak value ``p_i``.

Frequency correction (derivation)
---------------------------------
An extra delay ``dtau`` adds the beat frequency ``S dtau``.  In the
calibration capture the fine-bin spacing is ``f_s,cal / (I N_cal)``, so
``b_i - b_ref = S_cal (dtau_i - dtau_ref) I N_cal / f_s,cal`` and::

    dtau_i - dtau_ref = (b_i - b_ref) f_s,cal / (I N_cal S_cal)

In a capture with slope ``S`` and sample rate ``f_s`` this delay difference is
the beat offset ``S (dtau_i - dtau_ref)``, i.e. a phase advance per sample of
``2 pi S (dtau_i - dtau_ref) / f_s``.  The correction is therefore::

    exp(-j 2 pi (b_i - b_ref) / (I N_cal) * (S / S_cal) * (f_s,cal / f_s) * n)

(the ratio ``f_s,cal / f_s``, not its inverse: bins measured at a higher
calibration sample rate are wider in Hz).

Phase correction
----------------
``p_ref / p_i`` normalised to unit modulus (gains are not equalised), as in
ColoRadar.  ``arg p_i`` holds ``phi_i + 2 pi (f0 + S_cal t_adc,cal) dtau_i``
(the phase of the tone at the first ADC sample, when ``b_i`` is the true
peak): the frequency the delay phase was measured at is the calibration's
first-sample frequency.  The ColoRadar formula is exact when the corrected
capture has the same first-sample frequency ``f0 + S t_adc``.  For a capture
with another slope / ADC start, pass ``cal_first_sample_frequency``
(``f0,cal + S_cal t_adc,cal`` [Hz]); the frequency correction then uses the
absolute fast time and becomes ``exp(-j 2 pi (f0 + S t_n - f_cal,1) dtau_i)``
which removes the full delay phase at every frequency.

Coupling
--------
:func:`subtract_coupling` removes the measured Tx->Rx leakage (range-FFT
domain, ``[tx, rx, n_bins]``) from every chirp's range spectrum.
"""
from __future__ import annotations

import numpy as np

from ..errors import InputValueError
from ..radar.config import RadarConfig
from .range_fft import range_bins_m
from .windows import get_window


def _finite(x, name, where):
    x = np.asarray(x)
    ok = np.isfinite(x.real).all() and (not np.iscomplexobj(x) or np.isfinite(x.imag).all())
    if not ok:
        raise InputValueError(f"{where}: {name} holds NaN or Inf")
    return x


def _check_adc_tail(adc, radar, where):
    x = _finite(adc, "adc", where)
    if x.ndim < 4 or tuple(x.shape[-4:]) != tuple(radar.adc_shape):
        raise InputValueError(f"{where}: adc must be [..., tx, rx, chirp, sample] ending in "
                              f"{tuple(radar.adc_shape)}, got shape {x.shape}")
    if not np.iscomplexobj(x):
        x = x.astype(np.complex64)
    return x


def estimate_phase_frequency_calibration(adc, radar: RadarConfig, interp_factor: int = 5,
                                         window="hann", min_range: float = 0.5,
                                         max_range: float | None = None, refine: bool = False):
    """Per-channel corner peak bin and complex peak value (TI procedure).

    Parameters
    ----------
    adc : array_like
        Complex ``[tx, rx, chirp, sample]`` of a corner capture.
    radar : RadarConfig
        Its radar.
    interp_factor : int, optional
        Zero-padding factor ``I`` of the range FFT (5).
    window : str or array_like, optional
        Range window name, or an array ``[num_samples]``.
    min_range, max_range : float, optional
        Range gate [m] of the peak search (leakage lives below ~0.3 m);
        ``max_range`` default: all.
    refine : bool, optional
        ``False``: integer fine bins (as TI's ``RangeMat``, but 0-based);
        ``True``: parabolic refinement of the peak on the magnitude and the
        peak value evaluated at the refined frequency (a DTFT).

    Returns
    -------
    frequency_bins : numpy.ndarray
        float64 ``[tx, rx]``, in units of ``1 / (I N)`` cycles per sample
        (0-based).  Only differences of bins are used by
        :func:`phase_frequency_correct`.
    peaks : numpy.ndarray
        complex128 ``[tx, rx]`` peak values.
    """
    where = "estimate_phase_frequency_calibration"
    x = _check_adc_tail(adc, radar, where)
    if x.ndim != 4:
        raise InputValueError(f"{where}: adc must be one frame [tx, rx, chirp, sample], "
                              f"got shape {x.shape}")
    n = radar.num_samples
    nf = int(interp_factor) * n
    if isinstance(window, np.ndarray) or isinstance(window, (list, tuple)):
        w = np.asarray(window, dtype=np.float64).reshape(-1)
        if w.size != n:
            raise InputValueError(f"{where}: window array must have {n} entries, got {w.size}")
    else:
        w = get_window(window, n)
    xm = x.mean(axis=2).astype(np.complex128) * w                        # [tx, rx, N]
    spec = np.fft.fft(xm, nf, axis=-1)
    ranges = range_bins_m(radar, nf)
    gate = ranges >= min_range
    if max_range is not None:
        gate &= ranges <= max_range
    if not gate.any():
        raise InputValueError(f"{where}: empty range gate [{min_range}, {max_range}] m")
    mag = np.where(gate, np.abs(spec), -np.inf)
    k = np.argmax(mag, axis=-1)                                          # [tx, rx]
    bins = k.astype(np.float64)
    if refine:
        km = np.clip(k - 1, 0, nf - 1)
        kp = np.clip(k + 1, 0, nf - 1)
        a = np.take_along_axis(np.abs(spec), km[..., None], -1)[..., 0]
        b = np.take_along_axis(np.abs(spec), k[..., None], -1)[..., 0]
        c = np.take_along_axis(np.abs(spec), kp[..., None], -1)[..., 0]
        den = a - 2 * b + c
        delta = np.where(np.abs(den) > 0, 0.5 * (a - c) / np.where(den == 0, 1, den), 0.0)
        bins = bins + np.clip(delta, -0.5, 0.5)
        nn = np.arange(n)
        ph = np.exp(-2j * np.pi * bins[..., None] * nn / nf)
        peaks = np.sum(xm * ph, axis=-1)
    else:
        peaks = np.take_along_axis(spec, k[..., None], -1)[..., 0]
    return bins, peaks


def phase_frequency_correct(adc, radar: RadarConfig, frequency_bins, phase, cal_slope: float,
                            cal_sample_rate: float, cal_num_samples: int, interp_factor: int = 5,
                            reference=(0, 0), cal_first_sample_frequency: float | None = None):
    """Apply phase and frequency calibration to raw ADC.

    Channel ``i`` is multiplied by ``(p_ref / p_i) / |p_ref / p_i|`` and by
    ``exp(-j 2 pi (b_i - b_ref) / (I N_cal) (S / S_cal) (f_s,cal / f_s) n)``
    (derivation in the module docstring).

    Parameters
    ----------
    adc : array_like
        Complex ``[..., tx, rx, chirp, sample]``.
    radar : RadarConfig
        Waveform of ``adc``.
    frequency_bins : array_like
        ``[tx, rx]`` corner peak bins of the calibration (``interp_factor`` x
        interpolated FFT; 0- or 1-based alike).
    phase : array_like
        ``[tx, rx]`` complex peak values ``p_i``.
    cal_slope : float
        Calibration chirp slope ``S_cal`` [Hz/s].
    cal_sample_rate : float
        Calibration sample rate [Hz].
    cal_num_samples : int
        Calibration samples per chirp ``N_cal``.
    interp_factor : int, optional
        Zero-padding factor ``I`` (5).
    reference : tuple, optional
        ``(tx, rx)`` of the reference channel.
    cal_first_sample_frequency : float, optional
        ``f0,cal + S_cal t_adc,cal`` [Hz]; enables the exact delay model for
        waveforms that differ from the calibration's (module docstring).

    Returns
    -------
    numpy.ndarray
        Complex ``adc.shape`` (complex64 for complex64 input).
    """
    where = "phase_frequency_correct"
    x = _check_adc_tail(adc, radar, where)
    shape = (radar.num_tx, radar.num_rx)
    b = _finite(np.asarray(frequency_bins, dtype=np.float64), "frequency_bins", where)
    p = _finite(np.asarray(phase, dtype=np.complex128), "phase", where)
    for name, arr in (("frequency_bins", b), ("phase", p)):
        if arr.shape != shape:
            raise InputValueError(f"{where}: {name} must be [tx, rx] = {shape}, got {arr.shape}")
    if np.any(p == 0):
        raise InputValueError(f"{where}: phase holds zero peak values")
    if cal_slope == 0 or cal_sample_rate <= 0 or int(cal_num_samples) < 1 or int(interp_factor) < 1:
        raise InputValueError(f"{where}: cal_slope must be non-zero, cal_sample_rate, "
                              f"cal_num_samples and interp_factor positive")
    try:
        t0, r0 = (int(v) for v in reference)
    except (TypeError, ValueError):
        raise InputValueError(f"{where}: reference must be a (tx, rx) pair, got {reference!r}") \
            from None
    if not (0 <= t0 < shape[0] and 0 <= r0 < shape[1]):
        raise InputValueError(f"{where}: reference {reference} outside [tx, rx] = {shape}")
    db = b - b[t0, r0]                                                   # [tx, rx] fine bins
    pc = p[t0, r0] / p
    pc = pc / np.abs(pc)
    n = np.arange(radar.num_samples)
    # fine bins -> cycles per calibration sample -> delay -> cycles per sample here
    cycles = db / (int(interp_factor) * int(cal_num_samples)) * (radar.slope / cal_slope) \
        * (cal_sample_rate / radar.sample_rate)                           # [tx, rx]
    phase_n = cycles[..., None] * n                                      # [tx, rx, N] cycles
    if cal_first_sample_frequency is not None:
        dtau = db * cal_sample_rate / (int(interp_factor) * int(cal_num_samples) * cal_slope)
        f_first = radar.start_frequency + radar.slope * radar.adc_start_time
        phase_n = phase_n + ((f_first - float(cal_first_sample_frequency)) * dtau)[..., None]
    corr = pc[..., None] * np.exp(-2j * np.pi * phase_n)                 # [tx, rx, N]
    corr = corr[:, :, None, :].astype(x.dtype)
    return x * corr


def subtract_coupling(rfft, coupling):
    """Subtract measured Tx->Rx coupling from the first range bins of every chirp.

    Parameters
    ----------
    rfft : array_like
        Complex range spectrum ``[..., tx, rx, chirp, n_range]``.
    coupling : array_like
        Complex ``[tx, rx, n_bins]`` (``n_bins <= n_range``), in the same
        range-FFT convention (window, length, scale).

    Returns
    -------
    numpy.ndarray
        A new array: ``rfft[..., :n_bins] - coupling[:, :, None, :]``, other
        bins unchanged.
    """
    where = "subtract_coupling"
    x = _finite(rfft, "rfft", where)
    c = _finite(coupling, "coupling", where)
    if c.ndim != 3:
        raise InputValueError(f"{where}: coupling must be [tx, rx, n_bins], got {c.shape}")
    if x.ndim < 4 or x.shape[-4:-2] != c.shape[:2] or x.shape[-1] < c.shape[2]:
        raise InputValueError(f"{where}: rfft {x.shape} must be [..., tx={c.shape[0]}, "
                              f"rx={c.shape[1]}, chirp, n_range >= {c.shape[2]}]")
    out = np.array(x, dtype=np.result_type(x.dtype, np.complex64), copy=True)
    nb = c.shape[2]
    out[..., :nb] -= c[:, :, None, :].astype(out.dtype)
    return out


def estimate_coupling(rfft, n_bins: int):
    """Coupling estimate from an empty-scene range spectrum: chirp mean of the first bins.

    ``rfft`` complex ``[tx, rx, chirp, n_range]`` -> complex ``[tx, rx, n_bins]``.
    """
    x = _finite(rfft, "rfft", "estimate_coupling")
    if x.ndim != 4 or x.shape[-1] < int(n_bins):
        raise InputValueError(f"estimate_coupling: rfft must be [tx, rx, chirp, n_range >= "
                              f"{n_bins}], got {x.shape}")
    return x[..., : int(n_bins)].mean(axis=2)
