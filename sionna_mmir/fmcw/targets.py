"""Point targets as paths: exact per-pair delays, and sub-bin refinement.

:func:`point_target_paths` turns ``(range, azimuth, elevation, velocity)``
tuples into per-(tx, rx, path) amplitudes and delays for
:func:`~sionna_mmir.fmcw.synthesize_adc`; :func:`refine_point_target`
estimates one target's sub-bin range and azimuth from raw ADC by matched
filtering.
"""
from __future__ import annotations

import numpy as np

from ..errors import InputValueError
from ..radar.config import SPEED_OF_LIGHT
from .synthesize import synthesize_adc


def point_target_paths(radar, targets, origin=None):
    """Exact per-pair delays and ``1/R^2`` amplitudes of point targets.

    Parameters
    ----------
    radar : RadarConfig
        Element positions (radar frame).
    targets : iterable of tuple
        ``(range_m, azimuth_deg, elevation_deg, v_m_s)`` measured from
        ``origin``.
    origin : array_like, optional
        Radar-frame point the ranges and angles are measured from (default
        the radar origin; pass the virtual aperture's phase centre to place
        targets where the angle FFT sees them).

    Returns
    -------
    a : numpy.ndarray
        Complex amplitudes ``[tx, rx, P]``.
    tau : numpy.ndarray
        Delays ``[tx, rx, P]`` [s].
    tau_rate : numpy.ndarray
        Delay rates ``[tx, rx, P]`` [s/s] (``2 v / c``).

    Raises
    ------
    InputValueError
        A speed ``|v|`` not below the speed of light.
    """
    origin = np.zeros(3) if origin is None else np.asarray(origin, float)
    tx, rx = radar.tx_positions, radar.rx_positions
    a, tau, rate = [], [], []
    for R, az, el, v in targets:
        if not abs(v) < SPEED_OF_LIGHT:
            raise InputValueError(f"point target speed {v} m/s is not below the speed of light")
        az, el = np.radians(az), np.radians(el)
        u = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        x = origin + R * u
        d = np.linalg.norm(x - tx, axis=1)[:, None] + np.linalg.norm(x - rx, axis=1)[None, :]
        tau.append(d / SPEED_OF_LIGHT)
        rate.append(np.full(d.shape, 2 * v / SPEED_OF_LIGHT))
        a.append(np.ones(d.shape, complex) / (R * R))
    return np.stack(a, -1), np.stack(tau, -1), np.stack(rate, -1)


def refine_point_target(adc, radar, r0: float, az0_deg: float, origin):
    """Sub-bin range and azimuth of one point target by matched filtering.

    Maximises ``|b^H y|^2 / |b|^2`` over ``(R, az)``, ``y`` the raw ADC and
    ``b`` the synthesised single-path ADC (exact per-pair delays), from the
    FFT-grid detection ``(r0, az0_deg)``.

    Parameters
    ----------
    adc : numpy.ndarray
        Raw ADC ``[tx, rx, chirp, sample]``.
    radar : RadarConfig
        The capture's radar.
    r0 : float
        Initial range [m].
    az0_deg : float
        Initial azimuth [deg].
    origin : array_like
        Radar-frame point ranges are measured from [m].

    Returns
    -------
    tuple
        ``(range [m], azimuth [deg])``.
    """
    from scipy.optimize import minimize

    y = np.asarray(adc).ravel()

    def cost(p):
        _, tau, _ = point_target_paths(radar, [(p[0], p[1], 0.0, 0.0)], origin=origin)
        b = synthesize_adc(radar, np.ones(tau.shape, complex), tau).ravel()
        return -abs(np.vdot(b, y)) ** 2 / np.vdot(b, b).real

    simplex = [[r0, az0_deg], [r0 + radar.range_resolution / 3, az0_deg], [r0, az0_deg + 0.4]]
    res = minimize(cost, [r0, az0_deg], method="Nelder-Mead",
                   options=dict(initial_simplex=simplex, xatol=1e-4, fatol=1e-9))
    return float(res.x[0]), float(res.x[1])
