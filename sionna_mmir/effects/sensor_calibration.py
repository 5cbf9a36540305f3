"""Calibrate a radar unit's :class:`~.profile.SensorProfile` from captures of it.

Each capture's scene is the strongest return that is neither leakage nor
interference (:func:`~sionna_mmir.processing.detection.find_target`), a
point target at its sub-bin range and azimuth; the unit's effects are shared
by all captures.  Per capture ``c`` and virtual channel ``(t, r)`` the
chirp-averaged ADC is modelled as::

    y_c[t, r, n] = s_c g[t, r] b(tau_c[t, r] + d[t, r], n) + sum_k L[t, r, k] b(tau_k, n)

with ``b(tau, n) = exp(j 2 pi (f0 + S t_n) tau)``, ``tau_c`` the target's
exact per-pair delay, ``s_c`` the capture's scene amplitude, ``g`` / ``d``
the unit's channel gain / delay and ``L`` its leakage taps at delays
``tau_k`` (0 .. ``leak_max``).  The fit alternates (``rounds`` times): the
per-channel delays from a matched-filter search about the target, pooled
over captures by their weights; gains and scene amplitudes as a rank-one
fit; the leakage taps by regularised least squares on what the scenes leave,
pooled over captures (each at its own waveform).  The targets are re-located
with the current unit model in each round, so the scene and the unit are
fitted jointly.

Per-chip beat-frequency offsets are not separable from per-channel delays at
one slope (both shift the beat frequency); the per-channel delay holds them,
which is exact at the calibration slope and carries a frequency offset
wrongly to another slope (listed in ``not_fitted``).
"""
from __future__ import annotations

import os

import numpy as np

from ..errors import InputValueError
from .profile import SensorProfile, new_profile, residual_db

SPEED_OF_LIGHT = 299_792_458.0
#: per-unit effects of the library the profile holds (DC offset: the zero-delay leakage tap)
FITTED = ("channel_gain", "delay_offset", "coupling", "dc_offset")
#: why the other per-unit effects of the library are left out
NOT_FITTED = {
    "frequency_offset": "not separable from the per-channel delay at one slope",
    "iq_imbalance": "not fitted (an image of the target; small on the MMWCAS)",
    "chirp_nonlinearity": "not fitted",
    "if_filter": "not fitted; folded into the leakage taps at the calibration slope",
    "phase_noise": "variance effect, not part of the mean model",
}


def _averaged(cap) -> np.ndarray:
    """Chirp- and frame-averaged ADC ``[T, R, N]`` complex128 (the static part)."""
    x = np.asarray(cap.frames, dtype=np.complex128)
    if not np.all(np.isfinite(x)):
        raise InputValueError(f"{cap.source}: capture holds NaN or Inf samples")
    return x.mean(axis=(0, 3))


def _freqs(radar) -> np.ndarray:
    """Instantaneous frequency of each ADC sample ``f0 + S t_n`` [Hz]."""
    return radar.start_frequency + radar.slope * radar.sample_times()


class _Capture:
    """One calibration capture's data, waveform and scene state."""

    def __init__(self, cap, r_min: float):
        from ..fmcw.targets import point_target_paths, refine_point_target
        from ..processing.detection import find_target
        from ..processing.virtual_array import VirtualArray

        self.source = str(cap.source or cap.metadata.get("file", "capture"))
        self.radar = cap.radar
        self.y = _averaged(cap)
        self.f = _freqs(self.radar)
        r0, az0, _ = find_target(cap.frames, self.radar, r_min=r_min)
        self.centre = VirtualArray(self.radar).phase_centre()
        self.r, self.az_deg = refine_point_target(self.y[:, :, None, :], self.radar, r0,
                                                  np.degrees(az0), self.centre)
        _, tau, _ = point_target_paths(self.radar, [(self.r, self.az_deg, 0.0, 0.0)],
                                       origin=self.centre)
        self.tau = tau[..., 0]                                             # [T, R]
        self.s = 1.0 + 0j
        self.a = None
        self.steer = np.zeros(2)           # phase ramps: the path's directions (see _steering)

    @property
    def bin_delay(self) -> float:
        """Delay of one range bin [s]."""
        return self.radar.sample_rate / (abs(self.radar.slope) * self.radar.num_samples)

    def target(self, delay) -> np.ndarray:
        """Unit-amplitude target signal with channel delays ``delay``, ``[T, R, N]``."""
        phase = 2 * np.pi * self.radar.center_frequency * _plane_delay(self.radar, self.steer)
        return np.exp(2j * np.pi * (self.tau + delay)[..., None] * self.f + 1j * phase[..., None])

    def taps(self, leak_delays) -> np.ndarray:
        """Leakage basis ``[N, K]``."""
        return np.exp(2j * np.pi * np.outer(self.f, leak_delays))


