"""Planted effects of the independent generator: parameter draws and their physics.

Independence: plain NumPy/SciPy, written from the hardware's physics, not
from :mod:`sionna_mmir.effects`; where the library parameterises an effect
differently, the truth here keeps the physical form (e.g. per-channel
coupling delays, per-Rx filter tolerances, a continuous LO phase process).

Every ``draw_*`` takes a generator and the case context and returns a
JSON-ready dict of the drawn parameters; the ``apply_*`` / ``*_paths``
functions turn them into paths or act on the ADC.  Strengths (why they are
realistic for a TI MMWCAS cascade / AWR single chip):

``channel_gain``
    per chip N(0, 1 dB) and U(-pi, pi); per element
    N(0, 1 dB) Tx / N(0, 1.5 dB) Rx and N(0, 25 deg); a
    non-separable N(0, 0.2 dB), N(0, 2 deg) per channel.
    ColoRadar's cascade calibration peaks spread +-1.5 dB
    over Tx and +-2.5 dB over Rx with arbitrary phases.
``delay_offset``
    per chip U(-50, 50) ps (Tx and Rx), per element
    N(0, 15 ps).  ColoRadar's calibration bins differ by
    ~0.2 bin between chips (~80 ps at 79 MHz/us).
``frequency_offset``
    per Rx chip +-U(2, 8) kHz (0.06-0.26 of a 31 kHz
    cascade bin), the size of the same per-chip bin steps.
``chirp_nonlinearity``
    ramp error ``b2 (u^2 - 1/3) + b3 u^3`` with
    ``|b2|, |b3|`` U(0.2, 0.6) MHz: 0.1-1 MHz VCO ramp
    errors, 0.05-0.25 rad of beat phase at 8 m.
``phase_noise``
    L(1 MHz) U(-90, -85) dBc/Hz, flat inside a 0.3-0.8
    MHz PLL loop, -20 dB/decade outside, floor -135 dBc/Hz,
    offsets up to f_s / 2 (TI quotes -93 to -85 dBc/Hz at
    1 MHz for 76-81 GHz); one LO for all chips, a
    continuous process over the frame, applied exactly as
    ``Phi(t) - Phi(t - tau)`` to the strong paths (corners,
    walls, planted scatterers, coupling; the clutter's
    skirt is > 50 dB below it).
``coupling``
    a direct antenna path ``(d0 + |tx - rx|) / c``,
    ``d0`` U(0.10, 0.25) m, and a radome bounce at
    ``2 U(0.15, 0.3) m / c`` (equivalent ranges 0.05-0.3
    m); same-chip level +3..+12 dB over the strongest
    corner (the leakage is the largest peak of a TI range
    profile), other chips 10-20 dB lower, separable factors
    times (1 + 0.25 CN(0, 1)) per channel, the second path
    3-9 dB below the first.
``if_filter``
    TI's HPF1 {175, 235, 350} kHz, optionally HPF2 {350,
    700} kHz (1st or 2nd order), per-Rx corner tolerance
    N(0, 3 %); simulated with ``lfilter`` from the ramp
    start (HPF reset at ramp start, "fast init").
``iq_imbalance``
    per Rx gain +-U(0.5, 1) dB and phase +-U(3, 8) deg.
``dc_offset``
    per Rx U(2, 8) x the noise std, random phase.
``noise_floor``
    per Rx extra white U(-6, 0) dB of the thermal floor
    plus flicker ``(f_knee / f)`` with ``f_knee`` U(100,
    400) kHz (CMOS baseband), continuous over the frame.
``adc_clipping``
    I and Q clipped at the level exceeded by U(1, 5) % of
    the I/Q values.
``ego_motion``
    radar moving U(0.5, 2) m/s along its boresight.
``moving_scatterer``
    a person (0 dBsm) at 3-6 m walking 0.5-1.5 m/s.
``missing_scatterer``
    an unmodelled 0-7 dBsm post at 2.5-7 m.
``multipath_ghost``
    a trihedral seen via the floor (image point across
    ``z = 0``): the double bounce with ``Gamma^2`` (TE
    Fresnel of concrete at the grazing angle times the
    roughness loss) and the aspect toward the radar's
    image, the two mixed paths with ``Gamma`` and the
    trihedral's bistatic loss.  The floor, not a side wall:
    a corner aimed at the radar sees the radar's image in
    a side wall 50-90 deg off its axis (no return), in the
    floor 15-30 deg off (-6 to -15 dB), so this is the
    ghost real corner-reflector captures show.

Outside the library: ``outside:interference`` (another FMCW radar) and
``outside:tx_droop`` (power-amplifier droop over the frame); see
:func:`draw_interference` and :func:`draw_tx_droop`.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import signal

from .undeclared_adc import C0, FixedPaths, PointPaths, element_gain
from .undeclared_scene import coherent_factor, fresnel_te


def _db(x) -> np.ndarray:
    return 10.0 ** (np.asarray(x) / 20.0)


def _sign(rng, n=None):
    return np.where(rng.uniform(size=n) < 0.5, -1.0, 1.0)


def _c(z) -> list:
    """Complex array -> nested ``[re, im]`` lists (JSON)."""
    z = np.asarray(z, complex)
    return np.stack([z.real, z.imag], -1).tolist()


# ----------------------------------------------------------------- RF chain
def draw_channel_gain(rng, ctx) -> dict:
    """Chip x element complex gains, plus a small non-separable part."""
    nt, nr, ct, cr = ctx.num_tx, ctx.num_rx, ctx.tx_chip, ctx.rx_chip
    nc = ctx.num_chips
    chip_t = rng.normal(0, 1.0, nc) + 1j * rng.uniform(-np.pi, np.pi, nc)
    chip_r = rng.normal(0, 1.0, nc) + 1j * rng.uniform(-np.pi, np.pi, nc)
    el_t = rng.normal(0, 1.0, nt) + 1j * np.radians(rng.normal(0, 25, nt))
    el_r = rng.normal(0, 1.5, nr) + 1j * np.radians(rng.normal(0, 25, nr))
    ns = rng.normal(0, 0.2, (nt, nr)) + 1j * np.radians(rng.normal(0, 2, (nt, nr)))
    total = ((chip_t[ct] + el_t)[:, None] + (chip_r[cr] + el_r)[None, :] + ns)
    gain = _db(total.real) * np.exp(1j * total.imag)
    return {"tx_chip_db_rad": _c(chip_t), "rx_chip_db_rad": _c(chip_r),
            "tx_element_db_rad": _c(el_t), "rx_element_db_rad": _c(el_r),
            "nonseparable_db_rad": _c(ns), "gain": _c(gain)}


def gain_array(params) -> np.ndarray:
    """Complex ``[T, R]`` channel gain from :func:`draw_channel_gain`'s dict."""
    g = np.asarray(params["gain"])
    return g[..., 0] + 1j * g[..., 1]


