"""Sensor profiles: a radar unit's per-unit effects, stored once and applied frozen.

A :class:`SensorProfile` holds what belongs to the unit, not to a capture
(the effects whose class sets ``per_unit = True``), in a form that carries
to another waveform of the same unit:

* ``gain`` -- complex per-virtual-channel gain ``[T, R]`` (unit RMS, common
  phase removed): Tx / Rx chains, chips' LO phases, routing;
* ``delay`` -- per-virtual-channel delay offset ``[T, R]`` [s] (mean
  removed): a delay shifts the beat frequency by ``S delay`` and the phase by
  ``2 pi f delay`` at every instantaneous frequency ``f``, so it maps to any
  slope, sample rate and start frequency;
* ``leak`` -- Tx -> Rx leakage as ``K`` short-delay taps per channel,
  ``[T, R, K]`` complex ADC amplitudes (referred to zero delay) at the delays
  ``leak_delays`` ``[K]`` [s]: the leakage's beat frequency is ``S tau``, so
  a tap is at the same *range* at any slope / sample rate.

The forward model of a capture with a profile is (:meth:`SensorProfile.apply`)::

    y[t, r, c, n] = s * gain[t, r] * D[t, r, n] * x[t, r, c, n] + L[t, r, n]

with ``x`` the rendered scene, ``D = exp(j 2 pi (f0 + S t_n) delay)``, ``L``
the leakage taps synthesised at the capture's waveform, and ``s`` one complex
scene scale (the scene's reflectivity x system gain; it belongs to the
capture, not to the unit).  The profile is never subtracted from the data.

What does not carry to another waveform: the leakage amplitudes are in the
calibration captures' ADC units (the same receiver gain is assumed), and
they fold in the IF filter's response at the calibration slope (a tap at
``tau`` sits at beat frequency ``S tau``, so another slope sees another
filter gain); a changed number of samples per chirp is fine.  Per-unit
effects the calibration does not fit (IQ imbalance, chirp non-linearity,
IF filter, phase noise) are listed in ``not_fitted``.

File format (HDF5, :func:`save_profile` / :func:`load_profile`): attributes
``format`` (:data:`FORMAT_NAME`), ``format_version`` (:data:`FORMAT_VERSION`),
``radar`` (name), ``layout`` (fingerprint), ``waveform`` / ``sources`` /
``fitted`` / ``not_fitted`` / ``quality`` (JSON); datasets ``tx_positions``,
``rx_positions``, ``gain``, ``delay``, ``leak``, ``leak_delays``.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os

import numpy as np

from ..errors import ConfigError, InputValueError

#: ``format`` attribute of a profile file
FORMAT_NAME = "sionna_mmir sensor profile"
#: the newest format version this code reads and the one it writes
FORMAT_VERSION = 1
#: waveform values stored with a profile (those of the first calibration capture)
WAVEFORM_KEYS = ("start_frequency", "slope", "sample_rate", "num_samples", "adc_start_time")


def layout_fingerprint(radar) -> str:
    """Short hash of the radar's Tx / Rx element positions (0.1 mm grid):
    two radars with one fingerprint have the same array."""
    pos = np.concatenate([np.asarray(radar.tx_positions), np.asarray(radar.rx_positions)])
    key = np.round(pos * 1e4).astype(np.int64).tobytes()
    return hashlib.sha256(key + f"{radar.num_tx}x{radar.num_rx}".encode()).hexdigest()[:16]


@dataclasses.dataclass
class SensorProfile:
    """One radar unit's calibrated per-unit effects (see the module docstring).

    Parameters
    ----------
    radar : str
        The radar's name (``RadarConfig.name``).
    layout : str
        :func:`layout_fingerprint` of its array.
    tx_positions, rx_positions : numpy.ndarray
        ``[T, 3]`` / ``[R, 3]`` element positions [m] (for reports).
    waveform : dict
        The calibration waveform (:data:`WAVEFORM_KEYS`).
    gain : numpy.ndarray
        complex ``[T, R]`` channel gains.
    delay : numpy.ndarray
        ``[T, R]`` channel delay offsets [s].
    leak : numpy.ndarray
        complex ``[T, R, K]`` leakage taps [ADC units].
    leak_delays : numpy.ndarray
        ``[K]`` tap delays [s].
    sources : tuple of str
        The calibration captures.
    fitted, not_fitted : tuple of str
        Per-unit effects (library names) in the profile / left out.
    quality : dict
        Per source: residual before / after the calibration [dB], and notes.
    format_version : int
        Format of the file it came from.
    """

    radar: str
    layout: str
    tx_positions: np.ndarray
    rx_positions: np.ndarray
    waveform: dict
    gain: np.ndarray
    delay: np.ndarray
    leak: np.ndarray
    leak_delays: np.ndarray
    sources: tuple = ()
    fitted: tuple = ("channel_gain", "delay_offset", "coupling", "dc_offset")
    not_fitted: tuple = ()
    quality: dict = dataclasses.field(default_factory=dict)
    format_version: int = FORMAT_VERSION

    @property
    def num_tx(self) -> int:
        return int(self.gain.shape[0])

    @property
    def num_rx(self) -> int:
        return int(self.gain.shape[1])

    def check(self, where: str = "profile") -> None:
        """Raise :class:`ConfigError` (naming ``where``) on inconsistent shapes or NaN."""
        t, r = self.gain.shape if self.gain.ndim == 2 else (None, None)
        if t is None or self.delay.shape != (t, r) or self.leak.ndim != 3 \
                or self.leak.shape[:2] != (t, r) or self.leak_delays.shape != self.leak.shape[2:]:
            raise ConfigError(f"{where}: inconsistent shapes: gain {self.gain.shape}, delay "
                              f"{self.delay.shape}, leak {self.leak.shape}, leak_delays "
                              f"{self.leak_delays.shape}")
        if self.tx_positions.shape != (t, 3) or self.rx_positions.shape != (r, 3):
            raise ConfigError(f"{where}: element positions {self.tx_positions.shape} / "
                              f"{self.rx_positions.shape} do not match {t} Tx x {r} Rx channels")
        for name in ("gain", "delay", "leak", "leak_delays", "tx_positions", "rx_positions"):
            v = np.asarray(getattr(self, name))
            if not np.all(np.isfinite(v)):
                raise ConfigError(f"{where}: {name} holds NaN or Inf")
        for k in WAVEFORM_KEYS:
            v = self.waveform.get(k)
            if not isinstance(v, (int, float)) or not np.isfinite(v):
                raise ConfigError(f"{where}: waveform {k} is missing or not a number")

    def check_radar(self, radar, where: str = "profile") -> None:
        """Raise :class:`ConfigError` unless the profile is of ``radar``'s kind:
        the same channel counts, radar name and array layout."""
        if (self.num_tx, self.num_rx) != (radar.num_tx, radar.num_rx):
            raise ConfigError(f"{where}: the profile has {self.num_tx} Tx x {self.num_rx} Rx "
                              f"channels, the capture's radar {radar.num_tx} Tx x "
                              f"{radar.num_rx} Rx (mismatched channel counts)")
        if self.radar != radar.name or self.layout != layout_fingerprint(radar):
            raise ConfigError(f"{where}: the profile is of another radar ({self.radar!r}, "
                              f"layout {self.layout}); the capture's radar is {radar.name!r}, "
                              f"layout {layout_fingerprint(radar)}")

    # -------------------------------------------------------- forward model
    def channel_response(self, radar) -> np.ndarray:
        """``gain * exp(j 2 pi (f0 + S t_n) delay)``, complex ``[T, R, N]`` at ``radar``'s waveform."""
        f = radar.start_frequency + radar.slope * radar.sample_times()          # [N]
        return self.gain[..., None] * np.exp(2j * np.pi * self.delay[..., None] * f)

    def leakage(self, radar) -> np.ndarray:
        """The leakage taps synthesised at ``radar``'s waveform, complex ``[T, R, N]``."""
        f = radar.start_frequency + radar.slope * radar.sample_times()          # [N]
        basis = np.exp(2j * np.pi * np.outer(self.leak_delays, f))              # [K, N]
        return self.leak @ basis

    def apply(self, x, radar, scale=1.0) -> np.ndarray:
        """The forward model's ADC ``s H x + L`` of a rendered scene ``x`` ``[..., T, R, C, N]``."""
        x = np.asarray(x)
        h = self.channel_response(radar)[:, :, None, :]
        return scale * h * x + self.leakage(radar)[:, :, None, :]

    def scene_scale(self, x, data, radar) -> complex:
        """Least-squares scene scale ``s`` of ``data ~ s H x + L`` (the capture's, not the unit's)."""
        hx = self.channel_response(radar)[:, :, None, :] * np.asarray(x)
        rest = np.asarray(data) - self.leakage(radar)[:, :, None, :]
        den = np.vdot(hx, hx).real
        return complex(np.vdot(hx, rest) / den) if den > 0 else 1.0 + 0j

    def render_scale(self, x) -> float:
        """Scene scale for a render without a capture: the render's RMS channel amplitude
        is set to the calibration targets' (median ``scene_amplitude`` of ``quality``)."""
        amps = [q.get("scene_amplitude") for q in self.quality.values() if isinstance(q, dict)]
        amps = [a for a in amps if isinstance(a, (int, float)) and np.isfinite(a) and a > 0]
        rms = float(np.sqrt(np.mean(np.abs(np.asarray(x)) ** 2)))
        if not amps or rms <= 0:
            return 1.0
        return float(np.median(amps)) / rms

    def summary(self) -> dict:
        """JSON view for reports: identity, provenance and the sizes of the effects."""
        return {"radar": self.radar, "layout": self.layout, "channels": [self.num_tx, self.num_rx],
                "waveform": self.waveform, "sources": list(self.sources),
                "fitted": list(self.fitted), "not_fitted": list(self.not_fitted),
                "gain_spread_db": float(np.ptp(20 * np.log10(np.abs(self.gain) + 1e-30))),
                "delay_rms_ps": float(np.sqrt(np.mean(self.delay ** 2)) * 1e12),
                "leak_taps": int(self.leak_delays.size), "quality": self.quality,
                "format_version": self.format_version}


