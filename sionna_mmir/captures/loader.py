"""``load_capture``: open any supported capture by what it holds, then by its name.

A file that starts with a known signature is read by the reader of its
content, whatever its extension (an HDF5 capture renamed ``.bin`` is still
an HDF5 capture, not raw samples); see :func:`sniff`.  Files without a
signature (raw ``.bin`` samples, MATLAB v4) go by their extension:

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

from ..errors import CaptureFormatError, FrameIndexError
from ..radar.config import RadarConfig
from .capture import Capture

SUPPORTED = ("sionna_mmir HDF5 (.h5, .hdf5)", "TI MMWCAS calibration (.mat)",
             "ColoRadar run folder", "ColoRadar frame_N.bin", "DCA1000 raw (.bin)",
             "OpenRadar example (.npy)")


#: signatures: HDF5 at offset 0 or a power-of-two user block >= 512 bytes, NumPy, MATLAB
HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
NPY_MAGIC = b"\x93NUMPY"
MAT_TEXT = b"MATLAB "
_EXTENSIONS = {"hdf5": (".h5", ".hdf5"), "mat": (".mat",), "npy": (".npy",)}


def sniff(path) -> str | None:
    """What a file holds by its first bytes: ``"hdf5"``, ``"mat"`` (MATLAB
    v5 or v7.3, whose header text starts ``MATLAB``), ``"npy"``, or None.

    A MATLAB v7.3 file is HDF5 with a 512-byte user block; it is ``"mat"``.
    """
    with open(path, "rb") as f:
        head = f.read(8)
        if head.startswith(MAT_TEXT):
            return "mat"
        if head == HDF5_MAGIC:
            return "hdf5"
        if head.startswith(NPY_MAGIC):
            return "npy"
        size, offset = os.fstat(f.fileno()).st_size, 512
        while offset + 8 <= min(size, 1 << 20):           # HDF5 after a user block
            f.seek(offset)
            if f.read(8) == HDF5_MAGIC:
                return "hdf5"
            offset *= 2
    return None


def _kind(p: pathlib.Path) -> str:
    """The reader for file ``p``: its content's, else its extension's."""
    if p.stat().st_size == 0:
        raise CaptureFormatError(f"{p}: file is empty")
    content = sniff(p)
    ext = p.suffix.lower()
    if content is not None:
        return content
    for kind, exts in _EXTENSIONS.items():
        if ext in exts:
            return kind
    if ext == ".bin":
        return "bin"
    raise CaptureFormatError(f"{p}: unknown capture format {ext or '(no extension)'!r}; "
                             f"supported: {'; '.join(SUPPORTED)}")


def _select(cap: Capture, frame, path) -> Capture:
    if frame is None:
        return cap
    n = cap.num_frames
    try:
        idx = int(frame)
    except (TypeError, ValueError):
        raise FrameIndexError(f"{path}: frame must be an integer, got {frame!r}") from None
    if not -n <= idx < n:
        raise FrameIndexError(f"{path}: frame {idx} requested, the capture has {n} frame(s) "
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
        An unknown extension without a known signature (the message lists
        the supported formats), or a file its reader refuses.
    FrameIndexError
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
    kind = _kind(p)
    if kind == "hdf5":
        cap = Capture.load(p)
    elif kind == "mat":
        from .ti_mat import read_ti_mat

        cap = read_ti_mat(p)
    elif kind == "npy":
        from .openradar import read_openradar_npy

        cap = read_openradar_npy(p)
    elif frame_index_from_name(p) is not None:
        if radar is None:
            radar, _ = coloradar_radar(p.parent, calib_dir, sensor)
        cap = read_coloradar_frame(p, radar)
        if frame is not None and frame == frame_index_from_name(p):
            frame = None                     # "frame N" of frame_N.bin is this file
    else:
        from .dca1000 import read_dca1000

        cap = read_dca1000(p, radar=radar)
    return _select(cap, frame, os.fspath(p))
