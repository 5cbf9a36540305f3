"""The FMCW beat-signal model shared by the fast and the reference synthesiser.

For Tx ``i``, Rx ``j``, chirp loop ``l`` and fast-time sample ``k`` the
complex baseband ADC is (paper eq. 4, extended with motion)::

    s[i, j, l, k] = sum_p  a_ijp * exp(+j 2 pi phi_ijlkp)

    phi = (f0 + S t_k) * (tau_ijp + rho_ijp * T_il)  +  f0 * rho_ijp * t_k

with ``t_k = adc_start_time + k / f_s`` (from ramp start), ``T_il`` the ramp
start of Tx ``i`` in loop ``l`` (TDM schedule, :meth:`RadarConfig.chirp_start_times`)
and ``rho = d tau / dt`` the delay rate (``2 v / c`` for a monostatic target
receding at ``v``).  The delay is advanced to each chirp's start (slow time,
exact across chirps *and* TDM slots) and the intra-chirp Doppler shift
``f0 rho`` is kept; only the second-order term ``S rho t_k^2`` is dropped
(below 0.01 rad for ``|v| < 10`` m/s on the cascade waveform).  With ``rho``
absent every chirp is identical.

Amplitudes ``a`` [any unit, e.g. sqrt(W)] and delays ``tau`` [s] are per
(tx, rx, path): each pair has its own exact delay, so near-field geometry is
allowed.
"""
from __future__ import annotations

import numpy as np

from ..errors import InputValueError
from ..radar.config import RadarConfig


def broadcast_paths(radar: RadarConfig, a, tau, tau_rate=None):
    """Validate and broadcast inputs to ``[n_tx, n_rx, n_paths]`` NumPy arrays.

    ``a`` (complex), ``tau`` [s] and ``tau_rate`` [s/s] may be ``[P]``,
    ``[1, 1, P]``, ``[n_tx, n_rx, P]`` or anything that broadcasts to it.
    Returns ``(a complex128, tau float64, rho float64 or None, shape)``.
    """
    a = np.asarray(a)
    tau = np.asarray(tau, dtype=np.float64)
    arrays = {"a": a, "tau": tau}
    rho = None
    if tau_rate is not None:
        rho = np.asarray(tau_rate, dtype=np.float64)
        arrays["tau_rate"] = rho
    for name, arr in arrays.items():
        if arr.ndim not in (1, 3):
            raise InputValueError(f"synthesize_adc: '{name}' must be [paths] or "
                                  f"[tx, rx, paths], got shape {arr.shape}")
        if arr.ndim == 3 and (arr.shape[0] not in (1, radar.num_tx)
                              or arr.shape[1] not in (1, radar.num_rx)):
            raise InputValueError(
                f"synthesize_adc: '{name}' has shape {arr.shape} but the radar has "
                f"{radar.num_tx} tx and {radar.num_rx} rx")
        if np.iscomplexobj(arr):
            finite = np.isfinite(arr.real).all() and np.isfinite(arr.imag).all()
        else:
            finite = np.isfinite(arr).all()
        if not finite:
            raise InputValueError(f"synthesize_adc: '{name}' holds NaN or Inf")
    n_paths = {arr.shape[-1] for arr in arrays.values()}
    n_paths.discard(1)
    if len(n_paths) > 1:
        raise InputValueError(f"synthesize_adc: path counts differ between inputs: "
                              f"{ {k: v.shape for k, v in arrays.items()} }")
    P = n_paths.pop() if n_paths else 1
    shape = (radar.num_tx, radar.num_rx, P)

    def full(arr):
        arr = arr.reshape((1, 1, -1)) if arr.ndim == 1 else arr
        return np.broadcast_to(arr, shape)

    a_full = full(a).astype(np.complex128)
    tau_full = full(tau)
    rho_full = full(rho) if rho is not None else None
    return a_full, tau_full, rho_full, shape