def draw_delay_offset(rng, ctx) -> dict:
    """Per-chip and per-element Tx / Rx delays [ps]."""
    nc = ctx.num_chips
    tx = rng.uniform(-50, 50, nc)[ctx.tx_chip] + rng.normal(0, 15, ctx.num_tx)
    rx = rng.uniform(-50, 50, nc)[ctx.rx_chip] + rng.normal(0, 15, ctx.num_rx)
    return {"tx_ps": tx.tolist(), "rx_ps": rx.tolist()}


def delay_array(params) -> np.ndarray:
    """``[T, R]`` extra delay [s]."""
    return (np.asarray(params["tx_ps"])[:, None] + np.asarray(params["rx_ps"])[None]) * 1e-12


def draw_frequency_offset(rng, ctx) -> dict:
    """Beat-frequency offset per receive chip [Hz]."""
    df = _sign(rng, ctx.num_chips) * rng.uniform(2e3, 8e3, ctx.num_chips)
    return {"rx_chip_hz": df.tolist()}


def draw_chirp_nonlinearity(rng, ctx) -> dict:
    """Quadratic and cubic ramp-frequency error coefficients [Hz]."""
    b2, b3 = _sign(rng, 2) * rng.uniform(0.2e6, 0.6e6, 2)
    return {"b2_hz": float(b2), "b3_hz": float(b3), "ramp_s": ctx.radar.ramp_end_time}


