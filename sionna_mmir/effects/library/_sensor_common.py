"""Helpers shared by the sensor-chain effects (delay, frequency offset, IQ, IF, ADC).

* constructor-argument checks that raise :class:`~sionna_mmir.errors.ConfigError`
  naming the argument;
* the physical beat-frequency axis of the range bins (:func:`band_frequencies`);
* :class:`RowExtension` and :func:`filter_rows`: steady-state spectral
  operators (filters, time derivatives, per-bin phase shifts) on a finite
  ADC window, by extending every fast-time row with linear prediction before
  the DFT, as one host operator with its adjoint (AD through a fixed linear
  map in the rows, linear in each response);
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
import scipy.fft

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


def parabolic_offset(lft, mid, rgt) -> np.ndarray:
    """Offset in ``[-0.5, 0.5]`` samples of the vertex of the parabola through
    three equally spaced values around a peak (elementwise); 0 where they do
    not curve down or a neighbour is not finite (outside a search range)."""
    lft, mid, rgt = (np.asarray(a, np.float64) for a in (lft, mid, rgt))
    ok = np.isfinite(lft) & np.isfinite(rgt)
    den = np.where(ok, lft - 2 * mid + rgt, 0.0)
    num = np.where(ok, lft - rgt, 0.0)
    return np.clip(np.where(den < 0, 0.5 * num / np.where(den < 0, den, -1.0), 0.0), -0.5, 0.5)


def refine_peak(grid: np.ndarray, score: np.ndarray) -> float:
    """Grid value of the maximum of ``score`` refined by a parabola through its neighbours."""
    i = int(np.argmax(score))
    if 0 < i < len(grid) - 1:
        off = float(parabolic_offset(score[i - 1], score[i], score[i + 1]))
        return float(grid[i] + off * (grid[i + 1] - grid[i]))
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
    :meth:`fit` sees the model (so the map stays linear and AD exact); the
    effects model calls it again whenever an effect joins the model
    (:class:`ExtendedRows`); without a fit it is estimated from the signal
    itself.  If the
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

    def filter(self, x, E, responses, first=()):
        """:func:`filter_rows` with this extension's matrix ``E`` (:meth:`current`)."""
        return filter_rows(x, E, responses, first)


class ExtendedRows:
    """Mixin of the effects whose spectral operator extends the rows by a
    :class:`RowExtension` held in ``self.extension``: the predictor is
    frozen on the model the effect is added to and renewed on the whole
    model whenever another effect joins it
    (:meth:`~sionna_mmir.effects.base.Effect.refreeze`)."""

    frozen_on_model = True

    def refreeze(self, model: np.ndarray) -> None:
        self.extension.fit(model)


def filter_rows(x, E, responses, first=()):
    """``crop(IDFT(H_k DFT(extend(x))))`` for every response ``H_k`` (AD node).

    One DFT of the extended rows serves every response, and the crop, the
    products and the inverse DFTs happen in one host call (its adjoint in
    another): the steady-state filter outputs without a round trip to
    the device per step.

    Parameters
    ----------
    x : pair of tensors
        complex ADC ``[..., N]``.
    E : numpy.ndarray or None
        :meth:`RowExtension.current`'s extension matrix (None: plain
        circular DFT).
    responses : list
        each complex, broadcastable to ``[..., n]`` (``n`` the extended
        length, ``E.shape[0]`` or ``N``; e.g. ``(1, 1, 1, 1, n)`` for one
        response of every row); a Dr.Jit pair (AD) or a NumPy array
        (constant); on the unitary DFT's bins, ``np.fft`` order.
    first : sequence of bool
        per response, return only the window's first sample ``[..., 1]``
        (an inner product, no inverse DFT).

    Returns a list of complex pairs, ``[..., N]`` or ``[..., 1]``.
    """
    first = tuple(bool(f) for f in first) or (False,) * len(responses)
    if len(first) != len(responses):
        raise ValueError("filter_rows: one 'first' flag per response")
    hs, needs = [], []
    for h in responses:
        h = h if isinstance(h, tuple) else ops.tensor(np.asarray(h, complex))
        needs.append(dr.grad_enabled(h[0]) or dr.grad_enabled(h[1]))
        hs.append(h if needs[-1] else (dr.detach(h[0]), dr.detach(h[1])))
    m = 0 if E is None else (E.shape[0] - E.shape[1]) // 2
    out = dr.custom(_FilteredRows, x[0], x[1], hs, head=None if E is None else E[:m],
                    tail=None if E is None else E[E.shape[0] - m:], first=first,
                    needs=tuple(needs), needs_x=dr.grad_enabled(x[0]) or dr.grad_enabled(x[1]))
    return [(out[2 * k], out[2 * k + 1]) for k in range(len(hs))]


