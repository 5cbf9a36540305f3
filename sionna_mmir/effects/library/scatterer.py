"""A static point scatterer the scene lacks (plus the point-target geometry the
scene effects share).

Physical model (one extra specular point at ``p``, seen from the radar origin)::

    p      = r (cos el cos az, cos el sin az, sin el)                   [m]
    tau_tr = (|p - tx_t| + |p - rx_r|) / c                              [s]
    x[f, t, r, c, k] += A_phys exp(j 2 pi (f0 + S t_k) tau_tr)

exact per (tx, rx) pair (near field included).  The stored amplitude is
referred to the carrier phase of the range ``r`` at the centre frequency
``f_c`` (:attr:`RadarConfig.center_frequency`)::

    A = A_phys exp(+j 2 pi f_c 2 r / c)

so a change of ``r`` moves the beat frequency and the channel phases but not
the overall phase: the loss does not oscillate with period ``lambda / 2`` in
``r``, and the float32 phases stay small (:func:`ref_phase_np`).  The
summary reports ``A_phys``.

Parameters: ``range`` [m], ``azimuth`` [deg], ``elevation`` [deg] (only when
the array has an elevation aperture, or as ``fit_elevation`` says; otherwise
``el = 0``), ``amp`` (re, im)
[normalised ADC units]: 4 or 5 real numbers.  Several instances may be added
(``repeatable``); each one starts on the strongest peak of the residual's
range-azimuth map that is left.
"""
from __future__ import annotations

import functools

import numpy as np
from scipy.optimize import minimize

from ...utils.threads import one_blas_thread
from ...errors import ConfigError
from ...radar.config import SPEED_OF_LIGHT
from .. import ops
from ..base import Effect, ParamSpec
from ..scene_basis import behind_ground

dr, mi = ops.dr, ops.mi
C0 = SPEED_OF_LIGHT


# ------------------------------------------------------------- threads
def single_blas(fn):
    """Decorator: run ``fn`` under :func:`one_blas_thread`."""
    @functools.wraps(fn)
    def wrapped(*args, **kwargs):
        with one_blas_thread():
            return fn(*args, **kwargs)
    return wrapped


# --------------------------------------------------------------- geometry
def unit_vectors(az_deg, el_deg=0.0) -> np.ndarray:
    """Unit direction(s) ``[..., 3]`` for azimuth / elevation [deg] (radar frame)."""
    az = np.radians(np.asarray(az_deg, np.float64))
    el = np.radians(np.asarray(el_deg, np.float64))
    az, el = np.broadcast_arrays(az, el)
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1)


def has_elevation_aperture(radar, tol: float = 1e-6) -> bool:
    """Whether the virtual array spans more than one height (``z``)."""
    z = radar.virtual_positions()[..., 2]
    return bool(np.ptp(z) > tol)


def excess_np(points, elems) -> np.ndarray:
    """``|p - a| - |p|`` for points ``[..., 3]`` and elements ``[n, 3]`` -> ``[..., n]`` [m].

    Written as ``(|a|^2 - 2 p.a) / (|p - a| + |p|)`` (no cancellation).
    """
    p = np.asarray(points, np.float64)[..., None, :]
    a = np.asarray(elems, np.float64)
    dist = np.linalg.norm(p - a, axis=-1)
    norm = np.linalg.norm(p, axis=-1)
    return (np.sum(a * a, axis=-1) - 2.0 * np.sum(p * a, axis=-1)) / (dist + norm)


def _freq_terms(ctx):
    """``(2 pi (f0 + S t_k) / c, 2 pi S (t_k - t_c) / c)``, each ``[N]`` [rad/m]."""
    radar = ctx.radar
    tk = ctx.fast_time
    tc = (radar.center_frequency - radar.start_frequency) / radar.slope
    return (2 * np.pi * (radar.start_frequency + radar.slope * tk) / C0,
            2 * np.pi * radar.slope * (tk - tc) / C0)


