"""Ego motion: the radar moves towards the scene at radial velocity ``v``.

A radar moving with velocity ``v`` along boresight shortens every path's
delay at the rate ``d tau / dt = -2 v cos(theta) / c`` (``theta`` the angle
between boresight and the path).  For a model that renders a static scene
(the radar at its ``t = 0`` pose) the moved scene is the static render with
every path's delay advanced by ``rho cos(theta) T`` (``rho = -2 v / c``,
``T = T_slow`` the ramp start of the chirp, :attr:`EffectContext.slow_time`,
TDM slots and frame times included).  A delay change ``d`` multiplies a path
``exp(j 2 pi (f0 + S t_k) tau)`` by ``exp(j 2 pi (f0 + S t_k) d)``.

The direction of the energy is taken from the current model signal ``x``
(treated as a constant: no gradient flows through it), elevation as 0
(``cos(theta) = cos(az)``), in two parts:

1. when up to ``max_directions`` (default 6) dominant scatterers explain 90 %
   of the energy of ``x`` (a few-scatterer scene): the strongest
   peaks of its range profile, each with its channel vector ``d_j`` over the
   virtual array (the range spectrum at the peak) and azimuth ``az_j``
   (matched steering).  The components ``x_j = d_j (D^+ x)_j`` (``D^+`` the
   pseudo-inverse of ``D = [d_j]``, per sample) move with the ego factor
   ``c_j[t, r] = (b . u_t + b . u_r) / 2`` of each Tx-Rx pair (``u_t``,
   ``u_r`` the unit vectors from the elements to the point at the peak's
   range and ``az_j``; ``cos(az_j)`` in the far field, :func:`pair_cosines`),
   whatever range bin their (sidelobe) energy is in;
2. the rest ``x_rest = x - sum_j x_j`` moves per unitary-DFT range bin ``k``
   with the bin's strongest azimuth ``cos(az_k)``.

Then::

    x' = [sum_j x_j e^{j 2 pi f_c rho c_j T} e^{j phi_fast c_j}
          + IDFT(DFT(x_rest) e^{j 2 pi f_c rho cos(az_k) T}) e^{j phi_fast}]
    phi_fast = 2 pi [S (t_k - t_c) rho T + (f0 + S t_k) rho t_k]

with ``T = T_slow[f, t, c]``: the delay advanced to the sample time
``T + t_k`` exactly (``(f0 + S t_k)(tau + rho (T + t_k))``); the small
fast-time terms (range migration ``S rho T`` about the centre sample
``t_c``, intra-chirp Doppler ``f0 rho t_k`` and ``S rho t_k^2``) of the
remainder use ``cos(theta) = 1``.  Exact (to float32 and the direction
estimate) for point scatterers in the chosen directions; a range bin holding
several other directions keeps the Doppler of its strongest one.  With
``angle_aware=False`` everything uses ``cos(theta) = 1``: the first-order
model, exact only for near-boresight energy (relative rate error
``1 - cos(theta)``, 10 % at 25 deg).

One parameter, ``velocity`` ``[1]`` [m/s], positive towards the scene
(approaching scene, negative Doppler in :mod:`sionna_mmir.processing.doppler_fft`'s
convention).
"""
from __future__ import annotations

import functools

import numpy as np
from scipy.optimize import minimize_scalar

from ...errors import ConfigError
from ...radar.config import SPEED_OF_LIGHT
from .. import ops
from ..base import Effect, ParamSpec
from ._sensor_common import filter_rows
from .scatterer import one_blas_thread, single_blas, static_view, unit_vectors

dr, mi = ops.dr, ops.mi


def _centre_time(radar) -> float:
    return (radar.center_frequency - radar.start_frequency) / radar.slope


def phase_per_velocity(ctx) -> np.ndarray:
    """First-order (``cos theta = 1``) ``d phase / d v`` ``[F, T, 1, C, N]`` [rad per m/s]."""
    bins, fast = phase_terms(ctx)
    return bins + fast


