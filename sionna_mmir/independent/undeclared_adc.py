"""Raw FMCW ADC of point, mirror and fixed paths, written from first principles.

Independence: plain NumPy; nothing here comes from the package's FMCW
synthesiser, path solver or effects library.  Only the *convention* is shared
with :mod:`sionna_mmir.fmcw` so that captures read the same way.

Signal model
------------
For Tx ``i``, Rx ``j``, a chirp whose ramp starts at ``T`` (absolute time
[s], TDM slots and frames included) and fast time ``t`` [s] from the ramp
start, every path ``p`` contributes::

    a_ijp exp(+j 2 pi phi),
    phi = (f0 + S t) (tau_ijp(T) + rho_ijp t)            carrier x delay
          + tau e(t) - tau^2 e'(t) / 2                   ramp frequency error
          + Phi(T + t) - Phi(T + t - tau)                 LO phase noise [cycles]

``tau_ijp(T)`` is the exact delay of the pair at the chirp start, computed
from the element and scatterer positions at time ``T`` (so motion across
chirps and TDM slots is exact), ``rho = d tau / dt`` its rate within the
chirp (Doppler ``f0 rho`` and the tiny ``S rho t^2``).  The residual video
phase ``-S tau^2 / 2`` (< 2e-4 cycles at 10 m) is left out, as in the
package's convention.  ``e(t)`` is the ramp's instantaneous-frequency error
[Hz]; the two terms are the exact expansion of ``E(t) - E(t - tau)`` for
``E' = e`` up to ``tau^3 e''`` (< 1e-6 cycles here).

Amplitudes (monostatic radar equation per leg, ``G(theta) = 2 (q + 1)
cos^q theta`` element power gain, ``q`` = :data:`ELEMENT_Q`)::

    point:   a = coef sqrt(G(theta_t) G(theta_r)) / (R_t R_r),
             coef = lambda sqrt(sigma) Gamma e^{j psi} / (4 pi)^1.5
    mirror:  a = Gamma lambda sqrt(G G) / (4 pi L)       (specular plane, image Tx)

Phases are formed in float64, reduced modulo one cycle and evaluated in
float32 (error below 3e-4 rad); sums are float32 per chunk, accumulated in
complex128.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

C0 = 299_792_458.0
#: Exponent ``q`` of the ``cos^q`` element power pattern (half-power at +-45 deg).
ELEMENT_Q = 2.0
_CHUNK = 1_000_000          # elements of one [rows, R, P, K] phase block


def rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Rotation radar frame -> scene frame, ``Rz(yaw) Ry(pitch) Rx(roll)``, ``[3, 3]``."""
    cy, sy = math.cos(yaw), math.sin(yaw)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


@dataclasses.dataclass
class Elements:
    """Antenna phase centres in the scene frame at one instant.

    ``tx`` ``[T, 3]`` and ``rx`` ``[R, 3]`` [m]; ``boresight`` ``[3]`` unit
    vector; ``velocity`` ``[3]`` [m/s] of the whole array.
    """

    tx: np.ndarray
    rx: np.ndarray
    boresight: np.ndarray
    velocity: np.ndarray


def elements(radar, position, rot, velocity=None, t: float = 0.0) -> Elements:
    """Elements of ``radar`` at pose ``(position [3], rot [3, 3])`` moved by ``velocity * t``."""
    v = np.zeros(3) if velocity is None else np.asarray(velocity, float)
    origin = np.asarray(position, float) + v * t
    tx = origin + np.asarray(radar.tx_positions) @ rot.T
    rx = origin + np.asarray(radar.rx_positions) @ rot.T
    return Elements(tx, rx, rot[:, 0].copy(), v)


def element_gain(cos_theta: np.ndarray, q: float = ELEMENT_Q) -> np.ndarray:
    """Power gain ``2 (q + 1) cos^q theta`` (0 behind the array)."""
    return 2.0 * (q + 1.0) * np.clip(cos_theta, 0.0, None) ** q