def _channel_delays(caps, leak, leak_delays, delay, span_bins=1.5, steps=61):
    """Per-channel delays: matched-filter search about each capture's target, pooled."""
    num, den = 0.0, 0.0
    for c in caps:
        e = c.y - leak @ c.taps(leak_delays).T
        grid = np.linspace(-span_bins, span_bins, steps) * c.bin_delay
        phase = np.exp(-2j * np.pi * np.multiply.outer(grid, c.f))          # [G, N]
        base = e * np.conj(c.target(delay))                                # [T, R, N]
        score = np.abs(base @ phase.T) ** 2                                # [T, R, G]
        k = np.clip(np.argmax(score, axis=-1), 1, steps - 2)
        i = np.indices(k.shape)
        y0, y1, y2 = (score[i[0], i[1], k + o] for o in (-1, 0, 1))
        frac = 0.5 * (y0 - y2) / np.where(np.abs(y0 - 2 * y1 + y2) > 0, y0 - 2 * y1 + y2, 1.0)
        d = delay + (grid[k] + np.clip(frac, -1, 1) * (grid[1] - grid[0]))
        w = y1 / y1.sum()
        num = num + w * (d - np.sum(w * d))
        den = den + w
    return num / np.maximum(den, 1e-30)


def _ramp(g, y, k, span, steps) -> float:
    """Direction cosine ``u`` maximising ``|sum g exp(-j k u y)|`` (``y`` [m], broadcast to ``g``)."""
    best = 0.0
    for width in (span, 2 * span / (steps - 1)):
        u = best + np.linspace(-width, width, steps)
        ph = np.exp(-1j * k * np.multiply.outer(u, np.broadcast_to(y, g.shape)))
        best = u[np.argmax(np.abs(np.sum(ph * g, axis=(1, 2))))]
    return float(best)


def _steering(g, radar, span: float = 1.0, steps: int = 401, rx: bool = False) -> np.ndarray:
    """``(u, u_rx)``: the plane-wave phase ramps that best fit ``g`` across the aperture.

    ``u`` is the path's direction (a ramp over the virtual positions'
    azimuth); with ``rx``, ``u_rx`` is an extra ramp over the Rx positions
    only (else 0): a path that arrives from another direction than it left
    (a multipath via a wall).  Both belong to the scene.  The calibration
    fixes only ``u`` (the pair is not unique: the Tx positions of a cascade
    are 4 lambda/2 apart, so a Tx-side ramp aliases); the scene fit under a
    frozen profile fits both.  Elevation
    is left alone: the few elevated Tx of a cascade alias in elevation, so a
    fitted elevation would not be unique; targets are taken at elevation 0.
    """
    k = 2 * np.pi * radar.center_frequency / SPEED_OF_LIGHT
    yv = radar.virtual_positions()[..., 1]                                # [T, R]
    yr = np.asarray(radar.rx_positions)[None, :, 1]                       # [1, R]
    u = np.zeros(2)
    for _ in range(2 if rx else 1):
        u[0] = _ramp(g * np.exp(-1j * k * u[1] * yr), yv, k, span, steps)
        if rx:
            u[1] = _ramp(g * np.exp(-1j * k * u[0] * yv), yr, k, span, steps)
    return u


def _plane_delay(radar, u) -> np.ndarray:
    """Per-channel delay ``[T, R]`` [s] of the ramps ``u = (u, u_rx)`` of :func:`_steering`."""
    return (u[0] * radar.virtual_positions()[..., 1]
            + u[1] * np.asarray(radar.rx_positions)[None, :, 1]) / SPEED_OF_LIGHT


def _no_plane(delay, caps) -> np.ndarray:
    """``delay`` without its mean and its least-squares slope over the aperture's
    azimuth, which move into each capture's target delays (a delay linear in
    position is a direction; elevation is left alone, see :func:`_steering`)."""
    pos = caps[0].radar.virtual_positions().reshape(-1, 3)
    a = np.stack([np.ones(len(pos)), pos[:, 1]], 1)
    coef, *_ = np.linalg.lstsq(a, delay.ravel(), rcond=None)
    plane = (a[:, 1:] @ coef[1:]).reshape(delay.shape)
    for c in caps:
        c.tau = c.tau + plane
    return delay - plane - coef[0]


