"""The NumPy synthesis engine: batched matrix products with analytic adjoints.

The model is in :mod:`sionna_mmir.fmcw.model`.  Per "row" (one tx, rx and,
with motion, chirp loop) the fast-time signal is a sum of complex
exponentials ``s[k] = sum_p b_p z_p^k`` with ``z_p = exp(j 2 pi c1_p)``.
Splitting ``k = R q + r`` (``R ~ sqrt(K)``) gives
``s[R q + r] = sum_p (b_p z_p^{R q}) (z_p^r)``: a ``[Q x P] @ [P x R]``
matrix product per row.  Only ``Q + R`` (instead of ``K``) phasors per
(row, path) are formed, by recurrence, and BLAS does the ``K x P`` sum.
It is exact (no approximation beyond floating point); the vector-Jacobian
product is the same kind of product with the conjugate phasors.

:class:`Prepared` holds one synthesis (inputs broadcast and validated) with
its forward and vector-Jacobian products; :class:`DrAdc` is the Dr.Jit
result type of the differentiable front ends.
"""
from __future__ import annotations

import collections
import math

import numpy as np

from ..radar.config import RadarConfig
from ..utils.threads import one_blas_thread
from .model import broadcast_paths

DrAdc = collections.namedtuple("DrAdc", ["real", "imag"])
DrAdc.__doc__ = ("Dr.Jit ADC: ``real`` and ``imag`` are ``mi.TensorXf`` of shape "
                 "``[n_tx, n_rx, num_chirps, num_samples]``.")

_CHUNK_BYTES = 96 * 2 ** 20   # working-set budget of one row chunk


def _split(K: int) -> tuple[int, int]:
    inner = max(1, int(math.ceil(math.sqrt(K))))
    outer = int(math.ceil(K / inner))
    return outer, inner


def _cis(cycles) -> np.ndarray:
    """``exp(j 2 pi cycles)`` as complex64 (cycles reduced mod 1 in float64)."""
    ang = (2 * np.pi * np.mod(cycles, 1.0)).astype(np.float32)
    out = np.empty(ang.shape, np.complex64)
    out.real = np.cos(ang)
    out.imag = np.sin(ang)
    return out


def _powers(seed, z, n):
    """``seed * z**i`` for ``i < n`` stacked on a new axis -2: ``[..., n, P]``."""
    out = np.empty(z.shape[:-1] + (n, z.shape[-1]), np.complex64)
    out[..., 0, :] = seed
    for i in range(1, n):
        np.multiply(out[..., i - 1, :], z, out=out[..., i, :])
    return out


