"""Dr.Jit bridge for :func:`~sionna_mmir.fmcw.synthesize.synthesize_adc`.

A ``dr.CustomOp`` runs the BLAS-backed synthesiser on detached values and
supplies its analytic forward (JVP) and backward (VJP) derivatives, so
``synthesize_adc`` is one node of the Dr.Jit AD graph: gradients from any
loss on the ADC reach the amplitudes, delays and delay rates (and from there
the scene parameters that produced them).
"""
from __future__ import annotations

import numpy as np

from ..errors import InputValueError
from ..radar.config import RadarConfig


def is_drjit(x) -> bool:
    """True for Dr.Jit arrays/tensors or a tuple of them."""
    if x is None:
        return False
    if isinstance(x, (tuple, list)) and len(x) == 2:
        return is_drjit(x[0]) or is_drjit(x[1])
    mod = type(x).__module__ or ""
    return mod.startswith("drjit")


def _split_complex(a):
    import drjit as dr

    if isinstance(a, (tuple, list)):
        return a[0], a[1]
    if dr.is_complex_v(a):
        return a.real, a.imag
    if isinstance(a, np.ndarray):
        return np.real(a), np.imag(a)
    return a, None


def _shape_of(x) -> tuple:
    if x is None:
        return ()
    if isinstance(x, np.ndarray):
        return x.shape
    shape = getattr(x, "shape", None)
    if shape is None:
        return (len(x),)
    return tuple(shape)


def _flat(x, n_target, shape, name):
    """Differentiably broadcast ``x`` to a flat ``mi.Float`` of ``T*R*P`` entries."""
    import drjit as dr
    import mitsuba as mi

    T, R, P = shape
    if x is None:
        return dr.zeros(mi.Float, n_target)
    if isinstance(x, np.ndarray):
        x = mi.TensorXf(np.ascontiguousarray(x, dtype=np.float32))
    xs = _shape_of(x)
    arr = x.array if isinstance(x, mi.TensorXf) else mi.Float(x)
    if len(xs) == 1:
        xs = (1, 1, xs[0])
    if len(xs) != 3:
        raise InputValueError(f"synthesize_adc: '{name}' must be [P] or [tx, rx, P], got {xs}")
    if xs == (T, R, P):
        return arr
    t, r, p = np.meshgrid(np.arange(T), np.arange(R), np.arange(P), indexing="ij")
    idx = ((t % xs[0]) * xs[1] + (r % xs[1])) * xs[2] + (p % xs[2])
    return dr.gather(mi.Float, arr, mi.UInt32(idx.ravel().astype(np.uint32)))


def _np(x, shape):
    return np.asarray(x, dtype=np.float64).reshape(shape)


def _make_op():
    import drjit as dr
    import mitsuba as mi

    from .engine import Prepared as _Prepared

    class SynthesizeADCOp(dr.CustomOp):
        """Custom AD node: (a_re, a_im, tau, rho) -> (adc_re, adc_im)."""

        def eval(self, a_re, a_im, tau, rho, radar=None, shape=None, moving=False):
            self.radar, self.shape3, self.moving = radar, shape, moving
            a = _np(a_re, shape) + 1j * _np(a_im, shape)
            self.prep = _Prepared(radar, a, _np(tau, shape),
                                  _np(rho, shape) if moving else None)
            s = self.prep.forward()
            return (mi.Float(np.ascontiguousarray(s.real, np.float32).ravel()),
                    mi.Float(np.ascontiguousarray(s.imag, np.float32).ravel()))

        def forward(self):
            sh = self.shape3
            da = _np(self.grad_in("a_re"), sh) + 1j * _np(self.grad_in("a_im"), sh)
            dtau = _np(self.grad_in("tau"), sh)
            drho = _np(self.grad_in("rho"), sh) if self.moving else None
            ds = self.prep.jvp(da, dtau, drho)
            self.set_grad_out((mi.Float(np.ascontiguousarray(ds.real, np.float32).ravel()),
                               mi.Float(np.ascontiguousarray(ds.imag, np.float32).ravel())))

        def backward(self):
            g_re, g_im = self.grad_out()
            adc_shape = self.radar.adc_shape
            G = _np(g_re, adc_shape) + 1j * _np(g_im, adc_shape)
            ga, gt, gr = self.prep.vjp(G)
            self.set_grad_in("a_re", mi.Float(np.ascontiguousarray(ga.real, np.float32).ravel()))
            self.set_grad_in("a_im", mi.Float(np.ascontiguousarray(ga.imag, np.float32).ravel()))
            self.set_grad_in("tau", mi.Float(np.ascontiguousarray(gt, np.float32).ravel()))
            if self.moving:
                self.set_grad_in("rho", mi.Float(np.ascontiguousarray(gr, np.float32).ravel()))

        def name(self):
            return "SynthesizeADC"

    return SynthesizeADCOp


_OP = None


def synthesize_adc_drjit(radar: RadarConfig, a, tau, tau_rate=None):
    """Dr.Jit version of ``synthesize_adc``; returns :class:`DrAdc` tensors."""
    global _OP
    from ..utils.backend import init_backend

    init_backend()
    import drjit as dr
    import mitsuba as mi

    from .engine import DrAdc

    if _OP is None:
        _OP = _make_op()
    a_re, a_im = _split_complex(a)
    shapes = [s for s in (_shape_of(a_re), _shape_of(tau), _shape_of(tau_rate)) if s]
    P = max(s[-1] for s in shapes)
    shape = (radar.num_tx, radar.num_rx, P)
    n = radar.num_tx * radar.num_rx * P
    args = [_flat(x, n, shape, name) for x, name in
            ((a_re, "a"), (a_im, "a"), (tau, "tau"), (tau_rate, "tau_rate"))]
    for x, name in zip(args[:3], ("a", "a", "tau")):
        if not np.all(np.isfinite(np.asarray(dr.detach(x)))):
            raise InputValueError(f"synthesize_adc: '{name}' holds NaN or Inf")
    re, im = dr.custom(_OP, *args, radar=radar, shape=shape, moving=tau_rate is not None)
    return DrAdc(mi.TensorXf(re, radar.adc_shape), mi.TensorXf(im, radar.adc_shape))