def phase_terms(ctx):
    """``d phase / d v`` split into the per-bin slow-time term ``2 pi f_c rho' T_slow``
    and the fast-time term ``2 pi [S (t_k - t_c) rho' T_slow + (f0 + S t_k) rho' t_k]``
    (``rho' = -2 / c``): ``([F, T, 1, C, 1], [F, T, 1, C, N])`` [rad per m/s]."""
    radar = ctx.radar
    f0, S, fc = radar.start_frequency, radar.slope, radar.center_frequency
    tk = ctx.fast_time[None, None, None, None, :]
    Ts = ctx.slow_time[:, :, None, :, None]
    k = 2 * np.pi * (-2.0 / SPEED_OF_LIGHT)
    return k * fc * Ts, k * (S * (tk - _centre_time(radar)) * Ts + (f0 + S * tk) * tk)


def steering(ctx, az_deg) -> np.ndarray:
    """Unit-norm far-field steering vectors ``[T * R, A]`` (elevation 0, centre wavelength)."""
    radar = ctx.radar
    k = 2 * np.pi / radar.wavelength
    v = radar.virtual_positions().reshape(-1, 3)
    a = np.exp(-1j * k * v @ unit_vectors(az_deg).T)
    return a / np.sqrt(v.shape[0])


@functools.lru_cache(maxsize=16)
def _grid_steering(key, step: float, az_limit: float):
    pos, wavelength = key
    v = np.frombuffer(pos).reshape(-1, 3)
    grid = np.arange(-az_limit, az_limit + 1e-9, step)
    a = np.exp(-1j * (2 * np.pi / wavelength) * v @ unit_vectors(grid).T) / np.sqrt(len(v))
    a.setflags(write=False)
    return grid, a


def grid_steering(ctx, step: float, az_limit: float):
    """``(grid [A] deg, steering [T * R, A])`` over ``-az_limit .. az_limit`` (cached per array)."""
    radar = ctx.radar
    key = (np.ascontiguousarray(radar.virtual_positions(), np.float64).tobytes(),
           float(radar.wavelength))
    return _grid_steering(key, float(step), float(az_limit))


def bin_cosines(z, ctx, az_limit: float = 80.0) -> np.ndarray:
    """``cos(az_k)`` ``[N]`` of the strongest azimuth per unitary-DFT bin of ``z [T, R, N]``."""
    T, R, N = z.shape
    Z = np.fft.fft(z, axis=-1).reshape(T * R, N)
    step = 1.0
    grid, A = grid_steering(ctx, step, az_limit)
    logp = np.log(np.abs(np.conj(A).T @ Z) ** 2 + 1e-300)                   # [A, N]
    j = np.clip(np.argmax(logp, axis=0), 1, len(grid) - 2)
    n = np.arange(N)
    lft, mid, rgt = logp[j - 1, n], logp[j, n], logp[j + 1, n]
    den = lft - 2 * mid + rgt
    off = np.clip(np.where(den < 0, 0.5 * (lft - rgt) / np.where(den < 0, den, -1.0), 0.0),
                  -0.5, 0.5)                                                 # parabolic peak
    return np.cos(np.radians(grid[j] + off * step))


def _beam_peak(d, ctx, az0, width):
    """Azimuth [deg] maximising the matched-steering power of ``d [T R]`` in ``az0 +- width``."""
    out = minimize_scalar(lambda a: -float(np.abs(np.vdot(steering(ctx, [a])[:, 0], d))),
                          bounds=(az0 - width, az0 + width), method="bounded",
                          options={"xatol": 1e-4})
    return float(out.x)