def _gains(caps, leak, leak_delays, delay):
    """Rank-one ``a_c = s_c g``: channel gains ``g`` (unit RMS, zero mean phase, no
    phase ramp over the aperture: that is the target's direction, moved into its
    delays) and scene amplitudes ``s_c`` (set on the captures)."""
    for c in caps:
        b = c.target(delay)
        e = c.y - leak @ c.taps(leak_delays).T
        a = np.sum(e * np.conj(b), axis=-1) / np.sum(np.abs(b) ** 2, axis=-1)
        u = _steering(a, c.radar)                                  # the target's direction
        c.steer = c.steer + u
        c.a = a * np.exp(-2j * np.pi * c.radar.center_frequency * _plane_delay(c.radar, u))
    g = caps[0].a / np.sqrt(np.mean(np.abs(caps[0].a) ** 2))
    for _ in range(10):
        for c in caps:
            c.s = complex(np.vdot(g, c.a) / np.vdot(g, g))
        g = sum(np.conj(c.s) * c.a for c in caps) / sum(abs(c.s) ** 2 for c in caps)
    norm = np.sqrt(np.mean(np.abs(g) ** 2)) * np.exp(1j * np.angle(g.sum()))
    for c in caps:
        c.s *= norm
    return g / norm


def _leakage(caps, gain, delay, leak_delays, reg):
    """Leakage taps ``[T, R, K]``: regularised least squares on what the scenes leave."""
    k = len(leak_delays)
    m = np.zeros((k, k), complex)
    v = 0.0
    for c in caps:
        basis = c.taps(leak_delays)                                         # [N, K]
        rest = c.y - c.s * gain[..., None] * c.target(delay)
        m = m + basis.conj().T @ basis
        v = v + rest @ basis.conj()                                          # [T, R, K]
    m = m + reg * np.trace(m).real / k * np.eye(k)
    return np.linalg.solve(m, v.reshape(-1, k).T).T.reshape(v.shape)


def leak_tap_delays(radar, leak_max: float, spacing_bins: float = 0.5) -> np.ndarray:
    """Tap delays [s] from 0 to the delay of range ``leak_max``, ``spacing_bins`` range bins apart."""
    step = spacing_bins * radar.range_resolution
    return 2.0 * np.arange(0.0, leak_max + 0.5 * step, step) / SPEED_OF_LIGHT


def calibrate_profile(captures, *, rounds: int = 4, leak_max: float = 0.35, r_min: float = 1.0,
                      reg: float = 1e-3, names=None) -> SensorProfile:
    """Fit one unit's profile jointly with each capture's point-target scene.

    Parameters
    ----------
    captures : list of Capture
        Captures of one unit (same radar name, layout and channels; any
        slope / sample rate), each with a dominant return beyond ``r_min``.
    rounds : int
        Alternations of delays, gains and leakage.
    leak_max : float
        Farthest range the leakage taps reach [m].
    reg : float
        Tikhonov weight of the leakage taps (relative to the mean diagonal).
    names : list of str, optional
        The captures' names for the provenance (default their ``source``).

    Returns
    -------
    SensorProfile
        With ``quality`` per source: residual of the scene alone and of the
        scene with the profile [dB], the target's range / azimuth.
    """
    from .profile import layout_fingerprint

    if not captures:
        raise InputValueError("calibrate: no captures given")
    first = captures[0].radar
    for cap in captures[1:]:
        if (cap.radar.name, layout_fingerprint(cap.radar)) != (first.name,
                                                                layout_fingerprint(first)):
            raise InputValueError(f"{cap.source}: not the same radar as {captures[0].source} "
                                  f"({cap.radar.name!r} vs {first.name!r}, or another layout)")
    caps = [_Capture(c, r_min) for c in captures]
    for i, c in enumerate(caps):
        c.source = str(names[i]) if names is not None else c.source
    leak_delays = leak_tap_delays(first, leak_max)
    leak = np.zeros((*caps[0].y.shape[:2], len(leak_delays)), complex)
    delay = np.zeros(caps[0].y.shape[:2])
    gain = np.ones_like(leak[..., 0])
    for _ in range(int(rounds)):
        delay = _no_plane(_channel_delays(caps, leak, leak_delays, delay), caps)
        gain = _gains(caps, leak, leak_delays, delay)
        leak = _leakage(caps, gain, delay, leak_delays, reg)
    quality = {}
    for i, c in enumerate(caps):
        scene = c.s * gain[..., None] * c.target(delay)
        key = os.path.basename(c.source)
        quality[key if key not in quality else f"{key} ({i + 1})"] = {
            "target_range_m": round(float(c.r), 4), "scene_amplitude": float(abs(c.s)), "target_azimuth_deg": round(float(c.az_deg), 3),
            "residual_scene_db": round(residual_db(c.y, scene), 3),
            "residual_profile_db": round(residual_db(c.y, scene + leak @ c.taps(leak_delays).T), 3)}
    return new_profile(first, gain, delay, leak, leak_delays, sources=[c.source for c in caps],
                       quality=quality, not_fitted=not_fitted())


