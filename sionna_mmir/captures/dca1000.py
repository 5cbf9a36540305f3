"""TI DCA1000 raw captures (``adc_data.bin``, xWR16xx/18xx 2-lane complex) -> :class:`Capture`.

File layout: little-endian int16, complex samples packed in groups of four
values ``[I(k) I(k+1) Q(k) Q(k+1)]`` (two consecutive complex values of the
stream, TI's ``readDCA1000`` convention).  The complex stream is, per frame,
``[chirp loop][Tx slot in TDM order][Rx 0..3][sample]``.

Facts checked on ``awr1843_dca1000/moving_target_500frames.bin`` (AWR1843,
3 Tx x 4 Rx x 128 samples, 500 frames), decoded as above:

* IQ sign: the moving target stays in the lower (positive-frequency) half of
  the range FFT, bins ~14..46 (0.6-2.1 m, median 1.7 m); no conjugation.
* The layout is *not* fully consistent with the data, and is kept because it
  is TI's documented one (``readDCA1000.m``, OpenRadar) and comes closest to
  the README's "about 1.0-1.9 m".  But every tone has an image ``N/2`` bins
  higher (4-15 dB down), and power gathers in even FFT bins.  Looking inside
  the groups of four, the two complex values ``a = p0 + j p2`` and ``b = p1 + j p3`` carry the same
  signal with equal amplitude and a phase ``b/a`` proportional to the beat
  frequency through zero, i.e. ``b`` is ``a`` delayed by 1/4 of a group
  period, not by 1/2 (two consecutive samples, TI) nor a range-independent
  antenna phase (two Rx).  Read instead as 128 groups per (Tx, Rx pair) block,
  the ``a`` values form clean single-tone chirps (1-tap prediction residual
  6 % vs 64 % for the TI sequence) with the target at twice the beat
  frequency (1.1-4.2 m).  Which one is physical cannot be settled from this
  file alone.
"""
from __future__ import annotations

import os

import numpy as np

from ..errors import CaptureFormatError, InputValueError
from ..radar.config import RadarConfig
from .capture import Capture

DEFAULT_FRAME_PERIOD = 0.02   # s, the measured AWR1843 capture


def frame_bytes(radar: RadarConfig) -> int:
    """Bytes of one frame: ``n_tx * n_rx * num_chirps * num_samples * 2 (I, Q) * 2``."""
    return radar.num_tx * radar.num_rx * radar.num_chirps * radar.num_samples * 4


def decode_dca1000(raw: np.ndarray) -> np.ndarray:
    """int16 stream ``[4 M]`` in DCA1000 complex layout -> complex64 ``[2 M]``."""
    g = np.asarray(raw, dtype=np.int16).reshape(-1, 4).astype(np.float32)
    z = np.empty((g.shape[0], 2), dtype=np.complex64)
    z[:, 0] = g[:, 0] + 1j * g[:, 2]
    z[:, 1] = g[:, 1] + 1j * g[:, 3]
    return z.reshape(-1)


def read_dca1000(path, radar: RadarConfig | None = None, num_frames: int | None = None,
                 frame_period: float | None = None) -> Capture:
    """Read a DCA1000 ``.bin`` capture.

    ================  ========================================================
    ``path``          the ``.bin`` file
    ``radar``         waveform and layout; default :meth:`RadarConfig.awr1843`
                      (3 Tx x 4 Rx, 1 loop, 128 samples).  ``radar.num_chirps``
                      loops per frame, Tx fired in ``radar.tdm_order``
    ``num_frames``    read only the first frames (default: all)
    ``frame_period``  [s] for ``metadata``; default 0.02 s with the default
                      radar (the measured capture), else ``None``
    ================  ========================================================

    Returns a :class:`Capture` with complex64 frames ``[n_frames, n_tx, n_rx,
    num_chirps, num_samples]`` in ADC units (int16 counts), indexed by Tx
    index (slot ``s`` of a loop is Tx ``radar.tdm_order[s]``).
    ``metadata["iq_conjugated"]`` is False (the stored IQ already has targets
    at positive beat frequency).

    An empty file or a size that is not a whole number of frames raises
    :class:`CaptureFormatError` naming the file and the frame size.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: no such file")
    default = radar is None
    radar = RadarConfig.awr1843() if default else radar
    if frame_period is None and default:
        frame_period = DEFAULT_FRAME_PERIOD
    fb = frame_bytes(radar)
    layout = (f"{radar.name} layout {radar.num_tx} tx x {radar.num_rx} rx x "
              f"{radar.num_chirps} chirp x {radar.num_samples} samples")
    size = os.path.getsize(path)
    if size == 0:
        raise CaptureFormatError(f"{path}: file is empty (one frame of the {layout} is "
                                 f"{fb} bytes)")
    if size % fb:
        raise CaptureFormatError(f"{path}: size {size} bytes is not a multiple of one frame "
                                 f"({fb} bytes) of the {layout}")
    available = size // fb
    if num_frames is None:
        count = available
    else:
        if int(num_frames) != num_frames or int(num_frames) < 1:
            raise InputValueError(f"read_dca1000: num_frames must be a positive integer, "
                                  f"got {num_frames!r}")
        count = int(num_frames)
        if count > available:
            raise CaptureFormatError(f"{path}: {count} frames requested, the file holds "
                                     f"{available} frames of the {layout}")
    n_int16 = count * fb // 2
    if n_int16 % 4:
        raise CaptureFormatError(f"{path}: {count} frame(s) of the {layout} are not a whole "
                                 f"number of DCA1000 groups of four int16 values")
    raw = np.fromfile(path, dtype="<i2", count=n_int16)
    if raw.size != n_int16:
        raise CaptureFormatError(f"{path}: read {raw.size} int16 values, expected {n_int16}")
    z = decode_dca1000(raw).reshape(count, radar.num_chirps, radar.num_tx, radar.num_rx,
                                    radar.num_samples)
    frames = np.empty((count,) + radar.adc_shape, dtype=np.complex64)
    for slot, tx in enumerate(radar.tdm_order):
        frames[:, tx] = z[:, :, slot].transpose(0, 2, 1, 3)       # [frame, rx, loop, sample]
    metadata = {"file": os.path.basename(path), "format": "dca1000",
                "frame_period": None if frame_period is None else float(frame_period),
                "iq_conjugated": False, "frames_in_file": int(available)}
    return Capture(frames, radar, metadata, source=path)