def draw_phase_noise(rng, ctx) -> dict:
    """LO phase-noise profile (the process itself is drawn in :func:`lo_phase`).

    ``max_offset_hz`` = ``f_s / 2``: the skirt beyond the IF band is removed by
    the anti-alias filter, so the process is generated without it.
    """
    return {"l_1mhz_dbc_hz": float(rng.uniform(-90, -85)),
            "loop_bw_hz": float(rng.uniform(3e5, 8e5)), "floor_dbc_hz": -135.0,
            "max_offset_hz": ctx.radar.sample_rate / 2, "seed": int(rng.integers(2 ** 31))}


def phase_noise_psd(f, params) -> np.ndarray:
    """Two-sided LO phase PSD [rad^2/Hz] (= L(f) in dBc/Hz) at offsets ``f`` [Hz].

    ``L(f) = L1 (1 MHz^2 + f_loop^2) / (f^2 + f_loop^2) + L_floor`` up to
    ``max_offset_hz``, 0 beyond.
    """
    f = np.abs(np.asarray(f, float))
    l1 = 10 ** (params["l_1mhz_dbc_hz"] / 10)
    fl = params["loop_bw_hz"]
    psd = l1 * (1e12 + fl ** 2) / (f ** 2 + fl ** 2) + 10 ** (params["floor_dbc_hz"] / 10)
    return np.where(f <= params["max_offset_hz"], psd, 0.0)


def lo_phase(params, t_start: float, t_stop: float, dt: float):
    """One realisation of the LO phase [cycles] on ``[t_start, t_stop]`` (an ``LOPhase``).

    White Gaussian noise shaped by ``sqrt(PSD / dt)`` in the frequency domain.
    """
    from .undeclared_adc import LOPhase

    n = int(math.ceil((t_stop - t_start) / dt)) + 2
    rng = np.random.default_rng(params["seed"] + int(round(t_start * 1e3)))
    spec = np.fft.rfft(rng.normal(size=n))
    f = np.fft.rfftfreq(n, dt)
    phi = np.fft.irfft(spec * np.sqrt(phase_noise_psd(f, params) / dt), n)
    return LOPhase(t_start, dt, phi / (2 * np.pi))


def draw_coupling(rng, ctx) -> dict:
    """Tx -> Rx leakage: a direct antenna path and a radome bounce per channel.

    Amplitudes are relative to the strongest corner's RMS path amplitude
    (``ctx.ref_amp``).
    """
    nt, nr, nc = ctx.num_tx, ctx.num_rx, ctx.num_chips
    d0 = float(rng.uniform(0.10, 0.25))
    r_bounce = float(rng.uniform(0.15, 0.30))
    level_db = float(rng.uniform(3, 12))
    cross_db = -rng.uniform(10, 20, (nc, nc))
    np.fill_diagonal(cross_db, 0.0)
    u = _db(rng.normal(0, 1.0, nt)) * np.exp(1j * rng.uniform(-np.pi, np.pi, nt))
    w = _db(rng.normal(0, 1.0, nr)) * np.exp(1j * rng.uniform(-np.pi, np.pi, nr))
    blocks = _db(cross_db) * np.exp(1j * rng.uniform(-np.pi, np.pi, (nc, nc)))
    amps = []
    for m, rel_db in enumerate((0.0, float(-rng.uniform(3, 9)))):
        ns = 1 + 0.25 * (rng.normal(size=(nt, nr)) + 1j * rng.normal(size=(nt, nr))) / math.sqrt(2)
        a = (_db(level_db + rel_db) * np.exp(1j * rng.uniform(-np.pi, np.pi))
             * u[:, None] * w[None] * blocks[ctx.tx_chip][:, ctx.rx_chip] * ns)
        amps.append(a)
    return {"direct_extra_path_m": d0, "bounce_range_m": r_bounce, "level_db": level_db,
            "amp_rel": _c(np.stack(amps, -1))}


