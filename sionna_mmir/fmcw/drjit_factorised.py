"""Dr.Jit bridge for :mod:`sionna_mmir.fmcw.synthesize_factorised`.

A ``dr.CustomOp`` runs the factorised synthesiser (:data:`SYNTHESIS`: the
NUFFT one of :mod:`sionna_mmir.fmcw.synthesize_nufft`) on detached values and
supplies its analytic forward (JVP) and backward (VJP) derivatives, so the
ADC of factorised paths is one node of the Dr.Jit AD graph and the
``[tx, rx, path]`` expansion is never formed, neither in the forward pass nor
in the gradients.

Inputs are flat ``mi.Float`` arrays (element index slowest, path fastest)::

    c_re, c_im   [P]       per-path amplitude (beat convention)
    g_t, tau_t   [T * P]   Tx-leg gain and delay [s]
    g_r, tau_r   [R * P]   Rx-leg gain and delay [s]
    rate         [P]       delay rate [s/s] (optional)
"""
from __future__ import annotations

import numpy as np

from ..errors import InputValueError
from ..radar.config import RadarConfig
from .synthesize_factorised import check_factor_inputs
from .synthesize_nufft import NufftSynthesis

#: the synthesiser the AD node runs (forward, VJP, JVP); the exact matrix-product
#: twin :class:`~sionna_mmir.fmcw.synthesize_factorised.FactorisedSynthesis`
#: has the same interface (benchmarks and tests swap it in)
SYNTHESIS = NufftSynthesis

_WHERE = "synthesize_adc_factorised"
_NAMES = ("c_re", "c_im", "g_t", "tau_t", "g_r", "tau_r", "rate")


def _np(x, shape=None) -> np.ndarray:
    arr = np.asarray(x, dtype=np.float64)
    return arr if shape is None else arr.reshape(shape)


def _f32(x) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=np.float32).ravel()


def _as_float(x, name):
    """``mi.Float`` view of a flat Dr.Jit array / tensor or NumPy array."""
    import mitsuba as mi

    if isinstance(x, np.ndarray):
        return mi.Float(_f32(x))
    if isinstance(x, mi.TensorXf):
        return x.array
    try:
        return mi.Float(x)
    except TypeError as err:
        raise InputValueError(f"{_WHERE}: '{name}' must be a flat Dr.Jit Float array, "
                              f"got {type(x).__name__}") from err


def _inputs_numpy(radar, shape, c_re, c_im, g_t, tau_t, g_r, tau_r, rate):
    """Detached inputs as a validated :class:`FactorInputs`."""
    T, R, P = shape
    return check_factor_inputs(
        radar, _np(c_re) + 1j * _np(c_im), _np(g_t, (T, P)), _np(tau_t, (T, P)),
        _np(g_r, (R, P)), _np(tau_r, (R, P)), None if rate is None else _np(rate))


def _make_op():
    import drjit as dr
    import mitsuba as mi

    class SynthesizeADCFactorisedOp(dr.CustomOp):
        """Custom AD node: (c_re, c_im, g_t, tau_t, g_r, tau_r, rate) -> (adc_re, adc_im)."""

        def eval(self, c_re, c_im, g_t, tau_t, g_r, tau_r, rate, radar=None, shape=None,
                 moving=False, delays=True):
            self.radar, self.shape3, self.moving, self.delays = radar, shape, moving, delays
            x = _inputs_numpy(radar, shape, c_re, c_im, g_t, tau_t, g_r, tau_r,
                              rate if moving else None)
            self.synth = SYNTHESIS(radar, x)
            s = self.synth.forward()
            return mi.Float(_f32(s.real)), mi.Float(_f32(s.imag))

        def forward(self):
            T, R, P = self.shape3
            dc = _np(self.grad_in("c_re")) + 1j * _np(self.grad_in("c_im"))
            ds = self.synth.jvp(dc, _np(self.grad_in("g_t"), (T, P)), _np(self.grad_in("tau_t"), (T, P)),
                                _np(self.grad_in("g_r"), (R, P)), _np(self.grad_in("tau_r"), (R, P)),
                                _np(self.grad_in("rate")) if self.moving else None)
            self.set_grad_out((mi.Float(_f32(ds.real)), mi.Float(_f32(ds.imag))))

        def backward(self):
            g_re, g_im = self.grad_out()
            shape = self.radar.adc_shape
            g = self.synth.vjp(_np(g_re, shape) + 1j * _np(g_im, shape), delays=self.delays)
            self.set_grad_in("c_re", mi.Float(_f32(g["c"].real)))
            self.set_grad_in("c_im", mi.Float(_f32(g["c"].imag)))
            for name in ("g_t", "g_r") + (("tau_t", "tau_r") if self.delays else ()):
                self.set_grad_in(name, mi.Float(_f32(g[name])))
            if self.moving and self.delays:
                self.set_grad_in("rate", mi.Float(_f32(g["tau_rate"])))

        def name(self):
            return "SynthesizeADCFactorised"

    return SynthesizeADCFactorisedOp


_OP = None


def _check_sizes(radar, args) -> int:
    """Number of paths ``P`` from ``c_re``; raise if any flat size disagrees."""
    import drjit as dr

    P = dr.width(args["c_re"])
    T, R = radar.num_tx, radar.num_rx
    expected = dict(c_re=P, c_im=P, g_t=T * P, tau_t=T * P, g_r=R * P, tau_r=R * P, rate=P)
    for name, x in args.items():
        if x is not None and dr.width(x) != expected[name]:
            raise InputValueError(f"{_WHERE}: '{name}' has {dr.width(x)} entries, expected "
                                  f"{expected[name]} ({T} tx, {R} rx, {P} paths)")
    return P


def synthesize_adc_factorised_drjit(radar: RadarConfig, c_re, c_im, g_t, tau_t, g_r, tau_r,
                                    rate=None):
    """ADC of factorised paths inside the Dr.Jit AD graph.

    Flat inputs as in the module docstring (``mi.Float``, ``mi.TensorXf`` or
    NumPy).  Returns :class:`~sionna_mmir.fmcw.synthesize.DrAdc` (``real``,
    ``imag`` ``mi.TensorXf`` ``[T, R, num_chirps, num_samples]``); gradients
    flow to every input.  Wrong sizes, NaN or Inf raise
    :class:`~sionna_mmir.errors.InputValueError` naming the argument.
    """
    global _OP
    from ..utils.backend import init_backend

    init_backend()
    import drjit as dr
    import mitsuba as mi

    from .engine import DrAdc

    raw = dict(c_re=c_re, c_im=c_im, g_t=g_t, tau_t=tau_t, g_r=g_r, tau_r=tau_r, rate=rate)
    args = {k: None if v is None else _as_float(v, k) for k, v in raw.items()}
    P = _check_sizes(radar, args)
    shape = (radar.num_tx, radar.num_rx, P)
    # validate the detached values here, so that the error is raised outside the AD node
    _inputs_numpy(radar, shape, *(None if v is None else dr.detach(v) for v in args.values()))
    if _OP is None:
        _OP = _make_op()
    moving = rate is not None
    if not moving:
        args["rate"] = dr.zeros(mi.Float, P)
    # delay gradients only when something upstream needs them (a fit of
    # materials and beams does not: the VJP then runs one transform per pair)
    delays = bool(dr.grad_enabled(args["tau_t"], args["tau_r"], args["rate"]))
    re, im = dr.custom(_OP, *(args[k] for k in _NAMES), radar=radar, shape=shape, moving=moving,
                       delays=delays)
    return DrAdc(mi.TensorXf(re, radar.adc_shape), mi.TensorXf(im, radar.adc_shape))