def not_fitted() -> list:
    """Per-unit effects of the library (``Effect.per_unit``) a profile does not hold."""
    from .library import LIBRARY

    return sorted(n for n, cls in LIBRARY.items() if cls.per_unit and n not in FITTED)


def fit_scene(cap, profile, *, rounds: int = 3, r_min: float = 1.0,
              bistatic: bool = True) -> dict:
    """Fit a capture's point-target scene under a frozen profile (the unit is not refitted).

    The target's range, direction (a plane-wave phase over the aperture;
    with ``bistatic`` also a separate arrival direction at the Rx, see
    :func:`_steering`) and complex amplitude are fitted; the profile's gains, delays and leakage are
    applied as they are (:meth:`SensorProfile.apply`).

    Returns
    -------
    dict
        ``scene`` (the unit-free point target, ``[T, R, N]``), ``model`` (scene
        with the profile, ``[T, R, N]``), ``data`` (chirp-averaged capture),
        ``scale``, ``range_m``, ``azimuth_deg``, ``origin`` (where range and
        azimuth are measured from), ``arrival`` (the Rx-side arrival ramp,
        complex ``[T, R]``: a scene property a mesh placed at ``range_m`` /
        ``azimuth_deg`` does not produce), ``residual_db``.
    """
    profile.check_radar(cap.radar, str(cap.source))
    c = _Capture(cap, r_min)
    radar = c.radar
    leak = profile.leakage(radar)
    e = c.y - leak
    shifts = np.linspace(-1.5, 1.5, 61) * c.bin_delay

    def steer():
        base = c.target(profile.delay) * profile.gain[..., None]
        a = np.sum(e * np.conj(base), axis=-1) / np.sum(np.abs(base) ** 2, axis=-1)
        c.steer = c.steer + _steering(a * np.abs(profile.gain) ** 2, radar, rx=bistatic)

    for _ in range(int(rounds)):
        steer()
        base = c.target(profile.delay) * profile.gain[..., None]
        score = np.abs(np.einsum("trn,gn->g", e * np.conj(base),
                                 np.exp(-2j * np.pi * np.multiply.outer(shifts, c.f)))) ** 2
        c.tau = c.tau + shifts[int(np.argmax(score))]
    steer()
    unit = c.target(profile.delay)
    hx = profile.gain[..., None] * unit
    s = complex(np.vdot(hx, e) / np.vdot(hx, hx))
    model = s * hx + leak
    # a target at +az is nearer the +y elements: its delays fall as -sin(az) y / c
    az = np.degrees(np.arcsin(np.clip(np.sin(np.radians(c.az_deg)) - c.steer[0], -1, 1)))
    arrival = np.exp(2j * np.pi * radar.center_frequency * _plane_delay(radar, [0.0, c.steer[1]]))
    return {"scene": s * unit, "model": model, "data": c.y, "scale": s,
            "range_m": float(np.mean(c.tau) * SPEED_OF_LIGHT / 2), "azimuth_deg": float(az),
            "origin": c.centre, "arrival": arrival,
            "residual_db": residual_db(c.y, model)}


def calibrate_files(paths, out, *, overwrite: bool = False, waveform: dict | None = None,
                    calib_dir=None, sensor: str = "cascade", **options) -> SensorProfile:
    """Load captures of one unit, :func:`calibrate_profile` them and write the profile to ``out``.

    ``waveform`` fills values the files lack (older TI files); ``options`` go
    to :func:`calibrate_profile`.  Nothing is written unless the calibration
    succeeds; the write is atomic.
    """
    from ..captures.loader import load_capture
    from .profile import save_profile

    if not paths:
        raise InputValueError("calibrate: no captures given")
    caps = [load_capture(p, calib_dir=calib_dir, sensor=sensor, waveform=waveform)
            for p in paths]
    profile = calibrate_profile(caps, names=[os.fspath(p) for p in paths], **options)
    save_profile(profile, out, overwrite=overwrite)
    return profile
