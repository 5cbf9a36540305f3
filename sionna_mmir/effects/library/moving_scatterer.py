"""A moving point target the (static) scene model lacks, with a per-frame state.

In frame ``f`` the target is at range ``r_f`` and azimuth ``az_f`` (seen from
the radar origin, elevation 0) at the frame start ``t_f = f * frame_period``
and moves radially at ``v_f``.  Its delay for Tx ``t``, Rx ``r`` at the ramp
start ``T_slow[f, t, c]`` of a chirp (:attr:`EffectContext.slow_time`,
TDM slots included) is::

    tau = tau_tr(f) + rho_f (T_slow - t_f),   rho_f = 2 v_f / c
    tau_tr(f) = (|p_f - tx_t| + |p_f - rx_r|) / c,   p_f = r_f (cos az_f, sin az_f, 0)

(exact per (tx, rx) for the static part; the radial motion shifts every pair
alike), advanced to the sample time ``T_slow + t_k``::

    x[f, t, r, c, k] += A_phys,f exp(j 2 pi (f0 + S t_k)(tau + rho_f t_k))

(:mod:`sionna_mmir.fmcw.model` plus its dropped ``S rho t_k^2`` term).

The stored amplitude is referred to the carrier phase of the frame's mean
position at the centre frequency ``f_c`` (and centre sample time ``t_c``)::

    A_f = A_phys,f exp(j 2 pi [f_c (2 r_f / c + rho_f dT_mean) + f_c rho_f t_c])

(``dT_mean`` the mean of ``T_slow - t_f`` over the frame's chirps), so range
and velocity move the beat frequency and the phase progression across
channels and chirps but do not rotate the frame's overall phase.

Parameters (``5 F`` numbers): ``range`` ``[F]`` [m], ``azimuth`` ``[F]``
[deg], ``velocity`` ``[F]`` [m/s] (positive receding), ``amp`` ``[F, 2]``
(re, im) [normalised units].  The init tracks the strongest peak of the
per-frame range profile of the residual's chirp-to-chirp deviation (of the
residual itself with one chirp loop) over frames (Viterbi with a speed limit),
refines it to sub-bin, takes velocities from the chirp-to-chirp phase
(``C > 1``) or the track's slope, azimuths from a matched-steering grid and
amplitudes by least squares -- all vectorised over frames.
"""
from __future__ import annotations

import numpy as np

from ...errors import ConfigError
from .. import ops
from ..base import Effect, ParamSpec
from ._sensor_common import chirp_deviation, parabolic_offset
from .scatterer import (C0, DrGeometry, beat_ranges, check_range_limits, dr_ref_phase,
                        ref_phase_np, single_blas)

dr, mi = ops.dr, ops.mi


# ------------------------------------------------------------- model
def _centre_time(radar) -> float:
    return (radar.center_frequency - radar.start_frequency) / radar.slope


def velocity_phase(ctx) -> np.ndarray:
    """Referred phase per unit radial velocity, ``[T, C, N]`` [rad per m/s]."""
    radar = ctx.radar
    f0, S, fc = radar.start_frequency, radar.slope, radar.center_frequency
    tk = ctx.fast_time[None, None, :]
    tc = _centre_time(radar)
    dT = radar.chirp_start_times()[:, :, None]                        # T_slow - t_f
    return (4 * np.pi / C0) * ((f0 + S * tk) * dT - fc * dT.mean()
                               + (f0 + S * tk) * tk - (f0 + S * tc) * tc)


def moving_signal_np(ctx, r, az_deg, v, amp) -> np.ndarray:
    """The target's ADC ``[F, T, R, C, N]`` (NumPy reference of :meth:`MovingScatterer.apply`).

    ``r``, ``az_deg``, ``v`` ``[F]``; ``amp`` complex ``[F]`` (referred).
    """
    p = np.asarray(r)[:, None] * _unit(az_deg)
    static = ref_phase_np(ctx, p, p)                                  # [F, T, R, N]
    vel = np.asarray(v)[:, None, None, None] * velocity_phase(ctx)    # [F, T, C, N]
    ph = static[:, :, :, None, :] + vel[:, :, None, :, :]
    return np.asarray(amp)[:, None, None, None, None] * np.exp(1j * ph)


#: elevations a static point may have [deg] when its radial velocity is judged
#: (:func:`moves_as_static`): the tracked azimuth is in the array's plane, the
#: floor and ceiling seen from the radar are not
STATIC_ELEVATION_DEG = 60.0


