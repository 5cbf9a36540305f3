"""ADC synthesis from *factorised* paths, without the ``[tx, rx, path]`` expansion.

MIMO ray reuse (:mod:`sionna_mmir.paths.solver`) gives amplitudes and delays
that factor over the Tx and Rx elements::

    a[t, r, p]   = c[p] g_t[t, p] g_r[r, p]
    tau[t, r, p] = tau_t[t, p] + tau_r[r, p]        rho[t, r, p] = rho[p]

With the beat model of :mod:`sionna_mmir.fmcw.model`,
``phi = f_k (tau + rho T_tl) + f0 rho t_k`` (``f_k = f0 + S t_k``), the phasor
splits into a Tx and an Rx factor::

    exp(j 2 pi phi) = E_t[t, l, k, p] E_r[r, k, p]
    E_t = exp(j 2 pi f_k (tau_t + rho T_tl))     (TDM chirp start: a Tx property)
    E_r = exp(j 2 pi (f_k tau_r + f0 rho t_k))   (intra-chirp Doppler: per path)

so for every fast-time sample ``k`` the path sum is one matrix product::

    s[t, r, l, k] = sum_p A[k, (t, l), p] B[k, r, p],   A = g_t E_t,  B = c g_r E_r

``[T*L, P] @ [P, R]`` per ``k``, batched with ``np.matmul`` and chunked over
paths so the working set stays within :data:`CHUNK_BYTES`.  Only
``(T L + R) K P`` phasors are formed (each as a product of two of
``Q + R' ~ 2 sqrt(K)`` phasors computed from float64 phases), never the
``T R P`` expanded paths.  The result equals :func:`~sionna_mmir.fmcw.synthesize_adc`
on the expanded paths; the vector-Jacobian and Jacobian-vector products use
the same matrix-product structure.

``L`` is ``num_chirps`` with motion and 1 without (every chirp is the same).
"""
from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..errors import InputValueError
from ..utils.threads import one_blas_thread
from ..radar.config import RadarConfig

#: working-set budget of one chunk of paths [bytes]; small chunks keep the
#: arrays in the allocator's reuse range and the caches (measured faster)
CHUNK_BYTES = 32 * 2 ** 20
#: fewest paths per chunk (the inner dimension of the forward products)
MIN_CHUNK_PATHS = 32
#: chunks processed concurrently (NumPy releases the GIL; BLAS runs one
#: thread per chunk: robust on busy cores, where threaded BLAS stalls)
NUM_WORKERS = max(1, min(4, os.cpu_count() or 1))

_WHERE = "synthesize_adc_factorised"


# ----------------------------------------------------------------- validation
@dataclass
class FactorInputs:
    """Validated factorised paths (NumPy, float64 / complex128).

    Parameters
    ----------
    c : numpy.ndarray
        complex ``[P]``: per-path amplitude (beat convention)
    g_t : numpy.ndarray
        ``[T, P]``: Tx-leg gain (dimensionless)
    tau_t : numpy.ndarray
        ``[T, P]``: Tx-leg delay [s]
    g_r : numpy.ndarray
        ``[R, P]``: Rx-leg gain (dimensionless)
    tau_r : numpy.ndarray
        ``[R, P]``: Rx-leg delay [s]
    rho : numpy.ndarray, optional
        ``[P]``: delay rate ``d tau / dt`` [s/s], or ``None`` (static)
    """

    c: np.ndarray
    g_t: np.ndarray
    tau_t: np.ndarray
    g_r: np.ndarray
    tau_r: np.ndarray
    rho: np.ndarray | None

    @property
    def num_paths(self) -> int:
        return int(self.c.shape[0])


def _finite(name, arr, where):
    if np.iscomplexobj(arr):
        ok = np.isfinite(arr.real).all() and np.isfinite(arr.imag).all()
    else:
        ok = np.isfinite(arr).all()
    if not ok:
        raise InputValueError(f"{where}: '{name}' holds NaN or Inf")