class Prepared:
    """Inputs broadcast to ``[T, R, P]``; phasors generated per chunk of pairs.

    Rows are (tx, rx, loop) triples.  For a chunk of pairs the phasor seeds
    ``e0 = exp(j2pi c0)`` and ``z = exp(j2pi c1)`` of loop 0 come from float64
    phases; later loops follow by exact recurrence, because a Tx's chirps start
    ``loop_period`` apart, so ``c0`` and ``c1`` grow by constant steps.
    """

    def __init__(self, radar: RadarConfig, a, tau, rho):
        self.radar = radar
        self.a, self.tau, self.rho, (T, R, P) = broadcast_paths(radar, a, tau, rho)
        self.L = radar.num_chirps if self.rho is not None else 1
        self.shape = (T, R, self.L, P)
        self.K = radar.num_samples
        self.Q, self.Rr = _split(self.K)
        self.a_pairs = self.a.reshape(T * R, P)
        self.tau_pairs = self.tau.reshape(T * R, P)
        self.rho_pairs = None if self.rho is None else self.rho.reshape(T * R, P)
        self.T0 = np.repeat(radar.chirp_start_times()[:, 0], R)        # [T*R]

    def chunks(self):
        """Yield ``(slice of pairs, e0 [b, L, P], z [b, L, P])`` complex64."""
        radar = self.radar
        f0, S = radar.start_frequency, radar.slope
        t0, dt = radar.adc_start_time, 1.0 / radar.sample_rate
        n_pairs, P = self.tau_pairs.shape
        step = max(1, int(_CHUNK_BYTES // max(1, (self.Q + self.Rr + 2) * self.L * P * 8)))
        for s in range(0, n_pairs, step):
            sl = slice(s, min(n_pairs, s + step))
            tau = self.tau_pairs[sl]
            if self.rho_pairs is None:
                e0 = _cis((f0 + S * t0) * tau)[:, None, :]
                z = _cis(S * dt * tau)[:, None, :]
            else:
                rho = self.rho_pairs[sl]
                tau0 = tau + rho * self.T0[sl, None]
                e_seed = _cis((f0 + S * t0) * tau0 + f0 * rho * t0)
                z_seed = _cis(dt * (S * tau0 + f0 * rho))
                Tl = radar.loop_period
                e0 = _powers(e_seed, _cis((f0 + S * t0) * rho * Tl), self.L)
                z = _powers(z_seed, _cis(dt * S * rho * Tl), self.L)
            yield sl, e0, z

    def _blocks(self, e0, z, amp):
        """``X [.., Q, P] = amp e0 z^{R q}``, ``Y [.., R, P] = z^r``."""
        zq = z.copy()
        for _ in range(1, self.Rr):
            zq *= z
        X = _powers(amp * e0, zq, self.Q)
        Y = _powers(np.ones_like(z), z, self.Rr)
        return X, Y

    def _sum_paths(self, amp_fn):
        """``sum_p amp e0 z^k`` for all rows, ``[T, R, L, K]`` complex64."""
        T, R, L, P = self.shape
        out = np.empty((T * R, L, self.K), np.complex64)
        for sl, e0, z in self.chunks():
            X, Y = self._blocks(e0, z, amp_fn(sl))
            prod = np.matmul(X, np.swapaxes(Y, -1, -2))          # [b, L, Q, R]
            out[sl] = prod.reshape(prod.shape[0], L, -1)[..., :self.K]
        return out.reshape(T, R, L, self.K)

    def _expand(self, s):
        if self.L == 1 and self.radar.num_chirps > 1:
            s = np.broadcast_to(s, self.radar.adc_shape)
        return s

    def forward(self) -> np.ndarray:
        amp = self.a_pairs.astype(np.complex64)[:, None, :]
        return self._expand(self._sum_paths(lambda sl: amp[sl]))

    def _adjoint_sums(self, G):
        """``S0 = sum_k conj(E) G``, ``S1 = sum_k k conj(E) G``: ``[T*R, L, P]``."""
        T, R, L, P = self.shape
        Q, Rr, K = self.Q, self.Rr, self.K
        Gp = np.zeros((T * R, L, Q * Rr), np.complex64)
        Gp[..., :K] = G.reshape(T * R, L, K)
        Gp = Gp.reshape(T * R, L, Q, Rr)
        rw = np.arange(Rr, dtype=np.float32)
        qw = (Rr * np.arange(Q, dtype=np.float32))[:, None]
        S0 = np.empty((T * R, L, P), np.complex128)
        S1 = np.empty((T * R, L, P), np.complex128)
        ones = np.ones((1, 1, P), np.complex64)
        for sl, e0, z in self.chunks():
            X, Y = self._blocks(e0, z, ones)
            Yc = np.conj(Y)
            H = np.matmul(Gp[sl], Yc)                              # [b, L, Q, P]
            H1 = np.matmul(Gp[sl] * rw, Yc)
            Xc = np.conj(X)
            S0[sl] = np.sum(Xc * H, axis=-2)
            S1[sl] = np.sum(Xc * (qw * H + H1), axis=-2)
        return S0.reshape(T, R, L, P), S1.reshape(T, R, L, P)

    def vjp(self, G):
        """Gradients of a real loss w.r.t. ``a`` (complex), ``tau`` and ``rho``.

        ``G = dL/d Re(s) + j dL/d Im(s)``, ``[T, R, num_chirps, K]``.
        Returns full-shape ``[T, R, P]`` arrays (``grad_rho`` None when static).
        """
        radar = self.radar
        G = np.asarray(G, np.complex128)
        if self.L == 1:
            G = G.sum(axis=2, keepdims=True)
        with one_blas_thread():
            S0, S1 = self._adjoint_sums(G)
        f0, S, t0, dt = radar.start_frequency, radar.slope, radar.adc_start_time, 1.0 / radar.sample_rate
        W = 2 * np.pi * (f0 + S * t0) * S0 + 2 * np.pi * S * dt * S1     # sum_k w_k conj(E) G
        ac = np.conj(self.a)[:, :, None, :]
        grad_a = S0.sum(axis=2)
        grad_tau = np.imag(ac * W).sum(axis=2)
        grad_rho = None
        if self.rho is not None:
            Tl = radar.chirp_start_times()[:, None, :, None]
            grad_rho = np.imag(ac * (Tl * W + 2 * np.pi * f0 * (t0 * S0 + dt * S1))).sum(axis=2)
        return grad_a, grad_tau, grad_rho

    def jvp(self, da, dtau, drho):
        """Forward derivative ``ds`` for input tangents (full ``[T, R, P]`` shape)."""
        radar = self.radar
        T, R, L, P = self.shape
        f0, S, t0, dt = radar.start_frequency, radar.slope, radar.adc_start_time, 1.0 / radar.sample_rate
        dtau_l = np.broadcast_to(dtau[:, :, None, :], self.shape)
        drho_l = 0.0
        if self.rho is not None and drho is not None:
            Tl = radar.chirp_start_times()[:, None, :, None]
            drho_l = np.broadcast_to(drho[:, :, None, :], self.shape)
            dtau_l = dtau_l + Tl * drho_l
        alpha = 2 * np.pi * (f0 + S * t0) * dtau_l + 2 * np.pi * f0 * t0 * drho_l
        beta = 2 * np.pi * dt * (S * dtau_l + f0 * drho_l)
        a_l = self.a[:, :, None, :]
        amp0 = (da[:, :, None, :] + 1j * a_l * alpha).astype(np.complex64).reshape(T * R, L, P)
        amp1 = (1j * a_l * beta).astype(np.complex64).reshape(T * R, L, P)
        k = np.arange(self.K, dtype=np.float32)
        ds = self._sum_paths(lambda sl: amp0[sl]) + k * self._sum_paths(lambda sl: amp1[sl])
        return self._expand(ds)