@dataclasses.dataclass
class PointPaths:
    """Paths whose Tx leg ends at ``q_tx`` and whose Rx leg starts at ``q_rx``.

    ``q_tx``, ``q_rx`` ``[P, 3]`` [m] (equal for a plain point scatterer,
    an image point for a mirrored leg); ``coef`` ``[P]`` complex [m],
    ``lambda sqrt(sigma) Gamma e^{j psi} / (4 pi)^1.5``; ``velocity`` ``[P, 3]``
    [m/s] or None; ``strong`` paths also get LO phase noise.
    """

    q_tx: np.ndarray
    q_rx: np.ndarray
    coef: np.ndarray
    velocity: np.ndarray | None = None
    strong: bool = True

    def at(self, t: float) -> "PointPaths":
        """The paths with the scatterers moved to time ``t`` [s]."""
        if self.velocity is None:
            return self
        shift = self.velocity * t
        return dataclasses.replace(self, q_tx=self.q_tx + shift, q_rx=self.q_rx + shift)


@dataclasses.dataclass
class MirrorPaths:
    """Specular reflection of the radar in a finite plane (Tx -> plane -> Rx).

    ``origin`` ``[3]`` a corner of the rectangle, ``edge_u``, ``edge_v``
    ``[3]`` its two edges [m] (the normal is ``edge_u x edge_v``, towards
    the radar); ``gamma`` complex effective reflection coefficient.
    """

    origin: np.ndarray
    edge_u: np.ndarray
    edge_v: np.ndarray
    gamma: complex
    strong: bool = True
    velocity = None

    def at(self, t: float) -> "MirrorPaths":
        return self


@dataclasses.dataclass
class FixedPaths:
    """Paths rigid with the radar: ``tau`` [s] and ``amp`` ``[T, R, M]`` given."""

    tau: np.ndarray
    amp: np.ndarray
    strong: bool = True
    velocity = None

    def at(self, t: float) -> "FixedPaths":
        return self


def _legs(q: np.ndarray, e: np.ndarray, boresight, v_q, v_e):
    """Distances ``[E, P]``, element gains and range rates of the legs ``e -> q``."""
    d = q[None, :, :] - e[:, None, :]
    dist = np.linalg.norm(d, axis=-1)
    u = d / dist[..., None]
    gain = element_gain(u @ boresight)
    rel = (0.0 if v_q is None else v_q[None]) - v_e            # [3] or [1, P, 3]
    return dist, gain, np.sum(u * rel, axis=-1)


def _point_terms(g: PointPaths, el: Elements, rows):
    tx = el.tx[rows]
    d_t, g_t, r_t = _legs(g.q_tx, tx, el.boresight, g.velocity, el.velocity)
    d_r, g_r, r_r = _legs(g.q_rx, el.rx, el.boresight, g.velocity, el.velocity)
    tau = (d_t[:, None, :] + d_r[None, :, :]) / C0
    rate = (r_t[:, None, :] + r_r[None, :, :]) / C0
    amp = g.coef[None, None, :] * np.sqrt(g_t[:, None, :] * g_r[None, :, :]) / (
        d_t[:, None, :] * d_r[None, :, :])
    return tau, amp, rate


def _mirror_terms(g: MirrorPaths, el: Elements, rows, lam: float):
    n = np.cross(g.edge_u, g.edge_v)
    n = n / np.linalg.norm(n)
    tx = el.tx[rows]
    tx_img = tx - 2.0 * ((tx - g.origin) @ n)[:, None] * n
    d = tx_img[:, None, :] - el.rx[None, :, :]            # rx -> image tx
    length = np.linalg.norm(d, axis=-1)
    h_rx = (el.rx - g.origin) @ n
    h_img = (tx_img - g.origin) @ n
    frac = h_rx[None, :] / (h_rx[None, :] - h_img[:, None])
    spec = el.rx[None, :, :] + frac[..., None] * d          # specular points [T', R, 3]
    rel = spec - g.origin
    a = rel @ g.edge_u / (g.edge_u @ g.edge_u)
    b = rel @ g.edge_v / (g.edge_v @ g.edge_v)
    inside = (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1) & (h_rx[None, :] > 0)
    u_r = d / length[..., None]
    to_spec_t = spec - tx[:, None, :]
    u_t = to_spec_t / np.linalg.norm(to_spec_t, axis=-1, keepdims=True)
    gain = element_gain(u_t @ el.boresight) * element_gain(u_r @ el.boresight)
    amp = np.where(inside, g.gamma * lam * np.sqrt(gain) / (4 * np.pi * length), 0.0)
    v_img = el.velocity - 2.0 * (el.velocity @ n) * n
    rate = (u_r @ (v_img - el.velocity)) / C0
    return (length / C0)[..., None], amp[..., None].astype(complex), rate[..., None]