def dominant_directions(z, ctx, max_dirs: int, min_share: float = 1e-3,
                        max_corr: float = 0.95, min_explained: float = 0.9,
                        az_limit: float = 80.0):
    """Channel vectors of the strongest range peaks of ``z [T, R, N]``:
    ``(az [J] deg, D [T R, J], ranges [J] m)``.

    Local maxima of the range profile (unitary-DFT bins) in decreasing power,
    above ``min_share`` of the total, each giving its unit channel vector
    ``d_j = Z[:, k_j] / |Z[:, k_j]|`` (the scatterer's own array response,
    near field included) and its azimuth by matched steering; a vector that
    correlates more than ``max_corr`` with a chosen one (same direction) is
    skipped.  Unless the vectors explain ``min_explained`` of the energy of
    ``z`` (a few-scatterer scene) none is returned: a partial dictionary would
    give other directions' energy that projects on it the wrong Doppler.
    """
    T, R, N = z.shape
    Z = np.fft.fft(z, axis=-1).reshape(T * R, N)
    prof = np.sum(np.abs(Z) ** 2, axis=0)
    total = float(prof.sum())
    peaks = np.flatnonzero((prof >= np.roll(prof, 1)) & (prof >= np.roll(prof, -1)))
    peaks = peaks[np.argsort(prof[peaks])[::-1]]
    grid, A = grid_steering(ctx, 0.25, az_limit)
    az, cols, bins = [], [], []
    for k in peaks:
        if len(cols) >= max_dirs or total <= 0 or prof[k] < min_share * total:
            break
        d = Z[:, k] / np.linalg.norm(Z[:, k])
        if cols and np.max(np.abs(np.conj(np.stack(cols)) @ d)) > max_corr:
            continue
        cols.append(d)
        bins.append(k)
        az.append(_beam_peak(d, ctx, grid[int(np.argmax(np.abs(np.conj(A).T @ d)))], 0.25))
    none = np.zeros(0), np.zeros((T * R, 0), complex), np.zeros(0)
    if not cols:
        return none
    D = np.stack(cols, axis=1)
    explained = np.linalg.norm(D @ (np.linalg.pinv(D) @ Z)) ** 2 / max(total, 1e-300)
    if explained < min_explained:          # a rich scene: a partial dictionary would mis-move
        return none
    return np.array(az), D, np.abs(ctx.bin_ranges[np.array(bins)])


def pair_cosines(ctx, az_deg, ranges) -> np.ndarray:
    """Ego factor ``(b . u_t + b . u_r) / 2`` of every Tx-Rx pair for points at
    ``ranges`` [m] and azimuths ``az_deg`` [deg] (elevation 0) from the
    array centre, ``[J, T, R]``: ``b`` the boresight, ``u_t`` / ``u_r`` the
    unit vectors from each Tx / Rx to the point.  A moving radar shortens
    the pair's delay at ``-v (b . u_t + b . u_r) / c``; across a wide array
    in the near field the factor varies from pair to pair (the cascade's
    16 cm aperture at 2 m: +-1.2 deg of azimuth, 0.3 rad of Doppler phase
    over a 16-loop frame at 0.8 m/s), which one ``cos(az)`` per point misses.
    """
    tx = np.asarray(ctx.radar.tx_positions, np.float64)
    rx = np.asarray(ctx.radar.rx_positions, np.float64)
    centre = 0.5 * (tx.mean(axis=0) + rx.mean(axis=0))
    p = centre + np.asarray(ranges, np.float64)[:, None] * unit_vectors(az_deg)   # [J, 3]

    def boresight_share(el):
        d = p[:, None, :] - el[None]
        return d[..., 0] / np.linalg.norm(d, axis=-1)                              # [J, E]

    return 0.5 * (boresight_share(tx)[:, :, None] + boresight_share(rx)[:, None, :])


def _slow_correlation(model, data, ctx):
    """Per-chirp correlation ``z [F, T, C]`` of data with model and its slow-time phase rate."""
    z = np.einsum("ftrck,ftrck->ftc", np.conj(model), data)
    k0 = 2 * np.pi * (-2.0 / SPEED_OF_LIGHT) * ctx.radar.start_frequency * ctx.slow_time
    return z, k0


