"""Per-channel complex gain, separable over Tx and Rx.

Each Tx and each Rx path has its own gain and phase (chip LOs, traces,
amplifiers)::

    x[f, t, r, c, k] <- exp(a_t + a_r + j (phi_t + phi_r)) x[f, t, r, c, k]

``2 (T + R)`` real parameters (log-amplitude [Np] and phase [rad] per Tx and
per Rx).  The separable form is what the hardware has and is what lets a
held-out virtual channel be predicted from the others.
"""
from __future__ import annotations

import numpy as np

from .. import ops
from ..base import Effect, ParamSpec


def channel_gains(model: np.ndarray, data: np.ndarray) -> np.ndarray:
    """Least-squares complex gain of ``model`` onto ``data`` per (tx, rx), ``[T, R]``."""
    num = np.einsum("ftrck,ftrck->tr", np.conj(model), data)
    den = np.einsum("ftrck,ftrck->tr", np.conj(model), model).real
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 1.0)


def separable_log(h: np.ndarray):
    """Rank-1 split of ``log h[t, r]`` into Tx and Rx terms: ``(a_t, phi_t), (a_r, phi_r)``.

    Amplitudes by least squares on ``log|h|``; phases by alternating circular
    means (robust to wrapping).
    """
    T, R = h.shape
    la = np.log(np.maximum(np.abs(h), 1e-12))
    a_t = la.mean(axis=1) - la.mean() / 2
    a_r = la.mean(axis=0) - la.mean() / 2
    u = np.exp(1j * np.angle(h))
    p_r = np.zeros(R)
    for _ in range(20):
        p_t = np.angle(np.sum(u * np.exp(-1j * p_r)[None, :], axis=1))
        p_r = np.angle(np.sum(u * np.exp(-1j * p_t)[:, None], axis=0))
    return np.stack([a_t, p_t], axis=1), np.stack([a_r, p_r], axis=1)


class ChannelGain(Effect):
    """Separable per-Tx x per-Rx complex gain (``2 (T + R)`` parameters)."""

    name = "channel_gain"
    every_path = True
    channel_phase = True
    kind = "mean"
    stage = 1
    per_unit = True
    description = "per-Tx and per-Rx complex gain (chip LO phase, path loss)"

    def param_specs(self, ctx, model, residual):
        h = channel_gains(model, model + residual)
        tx, rx = separable_log(h)
        return {"tx": ParamSpec(tx, lower=[-5.0, -np.inf], upper=[5.0, np.inf], unit="Np, rad"),
                "rx": ParamSpec(rx, lower=[-5.0, -np.inf], upper=[5.0, np.inf], unit="Np, rad")}

    def apply(self, x, p, ctx):
        T, R = ctx.radar.num_tx, ctx.radar.num_rx
        st, sr = (1, T, 1, 1, 1), (1, 1, R, 1, 1)
        amp = ops.dr.exp(ops.column(p["tx"], 0, st) + ops.column(p["rx"], 0, sr))
        g = ops.scale(ops.cis(ops.column(p["tx"], 1, st) + ops.column(p["rx"], 1, sr)), amp)
        return ops.cmul(x, g)

    def summary(self, p, ctx):
        g = np.exp(p["tx"][:, 0][:, None] + p["rx"][:, 0][None, :]
                   + 1j * (p["tx"][:, 1][:, None] + p["rx"][:, 1][None, :]))
        db = 20 * np.log10(np.abs(g))
        return {"gain_db_spread": float(db.max() - db.min()),
                "tx_gain_db": (20 / np.log(10) * p["tx"][:, 0]).round(3).tolist(),
                "tx_phase_deg": np.degrees(np.angle(np.exp(1j * p["tx"][:, 1]))).round(2).tolist(),
                "rx_gain_db": (20 / np.log(10) * p["rx"][:, 0]).round(3).tolist(),
                "rx_phase_deg": np.degrees(np.angle(np.exp(1j * p["rx"][:, 1]))).round(2).tolist()}
