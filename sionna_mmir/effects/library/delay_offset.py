"""Extra delay per Tx and per Rx path (PCB traces, LO distribution, antenna feeds).

A path of round-trip delay ``tau`` gives the beat tone
``exp(j 2 pi (f0 + S t_k) tau)``.  Extra delays ``dtau_t`` in the Tx path and
``dtau_r`` in the Rx path add to every path of that virtual channel, so the
effect is *exact* for all paths at once::

    x[f, t, r, c, k] <- x[f, t, r, c, k] exp(j 2 pi (f0 + S t_k) (dtau_t + dtau_r))

``t_k`` is the fast time from ramp start (:attr:`EffectContext.fast_time`).
It moves a target's range peak by ``c (dtau_t + dtau_r) / 2`` and adds the
carrier phase ``2 pi f0 (dtau_t + dtau_r)``.

The carrier phase of the *mean* delay over all channels,
``2 pi f_c mean(dtau)`` (``f_c`` the carrier at the window centre), is
left out of the applied phase: it is a common phase, which the model's
nuisance gain already holds.  Applied, it would tie the gain's phase to the
common delay (0.48 rad per ps at 77 GHz), a narrow curved valley in which
the fit stalls picosecond-level short of the common delay that the beat
frequency drift determines.

Parameters: ``tx`` ``[T]`` and ``rx`` ``[R]`` delays [ps] (``T + R`` in all).
Only the sums ``dtau_t + dtau_r`` are observable: a constant moved from every
Rx to every Tx changes nothing (one gauge freedom, harmless for L-BFGS-B;
:meth:`DelayOffset.summary` reports the sums and a symmetric gauge).

Initial values (:func:`channel_delays`): per virtual channel a coarse delay
from the beat-frequency shift (envelope peak of the model-data correlation,
phase free), refined by the carrier phase relative to the common phase of
all channels (the carrier pins the delay to a ``1/f0 ~ 13 ps`` fringe, the
coarse delay picks the fringe); then a robust additive split (median polish)
into Tx and Rx terms.
"""
from __future__ import annotations

import numpy as np

from .. import ops
from ..base import Effect, ParamSpec
from ._sensor_common import (channel_products, check_float, last_axis, median_polish,
                             refine_peak, scalar, scan)

PS = 1e-12


def _carrier_rad_per_ps(ctx) -> np.ndarray:
    """``2 pi (f0 + S t_k)`` in rad per ps, ``[N]``."""
    r = ctx.radar
    return 2 * np.pi * (r.start_frequency + r.slope * ctx.fast_time) * PS


def channel_delays(ctx, model, data, max_ps: float, step_ps: float,
                   match_gain: bool = True) -> np.ndarray:
    """Per virtual channel delay [ps] best matching ``data`` to the delayed ``model``, ``[T, R]``.

    1. Coarse, from the beat-frequency shift alone: the peak of the envelope
       ``|sum_k z_k exp(-j 2 pi S t_k d)|`` (``z_k = sum conj(model) data``),
       which the unknown carrier phase cannot bias.
    2. Fine, from the carrier phase: the phase of
       ``s = sum_k z_k exp(-j 2 pi (f0 + S t_k) d)`` at the coarse delay, relative
       to the circular mean phase over all channels (the nuisance gain holds a
       common phase), divided by ``2 pi (f0 + S t)``: every channel lands on the
       carrier fringe (``1 / f0 ~ 13 ps``) nearest to its coarse estimate.
    3. With ``match_gain`` the common phase is given to the delays as well, so
       the initial model matches the current nuisance gain.
    """
    z = channel_products(model, data)                                   # [T, R, N]
    mag = np.abs(z)
    if not np.any(mag > 0):
        return np.zeros(z.shape[:2])
    T, R = z.shape[:2]
    carrier = _carrier_rad_per_ps(ctx)
    beat = carrier - carrier[0]                                         # envelope only
    grid = np.arange(-max_ps, max_ps + 0.5 * step_ps, step_ps)
    env = np.abs(scan(z, beat, grid))                                   # [T, R, G]
    coarse = np.array([[refine_peak(grid, env[t, r]) for r in range(R)] for t in range(T)])
    s = np.sum(z * np.exp(-1j * carrier * coarse[..., None]), axis=-1)  # [T, R]
    common = np.angle(np.sum(s))
    rate = np.sum(mag * carrier, axis=-1) / np.maximum(np.sum(mag, axis=-1), 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        fine = coarse + np.angle(s * np.exp(-1j * common)) / rate
    seen = rate > 0
    if match_gain:
        fine = fine + common / np.mean(rate[seen])
    # channels without model energy (e.g. held out of a cross-validation fold) carry
    # no information: NaN, ignored by the Tx/Rx split
    return np.where(seen, fine, np.nan)


class DelayOffset(Effect):
    """Separable per-Tx + per-Rx extra delay (``T + R`` parameters, ps)."""

    name = "delay_offset"
    every_path = True
    channel_phase = True
    kind = "mean"
    stage = 1
    per_unit = True
    description = "per-Tx and per-Rx extra delay (traces, LO distribution)"

    def __init__(self, max_offset_ps: float = 300.0, step_ps: float = 0.5):
        owner = type(self).__name__
        self.max_offset_ps = check_float(owner, "max_offset_ps", max_offset_ps, 0.0, 1e6,
                                         lo_open=True)
        self.step_ps = check_float(owner, "step_ps", step_ps, 0.0, 5.0, lo_open=True)

    def param_specs(self, ctx, model, residual):
        d = channel_delays(ctx, model, model + residual, self.max_offset_ps, self.step_ps,
                           match_gain=False)
        tx, rx = median_polish(d)
        lim = 2.0 * self.max_offset_ps
        return {"tx": ParamSpec(tx, lower=-lim, upper=lim, unit="ps"),
                "rx": ParamSpec(rx, lower=-lim, upper=lim, unit="ps")}

    def apply(self, x, p, ctx):
        T, R = ctx.radar.num_tx, ctx.radar.num_rx
        d = ops.view(p["tx"], (1, T, 1, 1, 1)) + ops.view(p["rx"], (1, 1, R, 1, 1))
        mean = sum(scalar(p["tx"], i) for i in range(T)) / T + \
            sum(scalar(p["rx"], i) for i in range(R)) / R
        w = _carrier_rad_per_ps(ctx)
        return ops.cmul(x, ops.cis(d * last_axis(w) - mean * float(np.mean(w))))

    def summary(self, p, ctx):
        tx, rx = np.asarray(p["tx"], float), np.asarray(p["rx"], float)
        total = tx[:, None] + rx[None, :]
        shift = 0.5 * (tx.mean() - rx.mean())
        c = 299_792_458.0
        return {"channel_delay_ps": total.round(4).tolist(),
                "mean_delay_ps": float(total.mean()),
                "mean_range_shift_mm": float(total.mean() * PS * c / 2 * 1e3),
                "tx_delay_ps": (tx - shift).round(4).tolist(),
                "rx_delay_ps": (rx + shift).round(4).tolist()}
