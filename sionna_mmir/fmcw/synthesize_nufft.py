"""ADC synthesis from factorised paths by non-uniform FFTs (the fast path).

Per Tx row ``i = (t, l)`` and Rx element ``r`` the fast-time signal of the
factorised paths (:mod:`sionna_mmir.fmcw.synthesize_factorised`) is a sum of
complex exponentials at *non-uniform* frequencies::

    s[i, r, k] = sum_p b[i, r, p] exp(j 2 pi x[i, r, p] k),      k = 0 .. K-1
    x = S dt tau + f0 rho dt                          [cycles / sample]
    b = c g_t g_r exp(j 2 pi (f_k0 tau + f0 rho t_0))  (tau = tau_0[i] + tau_r[r])

which is a type-1 NUFFT (Dutt & Rokhlin 1993; here the exponential-of-
semicircle kernel of FINUFFT, Barnett, Magland & af Klinteberg 2019,
"A parallel non-uniform fast Fourier transform library based on an
'exponential of semicircle' kernel", SIAM J. Sci. Comput. 41(5)).  With the
output modes ``m = k - h`` (``h = K // 2``) centred as FINUFFT expects, the
strength of path ``p`` is ``b exp(j 2 pi h x)``, which still factors into a
Tx-row phasor times an Rx phasor, so only ``(T L + R) P`` phasors are formed
from float64 phases; the ``[T, R, P]`` products are formed one Tx row at a
time.

Cost per row pair: ``P w`` kernel evaluations (``w ~ 7`` at the default
tolerance) and one ``2K``-point FFT, against ``K P`` multiply-adds for the
exact matrix products of :class:`~sionna_mmir.fmcw.synthesize_factorised.FactorisedSynthesis`
(the reference twin; it is also the JVP here).  The vector-Jacobian product
is two type-2 NUFFTs per row pair (of ``conj(G)`` and ``k conj(G)``).

Accuracy: relative l2 error ~1e-5 per row against the exact sum (single
precision NUFFT, ``eps = 1e-5``), below the float32 rounding of the
renderer's delays (1e-3 rad of carrier phase at 4.5 m).
"""
from __future__ import annotations

import numpy as np

from .synthesize_factorised import FactorisedSynthesis, _cis, _in_groups

#: requested NUFFT tolerance (relative l2 per transform)
NUFFT_EPS = 1e-5
#: paths per block: the per-row ``[R, block]`` temporaries stay in cache
#: (one unchunked row of 2M facet paths thrashed memory: VJP 8x the forward)
BLOCK_PATHS = 1 << 15


def _wrap(cycles, out=None):
    """``2 pi (cycles mod 1)`` in ``[-pi, pi)`` as float32 (FINUFFT's point range).

    The points are small (``|x| < 1`` cycle per sample for any delay inside
    the unambiguous range), so float32 keeps them to ~1e-7 cycles per sample,
    2e-5 cycles over a 256-sample chirp.  ``out``: float32 buffer to write to.
    """
    x = np.asarray(cycles, dtype=np.float32)
    k = np.floor(x + np.float32(0.5))                         # nearest integer
    out = np.subtract(x, k, out=out)                          # may be ``x`` itself
    out *= np.float32(2 * np.pi)
    return out


