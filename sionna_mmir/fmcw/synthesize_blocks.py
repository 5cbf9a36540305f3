r"""ADC synthesis for dense arrays: sub-array blocks and one NUFFT spread per block pair.

The per-pair NUFFT synthesiser (:mod:`sionna_mmir.fmcw.synthesize_nufft`)
spreads every path once per Tx-Rx pair: ``T R P w`` kernel products in scalar
code, ~40 s for a 100 x 100 array and 150k paths.  Here the pairs share the
spread.  The elements are cut into blocks of neighbours (``B_t`` Tx blocks,
``B_r`` Rx blocks); for Tx block ``b``, Rx block ``g`` and path ``p`` the
delays split into a block-pair reference and per-element remainders::

    tau[t, r, p] = tau_b[p] + tau_g[p] + d_t[t, p] + d_r[r, p]
    tau_b = (max + min) / 2 of tau_t over the block's elements   (likewise tau_g)

and with ``f_k = f_c + e_k`` (``f_c`` the mid-chirp frequency)::

    exp(j 2 pi f_k tau) = exp(j 2 pi f_k (tau_b + tau_g))       shared by the block pair
                        * exp(j 2 pi f_c d_t) exp(j 2 pi f_c d_r)  per element (any d: near field)
                        * exp(j 2 pi e_k (d_t + d_r))              kept to ``order`` in a Taylor series

Each Taylor term ``i + j = n <= order`` is a type-1 NUFFT over the fast-time
samples with the *shared* points ``S dt (tau_b + tau_g)`` and the separable
strengths ``A_i[t, p] B_j[r, p]``, ``A_i = g_t exp(j 2 pi (f_h tau_b + f_c d_t))
(j 2 pi d_t)^i / i!`` (``B_j`` likewise with ``c``), so the spread onto the
oversampled grid is a matrix product per chunk of paths::

    G[t, r, m] = sum_p A_i[t, p] (B_j[r, p] psi(m - u_p))     (BLAS, ~8 T R P w flops)

followed by one FFT per pair, the kernel's deconvolution and the weight
``e_k^n``.  The kernel is the exponential of semicircle (Barnett, Magland
& af Klinteberg 2019) on a 2x grid.

Error (beyond the kernel's, ~1e-3 at ``width=4``): the Taylor remainder,
at most ``z^(order+1) / (order+1)!`` with ``z = 2 pi max|e_k| max|d_t + d_r|``
(a block's half-length over ``c`` per leg: ``z = 0.51`` for 10-element
lambda/2 blocks of both arrays on the cascade waveform).  Static paths only
(one chirp loop); moving paths go to the exact synthesisers.
"""
from __future__ import annotations

import math

import numpy as np

from ..radar.config import SPEED_OF_LIGHT
from ..errors import InputValueError
from .synthesize_factorised import NUM_WORKERS, FactorInputs, _cis, _in_groups

#: sparse start bins are merged into one matrix product up to this many paths
CHUNK_PATHS = 512
#: ... or this many bins (bounds the zero padding)
CHUNK_BINS = 4
#: kernel table resolution (points per grid step; linear interpolation, ~1e-6)
TABLE_STEPS = 2048
#: grid oversampling
SIGMA = 2
#: default block length [m] (20 lambda/2 at 77 GHz), Taylor order and kernel
#: width: on the dense 100 x 100 hallway frame (155k paths) 2.4 % relative ADC
#: error, RAE power cube correlation 0.99999 with the exact synthesis
#: (the error bound: :func:`taylor_bound`, checked in ``tests/test_evidence.py``)
BLOCK_LENGTH, DEFAULT_ORDER, DEFAULT_WIDTH = 20 * SPEED_OF_LIGHT / 77e9 / 2, 0, 3


def es_kernel(z, width: int, beta: float) -> np.ndarray:
    """Exponential-of-semicircle kernel ``exp(beta (sqrt(1 - (2 z / w)^2) - 1))``, 0 outside."""
    x = (2.0 / width) * np.asarray(z, dtype=np.float64)
    out = np.exp(beta * (np.sqrt(np.maximum(1.0 - x * x, 0.0)) - 1.0))
    return np.where(np.abs(x) < 1.0, out, 0.0)