def ref_phase_np(ctx, p_tx, p_rx) -> np.ndarray:
    """Referred phase of the path Tx -> ``p_tx`` ... ``p_rx`` -> Rx, ``[..., T, R, N]`` [rad].

    ``p_tx`` / ``p_rx`` ``[..., 3]``: the (image) point the Tx / the Rx sees
    (the same point for a direct path).  With ``tau = (|p_tx - tx| + |p_rx - rx|)/c``
    and ``tau_o = (|p_tx| + |p_rx|) / c`` (delay seen from the origin)::

        phase = 2 pi (f0 + S t_k) tau - 2 pi f_c tau_o
              = 2 pi (f0 + S t_k)(tau - tau_o) + 2 pi S (t_k - t_c) tau_o
    """
    radar = ctx.radar
    fk, sk = _freq_terms(ctx)
    et = excess_np(p_tx, radar.tx_positions)                   # [..., T]
    er = excess_np(p_rx, radar.rx_positions)                   # [..., R]
    no = np.linalg.norm(p_tx, axis=-1) + np.linalg.norm(p_rx, axis=-1)
    return (fk * (et[..., :, None, None] + er[..., None, :, None])
            + sk * no[..., None, None, None])


def carrier_phase(ctx, path_length) -> np.ndarray:
    """``2 pi f_c L / c``: the phase :func:`ref_phase_np` removes for an origin path length
    ``L`` [m]."""
    return 2 * np.pi * ctx.radar.center_frequency * np.asarray(path_length) / C0


class DrGeometry:
    """Dr.Jit constants for :func:`dr_ref_phase` (element coordinates, frequency terms)."""

    def __init__(self, ctx):
        radar = ctx.radar
        T, R, N = radar.num_tx, radar.num_rx, radar.num_samples
        tx, rx = radar.tx_positions, radar.rx_positions
        self.tx = [ops.tensor(tx[:, i].reshape(1, T, 1, 1, 1)) for i in range(3)]
        self.rx = [ops.tensor(rx[:, i].reshape(1, 1, R, 1, 1)) for i in range(3)]
        self.tx2 = ops.tensor(np.sum(tx * tx, axis=1).reshape(1, T, 1, 1, 1))
        self.rx2 = ops.tensor(np.sum(rx * rx, axis=1).reshape(1, 1, R, 1, 1))
        fk, sk = _freq_terms(ctx)
        self.fk = ops.tensor(fk.reshape(1, 1, 1, 1, N))
        self.sk = ops.tensor(sk.reshape(1, 1, 1, 1, N))


def _dr_excess(P, norm, elems, elems2):
    """``|P - a| - |P|`` (Dr.Jit, stable form); ``P`` a 3-list, ``norm = |P|``."""
    d2 = sum(dr.square(P[i] - elems[i]) for i in range(3))
    dot = sum(P[i] * elems[i] for i in range(3))
    return (elems2 - 2.0 * dot) / (dr.sqrt(d2) + norm)


def dr_norm(P):
    return dr.sqrt(dr.square(P[0]) + dr.square(P[1]) + dr.square(P[2]))


def dr_ref_phase(geo: DrGeometry, P_tx, P_rx, norm_tx=None, norm_rx=None):
    """Dr.Jit version of :func:`ref_phase_np`: phase ``[.., T, R, 1, N]``.

    ``P_tx`` / ``P_rx``: lists of 3 coordinates (width-1 ``mi.Float`` or
    tensors broadcastable to ``[F, 1, 1, 1, 1]``); optional known norms.
    """
    nt = dr_norm(P_tx) if norm_tx is None else norm_tx
    nr = dr_norm(P_rx) if norm_rx is None else norm_rx
    et = _dr_excess(P_tx, nt, geo.tx, geo.tx2)                  # [.., T, 1, 1, 1]
    er = _dr_excess(P_rx, nr, geo.rx, geo.rx2)                  # [.., 1, R, 1, 1]
    return geo.fk * (et + er) + geo.sk * (nt + nr)


# ------------------------------------------------------------ detection
def static_view(x) -> np.ndarray:
    """Frame- and chirp-mean ``[T, R, N]`` of ``[F, T, R, C, N]`` (static part).

    Cells that are all zero (held out by a cross-validation mask) are left
    out of the mean; a channel with no observed cell stays zero.
    """
    x = np.asarray(x)
    seen = np.any(x != 0, axis=-1)                                   # [F, T, R, C]
    count = seen.sum(axis=(0, 3))
    return x.sum(axis=(0, 3)) / np.maximum(count, 1)[..., None]


