"""``load_capture``: open any supported capture by what its path is.

==========================  ==================================================
path                        reader
==========================  ==================================================
``*.h5`` / ``*.hdf5``       :meth:`Capture.load` (the package's own format)
``*.mat``                   :func:`~.ti_mat.read_ti_mat` (TI MMWCAS calibration)
a directory                 :func:`~.coloradar.read_coloradar_run`
``frame_N.bin``             :func:`~.coloradar.read_coloradar_frame`
any other ``*.bin``         :func:`~.dca1000.read_dca1000` (default AWR1843)
``*.npy``                   :func:`~.openradar.read_openradar_npy`
==========================  ==================================================
"""
from __future__ import annotations

import os
import pathlib

from ..errors import CaptureFormatError
from ..radar.config import RadarConfig
from .capture import Capture

SUPPORTED = ("sionna_mmir HDF5 (.h5, .hdf5)", "TI MMWCAS calibration (.mat)",
             "ColoRadar run folder", "ColoRadar frame_N.bin", "DCA1000 raw (.bin)",
             "OpenRadar example (.npy)")


def _select(cap: Capture, frame, path) -> Capture:
    if frame is None:
        return cap
    n = cap.num_frames
    try:
        idx = int(frame)
    except (TypeError, ValueError):
        raise IndexError(f"{path}: frame must be an integer, got {frame!r}") from None
    if not -n <= idx < n:
        raise IndexError(f"{path}: frame {idx} requested, the capture has {n} frame(s) "
                         f"(valid 0..{n - 1})")
    return cap.frame(idx)


def load_capture(path, frame: int | None = None, *, radar: RadarConfig | None = None,
                 calib_dir=None, sensor: str = "cascade") -> Capture:
    """Load a capture from ``path`` (see the module table for the dispatch).

    Parameters
    ----------
    path : str or os.PathLike
        File or ColoRadar run folder.
    frame : int, optional
        Frame index: for a run folder the ``N`` of ``frame_N.bin`` (default
        0); for multi-frame files the frame to keep (default: all frames).
    radar : RadarConfig, optional
        Radar for ``.bin`` files (DCA1000 default ``RadarConfig.awr1843()``;
        ColoRadar frames default to the calibration found in ``calib_dir`` or
        upward).
    calib_dir : str or os.PathLike, optional
        ColoRadar ``calib`` folder.
    sensor : {"cascade", "single_chip"}, optional
        ColoRadar sensor.

    Returns
    -------
    Capture

    Raises
    ------
    FileNotFoundError
        A missing path.
    CaptureFormatError
        An unknown extension (the message lists the supported formats).
    IndexError
        A frame index out of range.
    """
    from .coloradar import (coloradar_radar, find_frame_file, frame_index_from_name,
                            read_coloradar_frame, read_coloradar_run)

    p = pathlib.Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such file or folder")
    if p.is_dir():
        index = 0 if frame is None else frame
        if radar is not None:                 # explicit radar: no calibration lookup
            return read_coloradar_frame(find_frame_file(p, index, sensor), radar)
        return read_coloradar_run(p, frame=index, calib_dir=calib_dir, sensor=sensor)
    ext = p.suffix.lower()
    if ext in (".h5", ".hdf5"):
        cap = Capture.load(p)
    elif ext == ".mat":
        from .ti_mat import read_ti_mat

        cap = read_ti_mat(p)
    elif ext == ".bin" and frame_index_from_name(p) is not None:
        if radar is None:
            radar, _ = coloradar_radar(p.parent, calib_dir, sensor)
        cap = read_coloradar_frame(p, radar)
        if frame is not None and frame == frame_index_from_name(p):
            frame = None                     # "frame N" of frame_N.bin is this file
    elif ext == ".bin":
        from .dca1000 import read_dca1000

        cap = read_dca1000(p, radar=radar)
    elif ext == ".npy":
        from .openradar import read_openradar_npy

        cap = read_openradar_npy(p)
    else:
        raise CaptureFormatError(f"{p}: unknown capture format {ext or '(no extension)'!r}; "
                                 f"supported: {'; '.join(SUPPORTED)}")
    return _select(cap, frame, os.fspath(p))
