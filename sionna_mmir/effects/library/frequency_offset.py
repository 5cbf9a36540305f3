"""Beat-frequency offset per receive chip (LO / ramp start mismatch between chips).

In a cascade every chip derives its own LO ramp from the shared reference; a
small frequency offset ``df`` between the transmitted and the receiving
chip's ramp shifts every beat tone received by that chip::

    x[f, t, r, c, k] <- x[f, t, r, c, k] exp(j 2 pi df_{chip(r)} t_k)

``t_k`` is the fast time from ramp start, ``chip(r) = ctx.rx_chip[r]``.
Parameters: ``df`` ``[n_chips]`` [kHz] (one per receive chip).  A beat
offset ``df`` moves range peaks by ``df / (S / (c/2))`` metres, i.e.
``df / (f_s / N)`` bins.  With one chip it is close to a common extra delay
(:mod:`.delay_offset` shifts the beat by ``S dtau``, and the carrier too);
fit only one of the two for a single-chip radar unless the data tell them
apart.

Initial value: per chip the offset maximising
``|sum_k z_k exp(-j 2 pi df t_k)|`` over a grid ``|df| <= max_offset_khz``
(``z_k`` = conj(model) x data summed over the chip's channels, frames and
chirps), refined by a parabola.
"""
from __future__ import annotations

import numpy as np

from .. import ops
from ..base import Effect, ParamSpec
from ._sensor_common import channel_products, check_float, last_axis, refine_peak, scan

KHZ = 1e3


def chip_offsets(ctx, model, data, max_khz: float) -> np.ndarray:
    """Beat-frequency offset [kHz] per receive chip, ``[n_chips]``, from a coherent scan."""
    n_chips = int(ctx.rx_chip.max()) + 1
    z = channel_products(model, data).sum(axis=0)                       # [R, N]
    step = min(0.05, max_khz / 200.0)
    grid = np.arange(-max_khz, max_khz + 0.5 * step, step)
    w = 2 * np.pi * ctx.fast_time * KHZ                                  # rad per kHz
    out = np.zeros(n_chips)
    for chip in range(n_chips):
        zc = z[ctx.rx_chip == chip].sum(axis=0)
        if np.any(zc != 0):
            out[chip] = refine_peak(grid, np.abs(scan(zc, w, grid)))
    return out


class FrequencyOffset(Effect):
    """Per-receive-chip beat-frequency offset (``n_chips`` parameters, kHz)."""

    name = "frequency_offset"
    every_path = True
    channel_phase = True
    kind = "mean"
    stage = 1
    per_unit = True
    description = "beat-frequency offset per receive chip (LO ramp mismatch)"

    def __init__(self, max_offset_khz: float = 20.0):
        self.max_offset_khz = check_float(type(self).__name__, "max_offset_khz",
                                          max_offset_khz, 0.0, 1e5, lo_open=True)

    def param_specs(self, ctx, model, residual):
        df = chip_offsets(ctx, model, model + residual, self.max_offset_khz)
        lim = 2.0 * self.max_offset_khz
        return {"df": ParamSpec(df, lower=-lim, upper=lim, unit="kHz")}

    def apply(self, x, p, ctx):
        df_r = _rx_values(p["df"], ctx.rx_chip)                           # [1, 1, R, 1, 1]
        w = last_axis(2 * np.pi * ctx.fast_time * KHZ)
        return ops.cmul(x, ops.cis(df_r * w))

    def summary(self, p, ctx):
        df = np.asarray(p["df"], float)
        bin_khz = ctx.radar.sample_rate / ctx.radar.num_samples / KHZ
        return {"df_khz": df.round(4).tolist(),
                "df_bins": (df / bin_khz).round(5).tolist()}


def _rx_values(df, rx_chip: np.ndarray):
    """Per-chip tensor ``[n_chips]`` spread onto the Rx axis ``(1, 1, R, 1, 1)`` (AD gather)."""
    R = len(rx_chip)
    idx = ops.mi.UInt32(np.asarray(rx_chip, np.uint32))
    vals = ops.dr.gather(ops.mi.Float, df.array, idx)
    if R == 1:
        return vals + 0.0
    return ops.mi.TensorXf(vals, (1, 1, R, 1, 1))