def beat_ranges(radar, M: int) -> np.ndarray:
    """Range [m] of each bin of an ``M``-point FFT over samples (complex sampling:
    beat frequencies ``0 .. f_s`` map to ``0 .. max_range``; either slope sign)."""
    f = np.fft.fftfreq(M, 1.0 / radar.sample_rate)
    return np.mod(f / radar.slope, radar.sample_rate / abs(radar.slope)) * C0 / 2.0


def range_azimuth_map(z, ctx, az_deg, el_deg=0.0, pad: int = 4):
    """Range-azimuth power map of channels ``z [T, R, N]`` by direct matched steering.

    Hann-windowed, ``pad``-times zero-padded range FFT, then for every
    azimuth the far-field steering ``exp(+j k (tx + rx) . u(az, el))`` summed
    over the (tx, rx) pairs (``k = 2 pi / lambda`` at the centre frequency).
    Returns ``(power [M, A], ranges [M] m)``.
    """
    radar = ctx.radar
    N = radar.num_samples
    M = pad * N
    w = np.hanning(N + 2)[1:-1]
    Z = np.fft.fft(z * w, M, axis=-1)                                        # [T, R, M]
    ranges = beat_ranges(radar, M)
    u = unit_vectors(az_deg, el_deg)                                         # [A, 3]
    v = radar.virtual_positions()                                            # [T, R, 3]
    k = 2 * np.pi / radar.wavelength
    steer = np.exp(1j * k * (v.reshape(-1, 3) @ u.T))                      # [T R, A]
    beam = Z.reshape(-1, M).T @ steer
    return np.abs(beam) ** 2, ranges


def seen_channels(z) -> np.ndarray:
    """``[T, R]``: the channels of ``z [T, R, N]`` with any non-zero sample (the
    others are held out by a cross-validation mask)."""
    return np.any(np.asarray(z) != 0, axis=-1)


def matched_power(z, ctx, p, seen=None) -> tuple:
    """``(|s^H z|^2 / |s|^2, A)`` of the referred point signal ``s`` at ``p [3]`` on
    ``z [T, R, N]``, over the ``seen`` channels ``[T, R]`` (default all): with
    held-out channels zeroed, the signal's energy there must not count, or the
    least-squares amplitude ``A`` shrinks by the share held out."""
    ph = ref_phase_np(ctx, p, p)
    c = np.sum((np.cos(ph) - 1j * np.sin(ph)) * z)
    n = ph.size if seen is None else ph.shape[-1] * max(int(np.sum(seen)), 1)
    return float(abs(c) ** 2 / n), complex(c / n)


def refine_point(z, ctx, r0, az0, el0=0.0, fit_el=False, seen=None):
    """Local maximum of the exact matched filter from ``(r0, az0, el0)``.

    Nelder-Mead over ``(r [m], az [deg][, el [deg]])``.  Returns ``(r, az,
    el, A_ref)`` with ``A_ref`` the LS amplitude of the referred signal on
    the ``seen`` channels (:func:`matched_power`).
    """
    res = ctx.radar.range_resolution

    def point(v):
        return v[0] * unit_vectors(v[1], v[2] if fit_el else el0)

    def cost(v):
        return -matched_power(z, ctx, point(v), seen)[0]

    x0 = np.array([r0, az0] + ([el0] if fit_el else []), np.float64)
    step = np.array([res / 4, 1.0] + ([3.0] if fit_el else []))
    simplex = np.vstack([x0] + [x0 + np.diag(step)[i] for i in range(len(x0))])
    f0 = abs(cost(x0))
    out = minimize(cost, x0, method="Nelder-Mead",       # a polish: the fit refines further
                   options={"initial_simplex": simplex, "xatol": 1e-4, "fatol": 1e-7 * f0,
                            "maxiter": 80 * len(x0)})
    v = out.x
    el = float(v[2]) if fit_el else float(el0)
    _, a = matched_power(z, ctx, point(v), seen)
    return float(v[0]), float(v[1]), el, a