def moves_as_static(model, values) -> bool:
    """Whether a fitted track's radial velocity in every frame is that of a
    static point at its azimuth, at any elevation up to
    :data:`STATIC_ELEVATION_DEG`, to within half the radar's velocity
    resolution (:attr:`~sionna_mmir.radar.RadarConfig.velocity_resolution`).

    The static point's velocity is 0, or, where a component of ``model``
    moves the static scene (one with ``static_radial_velocity``, i.e. ego
    motion), ``-v cos(az) cos(el)``.  False with one chirp per frame (no
    velocity is resolved within a frame)."""
    ctx = model.ctx
    if ctx.shape[3] < 2:
        return False
    half = 0.5 * ctx.radar.velocity_resolution
    az = np.asarray(values["azimuth"], np.float64)
    v = np.asarray(values["velocity"], np.float64)
    ego = [c for c in model.components if hasattr(c.effect, "static_radial_velocity")]
    if ego:
        top = ego[0].effect.static_radial_velocity(ego[0].values, az)
        low = ego[0].effect.static_radial_velocity(ego[0].values, az, STATIC_ELEVATION_DEG)
    else:
        top = low = np.zeros_like(az)
    lo, hi = np.minimum(top, low) - half, np.maximum(top, low) + half
    return bool(np.all((v >= lo) & (v <= hi)))


def _unit(az_deg) -> np.ndarray:
    a = np.radians(np.asarray(az_deg, np.float64))
    return np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=-1)


# -------------------------------------------------------------- init
def range_profiles(residual, ctx, pad: int = 4):
    """Hann-windowed zero-padded range spectra ``[F, T, R, C, M]`` and their ranges ``[M]``."""
    N = ctx.radar.num_samples
    w = np.hanning(N + 2)[1:-1]
    spec = np.fft.fft(residual * w, pad * N, axis=-1)
    return spec, beat_ranges(ctx.radar, pad * N)


def track_bins(score, max_jump: int | None) -> np.ndarray:
    """Best path through ``score [F, M]`` (one bin per frame, ``|jump| <= max_jump``).

    Viterbi (dynamic programming) maximising the summed score; ``max_jump``
    None: every frame independent (arg max).  Returns bins ``[F]``.
    """
    F, M = score.shape
    if max_jump is None or max_jump >= M or F == 1:
        return np.argmax(score, axis=1)
    idx = np.arange(M)
    acc = score[0].copy()
    back = np.zeros((F, M), np.int64)
    for f in range(1, F):
        best = np.full(M, -np.inf)
        arg = idx.copy()
        for s in range(-max_jump, max_jump + 1):
            src = idx + s
            ok = (src >= 0) & (src < M)
            cand = np.where(ok, acc[np.clip(src, 0, M - 1)], -np.inf)
            better = cand > best
            best = np.where(better, cand, best)
            arg = np.where(better, np.clip(src, 0, M - 1), arg)
        acc = best + score[f]
        back[f] = arg
    path = np.empty(F, np.int64)
    path[-1] = int(np.argmax(acc))
    for f in range(F - 1, 0, -1):
        path[f - 1] = back[f, path[f]]
    return path


def _parabolic(logp, path) -> np.ndarray:
    """Sub-bin offsets of the peaks ``path [F]`` of ``logp [F, M]`` (wrapping)."""
    F, M = logp.shape
    f = np.arange(F)
    return parabolic_offset(logp[f, (path - 1) % M], logp[f, path], logp[f, (path + 1) % M])


def _track_slope(r, frame_period, half: int = 3) -> np.ndarray:
    """Local linear-fit slope of ``r [F]`` over ``+-half`` frames [m/s]."""
    F = len(r)
    out = np.zeros(F)
    for f in range(F):
        sl = slice(max(0, f - half), min(F, f + half + 1))
        t = np.arange(sl.start, sl.stop) * frame_period
        if len(t) > 1:
            out[f] = np.polyfit(t, r[sl], 1)[0]
    return out


def _chirp_velocity(y, ctx) -> np.ndarray:
    """Radial velocity [m/s] per frame from the loop-to-loop phase of ``y [F, T, R, C]``."""
    radar = ctx.radar
    z = np.sum(np.conj(y[..., :-1]) * y[..., 1:], axis=(1, 2, 3))
    return np.angle(z) / (2 * np.pi * radar.loop_period) * C0 / (2 * radar.start_frequency)


def _tone_values(residual, ctx, r) -> np.ndarray:
    """Matched tone of range ``r [F]`` in every channel and chirp: ``[F, T, R, C]``."""
    radar = ctx.radar
    tk = ctx.fast_time - _centre_time(radar)
    e = np.exp(-2j * np.pi * radar.slope * (2 * np.asarray(r) / C0)[:, None] * tk)   # [F, N]
    return np.einsum("ftrck,fk->ftrc", residual, e)