def es_transform(modes, n_grid: int, width: int, beta: float) -> np.ndarray:
    """``int psi(z) cos(2 pi m z / n_grid) dz`` for the modes ``m`` (Gauss-Legendre)."""
    x, wq = np.polynomial.legendre.leggauss(4 * width + 32)
    z = 0.5 * width * x
    m = np.asarray(modes, dtype=np.float64)[:, None]
    return (0.5 * width) * np.sum(wq * es_kernel(z, width, beta) * np.cos(2 * np.pi * m * z / n_grid),
                                  axis=1)


def _cis32(cycles: np.ndarray) -> np.ndarray:
    """``exp(j 2 pi cycles)`` (complex64) of float32 cycles of modest size (< ~1e3)."""
    ang = np.float32(2 * np.pi) * (cycles - np.floor(cycles))
    out = np.empty(cycles.shape, np.complex64)
    parts = out.view(np.float32).reshape(*cycles.shape, 2)
    np.cos(ang, out=parts[..., 0])
    np.sin(ang, out=parts[..., 1])
    return out


def element_blocks(positions: np.ndarray, n_blocks: int) -> list:
    """``n_blocks`` groups of neighbouring elements (sorted along the array's longest
    extent, cut into near-equal runs); a list of index arrays."""
    pos = np.asarray(positions, dtype=np.float64)
    axis = int(np.argmax(np.ptp(pos, axis=0))) if len(pos) > 1 else 0
    order = np.argsort(pos[:, axis], kind="stable")
    n = max(1, min(int(n_blocks), len(order)))
    return [np.sort(b) for b in np.array_split(order, n)]


