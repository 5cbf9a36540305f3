"""OpenRadar example arrays (``.npy``) -> :class:`Capture`.

The OpenRadar examples store TI ADC samples as complex128 whose real and
imaginary parts hold *unsigned* 16-bit values; a part ``>= 32768`` is a
negative int16 (subtract 65536).

* ``openradar_doppler_example_1.npy``: ``[128 chirps, 8 virtual, 128 samples]``
  from 2 Tx (TDM) x 4 Rx; virtual index ``v = tx * 4 + rx``.  Checked on the
  data: the phase steps between adjacent Rx at the strongest static target are
  the same for ``v = 0..3`` and ``v = 4..7`` (within a few degrees), as for a
  tx-major ordering, and not for an rx-major one.
* ``openradar_simple_frame_1.npy``: ``[128 chirps, 128 samples]``, one channel.

IQ sign: the Tx-Rx leakage shows at small *positive* beat frequencies (bins 1-3
well above bins 125-127), so the stored IQ follows the package convention;
no conjugation.

Waveform (OpenRadar's example configuration): start 77.4201 GHz, 60 MHz/us,
2.5 Msps, 128 samples, idle 30 us, ramp end 62 us.  The ADC start time is not
given; 6 us is assumed (any value up to 10.8 us fits the 51.2 us ADC window in
the ramp).  Layout: Tx 0 at 0, Tx 1 at 4 lambda/2 in azimuth, Rx 0..3 at
0..3 lambda/2 (lambda/2 at 76.8 GHz, as the other TI boards here).
"""
from __future__ import annotations

import os

import numpy as np

from ..errors import CaptureFormatError
from ..radar.config import RadarConfig
from .capture import Capture

WAVEFORM = dict(start_frequency=77.4201e9, slope=60e12, sample_rate=2.5e6, num_samples=128,
                idle_time=30e-6, adc_start_time=6e-6, ramp_end_time=62e-6)
TX_2 = [(0, 0), (4, 0)]
RX_4 = [(0, 0), (1, 0), (2, 0), (3, 0)]


def unsigned_to_signed(x: np.ndarray) -> np.ndarray:
    """complex with uint16-valued parts -> complex128 with int16-valued parts."""
    re = np.asarray(x.real, dtype=np.float64).copy()
    im = np.asarray(x.imag, dtype=np.float64).copy()
    re[re >= 32768] -= 65536
    im[im >= 32768] -= 65536
    return re + 1j * im


def openradar_radar(num_tx: int, num_rx: int, num_chirps: int) -> RadarConfig:
    """RadarConfig of the OpenRadar examples (``num_tx`` 1 or 2, ``num_rx`` 1 or 4)."""
    tx = TX_2[:num_tx]
    rx = RX_4[:num_rx]
    return RadarConfig._from_layout(tx, rx, 76.8e9, num_chirps=num_chirps, tdm_order=None,
                                    name=f"openradar_{num_tx}tx{num_rx}rx", **WAVEFORM)


def check_npy_size(path) -> None:
    """Compare a ``.npy`` file's declared array with the file size and the
    available memory before reading it (a header is cheap to read)."""
    from ..utils.memory import array_bytes, check_memory, format_bytes

    try:
        with open(path, "rb") as f:
            fmt = np.lib.format
            version = fmt.read_magic(f)
            header = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
            shape, _, dtype = header(f)
            offset = f.tell()
            size = os.fstat(f.fileno()).st_size
    except (ValueError, OSError, EOFError) as e:
        raise CaptureFormatError(f"{path}: not a readable .npy array ({e})") from None
    declared = array_bytes(shape, dtype.itemsize)
    if dtype.hasobject:
        raise CaptureFormatError(f"{path}: holds Python objects, not numbers")
    if offset + declared > size:
        raise CaptureFormatError(f"{path}: declares {shape} {dtype} ({format_bytes(declared)}) "
                                 f"but holds {format_bytes(size - offset)} of data (truncated?)")
    # the array, its real and imaginary parts as float64 and the signed copy
    check_memory(declared + 5 * array_bytes(shape, 16), f"{path}: reading its array")


def read_openradar_npy(path) -> Capture:
    """Read an OpenRadar example array.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.npy`` file: integers in ``[0, 65535]`` (unsigned 16-bit
        stored in a complex array), shape ``[chirp, 8, 128]`` or ``[chirp,
        128]``.

    Returns
    -------
    Capture
        Frames (complex64, ADC counts): ``[1, 2 tx, 4 rx, chirp, 128]`` with
        ``v = tx*4+rx`` for a ``[chirp, 8, 128]`` file, ``[1, 1 tx, 1 rx,
        chirp, 128]`` for a ``[chirp, 128]`` file.

    Raises
    ------
    FileNotFoundError
        No such file.
    CaptureFormatError
        Other shapes or values.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: no such file")
    check_npy_size(path)
    try:
        x = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as e:        # EOFError: an empty file
        raise CaptureFormatError(f"{path}: not a readable .npy array ({e})") from None
    if not np.issubdtype(x.dtype, np.number):
        raise CaptureFormatError(f"{path}: dtype {x.dtype} is not numeric")
    parts = np.stack([np.real(x), np.imag(x)]).astype(np.float64)
    if not np.all(np.isfinite(parts)):
        raise CaptureFormatError(f"{path}: array holds NaN or Inf")
    if parts.size and (parts.min() < 0 or parts.max() > 65535 or np.any(parts != np.round(parts))):
        raise CaptureFormatError(f"{path}: values are not unsigned 16-bit integers "
                                 f"(range {parts.min()}..{parts.max()})")
    y = unsigned_to_signed(x)
    if y.ndim == 3 and y.shape[1] == 8 and y.shape[2] == WAVEFORM["num_samples"]:
        n_chirps = y.shape[0]
        adc = y.reshape(n_chirps, 2, 4, y.shape[2]).transpose(1, 2, 0, 3)   # [tx, rx, chirp, N]
        radar = openradar_radar(2, 4, n_chirps)
    elif y.ndim == 2 and y.shape[1] == WAVEFORM["num_samples"]:
        adc = y[None, None]
        radar = openradar_radar(1, 1, y.shape[0])
    else:
        raise CaptureFormatError(
            f"{path}: array shape {x.shape} is not an OpenRadar example "
            f"([chirp, 8 virtual, 128 samples] or [chirp, 128 samples])")
    metadata = {"file": os.path.basename(path), "format": "openradar_npy",
                "frame_period": None, "iq_conjugated": False, "adc_start_time_assumed": True}
    if radar.num_tx == 2:
        metadata["virtual_index"] = "tx * 4 + rx"
    return Capture(adc.astype(np.complex64), radar, metadata, source=path)