def coupling_paths(params, ctx) -> FixedPaths:
    """The leakage as :class:`FixedPaths` (amplitudes in path units)."""
    sep = np.linalg.norm(ctx.radar.tx_positions[:, None] - ctx.radar.rx_positions[None], axis=-1)
    tau = np.stack([(params["direct_extra_path_m"] + sep) / C0,
                    np.full_like(sep, 2 * params["bounce_range_m"] / C0)], -1)
    a = np.asarray(params["amp_rel"])
    return FixedPaths(tau, (a[..., 0] + 1j * a[..., 1]) * ctx.ref_amp)


# --------------------------------------------------------------- the scene
def draw_missing_scatterer(rng, ctx) -> dict:
    """A static unmodelled point (a post / chair leg): 0-7 dBsm at 2.5-7 m."""
    for _ in range(1000):
        p = ctx.random_point(rng, 2.5, 7.0, 45.0, (0.5, 1.5))
        if ctx.clear_of_corners(p, 0.5, 10.0):
            break
    return {"position_m": p.tolist(), "rcs_dbsm": float(rng.uniform(0, 7)),
            "phase_rad": float(rng.uniform(-np.pi, np.pi))}


def point_paths(params, lam, velocity=None) -> PointPaths:
    """One isotropic point scatterer from a ``position_m / rcs_dbsm / phase_rad`` dict."""
    p = np.asarray(params["position_m"], float)[None]
    coef = (lam * math.sqrt(10 ** (params["rcs_dbsm"] / 10)) / (4 * np.pi) ** 1.5
            * np.exp(1j * params["phase_rad"]))
    v = None if velocity is None else np.asarray(velocity, float)[None]
    return PointPaths(p, p, np.array([coef]), v)


def draw_moving_scatterer(rng, ctx) -> dict:
    """A walking person: 0 dBsm at 3-6 m, 0.5-1.5 m/s, >= 30 % of it radial."""
    p = ctx.random_point(rng, 3.0, 6.0, 35.0, (1.0, 1.2))
    radial = (p - ctx.radar_pos)[:2] / np.linalg.norm((p - ctx.radar_pos)[:2])
    while True:
        d = rng.normal(size=2)
        d /= np.linalg.norm(d)
        if abs(d @ radial) >= 0.3:
            break
    v = float(rng.uniform(0.5, 1.5)) * np.array([d[0], d[1], 0.0])
    return {"position_m": p.tolist(), "velocity_mps": v.tolist(), "rcs_dbsm": 0.0,
            "phase_rad": float(rng.uniform(-np.pi, np.pi)),
            "radial_velocity_mps": float(v[:2] @ radial)}


def draw_multipath_ghost(rng, ctx) -> dict:
    """The floor bounce of the trihedral with the strongest double-bounce ghost."""
    best = None
    for k, c in enumerate(ctx.scene.corners):
        if c.kind != "trihedral":
            continue
        g = ghost_geometry(c, ctx.radar_pos, ctx.lam, ctx.radar.center_frequency)
        if best is None or g["double_amp"] > best[1]["double_amp"]:
            best = (k, g)
    k, g = best
    return {"corner": k, "surface": "floor", "image_m": g["image"].tolist(),
            "grazing_deg": g["grazing_deg"], "gamma": _c(g["gamma"]),
            "sigma_double_m2": g["sigma_double"], "sigma_mixed_m2": g["sigma_mixed"]}


