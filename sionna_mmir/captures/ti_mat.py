"""TI MMWCAS phase/frequency-calibration ``.mat`` files -> :class:`Capture`.

TI's cascade calibration stores, per (Rx, Tx), the 5x zero-padded range FFT of
the loop-averaged ADC, windowed by ``w / rms(w)`` with
``w[n] = 0.5 - 0.5 cos(2 pi n / (N + 1))``, ``n = 1..N`` (never zero)::

    calibResult.Rx_fft   complex [5N, 16, 12] = [fine bin, device Rx 1..16,
                         Tx in enable order 12, 11, ..., 1]

so ``ifft(Rx_fft, axis=0)[:N] / (w / rms(w))`` is the raw chirp-averaged ADC
(the remaining ``4N`` samples of the inverse FFT are ~1e-13 of the signal).

Facts checked on ``corner_4m7_slope79.mat`` / ``corner_6m1_slope79.mat``:

* IQ sign: the corner sits at fine bin 399 of 1280 (4.73 m), the Tx-Rx leakage
  at small positive bins; the stored IQ already follows the package
  convention (target at positive beat frequency), no conjugation.
* ``RangeMat`` / ``PeakValMat`` / ``AngleMat`` (12 x 16) are ``[Tx in enable
  order, device Rx]``: ``PeakValMat[e, r] == Rx_fft[RangeMat[e, r] - 1, r, e]``
  exactly, and ``AngleMat = angle(PeakValMat)`` in degrees.
* ``TxMismatch`` (3 x 4) flattened column-major (MATLAB ``(:)``) is the enable
  order, referenced to Tx 1: it equals, within 1 degree, the circular mean over
  Rx of ``angle(PeakValMat[e, :] / PeakValMat[Tx 1, :])``.  ``RxMismatch``
  (1 x 16, device Rx) is the circular mean over Tx of the phase relative to
  Rx 1.
"""
from __future__ import annotations

import os

import numpy as np

from ..errors import CaptureFormatError
from ..radar.config import RadarConfig
from .capture import Capture

NUM_TX, NUM_RX, INTERP = 12, 16, 5
#: the variables read (others are skipped unread)
WANTED = ("calibResult", "params")


def calibration_window(n: int) -> np.ndarray:
    """TI's calibration window ``w / rms(w)``, ``w[n] = 0.5 - 0.5 cos(2 pi n/(N+1))``, ``[N]``."""
    k = np.arange(1, n + 1)
    w = 0.5 - 0.5 * np.cos(2.0 * np.pi * k / (n + 1))
    return w / np.sqrt(np.mean(w ** 2))


def adc_from_rx_fft(rx_fft: np.ndarray) -> np.ndarray:
    """Invert TI's calibration spectrum: complex128 ``[tx (device order), rx, N]``.

    ``rx_fft`` is complex ``[5N, rx, tx in enable order]``; returns
    ``ifft(rx_fft)[:N] / (w / rms(w))`` re-indexed so Tx ``k`` is device Tx
    ``k + 1`` (the enable order is reversed).  Raises ``ValueError`` when the
    inverse FFT beyond sample ``N`` is not ~0 (not a 5x zero-padded FFT).
    """
    x = np.fft.ifft(np.asarray(rx_fft, dtype=np.complex128), axis=0)
    n = x.shape[0] // INTERP
    head, tail = np.abs(x[:n]).max(), np.abs(x[n:]).max()
    if head == 0 or tail > 1e-6 * head:
        raise ValueError(f"is not a {INTERP}x zero-padded FFT (inverse FFT beyond sample {n} "
                         f"reaches {tail:.3g}, signal {head:.3g})")
    adc = x[:n] / calibration_window(n)[:, None, None]                 # [N, rx, tx_enable]
    return np.ascontiguousarray(adc[:, :, ::-1].transpose(2, 1, 0))


def _loadmat(path) -> dict:
    """``calibResult`` and ``params`` of the file (other variables are skipped),
    and ``__names__``: every variable's name."""
    import scipy.io

    try:
        mat = scipy.io.loadmat(path, variable_names=WANTED)
        mat["__names__"] = [name for name, _, _ in scipy.io.whosmat(path)]
    except Exception as e:  # scipy raises ValueError / MatReadError / TypeError
        raise CaptureFormatError(f"{path}: not a readable MATLAB .mat file ({e})") from None
    return mat


