"""TI DCA1000 raw captures (``adc_data.bin``, little-endian int16) -> :class:`Capture`.

Layouts (``layout=`` of :func:`read_dca1000` / :func:`decode_dca1000`); a
frame is always ``[chirp loop][Tx slot in TDM order][Rx][...]``:

==========  =================================================================
``pairs``   (default) groups of four ``[I(4k) I(4k+1) Q(4k) Q(4k+1)]``: two
            complex samples ONE sample period apart, groups FOUR periods
            apart (samples ``4k+2``, ``4k+3`` of the stream are not stored).
            ``radar.num_samples = N`` output samples need ``N/2`` groups per
            (chirp, Rx); the output is the signal rebuilt on a uniform grid
            at ``radar.sample_rate`` (= half the stored stream's rate),
            assuming its beat band is ``[0, radar.sample_rate)`` (positive
            ranges up to ``c fs / 2S``).  Output samples ``2k`` are the
            stored ``4k`` values exactly; ``2k+1`` are rebuilt (per DFT bin
            of the group sequence the two aliases ``nu/4`` and ``nu/4+pi/2``
            are separated using ``b/a = exp(j w)``; exact for block-periodic
            tones; for others the Hann-windowed spectrum error is below
            -35 dB, rising to -26 dB within 5 % of the band edge).
``ti``      TI's ``readDCA1000`` for xWR16xx/18xx 2-lane complex: groups
            ``[I(k) I(k+1) Q(k) Q(k+1)]`` of consecutive samples.
``iq``      plain interleaved ``I0 Q0 I1 Q1``.
``two_rx``  groups ``[I(rx a) I(rx b) Q(rx a) Q(rx b)]`` (the data README's
            wording): per chirp ``N`` groups for Rx (0, 1), then (2, 3), ...
``real``    real-only ADC: one int16 per real sample, ``N`` per (chirp,
            Rx).  Returned as the analytic signal (positive-frequency half
            of the DFT, doubled) at the same rate and length, so a target's
            range bin ``k < N/2`` and the range axis ``k c fs / (2 S N)`` are
            those of the real samples; bins ``>= N/2`` are empty.
==========  =================================================================

Facts checked on ``awr1843_dca1000/moving_target_500frames.bin`` (6144-byte
frames; ``scripts/dca1000_layout_evidence.py`` prints the full table):

* Within a group, fitting each of the four int16 positions to the mover's
  tone (beat 20..65 deg per position): ``p1/p0`` phase = 0.99 w + 0.5 deg,
  ``p2/p0`` = -89.3 deg flat, ``p3/p0`` = 0.99 w - 89.6 deg, amplitudes 1.00,
  residuals < 2 deg.  So ``p0 + j p2`` and ``p1 + j p3`` are I/Q samples one
  period apart; TI's consecutive pairs would need slope 2, real samples
  phases w, 2w, 3w, two Rx slope 0.  No AWR1843/DCA1000 setting is known to
  drop samples 4k+2, 4k+3, so the file is not a plain DCA1000 dump, but it
  is the only reading consistent with the data.
* A 6144-byte frame holds two 1536-int16 chirp sets ``[Tx][Rx][32 groups]``:
  the leakage bin is identical in both (phase resultant 1.000), and the
  mover's phase step set 0 -> set 1 equals set 1 -> next frame's set 0
  (resultant of the difference 0.72): equally spaced sets, not two loops
  0.2 ms apart.  Hence 1000 frames of 3 x 4 x 64 samples, 10 ms apart at the
  README's 20 ms per 6144 bytes, 1.25 Msps (stream 2.5 Msps, 128 sample
  periods = 51.2 us in the 53.2 us ADC window).
* Criteria, ``pairs`` vs ``ti``: image N/2 bins above the mover -45 vs
  -6 dB; moving energy in even range bins 0.39 vs 0.94 (TI's 128-sample
  chirps are two near-copies); leakage (< 15 cm) coherent over frames 0.99 vs
  0.61; track steps < 4 cm per 20 ms 100 % vs 90 %; one linear phase over
  the 8 azimuth elements 0.92 vs 0.62, Tx x Rx rank-1 share 1.00 vs 0.75.
  The range-bin width measured from the mover's Doppler phase steps against
  its range track (carrier wavelength only) is 4.49 cm vs the ``pairs``
  4.53 cm (coherence 0.75; a 5 Msps reading's 9.06 cm gives 0.05, TI 0.08).
  ``real`` (256 or 2 x 128 samples), ``iq``, ``two_rx`` and conjugated TI
  fail at least three criteria.
* The mover then lies at 0.34-1.04 m (median 0.85 m), nearer than the data
  README's "about 1.0-1.9 m", which matches TI's decode (0.72-2.08 m, median
  1.71 m).  No IQ conjugation: targets at positive beat frequency.  The
  static (frame-mean) share of the energy is 1.4 %: the mover dominates.
"""
from __future__ import annotations