def _real(name, x, shape, where):
    arr = np.asarray(x)
    if np.iscomplexobj(arr):
        raise InputValueError(f"{where}: '{name}' must be real, got {arr.dtype}")
    if arr.shape != shape:
        raise InputValueError(f"{where}: '{name}' must have shape {shape}, got {arr.shape}")
    arr = arr.astype(np.float64, copy=False)
    _finite(name, arr, where)
    return arr


def check_factor_inputs(radar: RadarConfig, c, g_t, tau_t, g_r, tau_r, tau_rate=None,
                        where: str = _WHERE) -> FactorInputs:
    """Validate shapes (``c [P]``, ``g_t, tau_t [T, P]``, ``g_r, tau_r [R, P]``,
    ``tau_rate [P]``) and finiteness; raise :class:`InputValueError` naming the
    argument.  Returns :class:`FactorInputs`.
    """
    c = np.asarray(c)
    if c.ndim != 1:
        raise InputValueError(f"{where}: 'c' must be [paths], got shape {c.shape}")
    c = c.astype(np.complex128, copy=False)
    _finite("c", c, where)
    T, R, P = radar.num_tx, radar.num_rx, c.shape[0]
    g_t = _real("g_t", g_t, (T, P), where)
    tau_t = _real("tau_t", tau_t, (T, P), where)
    g_r = _real("g_r", g_r, (R, P), where)
    tau_r = _real("tau_r", tau_r, (R, P), where)
    rho = None if tau_rate is None else _real("tau_rate", tau_rate, (P,), where)
    return FactorInputs(c, g_t, tau_t, g_r, tau_r, rho)


# ------------------------------------------------------------------- phasors
def _split(K: int) -> tuple[int, int]:
    """``(Q, R')`` with ``Q R' >= K``, ``R' ~ sqrt(K)``: ``k = R' q + r``."""
    inner = max(1, int(math.ceil(math.sqrt(K))))
    return int(math.ceil(K / inner)), inner


#: elements per pass of :func:`_cis` (its float64 / float32 temporaries stay in cache)
CIS_CHUNK = 1 << 15


def _cis(cycles: np.ndarray) -> np.ndarray:
    """``exp(j 2 pi cycles)`` as complex64; ``cycles`` reduced mod 1 in float64.

    Works through the array in :data:`CIS_CHUNK` pieces with reused buffers:
    whole-array temporaries (tens of MB for the synthesiser's ``[rows, P]``
    phases) cost more in fresh pages than the arithmetic (measured 2-5x).
    """
    flat = np.ascontiguousarray(cycles, dtype=np.float64).reshape(-1)
    out = np.empty(flat.size, np.complex64)
    parts = out.view(np.float32).reshape(-1, 2)               # [n, (re, im)]
    n = min(CIS_CHUNK, flat.size)
    frac, ang = np.empty(n), np.empty(n, np.float32)
    for s in range(0, flat.size, CIS_CHUNK):
        e = min(flat.size, s + CIS_CHUNK)
        f, a = frac[:e - s], ang[:e - s]
        np.floor(flat[s:e], out=f)
        np.subtract(flat[s:e], f, out=f)                      # [0, 1), faster than np.mod
        np.multiply(f, 2 * np.pi, out=a, casting="same_kind")
        np.cos(a, out=parts[s:e, 0])
        np.sin(a, out=parts[s:e, 1])
    return out.reshape(np.shape(cycles))


def linear_phasors(c0: np.ndarray, c1: np.ndarray, K: int, amp=None) -> np.ndarray:
    """``amp exp(j 2 pi (c0 + k c1))`` for ``k < K``: complex64 ``[K, *c0.shape]``.

    ``c0``, ``c1`` in cycles (float64, same shape), ``amp`` (optional) real or
    complex, broadcastable to ``c0``.  With ``k = R' q + r`` the phasor is
    ``exp(j2pi (c0 + R' q c1)) exp(j2pi r c1)``: ``Q + R'`` phasors from
    float64 phases and one complex64 product per entry.
    """
    Q, Rr = _split(K)
    ext = (-1,) + (1,) * c0.ndim
    X = _cis(c0[None] + (Rr * np.arange(Q, dtype=np.float64)).reshape(ext) * c1[None])
    if amp is not None:
        X *= np.asarray(amp, dtype=np.complex64)
    Y = _cis(np.arange(Rr, dtype=np.float64).reshape(ext) * c1[None])
    out = np.empty((Q, Rr) + c0.shape, np.complex64)
    np.multiply(X[:, None], Y[None, :], out=out)
    return out.reshape((Q * Rr,) + c0.shape)[:K]