_pair_numpy = ops._numpy_pair          # one home: complex128 from a float32 pair


def _rows_times(x: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``x @ m`` over the last axis as one 2-D product (batched matmul is slow)."""
    with one_blas_thread():
        out = x.reshape(-1, x.shape[-1]) @ m
    return out.reshape(x.shape[:-1] + (m.shape[1],))


def _sum_to(a: np.ndarray, shape: tuple) -> np.ndarray:
    """``a`` summed over the axes that ``shape`` broadcasts (the adjoint of broadcasting)."""
    lead = a.ndim - len(shape)
    axes = tuple(range(lead)) + tuple(lead + i for i, d in enumerate(shape)
                                      if d == 1 and a.shape[lead + i] != 1)
    return np.sum(a, axis=axes, keepdims=True).reshape(shape)


def _column_support(M: np.ndarray):
    """``(columns, M[:, columns])``: the slice spanning ``M``'s nonzero columns."""
    nz = np.flatnonzero(np.any(M != 0, axis=0))
    cols = slice(int(nz[0]), int(nz[-1]) + 1) if nz.size else slice(0, 0)
    return cols, np.ascontiguousarray(M[:, cols])


class _FilteredRows(dr.CustomOp):
    """``y_k = C F^H diag(H_k) F P x`` for responses ``H_k`` (AD node,
    :func:`filter_rows`): ``P`` the row extension ``[head; I; tail]``,
    ``F`` the unitary DFT on the extended length ``n``, ``C`` the crop to the
    window (or, with ``first[k]``, to its first sample: ``w^T diag(H_k) F P x``,
    ``w_j = exp(2 pi i j m / n) / sqrt(n)``).

    Adjoints (``G = dL/dRe + j dL/dIm``): the spectral gradient
    ``S = sum_k conj(H_k) F C^T G_k`` gives ``G_x = P^H F^H S``, and
    ``G_H_k = sum conj(F P x) (F C^T G_k)`` over the axes ``H_k`` broadcasts.
    """

    def eval(self, re, im, hs, head=None, tail=None, first=(), needs=(), needs_x=True):
        self.first, self.needs, self.needs_x = first, needs, needs_x
        self.m = 0 if head is None else head.shape[0]
        # a predictor of order p reads only the p samples next to its edge:
        # the products use the matrices' nonzero columns alone
        self.head = None if head is None else _column_support(head)
        self.tail = None if tail is None else _column_support(tail)
        x = _pair_numpy(re, im)
        self.N = x.shape[-1]
        self.Xe = scipy.fft.fft(self._extend(x), axis=-1, norm="ortho", overwrite_x=True)
        n = self.Xe.shape[-1]
        self.w = np.exp(2j * np.pi * np.arange(n) * self.m / n) / np.sqrt(n)
        self.h_shapes = [tuple(h[0].shape) for h in hs]
        self.H = [self._response(h) for h in hs]
        outs = []
        for H, f in zip(self.H, first):
            y = self._one(self.Xe, H, f)
            outs += [mi.TensorXf(np.ascontiguousarray(y.real, np.float32)),
                     mi.TensorXf(np.ascontiguousarray(y.imag, np.float32))]
        return tuple(outs)

    def _extend(self, x):
        if self.head is None:
            return x
        (hs, h), (ts, t) = self.head, self.tail
        return np.concatenate([_rows_times(x[..., hs], h.T), x, _rows_times(x[..., ts], t.T)],
                              axis=-1)

    @staticmethod
    def _response(h):
        """A response as complex NumPy: flat ``[n]`` when every row shares it."""
        H = _pair_numpy(h[0], h[1])
        return H.ravel() if H.size == H.shape[-1] else H

    def _one(self, X, H, first):
        if first:
            if H.ndim == 1:
                return _rows_times(X, (H * self.w)[:, None])
            return np.sum(X * (H * self.w), axis=-1, keepdims=True)
        y = scipy.fft.ifft(X * H, axis=-1, norm="ortho", overwrite_x=True)
        return y[..., self.m:self.m + self.N]

    def _spectrum(self, g, first):
        """``F C^T g`` (or ``conj(w) g`` for a first-sample output)."""
        if first:
            return np.conj(self.w) * g
        pad = np.zeros(g.shape[:-1] + (self.Xe.shape[-1],), complex)
        pad[..., self.m:self.m + self.N] = g
        return scipy.fft.fft(pad, axis=-1, norm="ortho", overwrite_x=True)

    def forward(self):
        dX = scipy.fft.fft(self._extend(_pair_numpy(self.grad_in("re"), self.grad_in("im"))),
                           axis=-1, norm="ortho")
        dh = self.grad_in("hs")
        outs = []
        for k, (H, f) in enumerate(zip(self.H, self.first)):
            dY = dX * H
            if self.needs[k]:
                dY = dY + self.Xe * self._response(dh[k])
            y = self._one(dY, np.ones_like(H), f)
            outs += [mi.TensorXf(np.ascontiguousarray(y.real, np.float32)),
                     mi.TensorXf(np.ascontiguousarray(y.imag, np.float32))]
        self.set_grad_out(tuple(outs))

    def backward(self):
        g = self.grad_out()
        S_x = None
        gh = []
        for k, (H, f) in enumerate(zip(self.H, self.first)):
            S = self._spectrum(_pair_numpy(g[2 * k], g[2 * k + 1]), f)
            if self.needs_x:
                part = np.conj(H) * S
                S_x = part if S_x is None else S_x + part
            shape = self.h_shapes[k]
            G = (_sum_to(np.conj(self.Xe) * S, shape) if self.needs[k]
                 else np.zeros(shape, complex))
            gh.append(ops.tensor(G.reshape(shape)))
        self.set_grad_in("hs", gh)
        if not self.needs_x:                 # x is held fixed: no inverse DFT of S
            return
        G_e = scipy.fft.ifft(S_x, axis=-1, norm="ortho", overwrite_x=True)
        m, N = self.m, self.N
        gx = np.array(G_e[..., m:m + N])
        if self.head is not None:
            (hs, h), (ts, t) = self.head, self.tail
            gx[..., hs] += _rows_times(G_e[..., :m], np.conj(h))
            gx[..., ts] += _rows_times(G_e[..., m + N:], np.conj(t))
        gx = ops.tensor(gx)
        self.set_grad_in("re", gx[0])
        self.set_grad_in("im", gx[1])

    def name(self):
        return "FilteredRows"


def seen_chirp_mean(x: np.ndarray) -> np.ndarray:
    """Mean over chirp loops of ``x [F, T, R, C, N]`` over the chirps that are not
    all zero (held out), ``[F, T, R, 1, N]``."""
    seen = np.any(x != 0, axis=-1, keepdims=True)
    return x.sum(axis=3, keepdims=True) / np.maximum(seen.sum(axis=3, keepdims=True), 1)


def bin_power(residual: np.ndarray) -> np.ndarray:
    """Mean power per range bin (unitary DFT) of ``residual [..., N]`` over the
    rows that are not all zero, ``[N]``."""
    R = np.fft.fft(residual.reshape(-1, residual.shape[-1]), axis=-1, norm="ortho")
    P = np.abs(R) ** 2
    keep = P.sum(axis=-1) > 0
    return np.maximum(P[keep].mean(axis=0) if keep.any() else P.mean(axis=0), 1e-300)


#: a range bin whose chirp-to-chirp scatter exceeds the median bin's by this
#: factor carries a chirp-varying signal, not receiver noise (:func:`noise_bins`)
SCATTER_OUTLIER = 3.0


def noise_bins(power: np.ndarray) -> np.ndarray:
    """Which range bins of a chirp-to-chirp scatter spectrum ``power [N]`` hold
    receiver noise alone: those at most :data:`SCATTER_OUTLIER` times the
    median bin.  A mover, a drooping or ego-moving scene leaves its range bins
    far above the rest; judged with them, a noise shape that is lower
    anywhere else (a high-pass notch at near-DC bins) gains from the floor
    they inflate, whatever the receiver does."""
    power = np.asarray(power, float)
    return power <= SCATTER_OUTLIER * np.median(power)


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