def ghost_geometry(corner, radar_pos, lam, freq_hz) -> dict:
    """Floor image of ``corner``, grazing angle, TE coefficient and the RCS of each path."""
    c = corner.centre
    image = c * np.array([1.0, 1.0, -1.0])
    radar_img = radar_pos * np.array([1.0, 1.0, -1.0])
    d_h = np.linalg.norm((c - radar_pos)[:2])
    graze = math.atan2(radar_pos[2] + c[2], d_h)
    cos_i = math.sin(graze)
    gamma = complex(fresnel_te("concrete", freq_hz, cos_i) * coherent_factor(
        "concrete", freq_hz, cos_i))
    to_img, to_dir = radar_img - c, radar_pos - c
    s_double = corner.rcs(to_img, lam)
    bis = to_img / np.linalg.norm(to_img) + to_dir / np.linalg.norm(to_dir)
    beta = math.acos(np.clip(to_img @ to_dir / np.linalg.norm(to_img) / np.linalg.norm(to_dir),
                             -1, 1))
    s_mixed = corner.rcs(bis, lam) * corner.bistatic_factor(beta, lam)
    return {"image": image, "grazing_deg": math.degrees(graze), "gamma": gamma,
            "sigma_double": s_double, "sigma_mixed": s_mixed,
            "double_amp": abs(gamma) ** 2 * math.sqrt(s_double)}


def ghost_paths(params, corner, lam) -> PointPaths:
    """Double bounce (image - image) and the two mixed paths (image - corner)."""
    img = np.asarray(params["image_m"], float)
    c = corner.centre
    g = complex(*params["gamma"])
    ph = np.pi                                       # trihedral: three metal bounces
    k = lam / (4 * np.pi) ** 1.5 * np.exp(1j * ph)
    coef = np.array([k * g * g * math.sqrt(params["sigma_double_m2"]),
                     k * g * math.sqrt(params["sigma_mixed_m2"]),
                     k * g * math.sqrt(params["sigma_mixed_m2"])])
    return PointPaths(np.array([img, img, c]), np.array([img, c, img]), coef)


def draw_ego_motion(rng, ctx) -> dict:
    """Radar speed U(0.5, 2) m/s along its boresight, towards the scene."""
    return {"speed_mps": float(rng.uniform(0.5, 2.0))}


def draw_pose_offset(rng, ctx) -> dict:
    """True pose = nominal + a 1-3 cm shift in a random direction and +-0.5 deg of yaw."""
    d = rng.normal(size=3)
    shift = d / np.linalg.norm(d) * rng.uniform(0.01, 0.03)
    return {"position_offset_m": shift.tolist(), "yaw_offset_deg": float(_sign(rng) * 0.5)}


# ----------------------------------------------------------- mixer, IF, ADC
def draw_iq_imbalance(rng, ctx) -> dict:
    """Per-Rx I/Q gain [dB] and phase [deg] errors."""
    n = ctx.num_rx
    return {"gain_db": (_sign(rng, n) * rng.uniform(0.5, 1.0, n)).tolist(),
            "phase_deg": (_sign(rng, n) * rng.uniform(3.0, 8.0, n)).tolist()}


def apply_iq_imbalance(x, params) -> np.ndarray:
    """Mixer I/Q errors on ``x`` ``[..., R, L, K]`` (Rx on axis -3).

    The I branch has gain ``10^(g/40)`` and LO phase ``+phi/2``, the Q branch
    ``10^(-g/40)`` and ``-phi/2``: ``I' = a_I (I cos(phi/2) - Q sin(phi/2))``,
    ``Q' = a_Q (Q cos(phi/2) - I sin(phi/2))``.
    """
    g = np.asarray(params["gain_db"])[:, None, None]
    phi = np.radians(np.asarray(params["phase_deg"]))[:, None, None]
    a_i, a_q = 10 ** (g / 40), 10 ** (-g / 40)
    c, s = np.cos(phi / 2), np.sin(phi / 2)
    i, q = x.real, x.imag
    return a_i * (i * c - q * s) + 1j * a_q * (q * c - i * s)


