"""Complex tensor helpers and the unitary DFT as Dr.Jit AD nodes.

Complex signals are ``(re, im)`` pairs of ``mi.TensorXf`` of one shape
(``[F, T, R, C, N]`` for ADC).  :func:`dft` / :func:`idft` transform along the
last axis with the *unitary* DFT (``np.fft`` order, scaled by ``1/sqrt(N)``),
so residual energy is the same in the time and range domains (Parseval).  They
are ``dr.CustomOp`` nodes: the forward is SciPy's FFT in double precision; the
adjoint of the unitary DFT is its inverse, applied to ``G = dL/dRe y + j dL/dIm y``.
"""
from __future__ import annotations

import contextlib
import math

import numpy as np
import scipy.fft

from ..utils.backend import init_backend

init_backend()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

__all__ = ["single_thread", "tensor", "to_numpy", "cmul", "cis", "abs2", "conj", "cadd", "scale",
           "opaque",
           "dft", "idft", "zeros_like"]


def tensor(x, dtype=np.float32):
    """NumPy array -> ``mi.TensorXf`` (real) or ``(re, im)`` pair (complex)."""
    x = np.asarray(x)
    if np.iscomplexobj(x):
        return (mi.TensorXf(np.ascontiguousarray(x.real, dtype)),
                mi.TensorXf(np.ascontiguousarray(x.imag, dtype)))
    return mi.TensorXf(np.ascontiguousarray(x, dtype))


def to_numpy(z) -> np.ndarray:
    """``(re, im)`` pair (or a real tensor) -> complex128 / float64 NumPy array."""
    if isinstance(z, tuple):
        re, im = z
        return (np.asarray(dr.detach(re), np.float64)
                + 1j * np.asarray(dr.detach(im), np.float64))
    return np.asarray(dr.detach(z), np.float64)


def cmul(a, b):
    """``a * b`` for complex pairs (either may broadcast)."""
    return (a[0] * b[0] - a[1] * b[1], a[0] * b[1] + a[1] * b[0])


def cadd(a, b):
    return (a[0] + b[0], a[1] + b[1])


def scale(a, s):
    """Complex pair times a real tensor / scalar."""
    return (a[0] * s, a[1] * s)


def conj(a):
    return (a[0], -a[1])


def cis(phase):
    """``exp(j phase)`` as a pair."""
    s, c = dr.sincos(phase)
    return (c, s)


def abs2(a):
    return dr.square(a[0]) + dr.square(a[1])


def zeros_like(a):
    return (dr.zeros(mi.TensorXf, a[0].shape), dr.zeros(mi.TensorXf, a[0].shape))


def _numpy_pair(re, im):
    """Complex128 NumPy array of a float32 pair, filled in place (one allocation)."""
    shape = tuple(re.shape)
    out = np.empty(shape, np.complex128)
    out.real = np.asarray(re, np.float32).reshape(shape)
    out.imag = np.asarray(im, np.float32).reshape(shape)
    return out


class _UnitaryDFT(dr.CustomOp):
    """``y = F x / sqrt(N)`` (or the inverse) along the last axis."""

    def eval(self, re, im, inverse=False):
        self.inverse = inverse
        self.shape = tuple(re.shape)
        y = self._apply(_numpy_pair(re, im), inverse)
        return tensor(y)

    @staticmethod
    def _apply(x, inverse):
        # double precision: a single-precision FFT's rounding grows with the
        # row's largest tone and roughens the loss at noise-level bins enough
        # to stop L-BFGS-B early (fits end ~3 dB above the noise)
        fn = scipy.fft.ifft if inverse else scipy.fft.fft
        return fn(x, axis=-1, norm="ortho", overwrite_x=True)

    def forward(self):
        gre, gim = self.grad_in("re"), self.grad_in("im")
        dy = self._apply(_numpy_pair(gre, gim), self.inverse)
        self.set_grad_out(tensor(dy))

    def backward(self):
        gre, gim = self.grad_out()
        gx = self._apply(_numpy_pair(gre, gim), not self.inverse)   # unitary: adjoint = inverse
        out = tensor(gx)
        self.set_grad_in("re", out[0])
        self.set_grad_in("im", out[1])

    def name(self):
        return "UnitaryIDFT" if self.inverse else "UnitaryDFT"


def dft(z):
    """Unitary DFT along the last axis of a complex pair (AD node)."""
    return dr.custom(_UnitaryDFT, z[0], z[1], inverse=False)


def idft(z):
    """Inverse unitary DFT along the last axis (AD node)."""
    return dr.custom(_UnitaryDFT, z[0], z[1], inverse=True)


def column(t, j: int, shape: tuple):
    """Column ``j`` of a ``[n, m]`` parameter tensor, reshaped to ``shape`` (AD)."""
    n, m = t.shape
    idx = dr.arange(mi.UInt32, n) * m + j
    flat = dr.gather(mi.Float, t.array, idx)
    return _shaped(flat, shape)


def view(t, shape: tuple):
    """A parameter tensor reshaped (same element count) for broadcasting (AD)."""
    return _shaped(t.array, shape)


def _shaped(flat, shape):
    """``flat`` as a tensor of ``shape``; one element stays a width-1 ``mi.Float``.

    Dr.Jit 1.5 resizes a one-element *tensor* in place the first time it is
    broadcast, so reusing it fails; a width-1 ``mi.Float`` broadcasts safely.
    """
    if math.prod(shape) == 1:
        return flat + 0.0
    return mi.TensorXf(flat, shape)


def opaque(value):
    """A data-dependent scalar (a fitted position, a per-object constant) as a
    width-1 ``mi.Float`` held in memory: a Python float would be baked into
    the kernel as a literal, and every new value would compile a new kernel."""
    return dr.opaque(mi.Float, float(value))


def item(x) -> float:
    """The single value of a 0-d / one-element tensor or array as a Python float."""
    arr = getattr(x, "array", x)
    return float(np.asarray(dr.detach(arr), np.float64).ravel()[0])


@contextlib.contextmanager
def single_thread():
    """Run Dr.Jit's LLVM kernels on one thread inside the block.

    Dr.Jit 1.5's multi-threaded LLVM backend intermittently loses the whole
    gradient of small broadcast tensor graphs (reproduced in
    ``tests/test_effects_framework.py::test_09``: the same backward pass gives
    the right gradient or exactly zero from run to run); on one thread it is
    always right.  The effect tensors are small, so the cost is negligible.
    """
    n = dr.thread_count()
    dr.set_thread_count(1)
    try:
        yield
    finally:
        dr.set_thread_count(n)
