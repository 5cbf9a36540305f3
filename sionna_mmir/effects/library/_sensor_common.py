"""Helpers shared by the sensor-chain effects (delay, frequency offset, IQ, IF, ADC).

* constructor-argument checks that raise :class:`~sionna_mmir.errors.ConfigError`
  naming the argument;
* the physical beat-frequency axis of the range bins (:func:`band_frequencies`);
* :class:`RowExtension`: steady-state spectral operators (filters, time
  derivatives) on a finite ADC window, by extending every fast-time row with
  linear prediction before the DFT (AD through a fixed linear map);
* constant tensors shaped for broadcasting against ``[F, T, R, C, N]``;
* coherent grid scans and peak refinement for data-driven initial values;
* a numerically safe softplus on Dr.Jit tensors;
* the chirp-to-chirp deviation of a capture (:func:`chirp_deviation`): what
  a static scene and sensor do not repeat is receiver noise.
"""
from __future__ import annotations

import math
import numbers

import warnings

import numpy as np

from ...errors import ConfigError
from ...utils.threads import one_blas_thread
from .. import ops

dr, mi = ops.dr, ops.mi

LN10 = float(np.log(10.0))


# ------------------------------------------------------------------ checks
def check_float(owner: str, name: str, value, lo=-np.inf, hi=np.inf,
                lo_open=False, hi_open=False) -> float:
    """``value`` as a finite float in ``[lo, hi]`` (open ends on request) or ConfigError."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ConfigError(f"{owner}: {name} must be a number, got {value!r}")
    v = float(value)
    bad = (not np.isfinite(v) or v < lo or v > hi
           or (lo_open and v == lo) or (hi_open and v == hi))
    if bad:
        lo_b, hi_b = ("(" if lo_open else "["), (")" if hi_open else "]")
        raise ConfigError(f"{owner}: {name} must lie in {lo_b}{lo}, {hi}{hi_b}, got {value!r}")
    return v


def check_int(owner: str, name: str, value, lo: int, hi: int) -> int:
    """``value`` as an int in ``[lo, hi]`` or ConfigError."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ConfigError(f"{owner}: {name} must be an integer, got {value!r}")
    if not lo <= int(value) <= hi:
        raise ConfigError(f"{owner}: {name} must lie in [{lo}, {hi}], got {value!r}")
    return int(value)


# -------------------------------------------------------------- frequencies
def band_frequencies(ctx, band_start: float, n: int | None = None) -> np.ndarray:
    """:meth:`EffectContext.band_frequencies <sionna_mmir.effects.context.EffectContext.band_frequencies>`."""
    return ctx.band_frequencies(band_start, n)


def legendre_basis(u: np.ndarray, degrees) -> np.ndarray:
    """Legendre polynomials ``P_d(u)`` for ``d`` in ``degrees``, ``[len(degrees), len(u)]``."""
    out = []
    for d in degrees:
        c = np.zeros(d + 1)
        c[d] = 1.0
        out.append(np.polynomial.legendre.legval(u, c))
    return np.asarray(out)


def unit_fast_time(ctx) -> np.ndarray:
    """Fast time mapped onto ``u in [-1, 1]`` over the ADC window, ``[N]``."""
    t = ctx.fast_time
    if len(t) < 2:
        return np.zeros_like(t)
    return 2.0 * (t - t[0]) / (t[-1] - t[0]) - 1.0


# ----------------------------------------------------------------- tensors
def const(arr, shape: tuple):
    """A constant float32 tensor of ``shape`` (at least two elements) for broadcasting."""
    arr = np.ascontiguousarray(np.broadcast_to(np.asarray(arr, np.float64), shape), np.float32)
    if arr.size < 2:
        return mi.Float(float(arr.ravel()[0]))
    return mi.TensorXf(arr)


def last_axis(arr):
    """``[N]`` constant as a ``(1, 1, 1, 1, N)`` tensor."""
    arr = np.asarray(arr)
    return const(arr, (1, 1, 1, 1, arr.size))