def _grid_peak(z, ctx, min_range, max_range, az_grid):
    """``(range [m], az [deg], power)`` of the range-azimuth map's peak in range."""
    power, ranges = range_azimuth_map(z, ctx, az_grid)
    ok = (ranges >= min_range) & (ranges <= max_range)
    if not ok.any():
        raise ConfigError(f"no range bin between min_range={min_range} m and "
                          f"max_range={max_range} m")
    power = np.where(ok[:, None], power, -1.0)
    m, a = np.unravel_index(int(np.argmax(power)), power.shape)
    return ranges[m], az_grid[a], power[m, a]


def strongest_points(z, ctx, min_range, max_range, fit_el, count=1, az_limit=80.0,
                     depth_db=30.0):
    """Up to ``count`` strongest points of ``z [T, R, N]``, strongest first, by
    CLEAN: the grid peak of the range-azimuth map, refined, its point signal
    subtracted, again, until a peak is ``depth_db`` under the first (so a
    point's side lobes are never taken for another point).

    Channels that are all zero (held out) stay out of the amplitudes and the
    subtraction (:func:`matched_power`).

    Returns ``[(r [m], az [deg], el [deg], A_ref)]`` (at least one).
    """
    az_grid = np.arange(-az_limit, az_limit + 1e-9, 0.5)
    z = np.array(z, dtype=complex)
    seen = seen_channels(z)
    out, first = [], None
    for _ in range(max(int(count), 1)):
        r0, az0, pw = _grid_peak(z, ctx, min_range, max_range, az_grid)
        first = pw if first is None else first
        if pw < first * 10 ** (-depth_db / 10):
            break
        r, az, el, amp = refine_point(z, ctx, r0, az0, seen=seen)
        if fit_el:
            el_grid = np.arange(-45.0, 45.1, 3.0)
            pw = [matched_power(z, ctx, r * unit_vectors(az, e), seen)[0] for e in el_grid]
            r, az, el, amp = refine_point(z, ctx, r, az, el_grid[int(np.argmax(pw))],
                                          fit_el=True, seen=seen)
        out.append((r, az, el, amp))
        z -= amp * np.exp(1j * ref_phase_np(ctx, *(2 * [r * unit_vectors(az, el)]))) \
            * seen[..., None]
    return out


def strongest_point(z, ctx, min_range, max_range, fit_el, az_limit=80.0):
    """Strongest point of ``z [T, R, N]``: grid peak of the range-azimuth map, refined.

    Returns ``(r [m], az [deg], el [deg], A_ref)``.
    """
    return strongest_points(z, ctx, min_range, max_range, fit_el, 1, az_limit)[0]


def check_range_limits(cls_name, min_range, max_range):
    """ConfigError unless ``0 <= min_range < max_range`` (``max_range`` may be None)."""
    if not np.isfinite(min_range) or min_range < 0:
        raise ConfigError(f"{cls_name}: min_range must be >= 0 m, got {min_range}")
    if max_range is not None and (not np.isfinite(max_range) or max_range <= min_range):
        raise ConfigError(f"{cls_name}: max_range must be > min_range ({min_range} m), "
                          f"got {max_range}")


