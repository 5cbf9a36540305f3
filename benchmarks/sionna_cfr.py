"""Sionna RT's own ``Paths.cfr`` evaluated on given per-pair amplitudes and delays.

``Paths.cfr`` computes ``h(f) = sum_p a_p exp(-j 2 pi f tau_p)`` from
``self.cir()`` and reads nothing else but ``self.synthetic_array``.  The FMCW
beat signal of sionna_mmir is ``s[k] = sum_p a_p exp(+j 2 pi f_k tau_p)`` with
``f_k = f0 + S t_k``, i.e. ``s = conj(cfr(f_k))`` computed on ``conj(a)``.  This adapter feeds Sionna's unmodified
method with our paths, so both sides compute the same quantity.
"""
from __future__ import annotations

import numpy as np


class PathsAdapter:
    """Duck-typed stand-in exposing what ``sionna.rt.Paths.cfr`` reads."""

    synthetic_array = False

    def __init__(self, a, tau):
        import mitsuba as mi

        T, R, P = tau.shape
        # Sionna's CIR layout: [num_rx, rx_ant, num_tx, tx_ant, paths(, time)]
        a_rt = np.ascontiguousarray(np.transpose(a, (1, 0, 2))[:, None, :, None, :, None])
        t_rt = np.ascontiguousarray(np.transpose(tau, (1, 0, 2))[:, None, :, None, :])
        self._a = (mi.TensorXf(a_rt.real.astype(np.float32)), mi.TensorXf(a_rt.imag.astype(np.float32)))
        self._tau = mi.TensorXf(t_rt.astype(np.float32))

    def cir(self, **_):
        return self._a, self._tau


def sionna_beat_signal(radar, a, tau):
    """ADC ``[tx, rx, 1, K]`` through Sionna RT's ``Paths.cfr`` (static scene)."""
    import drjit as dr
    import mitsuba as mi
    from sionna.rt import Paths

    freqs = mi.Float((radar.start_frequency + radar.slope * radar.sample_times()).astype(np.float32))
    re, im = Paths.cfr(PathsAdapter(np.conj(a), tau), freqs, normalize_delays=False)
    dr.eval(re, im)
    h = re.numpy() + 1j * im.numpy()          # [rx, 1, tx, 1, time, K]
    return np.conj(np.transpose(h[:, 0, :, 0, 0, :], (1, 0, 2)))[:, :, None, :]