def scalar(p, j: int = 0):
    """Element ``j`` of a 1-D parameter tensor as a width-1 ``mi.Float`` (AD, safe to broadcast)."""
    n = math.prod(p.shape)
    if n == 1:
        return ops.view(p, (1, 1, 1, 1, 1))
    return ops.column(ops.view(p, (1, n)), j, (1, 1, 1, 1, 1))


def softplus(z):
    """``log(1 + exp(z))`` without overflow (Dr.Jit, AD)."""
    return dr.maximum(z, 0.0) + dr.log(1.0 + dr.exp(-dr.abs(z)))


# -------------------------------------------------------------- data scans
def channel_products(model: np.ndarray, data: np.ndarray) -> np.ndarray:
    """``sum_{f, c} conj(model) data`` per (tx, rx, sample), ``[T, R, N]``."""
    return np.einsum("ftrck,ftrck->trk", np.conj(model), data)


def scan(z: np.ndarray, phase_per_unit: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """``sum_k z[..., k] exp(-j phase_per_unit[k] grid[g])``, ``[..., G]`` complex."""
    e = np.exp(-1j * np.outer(phase_per_unit, grid))                    # [N, G]
    return _rows_times(z, e)


def refine_peak(grid: np.ndarray, score: np.ndarray) -> float:
    """Grid value of the maximum of ``score`` refined by a parabola through its neighbours."""
    i = int(np.argmax(score))
    if 0 < i < len(grid) - 1:
        a, b, c = score[i - 1], score[i], score[i + 1]
        den = a - 2 * b + c
        if den < 0:
            step = grid[i + 1] - grid[i]
            return float(grid[i] + 0.5 * (a - c) / den * step)
    return float(grid[i])


def median_polish(d: np.ndarray, iters: int = 6):
    """Robust additive split ``d[t, r] ~ a_t + b_r`` (Tukey's median polish), symmetric gauge.

    NaN entries (unobserved channels) are ignored; a row or column with no
    observation gets 0.
    """
    a = np.zeros(d.shape[0])
    b = np.zeros(d.shape[1])
    if not np.isfinite(d).any():
        return a, b
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for _ in range(iters):
            a = np.nan_to_num(np.nanmedian(d - b[None, :], axis=1))
            b = np.nan_to_num(np.nanmedian(d - a[:, None], axis=0))
    shift = 0.5 * (a.mean() - b.mean())
    return a - shift, b + shift


# -------------------------------------------------- linear-prediction extension
MAX_PREDICTION_ROWS = 256
MAX_EXTENSION_GAIN = 3.0


def prediction_coefficients(rows: np.ndarray, order: int, reg: float = 1e-7) -> np.ndarray:
    """Forward predictor ``x_n ~ sum_{j=1..order} a_j x_{n-j}`` pooled over ``rows`` ``[M, N]``.

    Regularised least squares on the strongest rows (at most 256).  A sum of
    up to ``order`` tones is predicted exactly, whatever each row's amplitudes.
    """
    energy = np.sum(np.abs(rows) ** 2, axis=1)
    keep = np.argsort(energy)[::-1][:MAX_PREDICTION_ROWS]
    rows = rows[keep[energy[keep] > 0]]
    N = rows.shape[1]
    lagged = [rows[:, order - j:N - j] for j in range(1, order + 1)]
    A = np.stack(lagged, axis=-1).reshape(-1, order)
    y = rows[:, order:].reshape(-1)
    with one_blas_thread():
        G = A.conj().T @ A
        G += reg * max(np.trace(G).real / order, 1e-30) * np.eye(order)
        return np.linalg.solve(G, A.conj().T @ y)


def edge_taper(n: int, margin: int) -> np.ndarray:
    """Weights ``[n + 2 margin]``: 1 on the window and the inner half of each
    extension, a raised cosine to 0 over the outer half."""
    w = np.ones(n + 2 * margin)
    k = margin // 2
    if k:
        ramp = 0.5 - 0.5 * np.cos(np.pi * (np.arange(k) + 0.5) / k)
        w[:k] = ramp
        w[-k:] = ramp[::-1]
    return w


def extension_matrix(a: np.ndarray, b: np.ndarray, n: int, margin: int) -> np.ndarray:
    """``E`` ``[n + 2 margin, n]``: ``E x`` is ``x`` with ``margin`` samples predicted
    before (backward predictor ``b``) and after (forward predictor ``a``)."""
    eye = np.eye(n, dtype=complex)
    fwd = list(eye)
    bwd = list(eye[::-1])
    for _ in range(margin):
        fwd.append(sum(a[j] * fwd[-1 - j] for j in range(len(a))))
        bwd.append(sum(b[j] * bwd[-1 - j] for j in range(len(b))))
    return np.array(bwd[n:][::-1] + list(eye) + fwd[n:])


class RowExtension:
    """Linear-prediction extension of the fast-time rows of an ADC tensor.

    A spectral operator (``IDFT(G(f) DFT(x))``) on a finite window treats the
    window as periodic: a tone off the bin grid wraps its end onto its start,
    so a filter's memory or a derivative sees a jump there (errors of ~1-10 %
    in the first / last samples).  The steady-state response needs the
    signal just outside the window.  A model ADC is a sum of tones, which a
    linear predictor of modest order continues accurately, so each row is
    extended by ``margin`` predicted samples on both sides, the operator is
    applied on the ``N + 2 margin`` grid and the window cut out again.

    The outer half of each extension is tapered to zero (raised cosine,
    :func:`edge_taper`) so the extended row has no wrap-around jump either and
    its spectrum no leakage skirts; the inner half must cover the operator's
    memory (a filter time constant of a few samples).

    The predictor is pooled over all rows (tones share frequencies across
    channels and chirps, only amplitudes differ) and *frozen* when
    :meth:`fit` sees the initial model (so the map stays linear and AD
    exact); without a fit it is estimated from the signal itself.  If the
    predicted samples grow (unstable predictor) or the signal is empty the
    extension is switched off (plain circular DFT).
    """

    def __init__(self, margin: int, order: int):
        self.margin = int(margin)
        self.order = int(order)
        self.matrix = None
        self.n = None

    def _build(self, x: np.ndarray):
        n = x.shape[-1]
        rows = np.asarray(x, complex).reshape(-1, n)
        order = self.effective_order(n)
        if self.margin == 0 or order < 1 or not np.any(rows != 0):
            return None
        a = prediction_coefficients(rows, order)
        b = prediction_coefficients(rows[:, ::-1], order)
        E = extension_matrix(a, b, n, self.margin)
        ext = _rows_times(rows, E.T)
        rms = np.sqrt(np.mean(np.abs(rows) ** 2))
        edge = np.sqrt(np.mean(np.abs(np.concatenate([ext[:, :self.margin],
                                                         ext[:, -self.margin:]], axis=1)) ** 2))
        if not np.isfinite(edge) or edge > MAX_EXTENSION_GAIN * rms:
            return None
        return edge_taper(n, self.margin)[:, None] * E

    def effective_order(self, n: int) -> int:
        """Predictor order used for rows of ``n`` samples: ``order``, capped at
        ``n // 4`` so every row gives at least three times as many prediction
        equations as unknowns (short rows, e.g. 64 samples, keep an extension)."""
        return min(self.order, n // 4)

    def fit(self, model: np.ndarray):
        """Freeze the predictor on ``model`` (complex NumPy ``[..., N]``)."""
        self.n = model.shape[-1]
        self.matrix = self._build(model)
        return self

    def current(self, x_numpy_fn, n: int):
        """The frozen matrix for length ``n``, else one built from ``x_numpy_fn()``."""
        if self.n == n:
            return self.matrix
        return self._build(x_numpy_fn())

    @property
    def length(self) -> int:
        """Extended length for the frozen matrix (``N`` when switched off)."""
        return self.n if self.matrix is None else self.matrix.shape[0]

    # NumPy versions (initial values)
    def extend_numpy(self, x: np.ndarray, E) -> np.ndarray:
        return x if E is None else _rows_times(x, E.T)

    def crop_numpy(self, y: np.ndarray, E) -> np.ndarray:
        return y if E is None else y[..., self.margin:self.margin + E.shape[1]]

    # Dr.Jit versions (AD).  ``E`` is the identity on the window, so only its
    # predicted rows cost a product: ``2 margin x N`` per row instead of
    # ``(N + 2 margin) x N``, and the crop is a slice.
    def extend(self, z, E):
        if E is None:
            return z
        m = (E.shape[0] - E.shape[1]) // 2
        return dr.custom(_RowExtend, z[0], z[1], head=E[:m], tail=E[E.shape[0] - m:])

    def crop(self, z, E):
        if E is None:
            return z
        return dr.custom(_LastAxisSlice, z[0], z[1], start=(E.shape[0] - E.shape[1]) // 2,
                         length=E.shape[1])


_pair_numpy = ops._numpy_pair          # one home: complex128 from a float32 pair





def _rows_times(x: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``x @ m`` over the last axis as one 2-D product (batched matmul is slow)."""
    with one_blas_thread():
        out = x.reshape(-1, x.shape[-1]) @ m
    return out.reshape(x.shape[:-1] + (m.shape[1],))


class _RowExtend(dr.CustomOp):
    """``[x head^T, x, x tail^T]`` over the last axis (AD node): a row extension
    whose matrix is the identity on the window (:meth:`RowExtension.extend`).

    ``head``, ``tail``: complex ``[m, N]``, the predicted samples before and
    after the window.  Adjoint: ``G_window + G_head conj(head) + G_tail conj(tail)``.
    """

    def eval(self, re, im, head=None, tail=None):
        self.head, self.tail = head, tail
        return ops.tensor(self._apply(_pair_numpy(re, im)))

    def _apply(self, x):
        return np.concatenate([_rows_times(x, self.head.T), x, _rows_times(x, self.tail.T)],
                              axis=-1)

    def forward(self):
        self.set_grad_out(ops.tensor(self._apply(_pair_numpy(self.grad_in("re"),
                                                             self.grad_in("im")))))

    def backward(self):
        g = _pair_numpy(*self.grad_out())
        m, n = self.head.shape
        gx = (g[..., m:m + n] + _rows_times(g[..., :m], np.conj(self.head))
              + _rows_times(g[..., m + n:], np.conj(self.tail)))
        gx = ops.tensor(gx)
        self.set_grad_in("re", gx[0])
        self.set_grad_in("im", gx[1])

    def name(self):
        return "RowExtend"


class _LastAxisSlice(dr.CustomOp):
    """``x[..., start:start + length]`` (AD node; the adjoint pads with zeros)."""

    def eval(self, re, im, start=0, length=1):
        self.start, self.length, self.full = int(start), int(length), int(re.shape[-1])
        return ops.tensor(_pair_numpy(re, im)[..., self.start:self.start + self.length])

    def forward(self):
        dx = _pair_numpy(self.grad_in("re"), self.grad_in("im"))
        self.set_grad_out(ops.tensor(dx[..., self.start:self.start + self.length]))

    def backward(self):
        g = _pair_numpy(*self.grad_out())
        gx = np.zeros(g.shape[:-1] + (self.full,), complex)
        gx[..., self.start:self.start + self.length] = g
        gx = ops.tensor(gx)
        self.set_grad_in("re", gx[0])
        self.set_grad_in("im", gx[1])

    def name(self):
        return "LastAxisSlice"


def seen_chirp_mean(x: np.ndarray) -> np.ndarray:
    """Mean over chirp loops of ``x [F, T, R, C, N]`` over the chirps that are not
    all zero (held out), ``[F, T, R, 1, N]``."""
    seen = np.any(x != 0, axis=-1, keepdims=True)
    return x.sum(axis=3, keepdims=True) / np.maximum(seen.sum(axis=3, keepdims=True), 1)


def chirp_deviation(x: np.ndarray) -> np.ndarray | None:
    """Deviation of each chirp of ``x [F, T, R, C, N]`` from the chirp mean, scaled
    by ``sqrt(C / (C - 1))`` so white noise keeps its power (held-out, all-zero
    chirps stay zero); ``None`` with one chirp loop.  A static scene and a static
    sensor repeat from chirp to chirp: what is left is receiver noise."""
    C = x.shape[3]
    if C < 2:
        return None
    seen = np.any(x != 0, axis=-1, keepdims=True)
    n = np.maximum(seen.sum(axis=3, keepdims=True), 2)
    return np.where(seen, (x - seen_chirp_mean(x)) * np.sqrt(n / (n - 1)), 0.0)
