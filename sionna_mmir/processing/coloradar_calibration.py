"""ColoRadar's measured calibration applied to a capture, from its calib folder.

Wires the readers of :mod:`sionna_mmir.captures.coloradar_calib` to the
corrections of :mod:`sionna_mmir.processing.calibration`:

1. phase / frequency correction of the raw ADC from
   ``cascade/phase_frequency_calib.txt`` (cascade only; the single chip has
   none), with ``interp_factor = 1`` by default because the stored bins read
   as plain 256-point bins (corner at 3.04 m, as documented; see
   ``PhaseFrequencyCalib.corner_range``);
2. coupling subtraction in the range-FFT domain from ``coupling_calib.txt``,
   on the first ``num_range_bins`` bins of every chirp's *unwindowed*
   ``num_samples``-point range FFT (ColoRadar's convention is not documented
   in the files; rectangular window is our assumption, stated here).
"""
from __future__ import annotations

import os

import numpy as np

from ..errors import InputValueError
from ..radar.config import RadarConfig
from .calibration import phase_frequency_correct, subtract_coupling
from .range_fft import range_fft


def coloradar_phase_frequency_correct(adc, radar: RadarConfig, calib_dir, interp_factor: int = 1):
    """Phase/frequency-correct cascade ADC ``[tx, rx, chirp, sample]`` (ColoRadar order)."""
    from ..captures.coloradar_calib import read_phase_frequency_calib

    path = os.path.join(os.fspath(calib_dir), "cascade", "phase_frequency_calib.txt")
    cal = read_phase_frequency_calib(path)
    if cal.phase.shape != (radar.num_tx, radar.num_rx):
        raise InputValueError(f"{path}: calibration is {cal.phase.shape} [tx, rx] but the radar "
                              f"has {radar.num_tx} x {radar.num_rx}")
    return phase_frequency_correct(adc, radar, cal.frequency_bins, cal.phase, cal.slope,
                                   cal.sample_rate, cal.num_samples, interp_factor=interp_factor)


def coloradar_range_fft(adc, radar: RadarConfig, calib_dir, sensor: str = "cascade",
                        phase_frequency: bool = True, interp_factor: int = 1):
    """Calibrated range spectrum ``[tx, rx, chirp, num_samples]`` (rectangular window).

    Applies the phase/frequency correction (cascade, optional) and subtracts
    the measured coupling from the first bins.
    """
    from ..captures.coloradar_calib import read_coupling_calib

    x = np.asarray(adc)
    if sensor == "cascade" and phase_frequency:
        x = coloradar_phase_frequency_correct(x, radar, calib_dir, interp_factor)
    path = os.path.join(os.fspath(calib_dir), sensor, "coupling_calib.txt")
    coupling = read_coupling_calib(path)
    spec, _ = range_fft(x, radar, window="rect")
    return subtract_coupling(spec, coupling)
