"""Range-azimuth, range-azimuth-elevation and range-Doppler maps from raw ADC.

The TDM-MIMO FFT pipeline of the paper:

1. range FFT over samples (:mod:`.range_fft`),
2. Doppler handling over chirp loops:

   * ``doppler='mean'``: coherent mean over chirps (the zero-Doppler bin,
     static scenes as in the paper; no TDM compensation, no window), or
   * ``doppler='noncoherent'``: Doppler FFT (:mod:`.doppler_fft`), TDM
     Tx-slot phase compensation per Doppler bin (:mod:`.virtual_array`),
     angle FFT, then the magnitudes summed over Doppler bins;

3. scatter onto the virtual grid (:class:`.virtual_array.VirtualArray`),
4. angle FFT(s) (:mod:`.angle_fft`), magnitude.

Scale: all windows have unit coherent gain and the FFTs are unnormalised, so a
static unit-amplitude point target on bin centres gives
``num_samples * n_elements`` (mean mode).  Axes: ``ranges_m`` from
:func:`.range_fft.range_bins_m`; angles ``arcsin(clip(v f_d / f_c))``
(:mod:`.angle_fft`), i.e. derived from direction sines.
"""
from __future__ import annotations

import numpy as np

from ..errors import ConfigError, InputValueError
from ..radar.config import RadarConfig
from .angle_fft import (angle_fft, angle_fft_2d, angles_from_spatial_frequency,
                        spatial_frequencies)
from .doppler_fft import doppler_bins_hz, doppler_fft
from .range_fft import range_fft
from .virtual_array import VirtualArray

_DOPPLER_MODES = ("mean", "noncoherent")


def check_adc(adc, radar: RadarConfig, where: str) -> np.ndarray:
    """Validate one frame of ADC ``[tx, rx, chirp, sample]`` and return it complex.

    Wrong shape (not ``radar.adc_shape``) or NaN / Inf raise
    :class:`~sionna_mmir.errors.InputValueError` naming ``where``.
    """
    x = np.asarray(adc)
    if x.shape != tuple(radar.adc_shape):
        raise InputValueError(
            f"{where}: adc must be [tx, rx, chirp, sample] = {tuple(radar.adc_shape)} for "
            f"radar '{radar.name}', got shape {x.shape}")
    if not np.iscomplexobj(x):
        x = x.astype(np.complex64 if x.dtype != np.float64 else np.complex128)
    if not (np.isfinite(x.real).all() and np.isfinite(x.imag).all()):
        raise InputValueError(f"{where}: adc holds NaN or Inf samples")
    return x


def _check_mode(doppler, where):
    if doppler not in _DOPPLER_MODES:
        raise ConfigError(f"{where}: doppler must be one of {_DOPPLER_MODES}, got {doppler!r}")


def _virtual_array(radar, virtual_array):
    return VirtualArray(radar) if virtual_array is None else virtual_array


def range_azimuth(adc, radar: RadarConfig, *, range_window="hann", azimuth_window="hann",
                  doppler_window="hann", n_range: int | None = None, n_azimuth: int = 128,
                  doppler: str = "mean", tdm_compensation: bool = True,
                  virtual_array: VirtualArray | None = None):
    """Range-azimuth magnitude map of one frame.

    Only the virtual-array row holding the most distinct azimuth positions is
    used (cascade: 86 elements at elevation 0).

    Parameters
    ----------
    adc : array_like
        Complex ``[tx, rx, chirp, sample]`` (= ``radar.adc_shape``).
    radar : RadarConfig
        Waveform and layout.
    range_window : str, optional
        Window over samples (unit coherent gain).
    azimuth_window : str, optional
        Window over the azimuth row's filled extent.
    doppler_window : str, optional
        Window over chirps (``'noncoherent'`` only).
    n_range : int, optional
        Range FFT length, default ``num_samples``.
    n_azimuth : int, optional
        Azimuth FFT length (128).
    doppler : {"mean", "noncoherent"}, optional
        ``'mean'`` (coherent chirp mean, zero Doppler) or ``'noncoherent'``
        (Doppler FFT + TDM compensation, magnitudes summed over Doppler bins).
    tdm_compensation : bool, optional
        Apply the Tx-slot Doppler phase correction (``'noncoherent'`` only).
    virtual_array : VirtualArray, optional
        A prebuilt :class:`.VirtualArray`.

    Returns
    -------
    ra : numpy.ndarray
        float ``[n_range, n_azimuth]`` magnitudes (float32 for complex64
        input).
    ranges_m : numpy.ndarray
        ``[n_range]`` [m].
    azimuths_rad : numpy.ndarray
        ``[n_azimuth]`` [rad], increasing (positive = left, ``+y``).
    """
    _check_mode(doppler, "range_azimuth")
    x = check_adc(adc, radar, "range_azimuth")
    va = _virtual_array(radar, virtual_array)
    if doppler == "mean":
        rfft, ranges = range_fft(x.mean(axis=2), radar, range_window, n_range)   # [tx, rx, R]
        row = va.azimuth_row_channels(rfft)                                       # [n_az, R]
        spec = angle_fft(row, 0, azimuth_window, n_azimuth, va.row_support)       # [A, R]
        ra = np.abs(spec).T
    else:
        rfft, ranges = range_fft(x, radar, range_window, n_range)                # [tx, rx, L, R]
        dspec, _ = doppler_fft(rfft, radar, doppler_window)                       # [tx, rx, D, R]
        if tdm_compensation:
            dspec = va.tdm_compensate(dspec, doppler_bins_hz(radar), doppler_axis=2)
        row = va.azimuth_row_channels(dspec)                                      # [n_az, D, R]
        spec = angle_fft(row, 0, azimuth_window, n_azimuth, va.row_support)       # [A, D, R]
        ra = np.abs(spec).sum(axis=1).T
    az = angles_from_spatial_frequency(spatial_frequencies(n_azimuth), radar)
    return np.ascontiguousarray(ra), ranges, az