def _grid_best(z, k0, grid, coherent_frames: bool):
    """Velocity of ``grid`` with the largest (frame-coherent or per-frame) correlation."""
    best, score = grid[0], -np.inf
    for s in range(0, len(grid), 512):
        g = grid[s:s + 512]
        ph = np.exp(-1j * g[:, None, None, None] * k0[None])              # [G, F, T, C]
        per = np.sum(ph * z[None], axis=(2, 3))                             # [G, F]
        val = np.abs(per.sum(axis=1)) ** 2 if coherent_frames else np.sum(np.abs(per) ** 2, axis=1)
        j = int(np.argmax(val))
        if val[j] > score:
            best, score = g[j], val[j]
    return float(best)


def estimate_velocity(model, data, ctx, max_speed: float, max_grid: int = 20000) -> float:
    """Velocity [m/s] that best aligns ``model`` (static render) with ``data``.

    1. within frames (frame-incoherent sum of the per-frame correlation over
       TDM slots and chirp loops) on a grid over ``[-max_speed, max_speed]``;
    2. coherently over the whole capture on a finer grid about step 1;
    3. a bounded scalar search of the exact correlation (all phase terms; the
       model's complex gain is free, so only the alignment counts).
    """
    lam = SPEED_OF_LIGHT / ctx.radar.start_frequency
    z, k0 = _slow_correlation(model, data, ctx)
    intra = float(np.ptp(ctx.radar.chirp_start_times()))
    total = float(np.ptp(ctx.slow_time))
    if total <= 0:
        return 0.0
    v = 0.0
    half = max_speed
    if intra > 0:
        step = lam / (16 * intra)
        grid = np.linspace(-max_speed, max_speed, int(min(max_grid, 2 * max_speed / step + 1)))
        v = _grid_best(z, k0, grid, coherent_frames=False)
        half = min(max_speed, lam / (4 * intra))
    step = lam / (16 * total)
    n = int(min(max_grid, 2 * half / step + 1))
    grid = np.clip(np.linspace(v - half, v + half, n), -max_speed, max_speed)
    v = _grid_best(z, k0, grid, coherent_frames=True)
    dphi = phase_per_velocity(ctx)
    width = max(grid[1] - grid[0], lam / (8 * total)) if n > 1 else lam / (8 * total)

    def cost(vv):
        return -float(np.abs(np.vdot(model * np.exp(1j * vv * dphi), data)) ** 2)

    lo, hi = max(-max_speed, v - 2 * width), min(max_speed, v + 2 * width)
    out = minimize_scalar(cost, bounds=(lo, hi), method="bounded",
                          options={"xatol": 1e-4 * width})
    return float(out.x) if out.fun <= cost(v) else v


def _component(x, d, dp, shape):
    """``d (dp . x)`` over the channel axes of ``x`` (Dr.Jit): ``d``, ``dp`` complex ``[T * R]``."""
    F, T, R, C, N = shape
    dp = ops.tensor(dp.reshape(1, T, R, 1, 1))
    c = ops.cmul(x, dp)
    c = tuple(ops.view(dr.sum(dr.sum(ci, axis=1), axis=1), (F, 1, 1, C, N)) for ci in c)
    return ops.cmul(ops.tensor(d.reshape(1, T, R, 1, 1)), c)