def image_rejection_db(gain_db, phase_deg) -> np.ndarray:
    """Image-to-signal power ratio [dB] of :func:`apply_iq_imbalance`.

    ``(1 + g^2 - 2 g cos phi) / (1 + g^2 + 2 g cos phi)``, ``g = 10^(gain_db / 20)``.
    """
    g = 10 ** (np.asarray(gain_db) / 20)
    cp = np.cos(np.radians(np.asarray(phase_deg)))
    return 10 * np.log10((1 + g * g - 2 * g * cp) / (1 + g * g + 2 * g * cp))


def draw_if_filter(rng, ctx) -> dict:
    """TI-style HPF corners (1st or 2nd order) with a per-Rx tolerance."""
    f1 = float(rng.choice([175e3, 235e3, 350e3]))
    corners = [f1] if rng.uniform() < 0.4 else [f1, float(rng.choice([350e3, 700e3]))]
    tol = 1 + rng.normal(0, 0.03, (ctx.num_rx, len(corners)))
    return {"corners_hz": corners, "rx_tolerance": tol.tolist()}


def hpf_response(f, corners_hz) -> np.ndarray:
    """Analog response ``prod_k (j f / f_k) / (1 + j f / f_k)`` at frequencies ``f`` [Hz]."""
    f = np.asarray(f, float)
    h = np.ones_like(f, dtype=complex)
    for fc in corners_hz:
        h *= (1j * f / fc) / (1 + 1j * f / fc)
    return h


def apply_if_filter(x, params, fs: float) -> np.ndarray:
    """Cascaded first-order high-passes along fast time (last axis), zero state at sample 0.

    Each stage is the bilinear transform of ``s / (s + 2 pi f_c)`` with the
    corner pre-warped (``scipy.signal.butter(1, f_c, "highpass", fs=fs)``),
    run by ``scipy.signal.lfilter`` on I and Q (identical real filters).
    """
    tol = np.asarray(params["rx_tolerance"])
    out = np.array(x, complex)
    for r in range(out.shape[-3]):
        for k, fc in enumerate(params["corners_hz"]):
            b, a = signal.butter(1, fc * tol[r, k], "highpass", fs=fs)
            out[..., r, :, :] = signal.lfilter(b, a, out[..., r, :, :], axis=-1)
    return out


def draw_dc_offset(rng, ctx) -> dict:
    """Per-Rx complex DC [ADC counts]."""
    n = ctx.num_rx
    mag = rng.uniform(2, 8, n) * ctx.noise_std
    return {"rx_counts": _c(mag * np.exp(1j * rng.uniform(-np.pi, np.pi, n)))}


def draw_adc_clipping(rng, ctx) -> dict:
    """Fraction of I/Q values above the clip level."""
    return {"fraction": float(rng.uniform(0.01, 0.05))}


def apply_clipping(x, fraction: float) -> tuple:
    """Hard clip of I and Q at the ``1 - fraction`` quantile of ``|I|, |Q|``; ``(x, level)``."""
    level = float(np.quantile(np.abs(np.concatenate([x.real.ravel(), x.imag.ravel()])),
                              1 - fraction))
    return (np.clip(x.real, -level, level) + 1j * np.clip(x.imag, -level, level)), level


def draw_noise_floor(rng, ctx) -> dict:
    """Per-Rx extra white level and a flicker knee (coloured noise over the frame)."""
    return {"rx_extra_white_db": rng.uniform(-6, 0, ctx.num_rx).tolist(),
            "flicker_knee_hz": float(rng.uniform(1e5, 4e5)), "flicker_exponent": 1.0,
            "seed": int(rng.integers(2 ** 31))}