def mean_range_azimuth(frames, radar: RadarConfig, **ra_kwargs) -> np.ndarray:
    """Non-coherent mean of the frames' range-azimuth maps.

    ``frames``: complex ``[F, T, R, C, N]`` (or one frame ``[T, R, C, N]``);
    ``ra_kwargs`` as :func:`range_azimuth`.  Returns float
    ``[n_range, n_azimuth]``."""
    frames = np.asarray(frames)
    if frames.ndim == 4:
        frames = frames[None]
    return np.mean([range_azimuth(f, radar, **ra_kwargs)[0] for f in frames], axis=0)


def range_azimuth_elevation(adc, radar: RadarConfig, *, range_window="hann",
                            azimuth_window="hann", elevation_window="hann",
                            doppler_window="hann", n_range: int | None = None,
                            n_azimuth: int = 128, n_elevation: int = 128,
                            doppler: str = "mean", tdm_compensation: bool = True,
                            virtual_array: VirtualArray | None = None):
    """Range-azimuth-elevation magnitude cube of one frame (2-D angle FFT).

    Arguments as :func:`range_azimuth`, plus ``elevation_window`` (over the
    grid's elevation extent) and ``n_elevation``.  The whole virtual grid
    ``[n_el, n_az]`` is used (empty cells zero, duplicates averaged).

    Returns ``(rae, ranges_m, azimuths_rad, elevations_rad)`` with ``rae``
    float ``[n_range, n_azimuth, n_elevation]``.  The angle axes are derived
    from spatial frequencies: ``azimuths_rad = arcsin(v f_d / f_c)`` where
    ``v`` measures ``sin(az) cos(el)``, and ``elevations_rad =
    arcsin(w f_d / f_c)`` with ``w`` measuring ``sin(el)``.  A target at true
    ``(az, el)`` therefore peaks at ``(arcsin(sin az cos el), el)``; only at
    zero elevation is the azimuth axis the true azimuth.  Only arrays with a
    filled elevation aperture (e.g. :meth:`RadarConfig.dense`) resolve
    elevation; the cascade's 4 sparse rows give strong elevation grating
    lobes.
    """
    _check_mode(doppler, "range_azimuth_elevation")
    x = check_adc(adc, radar, "range_azimuth_elevation")
    va = _virtual_array(radar, virtual_array)
    az_support = (0, va.n_az)
    el_support = (0, va.n_el)
    if doppler == "mean":
        rfft, ranges = range_fft(x.mean(axis=2), radar, range_window, n_range)   # [tx, rx, R]
        grid = np.ascontiguousarray(va.to_grid(rfft).transpose(2, 1, 0))         # [R, A0, E0]
        spec = angle_fft_2d(grid, (1, 2), (azimuth_window, elevation_window),
                            (n_azimuth, n_elevation), (az_support, el_support))  # [R, A, E]
        rae = np.abs(spec)
        az = angles_from_spatial_frequency(spatial_frequencies(n_azimuth), radar)
        el = angles_from_spatial_frequency(spatial_frequencies(n_elevation), radar)
        return rae, ranges, az, el
    else:
        rfft, ranges = range_fft(x, radar, range_window, n_range)
        dspec, _ = doppler_fft(rfft, radar, doppler_window)                       # [tx, rx, D, R]
        if tdm_compensation:
            dspec = va.tdm_compensate(dspec, doppler_bins_hz(radar), doppler_axis=2)
        mag = None
        for d in range(dspec.shape[2]):                                           # bounded memory
            grid = va.to_grid(dspec[:, :, d])
            spec = angle_fft(grid, 1, azimuth_window, n_azimuth, az_support)
            spec = np.abs(angle_fft(spec, 0, elevation_window, n_elevation, el_support))
            mag = spec if mag is None else mag + spec
    rae = np.ascontiguousarray(mag.transpose(2, 1, 0))
    az = angles_from_spatial_frequency(spatial_frequencies(n_azimuth), radar)
    el = angles_from_spatial_frequency(spatial_frequencies(n_elevation), radar)
    return rae, ranges, az, el


def range_doppler(adc, radar: RadarConfig, *, range_window="hann", doppler_window="hann",
                  n_range: int | None = None, n_doppler: int | None = None):
    """Range-Doppler magnitude map, summed non-coherently over all channels.

    Parameters
    ----------
    adc : array_like
        Complex ``[tx, rx, chirp, sample]``.
    radar : RadarConfig
        Waveform and layout.
    range_window, doppler_window : str, optional
        Windows over samples and chirps (unit coherent gain).
    n_range : int, optional
        Range FFT length (default ``num_samples``).
    n_doppler : int, optional
        Doppler FFT length (default ``num_chirps``).

    Returns
    -------
    rd : numpy.ndarray
        float ``[n_range, n_doppler]`` = ``sum_{tx,rx}
        |DopplerFFT(RangeFFT(adc))|``.
    ranges_m : numpy.ndarray
        ``[n_range]`` [m].
    velocities_m_s : numpy.ndarray
        ``[n_doppler]`` [m/s] in fftshift order, positive = moving away
        (:mod:`.doppler_fft`).
    """
    x = check_adc(adc, radar, "range_doppler")
    rfft, ranges = range_fft(x, radar, range_window, n_range)
    dspec, vel = doppler_fft(rfft, radar, doppler_window, n_doppler)
    rd = np.abs(dspec).sum(axis=(0, 1)).T
    return np.ascontiguousarray(rd), ranges, vel
