"""Radar captures: the Capture container and readers for real formats.

``Capture``
    ADC frames + RadarConfig + metadata, HDF5 I/O
``load_capture``
    open any supported file / folder by its kind
``read_ti_mat``
    TI MMWCAS calibration ``.mat``
``read_dca1000``
    DCA1000 ``.bin`` (AWR1843 by default)
``read_coloradar_frame``
    ColoRadar ``frame_N.bin``
``read_coloradar_run``
    ColoRadar run folder
``read_openradar_npy``
    OpenRadar example ``.npy``
``read_coloradar_config``
    ColoRadar ``waveform_cfg`` + ``antenna_cfg``
``read_coupling_calib``
    ColoRadar ``coupling_calib.txt``
``read_phase_frequency_calib``
    ColoRadar ``phase_frequency_calib.txt``

All readers return ADC in the package convention: ``[tx, rx, chirp, sample]``
by the radar's Tx/Rx index, a target at range ``R`` at positive beat
frequency ``S 2R / c``.
"""
from .capture import Capture
from .coloradar import read_coloradar_frame, read_coloradar_run
from .coloradar_calib import (PhaseFrequencyCalib, read_coloradar_config, read_coupling_calib,
                              read_phase_frequency_calib)
from .dca1000 import read_dca1000
from .loader import load_capture
from .openradar import read_openradar_npy
from .ti_mat import read_ti_mat

__all__ = ["Capture", "PhaseFrequencyCalib", "load_capture", "read_coloradar_config",
           "read_coloradar_frame", "read_coloradar_run", "read_coupling_calib", "read_dca1000",
           "read_openradar_npy", "read_phase_frequency_calib", "read_ti_mat"]