def _azimuths(y, ctx, v, az_limit) -> np.ndarray:
    """Azimuth [deg] per frame from channels ``y [F, T, R, C]`` (matched steering grid)."""
    radar = ctx.radar
    dT = radar.chirp_start_times()                                     # [T, C]
    dop = np.exp(-2j * np.pi * radar.start_frequency * (2 * v / C0)[:, None, None] * dT)
    yc = np.einsum("ftrc,ftc->ftr", y, dop)
    grid = np.arange(-az_limit, az_limit + 1e-9, 0.5)
    k = 2 * np.pi / radar.wavelength
    steer = np.exp(1j * k * np.einsum("tri,ai->tra", radar.virtual_positions(), _unit(grid)))
    power = np.abs(np.einsum("ftr,tra->fa", yc, steer)) ** 2
    j = np.argmax(power, axis=1)
    off = _parabolic(np.log(power + 1e-300), j)
    return np.clip(grid[j] + 0.5 * off, -az_limit, az_limit)


def track_init(residual, ctx, min_range, max_range, max_speed, az_limit=80.0):
    """Per-frame ``(r [F], az [F], v [F], amp [F] complex)`` of the strongest moving point.

    With several chirp loops the point is searched in the residual's
    chirp-to-chirp deviation (:func:`chirp_deviation`): a static scatterer the
    scene lacks repeats from chirp to chirp and drops out there however
    strong it is, a mover's Doppler progression stays.  Its range, velocity
    and azimuth come from the deviation, its amplitude from the residual.
    """
    radar = ctx.radar
    moving = chirp_deviation(residual)
    spec, ranges = range_profiles(residual if moving is None else moving, ctx)
    power = np.sum(np.abs(spec) ** 2, axis=(1, 2, 3))                   # [F, M]
    order = np.argsort(ranges)
    sel = order[(ranges[order] >= min_range) & (ranges[order] <= max_range)]
    if sel.size == 0:
        raise ConfigError(f"MovingScatterer: no range bin between min_range={min_range} m and "
                          f"max_range={max_range} m")
    amp = np.sqrt(power[:, sel])
    score = amp / np.maximum(amp.max(axis=1, keepdims=True), 1e-300)
    step = ranges[order[1]] - ranges[order[0]]
    jump = None
    if ctx.frame_period > 0:
        jump = int(np.ceil(max_speed * ctx.frame_period / step)) + 1
    path = sel[track_bins(score, jump)]
    off = _parabolic(np.log(power + 1e-300), path)
    r = ranges[path] + off * step * np.sign(radar.slope)
    y = _tone_values(residual if moving is None else moving, ctx, r)
    if radar.num_chirps > 1:
        v = _chirp_velocity(y, ctx)
    elif ctx.frame_period > 0 and len(r) > 2:
        v = _track_slope(r, ctx.frame_period)
    else:
        v = np.zeros(len(r))
    v = np.clip(v, -max_speed, max_speed)
    az = _azimuths(y, ctx, v, az_limit)
    s = moving_signal_np(ctx, r, az, v, np.ones(len(r)))
    a = np.einsum("ftrck,ftrck->f", np.conj(s), residual) / np.prod(s.shape[1:])
    return r, az, v, a


