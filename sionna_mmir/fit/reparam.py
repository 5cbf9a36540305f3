"""Reparameterisations keeping fitted parameters physical (paper Sec. 3.4).

=============  ================================  ===========================
parameter      physical = f(latent)              bounds
=============  ================================  ===========================
eps_real       ``1 + exp(z)``                     ``> 1``
eps_imag       ``exp(z)``                         ``> 0``
sigma_h [m]    ``exp(z)``                         ``> 0``
l_c [m]        ``exp(z)``                         ``> 0``
tau            ``sigmoid(z)``                     ``(0, 1)``
d [m]          ``exp(z)``                         ``> 0``
=============  ================================  ===========================

Both directions exist in NumPy (initialisation, reports) and Dr.Jit (inside
the AD graph, so gradients reach the latents).
"""
from __future__ import annotations

import numpy as np

#: floors applied before taking logs (so ITU metals with eps' = 1 stay finite)
FLOORS = np.array([1e-3, 1e-6, 1e-7, 1e-5, 1e-4, 1e-5])


def to_latent(mat: np.ndarray) -> np.ndarray:
    """``[..., 6]`` physical materials -> latents (float64)."""
    m = np.asarray(mat, dtype=np.float64)
    z = np.empty_like(m)
    z[..., 0] = np.log(np.maximum(m[..., 0] - 1.0, FLOORS[0]))
    for c in (1, 2, 3, 5):
        z[..., c] = np.log(np.maximum(m[..., c], FLOORS[c]))
    t = np.clip(m[..., 4], FLOORS[4], 1 - FLOORS[4])
    z[..., 4] = np.log(t / (1 - t))
    return z


def to_physical(z: np.ndarray) -> np.ndarray:
    """Latents -> physical materials (NumPy)."""
    z = np.asarray(z, dtype=np.float64)
    m = np.exp(z)
    m[..., 0] = 1.0 + m[..., 0]
    m[..., 4] = 1.0 / (1.0 + np.exp(-z[..., 4]))
    return m


def to_physical_dr(z_flat, n: int):
    """Latents (``mi.Float`` of ``n * 6``, row-major) -> physical ``mi.Float`` (AD)."""
    import drjit as dr
    import mitsuba as mi

    col = dr.arange(mi.UInt32, n * 6) % 6
    e = dr.exp(z_flat)
    sig = 1.0 / (1.0 + dr.exp(-z_flat))
    return dr.select(col == 0, 1.0 + e, dr.select(col == 4, sig, e))