def new_profile(radar, gain, delay, leak, leak_delays, sources=(), quality=None,
                not_fitted=()) -> SensorProfile:
    """A :class:`SensorProfile` of ``radar`` (identity and waveform taken from it)."""
    wf = {k: (int(getattr(radar, k)) if k == "num_samples" else float(getattr(radar, k)))
          for k in WAVEFORM_KEYS}
    p = SensorProfile(radar=str(radar.name), layout=layout_fingerprint(radar),
                      tx_positions=np.asarray(radar.tx_positions, np.float64),
                      rx_positions=np.asarray(radar.rx_positions, np.float64), waveform=wf,
                      gain=np.asarray(gain, np.complex128), delay=np.asarray(delay, np.float64),
                      leak=np.asarray(leak, np.complex128),
                      leak_delays=np.asarray(leak_delays, np.float64),
                      sources=tuple(str(s) for s in sources), quality=dict(quality or {}),
                      not_fitted=tuple(not_fitted))
    p.check("new profile")
    return p


def save_profile(profile: SensorProfile, path, overwrite: bool = False) -> str:
    """Write ``profile`` to HDF5 ``path`` atomically (never a partial file); returns the path."""
    import h5py

    from ..utils.atomic import atomic_path

    path = os.fspath(path)
    profile.check(path)
    if os.path.exists(path) and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True to replace it")
    with atomic_path(path, suffix=".h5.part", overwrite=overwrite) as tmp:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = FORMAT_NAME
            f.attrs["format_version"] = FORMAT_VERSION
            f.attrs["radar"] = profile.radar
            f.attrs["layout"] = profile.layout
            for k in ("waveform", "sources", "fitted", "not_fitted", "quality"):
                f.attrs[k] = json.dumps(_jsonable(getattr(profile, k)))
            for k in ("tx_positions", "rx_positions", "gain", "delay", "leak", "leak_delays"):
                f.create_dataset(k, data=getattr(profile, k))
    return path


