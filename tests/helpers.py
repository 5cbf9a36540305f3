"""Small test helpers: exact point-target geometry, peak finding."""
from __future__ import annotations

import numpy as np

C = 299_792_458.0


def point_target_delays(radar, xyz) -> np.ndarray:
    """Exact round-trip delays ``tau[tx, rx, 1]`` [s] to a point at ``xyz`` (radar frame, m).

    ``tau_ij = (|x - tx_i| + |x - rx_j|) / c`` with the element positions of
    ``radar.tx_positions`` / ``radar.rx_positions`` (radar at the origin).
    """
    x = np.asarray(xyz, dtype=np.float64).reshape(3)
    dt = np.linalg.norm(x[None, :] - radar.tx_positions, axis=1)
    dr = np.linalg.norm(x[None, :] - radar.rx_positions, axis=1)
    return ((dt[:, None] + dr[None, :]) / C)[:, :, None]


def aperture_centre(radar) -> np.ndarray:
    """Mean effective (two-way) phase centre ``(tx + rx) / 2`` over all pairs [m]."""
    return 0.5 * radar.virtual_positions().reshape(-1, 3).mean(axis=0)


def direction(az, el=0.0) -> np.ndarray:
    """Unit vector for azimuth ``az`` and elevation ``el`` [rad] in the radar frame."""
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def target_at(radar, rng, az, el=0.0) -> np.ndarray:
    """Point at range ``rng`` and angles seen from the aperture centre [m]."""
    return aperture_centre(radar) + rng * direction(az, el)


def direct_adc(radar, a, tau, tau_rate=None) -> np.ndarray:
    """Straightforward reference synthesis (independent of the package), complex128.

    ``s = sum_p a exp(j 2 pi (f0 + S t_k)(tau + tau_rate (T_chirp + t_k)))``,
    ``a``, ``tau``, ``tau_rate`` broadcastable to ``[tx, rx, P]``.
    """
    tk = radar.adc_start_time + np.arange(radar.num_samples) / radar.sample_rate
    tc = radar.chirp_start_times()                                     # [tx, L]
    shape = (radar.num_tx, radar.num_rx, np.broadcast(np.asarray(a), np.asarray(tau)).shape[-1])
    a = np.broadcast_to(np.asarray(a, dtype=np.complex128), shape)
    tau = np.broadcast_to(np.asarray(tau, dtype=np.float64), shape)
    rate = np.zeros(shape) if tau_rate is None else np.broadcast_to(
        np.asarray(tau_rate, dtype=np.float64), shape)
    f = radar.start_frequency + radar.slope * tk                        # [K]
    t = tc[:, None, :, None, None] + tk[None, None, None, :, None]      # [tx,1,L,K,1]
    d = tau[:, :, None, None, :] + rate[:, :, None, None, :] * t        # [tx,rx,L,K,P]
    ph = np.exp(2j * np.pi * f[None, None, None, :, None] * d)
    return np.sum(a[:, :, None, None, :] * ph, axis=-1)


def peak_index(arr) -> tuple:
    """Index tuple of the maximum of ``arr``."""
    return np.unravel_index(int(np.argmax(arr)), np.shape(arr))
