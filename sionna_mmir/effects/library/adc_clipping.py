"""ADC saturation: I and Q clip at ``+-A`` (strong near-range returns, coupling).

A hard clip ``min(max(v, -A), A)`` has no gradient in ``A`` below the rails
and a kink at them, so each of I and Q passes a smooth "hard-ish" clip built
from softplus functions of width ``s = softness A``::

    clip(v) = v - s softplus((v - A) / s) + s softplus((-v - A) / s)
    softplus(z) = log(1 + e^z)

It is linear to within ``s e^{-(A - |v|)/s}`` below the rails, tends to
``+-A`` beyond them and never exceeds ``|A|`` by more than ``s e^{-2 A / s}``
(below ``1e-80 A`` for the default ``softness = 0.01``)::

    I' = clip(Re x),  Q' = clip(Im x)

Parameter: ``log_a`` [1] = ``ln A`` with ``A`` in the model's normalised units
(the measured RMS is 1).  Stage 3, and it must be the last effect of the
chain (add it after the other ADC-stage effects: the model keeps insertion
order within a stage).

Initial value: ``A`` slightly above the measured peak ``max(|I|, |Q|)`` of
``model + residual`` (a clipped capture has its peak at the rail; an unclipped
one is left nearly unchanged).
"""
from __future__ import annotations

import numpy as np

from .. import ops
from ..base import Effect, ParamSpec
from ._sensor_common import check_float, scalar, softplus

dr = ops.dr


def smooth_clip(v, a, s):
    """Softplus clip of a real tensor ``v`` at ``+-a`` with knee width ``s`` (AD)."""
    return v - s * softplus((v - a) / s) + s * softplus((-v - a) / s)


class ADCClipping(Effect):
    """Smooth I/Q saturation at ``+-A`` (1 parameter, ln of normalised units)."""

    name = "adc_clipping"
    chirp_static = False
    pointwise = True
    kind = "mean"
    stage = 3
    description = "ADC saturation of I and Q at +-A (smooth clip); apply last"

    def __init__(self, softness: float = 0.01):
        self.softness = check_float(type(self).__name__, "softness", softness, 0.0, 0.5,
                                    lo_open=True)

    def param_specs(self, ctx, model, residual):
        y = model + residual
        peak = float(max(np.abs(y.real).max(), np.abs(y.imag).max()))
        if not peak > 0:
            peak = 1.0
        a0 = np.log(peak * (1.0 + 3.0 * self.softness))
        return {"log_a": ParamSpec([a0], lower=a0 - np.log(100.0), upper=a0 + np.log(100.0),
                                   unit="ln(normalised)")}

    def apply(self, x, p, ctx):
        a = dr.exp(scalar(p["log_a"]))
        s = self.softness * a
        return (smooth_clip(x[0], a, s), smooth_clip(x[1], a, s))

    def summary(self, p, ctx):
        return {"clip_level_normalised": float(np.exp(np.ravel(p["log_a"])[0])),
                "softness": self.softness}