def pair_terms(group, el: Elements, lam: float, rows=None):
    """Per-pair ``(tau [s], amp, rate [s/s])``, each ``[T', R, P]``, of one path group.

    ``rows`` selects Tx indices (default all).  Fixed paths have rate 0.
    """
    rows = np.arange(el.tx.shape[0]) if rows is None else np.atleast_1d(rows)
    if isinstance(group, PointPaths):
        return _point_terms(group, el, rows)
    if isinstance(group, MirrorPaths):
        return _mirror_terms(group, el, rows, lam)
    tau = np.asarray(group.tau, float)[rows]
    return tau, np.asarray(group.amp, complex)[rows], np.zeros_like(tau)


@dataclasses.dataclass
class RampError:
    """Chirp instantaneous-frequency error over the ramp (quadratic + cubic).

    ``e(t) = b2 (u^2 - 1/3) + b3 u^3`` [Hz], ``u = 2 t / ramp - 1``, so the
    error has zero mean over the whole ramp ``[0, ramp]`` [s].
    """

    b2: float
    b3: float
    ramp: float

    def e(self, t):
        """Frequency error ``[K]`` [Hz] at fast times ``t`` [s]."""
        u = 2.0 * np.asarray(t) / self.ramp - 1.0
        return self.b2 * (u * u - 1.0 / 3.0) + self.b3 * u ** 3

    def de(self, t):
        """Its time derivative ``[K]`` [Hz/s]."""
        u = 2.0 * np.asarray(t) / self.ramp - 1.0
        return (2.0 / self.ramp) * (2.0 * self.b2 * u + 3.0 * self.b3 * u * u)


@dataclasses.dataclass
class LOPhase:
    """LO phase ``Phi`` [cycles] sampled every ``dt`` [s] from ``t0`` [s] (linear interpolation)."""

    t0: float
    dt: float
    phi: np.ndarray

    def at(self, t):
        """``Phi(t)`` [cycles] for any array of absolute times ``t`` [s] (held at the ends)."""
        x = np.clip((np.asarray(t) - self.t0) / self.dt, 0.0, self.phi.size - 1.000001)
        i = x.astype(np.int64)
        w = x - i
        return self.phi[i] * (1.0 - w) + self.phi[i + 1] * w


def _phase(radar, tau, rate, t, ramp, lo, t_chirp):
    """Beat phase [cycles] modulo one, float32 ``[..., P, K]``."""
    f0, s = radar.start_frequency, radar.slope
    t_ref = float(t[0])
    dt = (t - t_ref).astype(np.float32)
    c0 = f0 * tau + (s * tau + f0 * rate) * t_ref + s * rate * t_ref ** 2
    c1 = s * tau + f0 * rate + 2.0 * s * rate * t_ref
    ph = np.multiply(c1.astype(np.float32)[..., None], dt)
    ph += (c0 - np.floor(c0)).astype(np.float32)[..., None]
    if np.any(rate):
        ph += (s * rate).astype(np.float32)[..., None] * (dt * dt)
    if ramp is not None:
        tau32 = tau.astype(np.float32)[..., None]
        ph += tau32 * ramp.e(t).astype(np.float32)
        ph -= (0.5 * tau32 * tau32) * ramp.de(t).astype(np.float32)
    if lo is not None:
        t_abs = t_chirp + t
        ph += (lo.at(t_abs)[None] - lo.at(t_abs - tau[..., None])).astype(np.float32)
    ph -= np.rint(ph)
    return ph