class EgoMotion(Effect):
    """Radar moving towards the scene at radial velocity ``v`` (1 parameter).

    Parameters
    ----------
    max_speed : float, optional
        bound of ``|v|`` and of the init search [m/s]
    angle_aware : bool, optional
        Doppler ``cos(theta)`` per dominant direction and per
        range bin (default), or ``cos(theta) = 1`` everywhere
    max_directions : int, optional
        dominant scatterers moved as a whole (default 6)
    """

    name = "ego_motion"
    chirp_static = False
    kind = "mean"
    stage = 1
    #: after the scene's static paths, before the movers (whose velocities are
    #: relative to the radar already) and the RF chain
    chain_order = 0.5
    #: a mover adopted before it may be a static object seen from the moving
    #: radar: left out of its start, refitted beside it when it is scored
    may_replace = ("moving_scatterer",)
    description = "radar ego motion along boresight (slow-time Doppler of the static scene)"

    def __init__(self, max_speed: float = 5.0, angle_aware: bool = True,
                 max_directions: int = 6):
        if not np.isfinite(max_speed) or max_speed <= 0:
            raise ConfigError(f"EgoMotion: max_speed must be > 0 m/s, got {max_speed}")
        if not isinstance(angle_aware, (bool, np.bool_)):
            raise ConfigError(f"EgoMotion: angle_aware must be True or False, got {angle_aware!r}")
        if isinstance(max_directions, bool) or int(max_directions) != max_directions \
                or max_directions < 0:
            raise ConfigError(f"EgoMotion: max_directions must be an integer >= 0, "
                              f"got {max_directions!r}")
        self.max_speed = float(max_speed)
        self.angle_aware = bool(angle_aware)
        self.max_directions = int(max_directions)

    @single_blas
    def param_specs(self, ctx, model, residual):
        v = estimate_velocity(model, model + residual, ctx, self.max_speed)
        return {"velocity": ParamSpec([v], lower=-self.max_speed, upper=self.max_speed,
                                      unit="m/s")}

    def apply(self, x, p, ctx):
        F, T, R, C, N = ctx.shape
        v = ops.view(p["velocity"], (1, 1, 1, 1, 1))
        bins, fast = phase_terms(ctx)
        fast = np.broadcast_to(fast, (F, T, 1, C, N))
        if not self.angle_aware:
            return ops.cmul(x, ops.cis(ops.tensor(bins + fast) * v))
        with one_blas_thread():
            z = static_view(ops.to_numpy(x))                                 # [T, R, N]
            az, D, rng = dominant_directions(z, ctx, self.max_directions)
            Dp = np.linalg.pinv(D) if len(az) else None                      # [J, T R]
            cos_tr = pair_cosines(ctx, az, rng)                              # [J, T, R]
            if len(az):
                z = z - (D @ (Dp @ z.reshape(T * R, N))).reshape(T, R, N)
            cos_k = bin_cosines(z, ctx).reshape(1, 1, 1, 1, N)
        moved, rest = None, x
        if len(az):
            for j in range(len(az)):
                xj = _component(x, D[:, j], Dp[j], (F, T, R, C, N))
                rest = (rest[0] - xj[0], rest[1] - xj[1])
                cos_j = cos_tr[j].reshape(1, T, R, 1, 1)
                xj = ops.cmul(xj, ops.cis(ops.tensor((bins + fast) * cos_j) * v))
                moved = xj if moved is None else ops.cadd(moved, xj)
        xr = filter_rows(rest, None, [ops.cis(ops.tensor(bins * cos_k) * v)])[0]
        xr = ops.cmul(xr, ops.cis(ops.tensor(fast) * v))
        return xr if moved is None else ops.cadd(moved, xr)

    def silenced(self, values):
        """The radar at rest (velocity 0: the static scene unchanged)."""
        return {**values, "velocity": np.zeros_like(np.asarray(values["velocity"]))}

    @staticmethod
    def static_radial_velocity(values, az_deg, el_deg=0.0):
        """Radial velocity [m/s] (positive receding, a mover's convention) of
        a static point at azimuth ``az_deg`` and elevation ``el_deg`` seen
        from the radar moving at the fitted ``values["velocity"]``:
        ``-v cos(az) cos(el)``."""
        v = float(np.asarray(values["velocity"]).reshape(-1)[0])
        return -v * np.cos(np.radians(az_deg)) * np.cos(np.radians(el_deg))

    def summary(self, p, ctx):
        v = float(p["velocity"][0])
        lam = ctx.radar.wavelength
        return {"velocity_m_s": round(v, 6),
                "doppler_hz": round(-2 * v / lam, 3),
                "displacement_m": round(v * float(np.ptp(ctx.slow_time)), 5)}
