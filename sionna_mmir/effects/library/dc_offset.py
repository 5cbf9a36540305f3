"""DC offset of the receive chain: a constant complex value added per Rx.

``x[f, t, r, c, k] <- x + d_r`` (ADC stage), ``2 R`` real parameters in
normalised units.  Shows up as energy in range bin 0 of every channel of an Rx.
"""
from __future__ import annotations

import numpy as np

from .. import ops
from ..base import Effect, ParamSpec


class DCOffset(Effect):
    """Per-Rx complex DC offset (``2 R`` parameters)."""

    name = "dc_offset"
    kind = "mean"
    stage = 3
    per_unit = True
    description = "constant complex offset per receiver (ADC DC)"

    def param_specs(self, ctx, model, residual):
        d = residual.mean(axis=(0, 1, 3, 4))                       # [R]
        return {"dc": ParamSpec(np.stack([d.real, d.imag], axis=1), unit="normalised")}

    def apply(self, x, p, ctx):
        R = ctx.radar.num_rx
        s = (1, 1, R, 1, 1)
        return (x[0] + ops.column(p["dc"], 0, s), x[1] + ops.column(p["dc"], 1, s))

    def summary(self, p, ctx):
        d = p["dc"][:, 0] + 1j * p["dc"][:, 1]
        return {"dc_abs": np.abs(d).round(6).tolist(),
                "dc_phase_deg": np.degrees(np.angle(d)).round(2).tolist()}