import os

import numpy as np

from ..errors import CaptureFormatError, InputValueError
from ..radar.config import RadarConfig
from ..utils.memory import array_bytes, check_memory
from .capture import Capture

LAYOUTS = ("pairs", "ti", "iq", "two_rx", "real")
DEFAULT_LAYOUT = "pairs"
DEFAULT_FRAME_PERIOD = 0.02   # s per 6144-byte frame of the measured AWR1843 capture
_GROUP = {"pairs": 4, "ti": 4, "two_rx": 4, "iq": 2, "real": 1}   # int16 per group


def _check_layout(layout: str) -> str:
    if layout not in LAYOUTS:
        raise InputValueError(f"DCA1000 layout must be one of {', '.join(LAYOUTS)}; "
                              f"got {layout!r}")
    return layout


def default_radar(layout: str = DEFAULT_LAYOUT) -> RadarConfig:
    """AWR1843 of the measured capture as each layout reads a 6144-byte frame.

    ``pairs``: 64 samples at 1.25 Msps (stored stream 2.5 Msps); ``real``: 256
    real samples at 5 Msps (the only rate at which 256 fit the ADC window);
    others: 128 complex samples at 2.5 Msps.  One chirp loop, Tx order 0, 1, 2.
    """
    layout = _check_layout(layout)
    if layout == "pairs":
        return RadarConfig.awr1843(sample_rate=1.25e6, num_samples=64)
    if layout == "real":
        return RadarConfig.awr1843(sample_rate=5e6, num_samples=256)
    return RadarConfig.awr1843()


def default_frame_period(layout: str = DEFAULT_LAYOUT) -> float:
    """Frame period [s] of the measured capture under ``layout`` (two frames per 20 ms
    for ``pairs``, one otherwise)."""
    return DEFAULT_FRAME_PERIOD / 2 if _check_layout(layout) == "pairs" else DEFAULT_FRAME_PERIOD


def frame_bytes(radar: RadarConfig, layout: str = DEFAULT_LAYOUT) -> int:
    """Bytes of one frame: ``n_tx * n_rx * num_chirps * num_samples`` samples of 4 bytes
    (2 for ``real``)."""
    per_sample = 2 if _check_layout(layout) == "real" else 4
    return radar.num_tx * radar.num_rx * radar.num_chirps * radar.num_samples * per_sample