# ------------------------------------------------------------ effect
class MovingScatterer(Effect):
    """Moving point target with a per-frame state (``5 F`` parameters).

    Parameters
    ----------
    min_range : float, optional
        smallest range [m] searched at init
    max_range : float, optional
        largest range [m] (None: 95 % of the radar's max range)
    max_speed : float, optional
        speed limit [m/s] of the tracker and bound of ``v_f``
    range_margin : float, optional
        ``r_f`` may move this many range bins from its init
    az_limit : float, optional
        azimuth search range ``+-az_limit`` [deg]
    """

    name = "moving_scatterer"
    #: tracked over frames of one chirp each, a repeatable scene detail is
    #: adopted only while it explains this much (nats per held-out sample):
    #: diffuse clutter is not a list of movers (:meth:`gain_floor`)
    min_gain_per_sample = 0.1
    chirp_static = False
    kind = "mean"
    stage = 0
    #: added after ego motion: its velocity is relative to the radar
    chain_order = 0.75
    repeatable = True
    additive = True
    description = "moving point target (per-frame range, azimuth, velocity, amplitude)"

    def __init__(self, min_range: float = 0.3, max_range: float | None = None,
                 max_speed: float = 3.0, range_margin: float = 3.0, az_limit: float = 80.0):
        check_range_limits("MovingScatterer", min_range, max_range)
        if not np.isfinite(max_speed) or max_speed <= 0:
            raise ConfigError(f"MovingScatterer: max_speed must be > 0 m/s, got {max_speed}")
        if not np.isfinite(range_margin) or range_margin <= 0:
            raise ConfigError(f"MovingScatterer: range_margin must be > 0 bins, got {range_margin}")
        if not np.isfinite(az_limit) or not 0 < az_limit <= 90:
            raise ConfigError(f"MovingScatterer: az_limit must be in (0, 90] deg, got {az_limit}")
        self.min_range = float(min_range)
        self.max_range = None if max_range is None else float(max_range)
        self.max_speed = float(max_speed)
        self.range_margin = float(range_margin)
        self.az_limit = float(az_limit)

    def supports(self, ctx) -> bool:
        """A track over frames, or the chirp-to-chirp phase of one frame: on one
        chirp of one frame a mover is a static scatterer with a free velocity,
        which the held-out score cannot tell from ``missing_scatterer``."""
        return ctx.num_frames >= 2 or ctx.shape[3] >= 2

    def gain_floor(self, ctx) -> float:
        """:attr:`min_gain_per_sample` when the init tracks the residual itself
        (one chirp loop per frame); none beyond the loop's own with several
        loops, where the init sees only what changes from chirp to chirp and
        static clutter, however much of it the scene lacks, cannot pose as a
        mover (a weak walker explains a few thousandths of a nat per sample
        of a whole frame)."""
        return self.min_gain_per_sample if ctx.shape[3] < 2 else 0.0

    def fitted_gain_floor(self, model, values) -> float:
        """:attr:`min_gain_per_sample` also for a fitted track that moves as
        the static scene does (:func:`moves_as_static`): a point at rest, or,
        once ego motion is adopted, a static point seen from the moving
        radar.  Such a "mover" is a scatterer the mesh lacks and is held to
        the floor that keeps diffuse clutter from becoming a list of
        scatterers, as ``missing_scatterer`` is; else :meth:`gain_floor`."""
        if moves_as_static(model, values):
            return float(self.min_gain_per_sample)
        return self.gain_floor(model.ctx)

    @single_blas
    def param_specs(self, ctx, model, residual):
        radar = ctx.radar
        rmax = 0.95 * radar.max_range if self.max_range is None else self.max_range
        r, az, v, a = track_init(residual, ctx, self.min_range, rmax, self.max_speed,
                                 self.az_limit)
        m = self.range_margin * radar.range_resolution
        return {"range": ParamSpec(r, lower=np.maximum(r - m, 0.0), upper=r + m, unit="m"),
                "azimuth": ParamSpec(az, lower=-90.0, upper=90.0, unit="deg"),
                "velocity": ParamSpec(v, lower=-self.max_speed, upper=self.max_speed,
                                      unit="m/s"),
                "amp": ParamSpec(np.stack([a.real, a.imag], axis=1),
                                 unit="normalised (referred to f_c)")}

    def apply(self, x, p, ctx):
        F, T, R, C, N = ctx.shape
        lead = (F, 1, 1, 1, 1)
        geo = DrGeometry(ctx)
        r = ops.view(p["range"], lead)
        sa, ca = dr.sincos(ops.view(p["azimuth"], lead) * (np.pi / 180.0))
        P = [r * ca, r * sa, 0.0 * r]
        static = dr_ref_phase(geo, P, P, r, r)                                   # [F, T, R, 1, N]
        kv = ops.tensor(velocity_phase(ctx).reshape(1, T, 1, C, N))
        amp = (ops.column(p["amp"], 0, lead), ops.column(p["amp"], 1, lead))
        # exp(j (static + v kv)) as the product of its two factors, each evaluated
        # once: the sines and cosines are taken on [F, T, R, 1, N] and
        # [F, T, 1, C, N], not on every sample (and not again in the backward)
        near = ops.cmul(ops.cis(static), amp)                                     # [F, T, R, 1, N]
        track = ops.cis(ops.view(p["velocity"], lead) * kv)                      # [F, T, 1, C, N]
        dr.eval(near, track)
        return ops.cadd(x, ops.cmul(near, track))

    def silenced(self, values):
        """The mover with zero amplitude (its track kept)."""
        return {**values, "amp": np.zeros_like(np.asarray(values["amp"]))}

    def summary(self, p, ctx):
        r = np.asarray(p["range"], np.float64)
        az = np.asarray(p["azimuth"], np.float64)
        v = np.asarray(p["velocity"], np.float64)
        a = np.abs(np.asarray(p["amp"])[:, 0] + 1j * np.asarray(p["amp"])[:, 1])
        return {"range_m": r.round(4).tolist(), "azimuth_deg": az.round(2).tolist(),
                "velocity_m_s": v.round(4).tolist(), "amplitude_abs": a.round(6).tolist(),
                "range_span_m": [round(float(r.min()), 4), round(float(r.max()), 4)],
                "mean_speed_m_s": round(float(np.mean(np.abs(v))), 4)}