def coloured_noise(params, ctx, sample_times) -> np.ndarray:
    """Extra receiver noise at absolute ``sample_times`` ``[F, T, L, K]`` -> ``[F, T, R, L, K]``.

    Per Rx and frame, one continuous process on the ``1 / f_s`` grid spanning
    the frame's chirps, white Gaussian shaped by ``sqrt(w_r + (f_knee /
    |f|)^gamma)`` in the frequency domain (``|f| >= 1 / span``), times the
    thermal noise std; every (tx, chirp, sample) reads its instant.
    """
    fs, sigma = ctx.radar.sample_rate, ctx.noise_std
    rng = np.random.default_rng(params["seed"])
    n_f = sample_times.shape[0]
    out = np.empty((n_f, ctx.num_tx, ctx.num_rx) + sample_times.shape[2:], complex)
    for fi in range(n_f):
        t0 = float(sample_times[fi].min())
        idx = np.rint((sample_times[fi] - t0) * fs).astype(int)
        n = int(idx.max()) + 1
        f = np.abs(np.fft.fftfreq(n, 1 / fs))
        f = np.maximum(f, fs / n)
        shape = (params["flicker_knee_hz"] / f) ** params["flicker_exponent"]
        for r in range(ctx.num_rx):
            w = 10 ** (params["rx_extra_white_db"][r] / 10)
            z = (rng.normal(size=n) + 1j * rng.normal(size=n)) * sigma / math.sqrt(2)
            z = np.fft.ifft(np.fft.fft(z) * np.sqrt(w + shape))
            out[fi, :, r] = z[idx]
    return out


# ------------------------------------------------------- outside the library
def draw_tx_droop(rng, ctx) -> dict:
    """Per-Tx power-amplifier droop over the frame (``outside:tx_droop``).

    Each PA heats while the frame's chirps fire and its gain sags
    exponentially (thermal time constant U(2, 6) ms) by U(0.5, 1.5) dB by the
    last chirp, recovering between frames.  Every library effect has the
    same amplitude in every chirp (channel gain, coupling, filters, IQ, DC)
    or only turns phase along slow time (ego / moving target, phase noise),
    so none can make a Tx-dependent amplitude ramp across chirps.
    """
    return {"droop_db": rng.uniform(0.5, 1.5, ctx.num_tx).tolist(),
            "time_constant_s": float(rng.uniform(2e-3, 6e-3))}


def droop_gain(params, rel_times) -> np.ndarray:
    """Amplitude gain ``[F, T, L]`` at chirp starts ``rel_times`` [s] from frame start."""
    tau = params["time_constant_s"]
    t_end = float(rel_times.max())
    shape = (1 - np.exp(-rel_times / tau)) / (1 - math.exp(-t_end / tau))
    return 10 ** (-np.asarray(params["droop_db"])[None, :, None] * shape / 20)


def draw_interference(rng, ctx) -> dict:
    """Another FMCW radar in the room (``outside:interference``).

    It sweeps from U(77, 78) GHz at U(0.3, 0.7) times our slope for U(40, 60)
    us every U(1.05, 1.6) ramps, with its own clock (random start, random
    phase per chirp), faces us within N(0, 10 deg) and radiates our EIRP
    +U(0, 6) dB.  Where its sweep crosses ours inside the IF band it leaves a
    short linear-FM burst (a few samples to a few tens of samples) in the
    chirps where the crossing happens; the anti-alias low-pass (4th-order
    Butterworth at 0.45 f_s, simulated at 8 f_s) shapes it.  No library
    effect mimics it: all are either tied to the scene's paths (a sum of beat
    tones with array-consistent phases), identical in every chirp, or
    stationary noise variances; this burst is non-stationary over chirps,
    spread over all range bins and independent of which Tx fires.
    """
    p = ctx.random_point(rng, 3.0, 7.0, 40.0, (0.8, 1.2))
    slope = float(rng.uniform(0.3, 0.7)) * ctx.radar.slope
    ramp = float(rng.uniform(40e-6, 60e-6))
    return {"position_m": p.tolist(), "start_hz": float(rng.uniform(77e9, 78e9)),
            "slope_hz_s": slope, "ramp_s": ramp, "period_s": ramp * float(rng.uniform(1.05, 1.6)),
            "start_offset_s": float(rng.uniform(0, 1e-4)), "power_db": float(rng.uniform(0, 6)),
            "pointing_error_deg": float(rng.normal(0, 10)), "seed": int(rng.integers(2 ** 31))}


