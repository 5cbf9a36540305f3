"""Radar signal processing: range / Doppler / angle FFTs, virtual array, calibration.

One stage per module:

=================  ===========================================================
``windows``        :func:`get_window` (unit coherent gain)
``range_fft``      :func:`range_fft` over samples
``doppler_fft``    :func:`doppler_fft` over chirp loops (+ = moving away)
``virtual_array``  :class:`VirtualArray`: TDM-MIMO grid, azimuth row, TDM phase
``angle_fft``      azimuth / elevation FFTs, spatial frequency -> angle
``imaging``        :func:`range_azimuth`, :func:`range_azimuth_elevation`,
                   :func:`range_doppler` (the public pipeline)
``rae``            :func:`rae_cube` (RAE power cube of a 2-D array, axes,
                   voxel positions), :func:`extruded_cube` (RA map extruded
                   over elevation)
``calibration``    phase / frequency correction, coupling subtraction
``polar``          :func:`polar_to_cartesian`
=================  ===========================================================
"""
from __future__ import annotations

from .angle_fft import (angle_fft, angles_from_spatial_frequency, azimuth_fft, elevation_fft,
                        spatial_frequencies)
from .calibration import (estimate_coupling, estimate_phase_frequency_calibration,
                          phase_frequency_correct, subtract_coupling)
from .doppler_fft import doppler_bins_hz, doppler_fft, doppler_velocities_m_s
from .imaging import check_adc, range_azimuth, range_azimuth_elevation, range_doppler
from .polar import polar_to_cartesian
from .range_fft import range_bins_m, range_fft, split_range_halves
from .rae import RAECube, check_elevation_aperture, extruded_cube, rae_cube
from .virtual_array import VirtualArray
from .windows import WINDOW_NAMES, get_window

__all__ = [
    "RAECube", "VirtualArray", "check_elevation_aperture", "extruded_cube", "rae_cube", "WINDOW_NAMES", "angle_fft", "angles_from_spatial_frequency",
    "azimuth_fft", "check_adc", "doppler_bins_hz", "doppler_fft", "doppler_velocities_m_s",
    "elevation_fft", "estimate_coupling", "estimate_phase_frequency_calibration",
    "get_window", "phase_frequency_correct", "polar_to_cartesian", "range_azimuth",
    "range_azimuth_elevation", "range_bins_m", "range_doppler", "range_fft",
    "spatial_frequencies", "split_range_halves", "subtract_coupling",
]
