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

dr, mi = ops.dr, ops.mi


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
        value, c_v, c_a = clip_terms(v0, a0, k)
        dr.eval(value, c_v, c_a)
    return value + c_v * (v - v0) + c_a * (a - a0)


def clip_terms(v0, a0, k: float) -> tuple:
    """``(c, c_v, c_a)``: :func:`smooth_clip` of ``v0`` at ``+-a0`` (knee
    ``k a0``) and its derivatives in ``v`` and ``a`` there (no AD; see
    :func:`clip_first_order`)."""
    s0 = k * a0
    u1, u2 = (v0 - a0) / s0, (-v0 - a0) / s0
    sp1, sp2 = softplus(u1), softplus(u2)
    g1, g2 = 1.0 / (1.0 + dr.exp(-u1)), 1.0 / (1.0 + dr.exp(-u2))
    value = v0 - s0 * sp1 + s0 * sp2
    c_v = 1.0 - g1 - g2
    c_a = -k * sp1 + g1 * (1.0 + k * u1) + k * sp2 - g2 * (1.0 + k * u2)
    return value, c_v, c_a


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
        """``mean_c clip(x + d_c)`` as its value plus its first-order term in
        ``x`` at evaluated coefficients (:func:`clip_first_order`): the chirp
        means of the clip and of its slope, ``x0`` the evaluated input,
        ``mean_c clip(x0 + d_c) + mean_c clip'(x0 + d_c) (x - x0)``.  The
        ``C`` clipped copies are computed once per evaluation outside AD; the
        graph the gradient runs through has the averaged input's size."""
        C = self.deviation.shape[3]
        if self._dev is None:        # chirps innermost: [F, T, R, N, C], flat
            d = np.moveaxis(self.deviation, 3, 4).ravel()
            self._dev = (mi.Float(np.ascontiguousarray(d.real, np.float32)),
                         mi.Float(np.ascontiguousarray(d.imag, np.float32)))
        shape = tuple(self.deviation.shape[:3]) + (1, self.deviation.shape[4])
        a = ops.opaque(float(np.exp(self.log_a)))
        out = []
        for v, d in zip(x, self._dev):
            v0 = dr.detach(v)
            with dr.suspend_grad():
                value, c_v, _ = clip_terms(dr.repeat(v0.array, C) + d, a, self.source.softness)
                mean, slope = (mi.TensorXf(dr.block_sum(t, C) * (1.0 / C), shape)
                               for t in (value, c_v))
                dr.eval(mean, slope)
            out.append(mean + slope * (v - v0))
        return tuple(out)

    def variance(self, x, X, p, ctx):
        raise NotImplementedError("AveragedClipping is a mean effect")