_SIM_UP = 8                                      # interference simulated at 8 f_s


def _burst(params, ctx, t_chirp, t, grid_up, dist, amp, phases) -> np.ndarray | None:
    """Baseband burst ``[R, K]`` on grid ``t`` (``grid_up`` per ADC sample) of the chirp
    starting at ``t_chirp``; None if the sweeps do not cross."""
    fs, f0, s = ctx.radar.sample_rate, ctx.radar.start_frequency, ctx.radar.slope
    fi, si, ramp, period = (params[k] for k in ("start_hz", "slope_hz_s", "ramp_s", "period_s"))
    up = _SIM_UP
    tt = t[0] + np.arange(t.size * up // grid_up) / (fs * up)
    out, hit = np.zeros((dist.size, tt.size), complex), False
    t_abs = t_chirp + tt
    first = int(math.floor((t_abs[0] - dist.max() / C0 - params["start_offset_s"]) / period))
    last = int(math.floor((t_abs[-1] - params["start_offset_s"]) / period))
    for m in range(max(first, 0), last + 1):
        tm = params["start_offset_s"] + m * period
        local = t_abs[None, :] - dist[:, None] / C0 - tm                  # [R, K']
        on = (local >= 0) & (local <= ramp)
        df = f0 + s * tt[None, :] - fi - si * local
        if not np.any(on & (np.abs(df) < 1.5 * fs)):
            continue
        hit = True
        ph = f0 * tt + 0.5 * s * tt ** 2 - (fi * local + 0.5 * si * local ** 2)
        ph = ph - np.floor(ph) + phases[m % phases.size]
        out += np.where(on, amp[:, None] * np.exp(2j * np.pi * ph), 0)
    if not hit:
        return None
    b, a = signal.butter(4, 0.45 * fs, fs=fs * up)
    return signal.lfilter(b, a, out, axis=-1)[:, ::up // grid_up]


def interference(params, ctx, el, chirp_times, t, grid_up: int = 1) -> tuple:
    """Interference at our Rx, path units, ``[F, T, R, L, K]``, and the hit chirps ``[F, T, L]``.

    ``t`` is the fast-time grid with ``grid_up`` (a divisor of 8) instants per ADC sample.
    """
    rng = np.random.default_rng(params["seed"])
    phases = rng.uniform(0, 1, 4096)
    p = np.asarray(params["position_m"])
    d = np.linalg.norm(el.rx - p, axis=1)
    u = (p - el.rx) / d[:, None]
    g_rx = element_gain(u @ el.boresight)
    g_int = element_gain(np.cos(np.radians(params["pointing_error_deg"])))
    amp = (10 ** (params["power_db"] / 20) * ctx.lam * np.sqrt(g_int * g_rx)
           / (4 * np.pi * d))
    n_f, n_t, n_l = chirp_times.shape
    out = np.zeros((n_f, n_t, el.rx.shape[0], n_l, t.size), complex)
    hits = np.zeros((n_f, n_t, n_l), bool)
    for idx in np.ndindex(n_f, n_t, n_l):
        b = _burst(params, ctx, float(chirp_times[idx]), t, grid_up, d, amp, phases)
        if b is not None:
            out[idx[0], idx[1], :, idx[2]] = b
            hits[idx] = True
    return out, hits