def check_declared(path) -> None:
    """Check the arrays the file declares before any is read (see :mod:`.mat5`).

    Raises :class:`CaptureFormatError` for a wrongly shaped ``Rx_fft``, a
    MATLAB v7.3 file, or arrays declaring more than ``MAX_RATIO`` times the
    file's size (a decompression bomb), and :class:`ResourceError` for
    arrays that do not fit in the available memory.
    """
    from ..utils.memory import check_memory, format_bytes
    from .mat5 import MAX_RATIO, MatHeaderError, declared_arrays

    try:
        arrays = declared_arrays(path, wanted=WANTED)
    except (MatHeaderError, OSError) as e:
        raise CaptureFormatError(f"{path}: not a readable MATLAB .mat file ({e})") from None
    if arrays is None:
        with open(path, "rb") as f:
            if f.read(10) == b"MATLAB 7.3":
                raise CaptureFormatError(f"{path}: MATLAB v7.3 (HDF5) .mat files are not read; "
                                         "save it with save(..., '-v7')")
        return                                        # v4: no compression, file-sized
    found = {a.name: a for a in arrays}
    rx = found.get("calibResult.Rx_fft")
    if rx is not None:
        _check_rx_shape(path, rx.shape, rx.is_complex)
    total, size = sum(a.nbytes for a in arrays), os.path.getsize(path)
    if total > MAX_RATIO * size + (1 << 20):
        raise CaptureFormatError(f"{path}: declares {format_bytes(total)} of arrays in a "
                                 f"{format_bytes(size)} file (more than {MAX_RATIO} times its "
                                 "size): not a measured calibration")
    work = 4 * rx.nbytes if rx is not None else 0     # inverse FFT, magnitudes, ADC
    check_memory(total + work, f"{path}: reading calibResult")


def _check_rx_shape(path, shape, is_complex: bool) -> None:
    if not is_complex:
        raise CaptureFormatError(f"{path}: calibResult.Rx_fft is real, expected complex")
    shape = tuple(shape)
    if len(shape) != 3 or shape[1:] != (NUM_RX, NUM_TX) or shape[0] % INTERP or shape[0] == 0:
        raise CaptureFormatError(f"{path}: calibResult.Rx_fft has shape {shape}, expected "
                                 f"(5N, {NUM_RX}, {NUM_TX})")


def _fields(path, mat, name):
    if name not in mat:
        raise CaptureFormatError(f"{path}: no variable {name!r} (found "
                                 f"{sorted(mat.get('__names__', []))})")
    v = mat[name]
    if not isinstance(v, np.ndarray) or v.dtype.names is None or v.size != 1:
        raise CaptureFormatError(f"{path}: {name!r} is not a MATLAB struct")
    s = v.reshape(-1)[0]
    return {f: np.asarray(s[f]) for f in v.dtype.names}


def _scalar(path, params, key):
    if key not in params:
        raise CaptureFormatError(f"{path}: params.{key} missing")
    try:
        val = float(np.asarray(params[key], dtype=np.float64).reshape(-1)[0])
    except (TypeError, ValueError, IndexError):
        raise CaptureFormatError(f"{path}: params.{key} is not a number") from None
    if not np.isfinite(val) or val <= 0:
        raise CaptureFormatError(f"{path}: params.{key} = {val} is not a positive number")
    return val


def _extras(path, cr: dict) -> dict:
    """The optional calibration matrices of ``calibResult``, in device Tx order."""
    extras = {}
    for key, dtype in (("RangeMat", np.int32), ("PeakValMat", np.complex128),
                       ("AngleMat", np.float64)):
        if key in cr:
            v = cr[key]
            if v.shape != (NUM_TX, NUM_RX):
                raise CaptureFormatError(f"{path}: calibResult.{key} has shape {v.shape}, "
                                         f"expected ({NUM_TX}, {NUM_RX})")
            extras[key] = np.ascontiguousarray(v[::-1].astype(dtype))
    if "RxMismatch" in cr:
        v = cr["RxMismatch"]
        if v.size != NUM_RX:
            raise CaptureFormatError(f"{path}: calibResult.RxMismatch has {v.size} values, "
                                     f"expected {NUM_RX}")
        extras["RxMismatch"] = v.reshape(-1).astype(np.float64)
    if "TxMismatch" in cr:
        v = cr["TxMismatch"]
        if v.size != NUM_TX:
            raise CaptureFormatError(f"{path}: calibResult.TxMismatch has {v.size} values, "
                                     f"expected {NUM_TX}")
        extras["TxMismatch"] = np.ascontiguousarray(
            v.reshape(-1, order="F")[::-1].astype(np.float64))
    return extras


