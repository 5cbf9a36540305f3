"""FMCW TDM-MIMO radar configuration (waveform, antenna layout, pose).

Radar frame
-----------
All element positions are metres in the *radar frame*:

* ``+x`` is boresight (the direction the antennas face),
* ``+y`` is to the radar's left, the azimuth axis of the arrays,
* ``+z`` is up, the elevation axis.

Azimuth ``phi = atan2(y, x)`` is positive towards ``+y``; elevation
``theta = asin(z / r)`` is positive upwards.  This matches Sionna RT, whose
antennas radiate along their local ``+x`` axis and whose orientations are
``(yaw, pitch, roll)`` rotations about ``z``, ``y`` and ``x``.

Layouts read from TI / ColoRadar tables (positions in half-wavelengths at a
design frequency, "azimuth" and "elevation" columns) map the azimuth column to
``+y`` and the elevation column to ``+z``.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np

from ..errors import ConfigError
from . import layouts

SPEED_OF_LIGHT = 299_792_458.0


def _as_positions(name: str, value) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] < 1:
        raise ConfigError(f"RadarConfig.{name} must have shape [n, 3] (metres), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"RadarConfig.{name} holds NaN or Inf")
    return arr


@dataclasses.dataclass
class RadarConfig:
    """An FMCW TDM-MIMO radar: waveform, antennas and pose.

    All quantities are SI.  ADC arrays are always indexed ``[tx, rx, chirp,
    sample]`` by the Tx/Rx index of ``tx_positions`` / ``rx_positions``;
    ``tdm_order`` only sets timing.

    Parameters
    ----------
    start_frequency : float
        Chirp start frequency ``f_0`` [Hz].
    slope : float
        Chirp slope ``S`` [Hz/s]; negative for a down-chirp, ``|S| >= MIN_SLOPE``.
    sample_rate : float
        Complex ADC sample rate ``f_s`` [Hz].
    num_samples : int
        ADC samples per chirp ``N``.
    num_chirps : int
        Chirp loops per frame (each loop fires every Tx once).
    idle_time : float
        Idle time before each ramp [s].
    adc_start_time : float
        ADC start measured from ramp start [s].
    ramp_end_time : float
        Ramp duration [s].
    tx_positions : numpy.ndarray
        ``[n_tx, 3]`` Tx phase centres, radar frame [m].
    rx_positions : numpy.ndarray
        ``[n_rx, 3]`` Rx phase centres, radar frame [m].
    tdm_order : tuple of int, optional
        Tx indices in firing order within one loop.
    position : numpy.ndarray, optional
        ``(3,)`` radar origin in the scene [m].
    orientation : numpy.ndarray, optional
        ``(yaw, pitch, roll)`` [rad], Sionna convention.
    name : str, optional
        A label.
    design_frequency : float, optional
        Frequency the layout's lambda/2 refers to [Hz].
    notes : tuple of str, optional
        Provenance notes (e.g. repaired config values).
    """

    #: smallest chirp slope magnitude accepted [Hz/s] (1 MHz/ms)
    MIN_SLOPE = 1e9

    start_frequency: float
    slope: float
    sample_rate: float
    num_samples: int
    num_chirps: int
    idle_time: float
    adc_start_time: float
    ramp_end_time: float
    tx_positions: np.ndarray
    rx_positions: np.ndarray
    tdm_order: tuple = None
    position: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    orientation: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    name: str = "radar"
    design_frequency: float = 76.8e9
    notes: tuple = ()

    def __post_init__(self):
        self.notes = tuple(str(n) for n in (self.notes or ()))
        for key in ("start_frequency", "slope", "sample_rate", "idle_time",
                    "adc_start_time", "ramp_end_time", "design_frequency"):
            v = getattr(self, key)
            try:
                v = float(v)
            except (TypeError, ValueError):
                raise ConfigError(f"RadarConfig.{key} must be a number, got {v!r}") from None
            if not math.isfinite(v):
                raise ConfigError(f"RadarConfig.{key} is not finite ({v})")
            setattr(self, key, v)
        for key in ("num_samples", "num_chirps"):
            v = getattr(self, key)
            if int(v) != v or int(v) < 1:
                raise ConfigError(f"RadarConfig.{key} must be a positive integer, got {v!r}")
            setattr(self, key, int(v))
        if self.start_frequency <= 0 or self.sample_rate <= 0 or self.design_frequency <= 0:
            raise ConfigError("RadarConfig: start_frequency, sample_rate and "
                              "design_frequency must be positive")
        self._check_slope()
        if self.idle_time < 0 or self.adc_start_time < 0:
            raise ConfigError("RadarConfig: idle_time and adc_start_time must be >= 0")
        adc_end = self.adc_start_time + self.num_samples / self.sample_rate
        if self.ramp_end_time < adc_end * (1 - 1e-6):
            raise ConfigError(
                f"RadarConfig: the ADC window ends at {adc_end * 1e6:.3f} us "
                f"(adc_start_time + num_samples / sample_rate) after the ramp ends at "
                f"{self.ramp_end_time * 1e6:.3f} us")
        self.tx_positions = _as_positions("tx_positions", self.tx_positions)
        self.rx_positions = _as_positions("rx_positions", self.rx_positions)
        if self.tdm_order is None:
            self.tdm_order = tuple(range(self.num_tx))
        order = tuple(int(i) for i in self.tdm_order)
        if sorted(order) != list(range(self.num_tx)):
            raise ConfigError(f"RadarConfig.tdm_order must be a permutation of "
                              f"0..{self.num_tx - 1}, got {order}")
        self.tdm_order = order
        self.position = np.asarray(self.position, dtype=np.float64).reshape(3)
        self.orientation = np.asarray(self.orientation, dtype=np.float64).reshape(3)
        if not (np.all(np.isfinite(self.position)) and np.all(np.isfinite(self.orientation))):
            raise ConfigError("RadarConfig: position / orientation hold NaN or Inf")

    def _check_slope(self) -> None:
        """A chirp: ``|slope| >= MIN_SLOPE`` and a sweep that stays above 0 Hz.

        Down-chirps (``slope < 0``) are supported (range processing mirrors
        their bins), so the sign is free; a magnitude below ``MIN_SLOPE``
        (1 MHz/ms) is no FMCW chirp, usually a slope given in MHz/us instead
        of Hz/s.
        """
        if abs(self.slope) < self.MIN_SLOPE:
            raise ConfigError(f"RadarConfig.slope = {self.slope:g} Hz/s: its magnitude must be "
                              f">= {self.MIN_SLOPE:g} Hz/s (the slope is in Hz/s, e.g. 79e12 "
                              f"for 79 MHz/us; negative for a down-chirp)")
        end = self.start_frequency + self.slope * self.ramp_end_time
        if end <= 0:
            raise ConfigError(f"RadarConfig: the chirp sweeps below 0 Hz (start_frequency "
                              f"{self.start_frequency:g} Hz + slope x ramp_end_time = {end:g} Hz)")

    # ------------------------------------------------------------------ sizes
    @property
    def num_tx(self) -> int:
        return int(self.tx_positions.shape[0])

    @property
    def num_rx(self) -> int:
        return int(self.rx_positions.shape[0])

    @property
    def adc_shape(self) -> tuple:
        """``(n_tx, n_rx, num_chirps, num_samples)``."""
        return (self.num_tx, self.num_rx, self.num_chirps, self.num_samples)

    # ------------------------------------------------------------- waveform
    @property
    def wavelength(self) -> float:
        """Wavelength at the centre of the sampled band [m]."""
        return SPEED_OF_LIGHT / self.center_frequency

    @property
    def center_frequency(self) -> float:
        """Frequency at the middle of the ADC window [Hz]."""
        t_mid = self.adc_start_time + 0.5 * self.num_samples / self.sample_rate
        return self.start_frequency + self.slope * t_mid

    @property
    def bandwidth(self) -> float:
        """Swept bandwidth seen by the ADC, ``|S| N / f_s`` [Hz]."""
        return abs(self.slope) * self.num_samples / self.sample_rate

    @property
    def range_resolution(self) -> float:
        """Range bin width ``c / 2B`` [m]."""
        return SPEED_OF_LIGHT / (2.0 * self.bandwidth)

    @property
    def max_range(self) -> float:
        """Largest unambiguous range with complex sampling, ``f_s c / 2|S|`` [m]."""
        return self.sample_rate * SPEED_OF_LIGHT / (2.0 * abs(self.slope))

    @property
    def chirp_period(self) -> float:
        """Time between consecutive chirp starts, ``idle + ramp_end`` [s]."""
        return self.idle_time + self.ramp_end_time

    @property
    def loop_period(self) -> float:
        """Time between chirps of the same Tx, ``n_tx * chirp_period`` [s]."""
        return self.num_tx * self.chirp_period

    @property
    def max_velocity(self) -> float:
        """Largest unambiguous radial velocity, ``lambda / (4 T_loop)`` [m/s]."""
        return self.wavelength / (4.0 * self.loop_period)

    @property
    def velocity_resolution(self) -> float:
        """Radial-velocity bin width ``lambda / (2 n_chirps T_loop)`` [m/s]."""
        return self.wavelength / (2.0 * self.num_chirps * self.loop_period)

    def sample_times(self) -> np.ndarray:
        """Fast-time sample instants ``t_k`` from ramp start, ``[num_samples]`` [s]."""
        return self.adc_start_time + np.arange(self.num_samples) / self.sample_rate

    def chirp_start_times(self) -> np.ndarray:
        """Ramp start of every (tx, chirp loop) in the frame, ``[n_tx, num_chirps]`` [s].

        Loop ``l`` fires the Tx of ``tdm_order`` in turn, so Tx ``i`` at slot
        ``s`` starts at ``(l * n_tx + s) * chirp_period + idle_time``.
        """
        slot = np.empty(self.num_tx, dtype=np.int64)
        slot[list(self.tdm_order)] = np.arange(self.num_tx)
        loops = np.arange(self.num_chirps)
        return ((loops[None, :] * self.num_tx + slot[:, None]) * self.chirp_period
                + self.idle_time)

    # ---------------------------------------------------------------- array
    @property
    def half_wavelength(self) -> float:
        """lambda/2 at ``design_frequency`` [m], the unit of the layout tables."""
        return SPEED_OF_LIGHT / (2.0 * self.design_frequency)

    def virtual_positions(self) -> np.ndarray:
        """Virtual element positions ``tx + rx``, ``[n_tx, n_rx, 3]`` [m]."""
        return self.tx_positions[:, None, :] + self.rx_positions[None, :, :]

    def virtual_grid(self) -> np.ndarray:
        """Virtual positions in units of lambda/2 at ``design_frequency``.

        Returns ``[n_tx, n_rx, 2]`` floats: ``(azimuth, elevation)`` = ``(y, z)``.
        """
        v = self.virtual_positions() / self.half_wavelength
        return v[..., 1:3]

    # ----------------------------------------------------------------- misc
    def replace(self, **changes) -> "RadarConfig":
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """Plain dict of the fields (arrays as lists), for HDF5/JSON."""
        out = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            out[f.name] = v.tolist() if isinstance(v, np.ndarray) else (
                list(v) if isinstance(v, tuple) else v)
        return out

    @classmethod
    def from_dict(cls, d: dict) -> "RadarConfig":
        """Inverse of :meth:`to_dict`; unknown or missing keys raise ConfigError."""
        if not isinstance(d, dict):
            raise ConfigError(f"RadarConfig: expected a dict of fields, got {type(d).__name__}")
        names = {f.name for f in dataclasses.fields(cls)}
        required = {f.name for f in dataclasses.fields(cls)
                    if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING}
        unknown = set(d) - names
        missing = required - set(d)
        if unknown:
            raise ConfigError(f"RadarConfig: unknown keys {sorted(unknown)}")
        if missing:
            raise ConfigError(f"RadarConfig: missing keys {sorted(missing)}")
        return cls(**d)

    def __eq__(self, other):
        if not isinstance(other, RadarConfig):
            return NotImplemented
        a, b = self.to_dict(), other.to_dict()
        return a == b

    # --------------------------------------------------------- constructors
    @classmethod
    def _from_layout(cls, tx_az_el, rx_az_el, design_frequency, **kw) -> "RadarConfig":
        hw = SPEED_OF_LIGHT / (2.0 * design_frequency)

        def to_xyz(az_el):
            az_el = np.asarray(az_el, dtype=np.float64).reshape(-1, 2)
            return np.stack([np.zeros(len(az_el)), az_el[:, 0] * hw, az_el[:, 1] * hw], axis=1)

        return cls(tx_positions=to_xyz(tx_az_el), rx_positions=to_xyz(rx_az_el),
                   design_frequency=design_frequency, **kw)

    @classmethod
    def mmwcas(cls, num_chirps: int = 16, slope: float = 78.986e12, **kw) -> "RadarConfig":
        """TI MMWCAS-RF-EVM cascade: 12 Tx x 16 Rx (4 x AWR2243).

        Tx/Rx indices follow the TI device numbering (Tx 1..12 -> 0..11, Rx
        1..16 -> 0..15); the TDM firing order is Tx 12, 11, ..., 1 as in TI's
        calibration captures.  The 192 virtual channels cover 86 uniform
        azimuth positions (0..85 lambda/2) at elevation 0, plus 3 elevated Tx.
        Waveform: 77 GHz start, 78.986 MHz/us, 8 Msps, 256 samples, idle 5 us,
        ADC start 6 us, ramp end 40 us.
        """
        params = dict(start_frequency=77e9, slope=slope, sample_rate=8e6, num_samples=256,
                      num_chirps=num_chirps, idle_time=5e-6, adc_start_time=6e-6,
                      ramp_end_time=40e-6, tdm_order=tuple(range(11, -1, -1)),
                      name="mmwcas")
        params.update(kw)
        return cls._from_layout(layouts.MMWCAS_TX, layouts.MMWCAS_RX, 76.8e9, **params)

    @classmethod
    def awr1843(cls, num_chirps: int = 1, **kw) -> "RadarConfig":
        """TI AWR1843BOOST: 3 Tx x 4 Rx, 8 uniform azimuth + 4 elevated virtual.

        Tx 0 and 2 lie on the azimuth axis 4 lambda/2 apart, Tx 1 is raised by
        lambda/2.  Waveform of the DCA1000 capture in the measured data: 77 GHz,
        64.598 MHz/us, 2.5 Msps, 128 samples, idle 7 us, ADC start 8.66 us,
        ramp end 61.89 us; TDM order Tx 0, 1, 2.
        """
        params = dict(start_frequency=77e9, slope=64.598e12, sample_rate=2.5e6,
                      num_samples=128, num_chirps=num_chirps, idle_time=7e-6,
                      adc_start_time=8.66e-6, ramp_end_time=61.89e-6, name="awr1843")
        params.update(kw)
        return cls._from_layout(layouts.AWR1843_TX, layouts.AWR1843_RX, 76.8e9, **params)

    @classmethod
    def dense(cls, n_tx: int = 100, n_rx: int = 100, num_chirps: int = 1, **kw) -> "RadarConfig":
        """Dense virtual aperture: ``n_tx`` Tx along elevation, ``n_rx`` Rx along azimuth.

        Elements are lambda/2 apart (at ``design_frequency``, default 77 GHz) so
        the ``n_tx * n_rx`` virtual elements form a filled lambda/2 grid in
        azimuth and elevation, centred on the radar origin.  Waveform defaults to
        the cascade's (8 Msps, 256 samples, 78.986 MHz/us); one chirp loop.
        """
        if int(n_tx) < 1 or int(n_rx) < 1:
            raise ConfigError("RadarConfig.dense: n_tx and n_rx must be >= 1")
        design = kw.pop("design_frequency", 77e9)
        el = np.arange(n_tx) - (n_tx - 1) / 2.0
        az = np.arange(n_rx) - (n_rx - 1) / 2.0
        tx = np.stack([np.zeros(n_tx), el], axis=1)      # (azimuth, elevation) in lambda/2
        rx = np.stack([az, np.zeros(n_rx)], axis=1)
        params = dict(start_frequency=77e9, slope=78.986e12, sample_rate=8e6, num_samples=256,
                      num_chirps=num_chirps, idle_time=5e-6, adc_start_time=6e-6,
                      ramp_end_time=40e-6, name=f"dense{n_tx}x{n_rx}")
        params.update(kw)
        return cls._from_layout(tx, rx, design, **params)

    #: preset constructors by name (command line, dataset specs)
    PRESETS = ("mmwcas", "awr1843", "dense")

    @classmethod
    def preset(cls, name: str, **kw) -> "RadarConfig":
        """A preset radar by name: ``"mmwcas"``, ``"awr1843"`` or ``"dense"``.

        ``kw`` go to the constructor (e.g. ``num_chirps=4``, ``position=...``).
        An unknown name raises :class:`~sionna_mmir.errors.ConfigError`.
        """
        if name not in cls.PRESETS:
            raise ConfigError(f"unknown radar preset {name!r}; choose from {list(cls.PRESETS)}")
        return getattr(cls, name)(**kw)


def rotation_matrix(orientation: Sequence[float]) -> np.ndarray:
    """Rotation radar frame -> scene frame for ``(yaw, pitch, roll)`` [rad].

    ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``, the convention of Sionna RT.
    """
    a, b, c = (float(v) for v in orientation)
    ca, sa, cb, sb, cc, sc = math.cos(a), math.sin(a), math.cos(b), math.sin(b), math.cos(c), math.sin(c)
    rz = np.array([[ca, -sa, 0], [sa, ca, 0], [0, 0, 1]])
    ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    rx = np.array([[1, 0, 0], [0, cc, -sc], [0, sc, cc]])
    return rz @ ry @ rx