class BlockSpreadSynthesis:
    """Forward ADC of static factorised paths by block-pair spreading (module docstring).

    Parameters
    ----------
    radar : RadarConfig
        The radar (waveform, element positions).
    inputs : FactorInputs
        Validated factorised paths (static: ``rho`` must be None).
    blocks : tuple of int, optional
        ``(B_t, B_r)``: Tx and Rx blocks (default: as many as it takes for
        blocks of at most :data:`BLOCK_LENGTH` along each array).
    order : int, optional
        Taylor order of the in-block fast-time term (0, 1 or 2).
    width : int, optional
        Kernel width in grid points (3: ~1e-2, 4: ~1e-3, 6: ~1e-5).
    workers : int, optional
        Threads (block pairs are shared out; BLAS one thread each).

    Raises
    ------
    InputValueError
        Moving paths, or a bad ``order`` / ``width`` / ``blocks``.
    """

    def __init__(self, radar, inputs: FactorInputs, blocks=None, order: int = DEFAULT_ORDER,
                 width: int = DEFAULT_WIDTH, workers: int = NUM_WORKERS):
        if inputs.rho is not None:
            raise InputValueError("BlockSpreadSynthesis: static paths only (rho is set)")
        if order not in (0, 1, 2) or not 2 <= int(width) <= 16:
            raise InputValueError(f"BlockSpreadSynthesis: order must be 0-2 and width 2-16, "
                                  f"got {order!r}, {width!r}")
        self.radar, self.x = radar, inputs
        self.T, self.R, self.P, self.K = radar.num_tx, radar.num_rx, inputs.num_paths, radar.num_samples
        if blocks is None:
            blocks = tuple(min(len(p), max(1, math.ceil(np.ptp(p, axis=0).max() / BLOCK_LENGTH
                                                      - 1e-9)))
                           for p in (radar.tx_positions, radar.rx_positions))
        if min(blocks) < 1:
            raise InputValueError(f"BlockSpreadSynthesis: blocks must be >= 1, got {blocks!r}")
        self.order, self.width, self.workers = int(order), int(width), int(workers)
        self.beta = 2.30 * self.width
        self.N = SIGMA * self.K
        a = radar.slope / radar.sample_rate                      # Hz per sample
        fk0 = radar.start_frequency + radar.slope * radar.adc_start_time
        self.a, self.f_h = a, fk0 + a * (self.K // 2)
        self.f_c = fk0 + a * 0.5 * (self.K - 1)
        self.e_max = a * 0.5 * (self.K - 1)                      # max |e_k| [Hz]
        self.tx_blocks = element_blocks(radar.tx_positions, blocks[0])
        self.rx_blocks = element_blocks(radar.rx_positions, blocks[1])
        m = np.arange(-(self.K // 2), self.K - self.K // 2)
        z = (np.arange(TABLE_STEPS + 1) / TABLE_STEPS)[:, None] - 0.5 * self.width \
            + np.arange(self.width)[None]
        self._table = es_kernel(z, self.width, self.beta).astype(np.float32)   # [steps+1, w]
        self.deconv = (1.0 / es_transform(m, self.N, self.width, self.beta)).astype(np.complex64)
        ek = (np.arange(self.K) - 0.5 * (self.K - 1)) / (0.5 * (self.K - 1) or 1.0)
        self.ek = ek.astype(np.float32)                          # e_k / e_max

    # ------------------------------------------------------------ factors
    def _side(self, tau, gain, idx, amp=None):
        """Reference delay ``[P]`` and strengths ``[order + 1][m, P]`` of one block
        (``amp`` given, the Rx side: ``[order + 1][P, m]``, paths slowest)."""
        t = tau[idx]
        ref = 0.5 * (t.max(axis=0) + t.min(axis=0))
        d = (t - ref[None]).astype(np.float32)                  # |d| < 1 ns: float32 is exact enough
        base = self.f_h * ref
        cyc = (base - np.floor(base)).astype(np.float32)[None] + np.float32(self.f_c) * d
        s = _cis32(cyc)
        s *= gain[idx].astype(np.float32)
        if amp is not None:
            s *= amp[None]
        terms = [s]
        z = (np.float32(2 * np.pi * self.e_max) * d) * np.complex64(1j)
        for i in range(1, self.order + 1):
            terms.append(terms[-1] * z / np.float32(i))
        if amp is not None:
            terms = [np.ascontiguousarray(t.T) for t in terms]
        return ref, terms

    def _spread_points(self, ref_t, ref_r):
        """Sorted order, first bins and kernel values ``[P, w]`` of the shared points."""
        x = self.a * (ref_t + ref_r)                            # cycles per sample
        u = self.N * (x - np.floor(x))
        g0 = np.ceil(u - 0.5 * self.width)
        frac = (g0 - u).astype(np.float32)                      # in (-w/2 - 1, -w/2]
        pos = (frac + np.float32(0.5 * self.width)) * np.float32(TABLE_STEPS)
        i = np.clip(pos.astype(np.int32), 0, TABLE_STEPS - 1)
        wgt = (pos - i)[:, None]
        vals = self._table[i] * (1 - wgt) + self._table[i + 1] * wgt   # [P, w]
        g0 = g0.astype(np.int64)
        order = np.argsort((g0 + self.width).astype(np.int16), kind="stable")
        return order, g0[order], vals[order]

    def _chunks(self, g0s):
        """``(start, stop)`` of the sorted paths: one start bin each, or several sparse
        bins merged until :data:`CHUNK_PATHS` paths or :data:`CHUNK_BINS` bins."""
        edges = np.flatnonzero(np.diff(g0s)) + 1
        bounds = np.concatenate([[0], edges, [len(g0s)]])
        out, start = [], 0
        for k in range(1, len(bounds)):
            stop = int(bounds[k])
            last = k == len(bounds) - 1
            if (last or stop - start >= CHUNK_PATHS
                    or g0s[min(stop, len(g0s) - 1)] - g0s[start] >= CHUNK_BINS):
                out.append((start, stop))
                start = stop
        return out

    # ------------------------------------------------------------ spread
    def _pair(self, tx, rx):
        """ADC block ``[m_t, m_r, K]`` of one block pair."""
        (ref_t, A), (ref_r, B) = tx, rx
        order, g0s, vals = self._spread_points(ref_t, ref_r)
        mt, mr, w, N = A[0].shape[0], B[0].shape[1], self.width, self.N
        As = [np.take(a, order, axis=1) for a in A]                   # [m_t, P]
        Bs = [np.take(b, order, axis=0) for b in B]                   # [P, m_r]
        acc = np.zeros((self.order + 1, mt, N + 2 * w, mr), np.complex64)
        for start, stop in self._chunks(g0s):
            lo, span, n = g0s[start], int(g0s[stop - 1] - g0s[start]), stop - start
            v = vals[start:stop, :, None]
            Bw = [b[start:stop, None, :] * v for b in Bs]             # [n, w, m_r]
            if span:
                Bw = [self._padded(b, g0s[start:stop] - lo, span) for b in Bw]
            Bm = [b.reshape(n, -1) for b in Bw]
            sl = slice(lo + w, lo + w + span + w)
            for k in range(self.order + 1):
                part = As[0][:, start:stop] @ Bm[k]
                for i in range(1, k + 1):
                    part += As[i][:, start:stop] @ Bm[k - i]
                acc[k, :, sl] += part.reshape(mt, span + w, mr)
        return self._finish(acc)

    @staticmethod
    def _padded(bw, offs, span):
        """``[n, w, m_r]`` kernel-weighted strengths placed at their bins: ``[n, span + w, m_r]``."""
        n, w, mr = bw.shape
        out = np.zeros((n, span + w, mr), np.complex64)
        out[np.arange(n)[:, None], offs[:, None] + np.arange(w)[None]] = bw
        return out

    def _finish(self, acc):
        """Fold the grid's wrap, FFT, deconvolve and weight the Taylor terms."""
        w, N, K = self.width, self.N, self.K
        acc = np.moveaxis(acc, 2, -1)                           # [terms, m_t, m_r, N + 2w]
        G = acc[..., w:w + N].copy()
        G[..., N - w:] += acc[..., :w]
        G[..., :w] += acc[..., N + w:]
        F = np.fft.ifft(G, axis=-1) * N
        h = K // 2
        modes = np.concatenate([F[..., N - h:], F[..., :K - h]], axis=-1) * self.deconv
        out = modes[0]
        for n in range(1, self.order + 1):
            out = out + modes[n] * (self.ek ** n)
        return out.astype(np.complex64)

    def forward(self) -> np.ndarray:
        """ADC, complex64 ``[T, R, num_chirps, K]``."""
        x = self.x
        cx = x.c.astype(np.complex64)
        sides = [("t", b) for b in self.tx_blocks] + [("r", b) for b in self.rx_blocks]

        def side(group):
            return [self._side(x.tau_t, x.g_t, b) if k == "t" else
                    self._side(x.tau_r, x.g_r, b, amp=cx) for k, b in group]
        done = _in_groups(side, sides, self.workers)
        n = len(sides)
        flat = [None] * n
        for g, res in enumerate(done):                  # _in_groups deals round-robin
            for i, r in zip(range(g, n, len(done)), res):
                flat[i] = r
        txs, rxs = flat[:len(self.tx_blocks)], flat[len(self.tx_blocks):]
        out = np.zeros((self.T, self.R, self.K), np.complex64)
        jobs = [(i, j) for i in range(len(txs)) for j in range(len(rxs))]

        def run(group):
            for i, j in group:
                out[np.ix_(self.tx_blocks[i], self.rx_blocks[j])] = self._pair(txs[i], rxs[j])
        _in_groups(run, jobs, self.workers)
        return np.ascontiguousarray(np.broadcast_to(out[:, :, None], self.radar.adc_shape))


def synthesize_adc_blocks(radar, c, g_t, tau_t, g_r, tau_r, **options) -> np.ndarray:
    """ADC of static factorised paths by :class:`BlockSpreadSynthesis`.

    Parameters
    ----------
    radar : RadarConfig
        The radar.
    c : numpy.ndarray
        Complex ``[P]`` amplitudes.
    g_t, tau_t : numpy.ndarray
        ``[T, P]`` Tx-leg gains and delays [s].
    g_r, tau_r : numpy.ndarray
        ``[R, P]`` Rx-leg gains and delays [s].
    **options
        ``blocks``, ``order``, ``width``, ``workers`` of :class:`BlockSpreadSynthesis`.

    Returns
    -------
    numpy.ndarray
        complex64 ``radar.adc_shape``.
    """
    from .synthesize_factorised import check_factor_inputs

    x = check_factor_inputs(radar, c, g_t, tau_t, g_r, tau_r, where="synthesize_adc_blocks")
    if x.num_paths == 0:
        return np.zeros(radar.adc_shape, np.complex64)
    return BlockSpreadSynthesis(radar, x, **options).forward()


def taylor_bound(radar, inputs: FactorInputs, blocks, order: int) -> float:
    """Bound of the Taylor remainder ``z^(order+1) / (order+1)!`` for these paths and blocks."""
    syn = BlockSpreadSynthesis(radar, inputs, blocks=blocks, order=order)
    d = 0.0
    for tau, bl in ((inputs.tau_t, syn.tx_blocks), (inputs.tau_r, syn.rx_blocks)):
        d += max(float(np.max(np.ptp(tau[b], axis=0))) / 2 for b in bl)
    z = 2 * np.pi * syn.e_max * d
    return z ** (order + 1) / math.factorial(order + 1)