def render_rows(radar, tau, amp, rate, t, ramp=None, lo=None, t_chirp=0.0) -> np.ndarray:
    """Sum of paths ``[T', R, P]`` at fast times ``t`` ``[K]`` -> complex128 ``[T', R, K]``."""
    rows, n_rx, n_p = tau.shape
    out = np.zeros((rows, n_rx, t.size), complex)
    step = max(1, _CHUNK // max(1, rows * n_rx * t.size))
    for lo_p in range(0, n_p, step):
        sl = slice(lo_p, lo_p + step)
        ang = _phase(radar, tau[..., sl], rate[..., sl], t, ramp, lo, t_chirp)
        ang *= np.float32(2 * np.pi)
        c, s = np.cos(ang), np.sin(ang)
        a = amp[..., sl]
        ar, ai = a.real.astype(np.float32), a.imag.astype(np.float32)
        re = np.einsum("trp,trpk->trk", ar, c) - np.einsum("trp,trpk->trk", ai, s)
        im = np.einsum("trp,trpk->trk", ar, s) + np.einsum("trp,trpk->trk", ai, c)
        out += re + 1j * im
    return out


@dataclasses.dataclass
class Motion:
    """Radar pose and motion: ``position`` [m], ``rot`` ``[3, 3]``, ``velocity`` [m/s]."""

    position: np.ndarray
    rot: np.ndarray
    velocity: np.ndarray | None = None


def _varying(group, motion, lo) -> bool:
    return (group.velocity is not None or motion.velocity is not None
            or (lo is not None and group.strong))


def _terms(groups, el: Elements, lam: float, rows=None, t: float | None = None):
    """``(tau, amp, rate)`` of several groups concatenated along the path axis."""
    parts = [pair_terms(g if t is None else g.at(t), el, lam, rows) for g in groups]
    return tuple(np.concatenate([p[k] for p in parts], axis=-1) for k in range(3))


def render(radar, groups, motion: Motion, t, chirp_times, *, ramp=None, lo=None,
           dtau=None) -> np.ndarray:
    """Noise-free beat signal of all path groups, complex128 ``[F, T, R, L, K]``.

    ``t`` ``[K]`` fast times from ramp start [s]; ``chirp_times`` ``[F, T, L]``
    absolute ramp starts [s] (TDM schedule and frame offsets); ``dtau``
    ``[T, R]`` [s] extra delay of every path of a channel (RF chain delays);
    ``ramp`` a :class:`RampError`; ``lo`` one :class:`LOPhase` per frame.
    Groups that move (or get LO phase noise) are evaluated chirp by chirp
    with the geometry at the chirp start; the rest once.
    """
    n_f, n_t, n_l = chirp_times.shape
    lam = C0 / radar.center_frequency
    dtau = np.zeros((n_t, radar.num_rx)) if dtau is None else dtau
    out = np.zeros((n_f, n_t, radar.num_rx, n_l, t.size), complex)
    static = [g for g in groups if not _varying(g, motion, lo)]
    if static:
        tau, amp, rate = _terms(static, elements(radar, motion.position, motion.rot), lam)
        out += render_rows(radar, tau + dtau[..., None], amp, rate, t, ramp)[:, :, None]
    moving = [g for g in groups if _varying(g, motion, lo)]
    sets = [(s, lo is not None and s) for s in (True, False)]
    for f, i, li in np.ndindex(n_f, n_t, n_l) if moving else ():
        tc = float(chirp_times[f, i, li])
        el = elements(radar, motion.position, motion.rot, motion.velocity, tc)
        for strong, with_lo in sets:
            sel = [g for g in moving if bool(g.strong) == strong]
            if sel:
                tau, amp, rate = _terms(sel, el, lam, [i], tc)
                out[f, i, :, li] += render_rows(
                    radar, tau + dtau[i][None, :, None], amp, rate, t, ramp,
                    lo[f] if with_lo else None, tc)[0]
    return out