def _jsonable(v):
    return list(v) if isinstance(v, tuple) else v


def _attr_json(path, attrs, key, kind):
    try:
        v = json.loads(attrs[key])
    except (KeyError, TypeError, ValueError):
        raise ConfigError(f"{path}: attribute {key!r} is missing or not JSON") from None
    if not isinstance(v, kind):
        raise ConfigError(f"{path}: attribute {key!r} is not a {kind.__name__}")
    return v


def load_profile(path) -> SensorProfile:
    """Read and check a profile written by :func:`save_profile`.

    Raises
    ------
    ConfigError
        Not a profile, a profile of a newer format version, missing or
        inconsistent fields, NaN / Inf values (the message names ``path``).
    FileNotFoundError
        No such file.
    """
    import h5py

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(2, "no such file", path)
    try:
        f = h5py.File(path, "r")
    except OSError:
        raise ConfigError(f"{path}: not an HDF5 file (a sensor profile is written by "
                          "`sionna-mmir calibrate`)") from None
    with f:
        a = f.attrs
        if a.get("format") != FORMAT_NAME:
            raise ConfigError(f"{path}: not a sensor profile (format {a.get('format')!r})")
        version = a.get("format_version")
        if not isinstance(version, (int, np.integer)):
            raise ConfigError(f"{path}: format_version is missing or not an integer")
        if int(version) > FORMAT_VERSION:
            raise ConfigError(f"{path}: profile format version {int(version)} is newer than "
                              f"this sionna_mmir reads ({FORMAT_VERSION}); upgrade sionna_mmir")
        arrays = {}
        for k in ("tx_positions", "rx_positions", "gain", "delay", "leak", "leak_delays"):
            if k not in f or not isinstance(f[k], h5py.Dataset) or f[k].size > 1 << 24:
                raise ConfigError(f"{path}: dataset {k!r} is missing or too large")
            arrays[k] = np.asarray(f[k][()])
        p = SensorProfile(radar=str(a.get("radar", "")), layout=str(a.get("layout", "")),
                          waveform=_attr_json(path, a, "waveform", dict),
                          sources=tuple(_attr_json(path, a, "sources", list)),
                          fitted=tuple(_attr_json(path, a, "fitted", list)),
                          not_fitted=tuple(_attr_json(path, a, "not_fitted", list)),
                          quality=_attr_json(path, a, "quality", dict),
                          format_version=int(version), **arrays)
    if p.gain.dtype.kind != "c" or p.leak.dtype.kind != "c":
        raise ConfigError(f"{path}: gain and leak must be complex")
    p.check(path)
    return p


