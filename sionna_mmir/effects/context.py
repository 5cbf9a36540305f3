"""``EffectContext``: the radar, data shape and time axes the effects need.

Every effect acts on ADC tensors of shape ``[F, T, R, C, N]`` (frames, Tx,
Rx, chirp loops, fast-time samples), the layout of
:class:`~sionna_mmir.captures.Capture.frames`.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import InputValueError
from ..radar.config import SPEED_OF_LIGHT, RadarConfig

IF_BAND_START = -0.1      # complex IF band [-0.1 f_s, 0.9 f_s): see band_frequencies


@dataclasses.dataclass
class EffectContext:
    """Radar and axes of one capture.

    The chip grouping defaults to the TI MMWCAS cascade (4 chips of 3 Tx and
    4 Rx, in array index order) for a 12 x 16 radar and one chip otherwise.

    Parameters
    ----------
    radar : RadarConfig
        :class:`~sionna_mmir.radar.RadarConfig`
    num_frames : int, optional
        ``F``
    frame_period : float, optional
        seconds between frames (0 when unknown / one frame)
    tx_chip : numpy.ndarray, optional
        ``[T]`` int, chip (LO / receive path group) of each Tx
    rx_chip : numpy.ndarray, optional
        ``[R]`` int, chip of each Rx
    basis : SceneBasis, optional
        The base model split per object
        (:class:`~sionna_mmir.effects.scene_basis.SceneBasis`), for the
        scene-side effects; ``None`` without one.
    """

    radar: RadarConfig
    num_frames: int = 1
    frame_period: float = 0.0
    tx_chip: np.ndarray = None
    rx_chip: np.ndarray = None
    basis: object = None

    def __post_init__(self):
        T, R = self.radar.num_tx, self.radar.num_rx
        if self.num_frames < 1:
            raise InputValueError(f"EffectContext: num_frames must be >= 1, got {self.num_frames}")
        if not np.isfinite(self.frame_period) or self.frame_period < 0:
            raise InputValueError(f"EffectContext: frame_period must be >= 0 s, got {self.frame_period}")
        cascade = (T, R) == (12, 16)
        if self.tx_chip is None:
            self.tx_chip = np.arange(T) // 3 if cascade else np.zeros(T, int)
        if self.rx_chip is None:
            self.rx_chip = np.arange(R) // 4 if cascade else np.zeros(R, int)
        self.tx_chip = np.asarray(self.tx_chip, dtype=np.int64).reshape(T)
        self.rx_chip = np.asarray(self.rx_chip, dtype=np.int64).reshape(R)

    @classmethod
    def from_capture(cls, capture, **kw) -> "EffectContext":
        """Context of a :class:`~sionna_mmir.captures.Capture` (frame period from metadata)."""
        period = float(capture.metadata.get("frame_period", 0.0) or 0.0)
        return cls(radar=capture.radar, num_frames=capture.frames.shape[0],
                   frame_period=period, **kw)

    # ------------------------------------------------------------- shapes
    @property
    def shape(self) -> tuple:
        """``(F, T, R, C, N)``."""
        return (self.num_frames,) + tuple(self.radar.adc_shape)

    @property
    def num_chips(self) -> int:
        return int(max(self.tx_chip.max(), self.rx_chip.max())) + 1

    def check(self, x, name: str) -> np.ndarray:
        """``x`` as complex128 ``[F, T, R, C, N]``; clear error on shape / NaN."""
        arr = np.asarray(x)
        if arr.ndim == 4:
            arr = arr[None]
        if arr.shape != self.shape:
            raise InputValueError(f"{name}: shape {arr.shape} does not match the radar's "
                                  f"[frame, tx, rx, chirp, sample] = {self.shape}")
        if arr.size == 0:
            raise InputValueError(f"{name}: empty array")
        if not np.all(np.isfinite(arr)):
            raise InputValueError(f"{name}: holds NaN or Inf")
        return arr.astype(np.complex128)

    # --------------------------------------------------------------- axes
    @property
    def fast_time(self) -> np.ndarray:
        """``t_k`` from ramp start, ``[N]`` [s]."""
        return self.radar.sample_times()

    @property
    def slow_time(self) -> np.ndarray:
        """Ramp start of every (frame, tx, loop), ``[F, T, C]`` [s]."""
        frames = np.arange(self.num_frames) * self.frame_period
        return frames[:, None, None] + self.radar.chirp_start_times()[None]

    @property
    def beat_frequencies(self) -> np.ndarray:
        """Frequency of each unitary-DFT bin along samples, ``[N]`` [Hz] (``np.fft`` order)."""
        return np.fft.fftfreq(self.radar.num_samples, d=1.0 / self.radar.sample_rate)

    @property
    def bin_ranges(self) -> np.ndarray:
        """Monostatic range of each DFT bin, ``[N]`` [m] (negative half negative)."""
        return self.beat_frequencies * SPEED_OF_LIGHT / (2.0 * self.radar.slope)

    def band_frequencies(self, band_start: float = IF_BAND_START, n: int | None = None):
        """Physical beat frequency of every range bin, ``[n]`` [Hz] (``np.fft`` order).

        ``n`` is the DFT length (default ``N``, the samples per chirp).
        Complex samples only fix a bin's frequency modulo ``f_s``; the bins are
        mapped into the band ``[band_start f_s, (band_start + 1) f_s)`` (up-chirp;
        mirrored for a down-chirp, where targets have negative beat
        frequencies).  ``band_start = -0.5`` is ``np.fft.fftfreq``; the default
        ``-0.1`` keeps near-DC leakage and images on the negative side and every
        target up to ``0.9 max_range`` on the positive side (about the usable
        complex IF band).
        """
        fs = self.radar.sample_rate
        sgn = 1.0 if self.radar.slope > 0 else -1.0
        f = sgn * np.fft.fftfreq(n or self.radar.num_samples, d=1.0 / fs)
        lo = band_start * fs
        return sgn * (lo + np.mod(f - lo, fs))

    @property
    def band_ranges(self) -> np.ndarray:
        """Range of each DFT bin in the IF band of :meth:`band_frequencies`, ``[N]`` [m]:
        ``0 .. 0.9 max_range`` for targets, small negative values for the bins
        just below DC (leakage, images)."""
        return self.band_frequencies() * SPEED_OF_LIGHT / (2.0 * self.radar.slope)

    def delay_of_range(self, r):
        """Round-trip delay [s] of a monostatic range ``r`` [m]."""
        return 2.0 * np.asarray(r) / SPEED_OF_LIGHT