def _in_groups(fn, items, workers: int) -> list:
    """``fn(group)`` for ``workers`` round-robin groups of ``items``, on threads
    with single-threaded BLAS; returns the results per group."""
    items = list(items)
    groups = [items[i::workers] for i in range(max(1, min(workers, len(items))))]
    with one_blas_thread():
        if len(groups) == 1:
            return [fn(groups[0])]
        with ThreadPoolExecutor(max_workers=len(groups)) as pool:
            return list(pool.map(fn, groups))


# ---------------------------------------------------------------- synthesiser
class FactorisedSynthesis:
    """Forward, VJP and JVP of the factorised synthesis for fixed inputs.

    Rows of the Tx factor are ``(t, l)`` pairs (``L = num_chirps`` with
    motion, else 1); all per-chunk arrays are laid out ``[K, rows, paths]`` so
    that each sample's slice is a contiguous matrix for BLAS.
    """

    def __init__(self, radar: RadarConfig, inputs: FactorInputs, chunk_bytes: int = CHUNK_BYTES,
                 workers: int = NUM_WORKERS):
        self.radar, self.x = radar, inputs
        self.T, self.R, self.P = radar.num_tx, radar.num_rx, inputs.num_paths
        self.moving = inputs.rho is not None
        self.L = radar.num_chirps if self.moving else 1
        self.K = radar.num_samples
        self.f0, self.S = radar.start_frequency, radar.slope
        self.t0, self.dt = radar.adc_start_time, 1.0 / radar.sample_rate
        self.fk0 = self.f0 + self.S * self.t0                   # f_k at k = 0 [Hz]
        self.Tl = radar.chirp_start_times()[:, :self.L]         # [T, L] [s]
        self.chunk_bytes = int(chunk_bytes)
        self.workers = int(workers)

    # ------------------------------------------------------------ helpers
    def _chunks(self, arrays_per_path: int):
        """Slices of paths whose ``arrays_per_path`` complex64 ``[K, T L + R]``
        working arrays fit in the chunk budget."""
        per_path = max(1, arrays_per_path * self.K * (self.T * self.L + self.R) * 8)
        step = max(MIN_CHUNK_PATHS, self.chunk_bytes // per_path)
        for s in range(0, self.P, step):
            yield slice(s, min(self.P, s + step))

    def _tau0(self, sl) -> np.ndarray:
        """Tx-leg delay at each chirp start, ``[T*L, n]`` [s]."""
        tau = self.x.tau_t[:, None, sl]
        if self.moving:
            tau = tau + self.x.rho[None, None, sl] * self.Tl[:, :, None]
        return np.broadcast_to(tau, (self.T, self.L, tau.shape[-1])).reshape(self.T * self.L, -1)

    def _tx_phasors(self, sl, gain: bool = False) -> np.ndarray:
        """``E_t`` (``gain``: ``A = g_t E_t``), complex64 ``[K, T*L, n]``."""
        tau0 = self._tau0(sl)
        return linear_phasors(self.fk0 * tau0, self.S * self.dt * tau0, self.K,
                              self._tx_gain(sl) if gain else None)

    def _rx_phasors(self, sl, amp: bool = False) -> np.ndarray:
        """``E_r`` (``amp``: ``B = c g_r E_r``), complex64 ``[K, R, n]``, with the
        intra-chirp Doppler term."""
        tau = self.x.tau_r[:, sl]
        c0, c1 = self.fk0 * tau, self.S * self.dt * tau
        if self.moving:
            rho = self.x.rho[None, sl]
            c0 = c0 + self.f0 * rho * self.t0
            c1 = c1 + self.f0 * rho * self.dt
        return linear_phasors(c0, c1, self.K, self._rx_amp(sl) if amp else None)

    def _tx_gain(self, sl) -> np.ndarray:
        """``g_t`` per Tx row, ``[T*L, n]`` float32."""
        g = self.x.g_t[:, None, sl].astype(np.float32)
        return np.broadcast_to(g, (self.T, self.L, g.shape[-1])).reshape(self.T * self.L, -1)

    def _rx_amp(self, sl) -> np.ndarray:
        """``c g_r``, ``[R, n]`` complex64."""
        return (self.x.c[None, sl] * self.x.g_r[:, sl]).astype(np.complex64)

    def _to_adc(self, acc: np.ndarray) -> np.ndarray:
        """``[K, T*L, R]`` -> complex64 ``[T, R, num_chirps, K]``."""
        T, R, L, K = self.T, self.R, self.L, self.K
        s = acc.reshape(K, T, L, R).transpose(1, 3, 2, 0)
        return np.ascontiguousarray(np.broadcast_to(s, (T, R, self.radar.num_chirps, K)))

    def _freq_weights(self) -> np.ndarray:
        """``[2, K]`` complex64 rows ``1`` and ``k`` (sums ``S0``, ``S1`` over samples)."""
        return np.stack([np.ones(self.K), np.arange(self.K, dtype=np.float64)]).astype(np.complex64)

    # ------------------------------------------------------------ forward
    def forward(self) -> np.ndarray:
        """ADC, complex64 ``[T, R, num_chirps, K]``."""
        return self._to_adc(self._sum(self._forward_chunk, self._chunks(1)))

    def _sum(self, fn, chunks) -> np.ndarray:
        """Sum of the ``[K, T*L, R]`` partial ADCs ``fn(chunk)`` of all chunks."""
        def group_sum(group):
            acc = np.zeros((self.K, self.T * self.L, self.R), np.complex64)
            for sl in group:
                acc += fn(sl)
            return acc
        parts = _in_groups(group_sum, chunks, self.workers)
        return parts[0] if len(parts) == 1 else np.sum(parts, axis=0)

    def _forward_chunk(self, sl) -> np.ndarray:
        A = self._tx_phasors(sl, gain=True)
        B = self._rx_phasors(sl, amp=True)
        return np.matmul(A, B.swapaxes(1, 2))

    # ------------------------------------------------------------ adjoint
    def _upstream(self, G) -> np.ndarray:
        """``conj(G)`` as complex64 ``[K, T*L, R]`` (summed over chirps when static)."""
        G = np.asarray(G)
        if G.shape != self.radar.adc_shape:
            raise InputValueError(f"{_WHERE}: upstream gradient must have shape "
                                  f"{self.radar.adc_shape}, got {G.shape}")
        G = G.astype(np.complex128, copy=False)
        if not self.moving:
            G = G.sum(axis=2, keepdims=True)
        Gk = np.conj(G).transpose(3, 0, 2, 1).reshape(self.K, self.T * self.L, self.R)
        return np.ascontiguousarray(Gk, dtype=np.complex64)

    def vjp(self, G, delays: bool = True) -> dict:
        """Gradients of a real loss for ``G = dL/d Re(s) + j dL/d Im(s)``.

        ``G`` is ``[T, R, num_chirps, K]``.  Returns a dict: ``c`` complex128
        ``[P]`` (``dL/d Re c + j dL/d Im c``), ``g_t``, ``tau_t`` ``[T, P]``,
        ``g_r``, ``tau_r`` ``[R, P]`` and ``tau_rate`` ``[P]`` (None when static),
        float64; delay gradients per second.  ``delays=False``: the caller
        needs no delay gradients; they are returned as zeros (this reference
        computes them anyway, the NUFFT synthesiser skips the work).
        """
        T, R, P = self.T, self.R, self.P
        Gk = self._upstream(G)
        W = self._freq_weights()
        out = dict(c=np.zeros(P, np.complex128), g_t=np.zeros((T, P)), tau_t=np.zeros((T, P)),
                   g_r=np.zeros((R, P)), tau_r=np.zeros((R, P)),
                   tau_rate=np.zeros(P) if self.moving else None)
        _in_groups(lambda group: [self._vjp_chunk(sl, Gk, W, out) for sl in group],
                   self._chunks(3), self.workers)
        if not delays:
            for name in ("tau_t", "tau_r", "tau_rate"):
                if out[name] is not None:
                    out[name][:] = 0.0
        return out

    def _vjp_chunk(self, sl, Gk, W, out):
        """Gradients of the paths in ``sl`` (written into ``out``'s slices)."""
        T, R, L, K = self.T, self.R, self.L, self.K
        n = sl.stop - sl.start
        E_t = self._tx_phasors(sl)
        E_r = self._rx_phasors(sl)
        # Rx side: H_B = sum_(t,l) conj(G) A, then Z_B = H_B E_r summed over k
        Z = np.matmul(Gk.swapaxes(1, 2), E_t * self._tx_gain(sl))      # [K, R, n]
        Z *= E_r
        SB = (W @ Z.reshape(K, -1)).reshape(2, R, n).astype(np.complex128)
        del Z
        # Tx side: H_A = sum_r conj(G) B, then Z_A = H_A E_t summed over k
        Z = np.matmul(Gk, E_r * self._rx_amp(sl))                      # [K, T*L, n]
        Z *= E_t
        SA = (W @ Z.reshape(K, -1)).reshape(2, T, L, n).astype(np.complex128)
        del Z, E_t, E_r
        self._rx_grads(sl, SB, out)
        self._tx_grads(sl, SA, out)

    def _rx_grads(self, sl, SB, out):
        """Gradients from ``SB = [sum_k Z_B, sum_k k Z_B]`` (``[2, R, n]``)."""
        c, g_r = self.x.c[sl], self.x.g_r[:, sl]
        W = self.fk0 * SB[0] + self.S * self.dt * SB[1]              # sum_k f_k Z_B
        out["g_r"][:, sl] = np.real(c * SB[0])
        out["tau_r"][:, sl] = -2 * np.pi * np.imag(c * g_r * W)
        out["c"][sl] = np.conj(np.sum(g_r * SB[0], axis=0))
        if self.moving:
            Tk = self.t0 * SB[0] + self.dt * SB[1]                    # sum_k t_k Z_B
            out["tau_rate"][sl] += -2 * np.pi * self.f0 * np.imag(c * np.sum(g_r * Tk, axis=0))

    def _tx_grads(self, sl, SA, out):
        """Gradients from ``SA = [sum_k Z_A, sum_k k Z_A]`` (``[2, T, L, n]``)."""
        g_t = self.x.g_t[:, sl]
        W = self.fk0 * SA[0] + self.S * self.dt * SA[1]              # sum_k f_k Z_A, [T, L, n]
        out["g_t"][:, sl] = np.real(SA[0].sum(axis=1))
        out["tau_t"][:, sl] = -2 * np.pi * g_t * np.imag(W.sum(axis=1))
        if self.moving:
            WT = np.sum(W * self.Tl[:, :, None], axis=1)             # [T, n]
            out["tau_rate"][sl] += -2 * np.pi * np.imag(np.sum(g_t * WT, axis=0))

    # ------------------------------------------------------------ tangent
    def jvp(self, dc, dg_t, dtau_t, dg_r, dtau_r, drho=None) -> np.ndarray:
        """Forward derivative ``ds`` (complex64 ``[T, R, num_chirps, K]``).

        Tangents have the shapes of the inputs (``dc`` complex ``[P]``,
        ``dg_t, dtau_t [T, P]``, ``dg_r, dtau_r [R, P]``, ``drho [P]`` or None).
        """
        tangents = (dc, dg_t, dtau_t, dg_r, dtau_r, drho if self.moving else None)
        return self._to_adc(self._sum(lambda sl: self._jvp_chunk(sl, *tangents), self._chunks(4)))

    def _jvp_chunk(self, sl, dc, dg_t, dtau_t, dg_r, dtau_r, drho) -> np.ndarray:
        """``sum_p (dA B + A dB)`` over the paths in ``sl``: ``[K, T*L, R]``."""
        T, L, K = self.T, self.L, self.K
        n = sl.stop - sl.start
        fk = (self.fk0 + self.S * self.dt * np.arange(K)).astype(np.float32)[:, None, None]
        E_t, E_r = self._tx_phasors(sl), self._rx_phasors(sl)
        # dA = E_t (dg_t + j 2pi f_k g_t (dtau_t + T_tl drho))
        dtau0 = np.broadcast_to(dtau_t[:, None, sl], (T, L, n))
        if drho is not None:
            dtau0 = dtau0 + drho[None, None, sl] * self.Tl[:, :, None]
        alpha = (2 * np.pi * self.x.g_t[:, None, sl] * dtau0).reshape(T * L, n).astype(np.float32)
        dgt = np.broadcast_to(dg_t[:, None, sl], (T, L, n)).reshape(T * L, n).astype(np.float32)
        dA = E_t * (dgt + 1j * fk * alpha)
        # dB = E_r (dc g_r + c dg_r + j 2pi c g_r (f_k dtau_r + f0 t_k drho))
        c, g_r = self.x.c[None, sl], self.x.g_r[:, sl]
        cg = 2j * np.pi * c * g_r
        dB = (dc[None, sl] * g_r + c * dg_r[:, sl]).astype(np.complex64) \
            + fk * (cg * dtau_r[:, sl]).astype(np.complex64)
        if drho is not None:
            tk = (self.t0 + self.dt * np.arange(K)).astype(np.float32)[:, None, None]
            dB = dB + tk * (cg * self.f0 * drho[None, sl]).astype(np.complex64)
        dB *= E_r
        E_r *= self._rx_amp(sl)                                         # B
        E_t *= self._tx_gain(sl)                                        # A
        return np.matmul(dA, E_r.swapaxes(1, 2)) + np.matmul(E_t, dB.swapaxes(1, 2))


def synthesize_adc_factorised(radar: RadarConfig, c, g_t, tau_t, g_r, tau_r, tau_rate=None) -> np.ndarray:
    """Raw complex baseband FMCW ADC from factorised paths (NumPy).

    Equals ``synthesize_adc(radar, c g_t g_r, tau_t + tau_r, tau_rate)`` on
    the ``[T, R, P]`` expansion.

    Parameters
    ----------
    radar : RadarConfig
        Waveform and layout (``T`` Tx, ``R`` Rx).
    c : array_like
        Complex ``[P]``, per-path amplitude (beat convention).
    g_t : array_like
        ``[T, P]``, Tx-leg gain.
    tau_t : array_like
        ``[T, P]``, Tx-leg delay [s].
    g_r : array_like
        ``[R, P]``, Rx-leg gain.
    tau_r : array_like
        ``[R, P]``, Rx-leg delay [s].
    tau_rate : array_like, optional
        ``[P]``, delay rate ``d tau / dt`` [s/s].

    Returns
    -------
    numpy.ndarray
        complex64 ``[T, R, num_chirps, num_samples]``.

    Raises
    ------
    InputValueError
        NaN / Inf or wrong shapes (the message names the argument).
    """
    inputs = check_factor_inputs(radar, c, g_t, tau_t, g_r, tau_r, tau_rate)
    return FactorisedSynthesis(radar, inputs).forward()


def synthesize_adc_factorised_vjp(radar: RadarConfig, G, c, g_t, tau_t, g_r, tau_r,
                                  tau_rate=None) -> dict:
    """Vector-Jacobian product of :func:`synthesize_adc_factorised`.

    ``G = dL/d Re(s) + j dL/d Im(s)``, ``[T, R, num_chirps, num_samples]``,
    for a real loss ``L``.  Returns ``dict(c, g_t, tau_t, g_r, tau_r, tau_rate)``
    of gradients with the inputs' shapes (``c`` as ``dL/d Re c + j dL/d Im c``;
    ``tau_rate`` None when not given).
    """
    inputs = check_factor_inputs(radar, c, g_t, tau_t, g_r, tau_r, tau_rate)
    return FactorisedSynthesis(radar, inputs).vjp(G)