def read_ti_mat(path) -> Capture:
    """Read a TI MMWCAS calibration ``.mat`` file.

    Re-indexing: the file's Tx axis (``Rx_fft`` axis 2 and the first axis of
    ``RangeMat``/``PeakValMat``/``AngleMat``) is the enable order 12..1; it is
    reversed, so index ``k`` is device Tx ``k + 1``.  ``TxMismatch`` (3 x 4) is
    flattened column-major (enable order) then reversed; ``RxMismatch`` is
    flattened.  Optional matrices that are absent are left out.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.mat`` file.

    Returns
    -------
    Capture
        One frame.  ``frames``: complex64 ``[1, 12, 16, 1, N]`` (N = 256), the
        raw chirp-averaged ADC, indexed ``[device Tx 1..12, device Rx 1..16,
        1, sample]`` like :meth:`RadarConfig.mmwcas`.  ``radar``:
        ``RadarConfig.mmwcas(num_chirps=1, slope=params.Slope_MHzperus * 1e12,
        sample_rate=params.Sampling_Rate_sps, num_samples=N)``.  ``extras``:
        ``RangeMat`` int32 ``[tx, rx]`` (1-based fine bins of the 5N FFT),
        ``PeakValMat`` complex128 ``[tx, rx]``, ``AngleMat`` float64 ``[tx,
        rx]`` [deg], ``RxMismatch`` float64 ``[16]`` [deg], ``TxMismatch``
        float64 ``[12]`` [deg], all in device order (``Rx_fft`` itself is not
        kept: it is ``fft(adc * w / rms(w), 5N)``).  ``metadata``: ``file``,
        ``format="ti_mat"``, ``chirps_averaged=True``, ``frame_period=None``,
        ``iq_conjugated=False``.

    Raises
    ------
    CaptureFormatError
        Missing ``calibResult`` / ``Rx_fft`` / ``params``, a non-complex or
        wrongly shaped ``Rx_fft``, or an ``Rx_fft`` that is not a 5x
        zero-padded FFT, a MATLAB v7.3 file, or arrays declaring far more
        than the file holds (the message names the file); checked on the
        declared headers before anything is read where possible.
    ResourceError
        Arrays that do not fit in the available memory.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: no such file")
    check_declared(path)
    mat = _loadmat(path)
    cr = _fields(path, mat, "calibResult")
    params = _fields(path, mat, "params")
    if "Rx_fft" not in cr:
        raise CaptureFormatError(f"{path}: calibResult has no field 'Rx_fft' "
                                 f"(fields {sorted(cr)})")
    X = cr["Rx_fft"]
    if not np.iscomplexobj(X):
        raise CaptureFormatError(f"{path}: calibResult.Rx_fft is {X.dtype}, expected complex")
    _check_rx_shape(path, X.shape, True)
    if not np.all(np.isfinite(X)):
        raise CaptureFormatError(f"{path}: calibResult.Rx_fft holds NaN or Inf")
    n = X.shape[0] // INTERP
    try:
        adc = adc_from_rx_fft(X)[:, :, None, :]                        # [tx_dev, rx, 1, N]
    except ValueError as e:
        raise CaptureFormatError(f"{path}: calibResult.Rx_fft {e}") from None

    slope = _scalar(path, params, "Slope_MHzperus") * 1e12
    fs = _scalar(path, params, "Sampling_Rate_sps")
    radar = RadarConfig.mmwcas(num_chirps=1, slope=slope, sample_rate=fs, num_samples=n)

    extras = _extras(path, cr)
    metadata = {"file": os.path.basename(path), "format": "ti_mat", "chirps_averaged": True,
                "frame_period": None, "iq_conjugated": False,
                "interp_factor": INTERP, "tx_order_in_file": "enable order 12..1 (reversed)"}
    return Capture(adc, radar, metadata, source=path, extras=extras)