# --------------------------------------------------------------- effect
class MissingScatterer(Effect):
    """A static point scatterer missing from the scene (4 or 5 parameters).

    Parameters
    ----------
    min_range : float, optional
        smallest range [m] searched at init (skips DC/coupling)
    max_range : float, optional
        largest range [m] searched (None: 95 % of max range)
    range_margin : float, optional
        the fitted range may move this many range bins from init
    fit_elevation : bool, optional
        None: fit ``el`` when the array has an elevation
        aperture; False: ``el = 0``; True: always
    """

    name = "missing_scatterer"
    #: a repeatable scene detail is adopted only while it explains this much
    #: (nats per held-out sample): diffuse clutter is not a list of missing scatterers
    min_gain_per_sample = 0.1
    kind = "mean"
    stage = 0
    repeatable = True
    additive = True
    description = "static point scatterer the scene lacks (exact per-pair delays)"

    def __init__(self, min_range: float = 0.1, max_range: float | None = None,
                 range_margin: float = 3.0, fit_elevation: bool | None = None):
        check_range_limits("MissingScatterer", min_range, max_range)
        if fit_elevation is not None and not isinstance(fit_elevation, (bool, np.bool_)):
            raise ConfigError(f"MissingScatterer: fit_elevation must be None, True or False, "
                              f"got {fit_elevation!r}")
        self.fit_elevation = None if fit_elevation is None else bool(fit_elevation)
        if not np.isfinite(range_margin) or range_margin <= 0:
            raise ConfigError(f"MissingScatterer: range_margin must be > 0 bins, "
                              f"got {range_margin}")
        self.min_range = float(min_range)
        self.max_range = None if max_range is None else float(max_range)
        self.range_margin = float(range_margin)

    @single_blas
    def param_specs(self, ctx, model, residual):
        radar = ctx.radar
        fit_el = (has_elevation_aperture(radar) if self.fit_elevation is None
                  else self.fit_elevation)
        rmax = 0.95 * radar.max_range if self.max_range is None else self.max_range
        r, az, el, a = strongest_point(static_view(residual), ctx, self.min_range, rmax, fit_el)
        margin = self.range_margin * radar.range_resolution
        specs = {"range": ParamSpec([r], lower=max(0.0, r - margin), upper=r + margin, unit="m"),
                 "azimuth": ParamSpec([az], lower=-90.0, upper=90.0, unit="deg")}
        if fit_el:
            specs["elevation"] = ParamSpec([el], lower=-90.0, upper=90.0, unit="deg")
        specs["amp"] = ParamSpec([a.real, a.imag], unit="normalised (referred to f_c, 2r/c)")
        return specs

    def fitted_gain_floor(self, model, values) -> float:
        """Infinite for a point the radar would see through the ground: its
        line of sight crosses one of the scene's ground objects and it lies
        more than :data:`~sionna_mmir.effects.scene_basis.GROUND_MARGIN_M`
        below it (:func:`~sionna_mmir.effects.scene_basis.behind_ground`).
        What is fitted there is a multipath image via the ground or a
        sensor artefact: in the suite's rooms and halls the ghost runs'
        floor images (1.1-1.6 m under the floor) were adopted as points, and
        in the AWR1843 room of seed 2 a point 6.5 m under the floor, where
        the complex ADC folds the IQ image of a corner at 1.8 m, took the
        planted IQ imbalance's gain.  Else :meth:`gain_floor`."""
        grounds = getattr(model.ctx.basis, "grounds", None) or []
        if grounds:
            el = float(values["elevation"][0]) if "elevation" in values else 0.0
            point = float(values["range"][0]) * unit_vectors(float(values["azimuth"][0]), el)
            if behind_ground(point, grounds):
                return float("inf")
        return self.gain_floor(model.ctx)

    def apply(self, x, p, ctx):
        one = (1, 1, 1, 1, 1)
        geo = DrGeometry(ctx)
        r = ops.view(p["range"], one)
        sa, ca = dr.sincos(ops.view(p["azimuth"], one) * (np.pi / 180.0))
        se, ce = (dr.sincos(ops.view(p["elevation"], one) * (np.pi / 180.0))
                  if "elevation" in p else (0.0, 1.0))
        P = [r * ce * ca, r * ce * sa, r * se]
        phase = dr_ref_phase(geo, P, P, r, r)                              # [1, T, R, 1, N]
        amp = (ops.column(ops.view(p["amp"], (1, 2)), 0, one),
               ops.column(ops.view(p["amp"], (1, 2)), 1, one))
        return ops.cadd(x, ops.cmul(ops.cis(phase), amp))

    def summary(self, p, ctx):
        r = float(p["range"][0])
        az = float(p["azimuth"][0])
        el = float(p["elevation"][0]) if "elevation" in p else 0.0
        a_ref = complex(p["amp"][0], p["amp"][1])
        a_phys = a_ref * np.exp(-1j * carrier_phase(ctx, 2 * r))
        return {"range_m": round(r, 5), "azimuth_deg": round(az, 3), "elevation_deg": round(el, 3),
                "position_m": (r * unit_vectors(az, el)).round(4).tolist(),
                "amplitude_abs": round(abs(a_ref), 6),
                "amplitude_db": round(float(20 * np.log10(max(abs(a_ref), 1e-30))), 2),
                "amplitude_phase_deg": round(float(np.degrees(np.angle(a_phys))), 2)}