class NufftSynthesis(FactorisedSynthesis):
    """Forward and VJP of the factorised synthesis by FINUFFT (JVP: exact, inherited).

    Same constructor and outputs as
    :class:`~sionna_mmir.fmcw.synthesize_factorised.FactorisedSynthesis`
    (``forward() -> complex64 [T, R, num_chirps, K]``, ``vjp(G) -> dict``);
    ``eps`` is the NUFFT tolerance.
    """

    def __init__(self, radar, inputs, eps: float = NUFFT_EPS, **kwargs):
        super().__init__(radar, inputs, **kwargs)
        self.eps = float(eps)
        self.h = self.K // 2
        self._prepare()

    # ------------------------------------------------------------ set-up
    def _prepare(self):
        """Per-row and per-Rx phasors (float64 phases) and point offsets (float32)."""
        x, h = self.x, self.h
        a = self.S * self.dt                                      # cycles/sample per second
        fh = self.fk0 + h * a                                     # strength frequency [Hz]
        tau0 = self._tau0(slice(None))                            # [T*L, P]
        self.row_t = np.repeat(np.arange(self.T), self.L)         # row -> t
        self.row_l = np.tile(np.arange(self.L), self.T)           # row -> l
        self.xt = (a * tau0).astype(np.float32)                   # [T*L, P] cycles/sample
        self.et = _cis(fh * tau0)                                 # [T*L, P] unit phasor
        self.gt = self._tx_gain(slice(None))                      # [T*L, P] float32
        xr = a * x.tau_r
        cr = fh * x.tau_r
        if self.moving:
            xr = xr + self.f0 * x.rho[None] * self.dt
            cr = cr + self.f0 * x.rho[None] * (self.t0 + h * self.dt)
        self.xr = xr.astype(np.float32)                           # [R, P]
        self.er = _cis(cr)                                        # [R, P] unit phasor
        self.cgr = (x.c[None] * x.g_r).astype(np.complex64)       # [R, P]

    def _plan(self, kind: int, n_trans: int):
        import finufft
        # spread_sort=0: the fine grid (2K points) sits in L1 cache, so sorting
        # the points buys nothing in 1-D (measured: type 1 0.54 -> 0.42 ms per
        # 32k points, same result to 2e-7)
        return finufft.Plan(kind, (self.K,), n_trans=n_trans, eps=self.eps, isign=1,
                            dtype=np.complex64, nthreads=1, modeord=0, spread_sort=0)

    def _run(self, fn, kind: int, n_trans: int) -> list:
        """``fn(items, plan)`` on the worker threads, one FINUFFT plan each.

        Plans are made and destroyed on this (the calling) thread: FFTW's
        planner is not thread-safe (only execution is); FINUFFT guards it,
        this keeps the workers to ``setpts`` / ``execute`` regardless.
        """
        items = self._items()
        n = max(1, min(self.workers, len(items)))
        plans = [self._plan(kind, n_trans) for _ in range(n)]
        groups = [(items[g::n], plans[g]) for g in range(n)]
        try:
            return _in_groups(lambda grp: fn(*grp[0]), groups, n)
        finally:
            del groups
            plans.clear()

    def _items(self):
        """``(row, path slice)`` work items, rows fastest."""
        P = self.P
        return [(i, slice(s, min(P, s + BLOCK_PATHS)))
                for s in range(0, P, BLOCK_PATHS) for i in range(self.T * self.L)]

    # ------------------------------------------------------------ forward
    def _points(self, i, sl, out=None):
        """FINUFFT points of Tx row ``i`` and every Rx element: float32 ``[R, n]``."""
        x = np.add(self.xt[i, sl][None], self.xr[:, sl], out=out)
        return _wrap(x, out=x)

    def forward(self):
        """ADC, complex64 ``[T, R, num_chirps, K]``."""
        B = self.er * self.cgr                                    # [R, P] Rx part of the strength

        def run(items, plan):
            out = np.zeros((self.T * self.L, self.R, self.K), np.complex64)
            pts_buf = np.empty((self.R, BLOCK_PATHS), np.float32)
            st_buf = np.empty((self.R, BLOCK_PATHS), np.complex64)
            for i, sl in items:
                n = sl.stop - sl.start
                pts = self._points(i, sl, out=pts_buf[:, :n])
                strength = np.multiply((self.gt[i, sl] * self.et[i, sl])[None], B[:, sl],
                                       out=st_buf[:, :n])
                for r in range(self.R):
                    plan.setpts(pts[r])
                    out[i, r] += plan.execute(strength[r])
            return out

        out = np.sum(self._run(run, 1, 1), axis=0)
        s = out.reshape(self.T, self.L, self.R, self.K).transpose(0, 2, 1, 3)
        return np.ascontiguousarray(np.broadcast_to(s, self.radar.adc_shape))

    # ------------------------------------------------------------ adjoint
    def vjp(self, G, delays: bool = True) -> dict:
        """Gradients for ``G = dL/d Re(s) + j dL/d Im(s)`` (``[T, R, num_chirps, K]``);
        the dict of :meth:`FactorisedSynthesis.vjp`.

        Per row pair ``Z0 = sum_k conj(G) E`` and ``Z1 = sum_k k conj(G) E``
        (``E`` the path's phasor) come from one two-transform type-2 NUFFT; the
        gradients are ``c: conj(sum g_t g_r Z0)``, ``g_t: Re(c g_r Z0)``,
        ``g_r: Re(c g_t Z0)``, ``tau: -2 pi Im(c g_t g_r W)`` with
        ``W = sum_k f_k conj(G) E = f_k0 Z0 + S dt Z1`` and, with motion,
        ``rho: -2 pi Im(c g_t g_r (T_tl W + f0 (t_0 Z0 + dt Z1)))``.
        With ``delays=False`` (nothing upstream needs the delay gradients, e.g.
        a fit of materials and beams only) ``Z1`` is not formed -- one
        transform per pair instead of two -- and the delay gradients are zeros.
        """
        T, R, P, K = self.T, self.R, self.P, self.K
        Gk = self._upstream(G)                                    # [K, T*L, R] conj(G)
        Gk = np.ascontiguousarray(Gk.transpose(1, 2, 0))          # [T*L, R, K]
        kw = np.arange(K, dtype=np.float32)
        fk0, a = np.float32(self.fk0), np.float32(self.S * self.dt)
        f0t0, f0dt = np.float32(self.f0 * self.t0), np.float32(self.f0 * self.dt)
        g_r = self.x.g_r.astype(np.float32)                       # [R, P]
        cgr = self.cgr                                            # [R, P] c g_r
        c = self.x.c.astype(np.complex64)[None]                   # [1, P]
        nv = 2 if delays else 1                                   # transforms per pair

        def run(items, plan):
            # delay accumulators only when they are formed (zeros added once below)
            acc = dict(cg=np.zeros(P, np.complex128), g_t=np.zeros((T, P)),
                       g_r=np.zeros((R, P)))
            if delays:
                acc.update(tau_t=np.zeros((T, P)), tau_r=np.zeros((R, P)),
                           tau_rate=np.zeros(P) if self.moving else None)
            F = np.empty((nv, K), np.complex64)
            pts_buf = np.empty((R, BLOCK_PATHS), np.float32)
            U_buf = np.empty((R, nv, BLOCK_PATHS), np.complex64)
            for i, sl in items:
                t, gt, n = self.row_t[i], self.gt[i, sl], sl.stop - sl.start
                pts = self._points(i, sl, out=pts_buf[:, :n])
                U = U_buf[:, :, :n]
                for r in range(R):
                    plan.setpts(pts[r])
                    F[0] = Gk[i, r]
                    if delays:
                        np.multiply(Gk[i, r], kw, out=F[1])
                    U[r] = plan.execute(F).reshape(nv, n)
                # Z0 = e Y with the row phasor e = E_t and Y = E_r U0: the sums
                # over Rx need Y only (cg, g_t), g_r needs Re(c g_t e Y)
                e, cs = self.et[i, sl], c[0, sl]
                Y = U[:, 0] * self.er[:, sl]                      # [R, n]
                Yv = Y.view(np.float32).reshape(R, n, 2)          # (re, im)
                Yg = np.multiply(Y, g_r[:, sl], out=U[:, 0])          # g_r Y (U0 is spent)
                eS = e * Yg.sum(axis=0)
                acc["cg"][sl] += gt * eS
                acc["g_t"][t, sl] += (cs * eS).real
                q = cs * e * gt                                   # [n]
                acc["g_r"][:, sl] += Yv[..., 0] * q.real - Yv[..., 1] * q.imag
                if not delays:
                    continue
                Z0 = e[None] * Y
                Z1 = e[None] * self.er[:, sl] * U[:, 1]
                cg = cgr[:, sl]
                W = fk0 * Z0 + a * Z1
                dtau = (-2 * np.pi) * gt * np.imag(cg * W)        # [R, n]
                acc["tau_t"][t, sl] += np.sum(dtau, axis=0)
                acc["tau_r"][:, sl] += dtau
                if self.moving:
                    Tl = np.float32(self.Tl[t, self.row_l[i]])
                    V = Tl * W + f0t0 * Z0 + f0dt * Z1
                    acc["tau_rate"][sl] += (-2 * np.pi) * gt * np.sum(np.imag(cg * V), axis=0)
            return acc

        parts = self._run(run, 2, nv)
        out = parts[0]
        for p in parts[1:]:
            for k, v in p.items():
                if v is not None:
                    out[k] += v
        if not delays:
            out.update(tau_t=np.zeros((T, P)), tau_r=np.zeros((R, P)),
                       tau_rate=np.zeros(P) if self.moving else None)
        out["c"] = np.conj(out.pop("cg"))
        return out