def load_for(path, radar) -> SensorProfile:
    """:func:`load_profile` and :meth:`SensorProfile.check_radar` against ``radar``."""
    p = load_profile(path)
    p.check_radar(radar, os.fspath(path))
    return p


def with_profile(cap, profile: SensorProfile, scale=None, name: str = "profile"):
    """A rendered capture as the unit would have captured it: ``s H x + L`` on every frame
    (``scale`` ``s``: ADC units per rendered unit, default :meth:`SensorProfile.render_scale`)."""
    from ..captures.capture import Capture

    if scale is not None and not (np.isfinite(scale) and scale > 0):
        raise ConfigError(f"--scene-scale {scale}: expected a positive number")
    s = profile.render_scale(cap.frames) if scale is None else float(scale)
    frames = np.stack([profile.apply(f, cap.radar, s) for f in cap.frames]).astype(np.complex64)
    meta = dict(cap.metadata, sensor_profile=os.path.basename(os.fspath(name)), scene_scale=s)
    return Capture(frames, cap.radar, meta, cap.source, dict(cap.extras or {}))


def residual_db(data, model) -> float:
    """``10 log10(|data - model|^2 / |data|^2)`` [dB] (0 dB: the model explains nothing)."""
    d = np.asarray(data)
    e = float(np.vdot(d, d).real)
    if e <= 0:
        raise InputValueError("residual_db: the data are all zero")
    r = d - np.asarray(model)
    return float(10 * np.log10(max(np.vdot(r, r).real, 1e-300) / e))


class FrozenProfile:
    """A :class:`SensorProfile` as a parameter-free mean effect of an
    :class:`~sionna_mmir.effects.EffectModel` (stage 1): ``x -> H x + L / scale``,
    ``scale`` the model's normalisation (the RMS of the measured ADC).

    Built by :func:`frozen_profile_effect` (which subclasses :class:`~.base.Effect`
    lazily to keep this module importable on its own).
    """


def frozen_profile_effect(profile: SensorProfile, radar, scale: float):
    """The effect of :class:`FrozenProfile` for ``radar`` and the model's ``scale``."""
    from . import ops
    from .base import Effect

    h = profile.channel_response(radar)[None, :, :, None, :]
    leak = profile.leakage(radar)[None, :, :, None, :] / float(scale)

    class _Frozen(Effect, FrozenProfile):
        name = "sensor_profile"
        kind = "mean"
        stage = 1
        per_unit = True
        description = "the unit's calibrated channel gains, delays and leakage (frozen)"

        def param_specs(self, ctx, model, residual):
            return {}

        def apply(self, x, p, ctx):
            return ops.cadd(ops.cmul(x, ops.tensor(h)), ops.tensor(leak))

        def summary(self, p, ctx):
            return profile.summary()

    return _Frozen()