def _analytic(r: np.ndarray) -> np.ndarray:
    n = r.shape[-1]
    spec = np.fft.fft(r, axis=-1)
    spec[..., n // 2 + 1:] = 0
    spec[..., 1:(n + 1) // 2] *= 2
    return np.fft.ifft(spec, axis=-1)


def _rebuild_pairs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Samples at ``4k`` (``a``) and ``4k+1`` (``b``) -> uniform samples at ``2k`` spacing.

    Per DFT bin ``m`` of the group sequence (frequency ``nu = 2 pi m / K`` per
    group) the in-band candidates are ``w = nu/4`` and ``w + pi/2`` per stream
    sample; ``a = lo + hi`` and ``b = exp(j w) (lo + j hi)`` separate them.
    """
    K = a.shape[-1]
    A = np.fft.fft(a, axis=-1)
    B = np.fft.fft(b, axis=-1)
    w = np.pi * np.arange(K) / (2 * K)
    hi = (B * np.exp(-1j * w) - A) / (1j - 1)
    lo = A - hi
    return np.fft.ifft(np.concatenate([2 * lo, 2 * hi], axis=-1), axis=-1)


def decode_dca1000(raw: np.ndarray, layout: str = DEFAULT_LAYOUT,
                   num_samples: int | None = None, num_rx: int = 1) -> np.ndarray:
    """int16 stream -> complex64 samples.

    With ``num_samples`` the stream is cut into (chirp, Rx) blocks and the result is
    ``[n_blocks, num_samples]`` in stream order (``num_rx`` Rx per chirp, needed by
    ``two_rx`` only).  ``ti`` and ``iq`` also accept ``num_samples=None`` and
    return the flat stream ``[M / 2]``.
    """
    layout = _check_layout(layout)
    raw = np.asarray(raw)
    if raw.ndim != 1:
        raise InputValueError(f"decode_dca1000: raw must be a 1-D int16 stream, got shape "
                              f"{raw.shape}")
    g = raw.astype(np.float64)
    n = g.size
    if num_samples is None:
        if layout not in ("ti", "iq"):
            raise InputValueError(f"decode_dca1000: layout {layout!r} needs num_samples")
        block = _GROUP[layout]
    else:
        num_samples, num_rx = int(num_samples), int(num_rx)
        if num_samples < 1 or num_rx < 1:
            raise InputValueError("decode_dca1000: num_samples and num_rx must be >= 1")
        if layout == "pairs" and num_samples % 2:
            raise InputValueError(f"decode_dca1000: layout 'pairs' needs an even num_samples, "
                                  f"got {num_samples}")
        if layout == "two_rx" and num_rx % 2:
            raise InputValueError(f"decode_dca1000: layout 'two_rx' needs an even num_rx, "
                                  f"got {num_rx}")
        per_sample = 1 if layout == "real" else 2
        block = num_samples * per_sample * (num_rx if layout == "two_rx" else 1)
    if n % block:
        raise CaptureFormatError(f"decode_dca1000: {n} int16 values are not a whole number of "
                                 f"{layout!r} blocks of {block}")
    if layout == "ti":
        q = g.reshape(-1, 4)
        z = np.stack([q[:, 0] + 1j * q[:, 2], q[:, 1] + 1j * q[:, 3]], axis=1)
    elif layout == "iq":
        q = g.reshape(-1, 2)
        z = q[:, 0] + 1j * q[:, 1]
    elif layout == "real":
        z = _analytic(g.reshape(-1, num_samples))
    elif layout == "two_rx":
        q = g.reshape(-1, num_rx // 2, num_samples, 4)            # [chirp, rx pair, n, 4]
        z = np.stack([q[..., 0] + 1j * q[..., 2], q[..., 1] + 1j * q[..., 3]], axis=2)
    else:                                                          # pairs
        q = g.reshape(-1, num_samples // 2, 4)
        z = _rebuild_pairs(q[..., 0] + 1j * q[..., 2], q[..., 1] + 1j * q[..., 3])
    z = z.astype(np.complex64)
    return z.reshape(-1) if num_samples is None else z.reshape(-1, num_samples)


def _frame_count(path, radar: RadarConfig, layout: str, num_frames) -> tuple:
    """``(frames to read, frames in the file)``, the file size and the memory
    the read takes checked."""
    fb = frame_bytes(radar, layout)
    desc = (f"{radar.name} layout {radar.num_tx} tx x {radar.num_rx} rx x "
            f"{radar.num_chirps} chirp x {radar.num_samples} samples ({layout!r} DCA1000 layout)")
    size = os.path.getsize(path)
    if size == 0:
        raise CaptureFormatError(f"{path}: file is empty (one frame of the {desc} is "
                                 f"{fb} bytes)")
    if size % fb:
        raise CaptureFormatError(f"{path}: size {size} bytes is not a multiple of one frame "
                                 f"({fb} bytes) of the {desc}")
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
                                     f"{available} frames of the {desc}")
    n_int16 = count * fb // 2
    if n_int16 % _GROUP[layout]:
        raise CaptureFormatError(f"{path}: {count} frame(s) of the {desc} are not a whole "
                                 f"number of DCA1000 groups of {_GROUP[layout]} int16 values")
    # the int16 samples, the decoded complex samples, the frames and Capture's checks
    check_memory(2 * n_int16 + 3 * array_bytes((count, *radar.adc_shape), 8),
                 f"{path}: reading {count} frame(s)")
    return count, available


def read_dca1000(path, radar: RadarConfig | None = None, num_frames: int | None = None,
                 frame_period: float | None = None, layout: str = DEFAULT_LAYOUT) -> Capture:
    """Read a DCA1000 ``.bin`` capture.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.bin`` file.
    radar : RadarConfig, optional
        Waveform and layout of the returned frames; default
        :func:`default_radar` of ``layout`` (AWR1843, 3 Tx x 4 Rx, 1 loop;
        ``pairs``: 64 samples at 1.25 Msps).  ``radar.num_chirps`` loops per
        frame, Tx fired in ``radar.tdm_order``.
    num_frames : int, optional
        Read only the first frames (default: all).
    frame_period : float, optional
        Frame period for ``metadata`` [s]; default with the default radar
        :func:`default_frame_period` (0.01 s ``pairs``, 0.02 s otherwise),
        else ``None``.
    layout : str, optional
        Byte layout, one of :data:`LAYOUTS` (module docstring); ``"ti"`` is
        TI's documented ``readDCA1000`` reading.

    Returns
    -------
    Capture
        complex64 frames ``[n_frames, n_tx, n_rx, num_chirps, num_samples]``
        in ADC units (int16 counts), indexed by Tx index (slot ``s`` of a loop
        is Tx ``radar.tdm_order[s]``).  ``metadata["iq_conjugated"]`` is False
        (targets at positive beat frequency); ``metadata["layout"]`` names the
        layout.

    Raises
    ------
    CaptureFormatError
        An empty file or a size that is not a whole number of frames (the
        message names the file and the frame size).
    """
    layout = _check_layout(layout)
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: no such file")
    default = radar is None
    radar = default_radar(layout) if default else radar
    if frame_period is None and default:
        frame_period = default_frame_period(layout)
    if layout == "pairs" and radar.num_samples % 2:
        raise CaptureFormatError(f"{path}: the 'pairs' layout stores samples in pairs; "
                                 f"num_samples must be even, got {radar.num_samples}")
    if layout == "two_rx" and radar.num_rx % 2:
        raise CaptureFormatError(f"{path}: the 'two_rx' layout pairs Rx; num_rx must be "
                                 f"even, got {radar.num_rx}")
    count, available = _frame_count(path, radar, layout, num_frames)
    n_int16 = count * frame_bytes(radar, layout) // 2
    raw = np.fromfile(path, dtype="<i2", count=n_int16)
    if raw.size != n_int16:
        raise CaptureFormatError(f"{path}: read {raw.size} int16 values, expected {n_int16}")
    z = decode_dca1000(raw, layout, radar.num_samples, radar.num_rx)
    z = z.reshape(count, radar.num_chirps, radar.num_tx, radar.num_rx, radar.num_samples)
    frames = np.empty((count,) + radar.adc_shape, dtype=np.complex64)
    for slot, tx in enumerate(radar.tdm_order):
        frames[:, tx] = z[:, :, slot].transpose(0, 2, 1, 3)       # [frame, rx, loop, sample]
    metadata = {"file": os.path.basename(path), "format": "dca1000", "layout": layout,
                "frame_period": None if frame_period is None else float(frame_period),
                "iq_conjugated": False, "frames_in_file": int(available)}
    if layout == "pairs":
        metadata["stored_sample_rate"] = 2 * radar.sample_rate
        metadata["rebuilt_samples"] = "odd output samples (stream samples 4k+2)"
    elif layout == "real":
        metadata["real_samples"] = True
    return Capture(frames, radar, metadata, source=path)
