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

Behind a chirp-varying effect (a moving scatterer, ego motion) the input
differs from chirp to chirp and the clip does not commute with the chirp
average.  Held at its level, its chirp-averaged counterpart
(:class:`AveragedClipping`) is the chirp mean of the clipped inputs, each
the averaged model's input plus that chirp's deviation from the mean, the
deviation taken from the full model at its held values (exact there; an
approximation while other components of the averaged model move).
"""
from __future__ import annotations

import numpy as np

from .. import ops
from ..base import Effect, ParamSpec
from ..frozen import FrozenPart
from ._sensor_common import check_float, scalar, softplus

dr = ops.dr


def smooth_clip(v, a, s):
    """Softplus clip of a real tensor ``v`` at ``+-a`` with knee width ``s``
    (AD through every operation; the reference for :func:`clip_first_order`)."""
    return v - s * softplus((v - a) / s) + s * softplus((-v - a) / s)


def clip_first_order(v, a, k: float):
    """:func:`smooth_clip` of ``v`` at ``+-a`` with ``s = k a``, written as its
    value plus its first-order terms in ``v`` and ``a`` at evaluated
    coefficients: ``c(v0, a0) + c_v (v - v0) + c_a (a - a0)``.

    Equal in value and first derivatives (all that L-BFGS uses); the
    coefficients are evaluated once, so the backward pass reads two arrays
    instead of tracing the clip's uses of its input, and the whole chain
    before it, again for every reduction that needs the adjoint (NOTES.md
    has the measured evaluation times).  With ``u1 = (v - a) / s``,
    ``u2 = (-v - a) / s`` and the logistic ``sig``::

        c_v = 1 - sig(u1) - sig(u2)
        c_a = -k softplus(u1) + sig(u1) (1 + k u1) + k softplus(u2) - sig(u2) (1 + k u2)
    """
    v0, a0 = dr.detach(v), dr.detach(a)
    with dr.suspend_grad():
        s0 = k * a0
        u1, u2 = (v0 - a0) / s0, (-v0 - a0) / s0
        sp1, sp2 = softplus(u1), softplus(u2)
        g1, g2 = 1.0 / (1.0 + dr.exp(-u1)), 1.0 / (1.0 + dr.exp(-u2))
        value = v0 - s0 * sp1 + s0 * sp2
        c_v = 1.0 - g1 - g2
        c_a = -k * sp1 + g1 * (1.0 + k * u1) + k * sp2 - g2 * (1.0 + k * u2)
        dr.eval(value, c_v, c_a)
    return value + c_v * (v - v0) + c_a * (a - a0)


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
        return (clip_first_order(x[0], a, self.softness),
                clip_first_order(x[1], a, self.softness))

    def averaged_counterpart(self, values, ctx, model_input):
        """This clip at ``values`` on chirp-averaged data
        (:class:`AveragedClipping`); ``model_input()`` is the full model's
        input to it, ``[F, T, R, C, N]``."""
        x = model_input()
        return AveragedClipping(self, float(np.ravel(values["log_a"])[0]),
                                x - x.mean(axis=3, keepdims=True))

    def summary(self, p, ctx):
        return {"clip_level_normalised": float(np.exp(np.ravel(p["log_a"])[0])),
                "softness": self.softness}


class AveragedClipping(FrozenPart):
    """:class:`ADCClipping` at a fixed level on chirp-averaged data:
    ``mean_c clip(x + d_c)`` for the averaged input ``x [F, T, R, 1, N]``
    and the per-chirp deviations ``d [F, T, R, C, N]`` of the full model's
    input from its chirp mean (no parameters).

    Parameters
    ----------
    source : ADCClipping
        the effect it stands for
    log_a : float
        ``ln A`` (normalised units)
    deviation : numpy.ndarray
        complex ``[F, T, R, C, N]``
    """

    _CACHED = ("_dev",)

    def __init__(self, source, log_a: float, deviation):
        self._stand_for(source, "at a fixed level")
        self.log_a = float(log_a)
        self.deviation = np.asarray(deviation, np.complex64)
        self._dev = None

    def apply(self, x, p, ctx):
        if self._dev is None:
            self._dev = ops.tensor(self.deviation)
        C = self.deviation.shape[3]
        shape = tuple(self.deviation.shape[:3]) + (1, self.deviation.shape[4])
        a = ops.opaque(float(np.exp(self.log_a)))
        z = ops.cadd(x, self._dev)
        return tuple(ops.view(dr.sum(clip_first_order(v, a, self.source.softness), axis=3),
                              shape) * (1.0 / C) for v in z)

    def variance(self, x, X, p, ctx):
        raise NotImplementedError("AveragedClipping is a mean effect")
